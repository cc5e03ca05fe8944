"""PSO identification of the thermal model from flight logs (the paper's method, vectorised over the swarm).

Start with :func:`identify` (flights -> :class:`IdentificationResult`), :func:`flight_errors` and
:func:`simulate_flight`; the search space is :class:`ParameterSpace` (:func:`default_space`).
"""

from ecu_monitor.identify.fit import IdentificationResult, identify, polish
from ecu_monitor.identify.objective import SwarmObjective
from ecu_monitor.identify.problem import (
    DEFAULT_FREE,
    IDENTIFICATION_DT_S,
    REFERENCE_DT_S,
    ErrorStats,
    FlightGrid,
    ParameterSpace,
    default_space,
    flight_errors,
    heat_map_breakpoints,
    model_inputs,
    prepare_flight,
    simulate_flight,
    visited_weight_s,
)
from ecu_monitor.identify.pso import PsoRun, PsoSettings, constriction_factor, minimise

__all__ = [
    "DEFAULT_FREE",
    "IDENTIFICATION_DT_S",
    "REFERENCE_DT_S",
    "ErrorStats",
    "FlightGrid",
    "IdentificationResult",
    "ParameterSpace",
    "PsoRun",
    "PsoSettings",
    "SwarmObjective",
    "constriction_factor",
    "default_space",
    "flight_errors",
    "heat_map_breakpoints",
    "identify",
    "minimise",
    "model_inputs",
    "polish",
    "prepare_flight",
    "simulate_flight",
    "visited_weight_s",
]
