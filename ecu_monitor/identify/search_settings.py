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

# effect parameter name -> (Coefficients field, lower, upper, log-scaled): each effect declares its own
# (the mixture_index gain's range is the source's, default_space)
_EFFECT_FIELDS: dict[str, tuple[str, float, float, bool]] = {
    f"effects.{name}.{parameter}": (spec.coefficient, *spec.search, False)
    for name, kind in EFFECT_TYPES.items()
    for parameter, spec in kind.PARAMETERS.items()
}
_EFFECT_TYPES: dict[str, type] = dict(EFFECT_TYPES)
_SCALE_PARAMETERS = {"c_w", "r_ce", "alpha_r_e", "heat_map"}
_KNOWN_FREE = {"c_w", "r_ce", "tau_w", "alpha_r_e", "a", "b", "heat_map", *_EFFECT_FIELDS}
