"""Thermal model of the cylinder head: pure functions of (state, inputs, params); imports nothing above.

Start with :class:`ThermalParams` (model.yaml), :func:`flight_inputs`, :func:`coefficients` and
:func:`rk4_step`. The equations are written once, in :mod:`.equations` (docs/model.md).
"""

from ecu_monitor.model.atmosphere import air_density_kg_m3, isa_pressure_pa
from ecu_monitor.model.effects import (
    EFFECT_NAMES,
    EFFECT_TYPES,
    MIXTURE_SOURCES,
    AirspeedCooling,
    DensityCooling,
    Effects,
    MixtureCooling,
    MixtureIndex,
    SensorLag,
)
from ecu_monitor.model.heatmap import HeatMap, bilinear, reference_heat_map
from ecu_monitor.model.inputs import AMBIENT_COLUMNS, flight_inputs, input_columns
from ecu_monitor.model.params import (
    NOMINAL_TERMS,
    AirframeTerms,
    ThermalParams,
    airframe_warning,
    load_model,
    paper_table_a1,
    save_model,
)
from ecu_monitor.model.thermal import (
    EFFECT_COEFFICIENTS,
    STATE_NAMES,
    Coefficients,
    Drive,
    InputSeries,
    PackedCoefficients,
    coefficients,
    compute_drive,
    derivatives,
    initial_pade_state,
    pack_coefficients,
    rk4_step,
    scalar_coefficients,
    sensor_step,
    simulate,
    stack_coefficients,
    steady_state_cht,
    unpack_coefficients,
)

__all__ = [
    "AMBIENT_COLUMNS",
    "EFFECT_COEFFICIENTS",
    "EFFECT_NAMES",
    "EFFECT_TYPES",
    "MIXTURE_SOURCES",
    "NOMINAL_TERMS",
    "STATE_NAMES",
    "AirframeTerms",
    "AirspeedCooling",
    "Coefficients",
    "DensityCooling",
    "Drive",
    "Effects",
    "HeatMap",
    "InputSeries",
    "MixtureCooling",
    "MixtureIndex",
    "PackedCoefficients",
    "SensorLag",
    "ThermalParams",
    "air_density_kg_m3",
    "airframe_warning",
    "bilinear",
    "coefficients",
    "compute_drive",
    "derivatives",
    "flight_inputs",
    "initial_pade_state",
    "input_columns",
    "isa_pressure_pa",
    "load_model",
    "pack_coefficients",
    "paper_table_a1",
    "reference_heat_map",
    "rk4_step",
    "save_model",
    "scalar_coefficients",
    "sensor_step",
    "simulate",
    "stack_coefficients",
    "steady_state_cht",
    "unpack_coefficients",
]
