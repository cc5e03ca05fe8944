"""Thermal model of the cylinder head: pure functions of (state, inputs, params); imports nothing above.

Start with :class:`ThermalParams` (model.yaml), :func:`coefficients` and :func:`rk4_step`.
"""

from ecu_monitor.model.atmosphere import air_density_kg_m3, isa_pressure_pa
from ecu_monitor.model.effects import (
    EFFECT_NAMES,
    AirspeedCooling,
    DensityCooling,
    Effects,
    MixtureCooling,
    SensorLag,
)
from ecu_monitor.model.heatmap import HeatMap, bilinear, reference_heat_map
from ecu_monitor.model.params import ThermalParams, load_model, paper_table_a1, save_model
from ecu_monitor.model.thermal import (
    STATE_NAMES,
    Coefficients,
    Drive,
    InputSeries,
    coefficients,
    compute_drive,
    derivatives,
    initial_pade_state,
    rk4_step,
    sensor_step,
    simulate,
    stack_coefficients,
    steady_state_cht,
)

__all__ = [
    "EFFECT_NAMES",
    "STATE_NAMES",
    "AirspeedCooling",
    "Coefficients",
    "DensityCooling",
    "Drive",
    "Effects",
    "HeatMap",
    "InputSeries",
    "MixtureCooling",
    "SensorLag",
    "ThermalParams",
    "air_density_kg_m3",
    "bilinear",
    "coefficients",
    "compute_drive",
    "derivatives",
    "initial_pade_state",
    "isa_pressure_pa",
    "load_model",
    "paper_table_a1",
    "reference_heat_map",
    "rk4_step",
    "save_model",
    "sensor_step",
    "simulate",
    "stack_coefficients",
    "steady_state_cht",
]
