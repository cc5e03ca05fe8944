"""The numbers of the identification's search space: default free parameters, bounds, priors, effect fields."""

from __future__ import annotations

from ecu_monitor.model.effects import EFFECT_TYPES

#: Model free parameters by default (r_ce anchors the scale, a and b are fixed: see module doc).
DEFAULT_FREE: tuple[str, ...] = ("c_w", "tau_w", "alpha_r_e", "heat_map")
#: Largest radiation fraction searched (1 would mean no convection at the reference point).
MAX_RADIATION_FRACTION = 0.99
#: Bounds of the convective time constant C_w R_Ce, s (wide: engines from model aircraft to radials).
TIME_CONSTANT_BOUNDS_S = (0.5, 20000.0)
#: A coordinate closer than this fraction of its range (in search units) to a bound is reported.
BOUND_TOLERANCE = 0.01
#: Heat-map prior: standard deviation of a second difference between neighbouring breakpoints, as a
#: fraction of the largest observed temperature rise, and of a fall of the heat with rising power, degC.
HEAT_SMOOTH_SIGMA = 0.5
HEAT_MONOTONE_SIGMA_C = 2.0
#: A heat-map breakpoint whose total bilinear weight over the training flights is below this many
#: seconds of flight is "not visited": it is not identified and takes the value of the nearest visited
#: one (its base value would be a guess, and even a few seconds of weight on a wrong guess bias the fit).
MIN_VISIT_S = 20.0
#: Prior penalty scale: one prior standard deviation costs as much as 1 degC^2 of mean squared error.
PRIOR_SCALE_C = 1.0

# effect parameter name -> (Coefficients field, lower, upper, log-scaled)
_EFFECT_FIELDS: dict[str, tuple[str, float, float, bool]] = {
    "effects.airspeed_cooling.gain_per_mps": ("airspeed_gain_per_mps", -0.05, 0.1, False),
    "effects.airspeed_cooling.reference_mps": ("airspeed_reference_mps", 1.0, 200.0, False),
    "effects.airspeed_cooling.floor": ("airspeed_floor", 0.05, 1.0, False),
    "effects.density_cooling.exponent": ("density_exponent", 0.0, 1.5, False),
    "effects.density_cooling.reference_kg_m3": ("density_reference_kg_m3", 0.3, 1.6, False),
    "effects.sensor_lag.time_constant_s": ("sensor_lag_s", 0.0, 60.0, False),
    "effects.mixture_cooling.fraction": ("mixture_fraction", 0.0, 0.6, False),
    "effects.mixture_cooling.onset": ("mixture_onset", 0.0, 0.95, False),
    "effects.airspeed_cooling.prop_wash_mps": ("airspeed_prop_wash_mps", 0.0, 60.0, False),
    "effects.mixture_index.gain": ("mixture_gain", -0.01, 0.01, False),  # default_space: per source
    "effects.mixture_index.reference": ("mixture_reference", 0.0, 1200.0, False),
}
_EFFECT_TYPES: dict[str, type] = EFFECT_TYPES
_SCALE_PARAMETERS = {"c_w", "r_ce", "alpha_r_e", "heat_map"}
_KNOWN_FREE = {"c_w", "r_ce", "tau_w", "alpha_r_e", "a", "b", "heat_map", *_EFFECT_FIELDS}
