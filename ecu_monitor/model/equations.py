"""The model's equations, written once: the drive (heat map, g(z), effects) and the heat balance.

    C_w dT/dt = gamma_Q * H * (w - Q_SL0)  -  (1/gamma_D) * [ G (T - T_e) + (T^4 - T_e^4)/(alpha R_e) ]
    w' = (2/tau_w) (2 Q_SL0 - w)                     (first-order Pade delay of the heat path)
    H = g(z) * effects' heat factors,   g(z) = (p/p_SL)^a (T_SL/T_e)^b
    G = (1/R_Ce) * max(0.05, airspeed factor (mass flow) + engine-speed term) * density factor

Every function here is plain arithmetic on its arguments plus the primitives ``exp``, ``log``,
``expm1``, ``maximum``, ``minimum`` and ``finite_or``. So the same code runs on numpy arrays (a whole
flight, a swarm: :mod:`.thermal`) and, compiled by numba, inside the kernels, the filters and the step:
each function is ``register_jitable`` (a plain Python function called from Python, compiled into any
numba function that calls it, inlined so that it takes that caller's fast-math flags), and each
primitive declares both its meanings below (numpy's in Python, the ``math`` module's compiled). Nothing
else in the code base writes these equations; a test runs every kernel against
:func:`ecu_monitor.model.thermal.simulate` with every effect on.

Per-parameter-set coefficients travel as one indexable row ``coef`` (a :class:`Coefficients`, or a
row of the swarm kernel's matrix) read with the index constants below (``coef[C_W]``), so a new
coefficient needs no change to any kernel's argument list.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numba.extending import overload, register_jitable

from ecu_monitor.model.atmosphere import (
    ISA_PRESSURE_EXPONENT,
    KELVIN_OFFSET,
    LAPSE_RATE_K_PER_M,
    SEA_LEVEL_PRESSURE_PA,
    SEA_LEVEL_TEMPERATURE_K,
)

__all__ = [
    "PARAMETER_FIELDS",
    "Coefficients",
    "blend",
    "conditions",
    "derivatives",
    "dissipation",
    "drive",
    "isa_log_pressure_ratio",
    "lag_fraction",
    "probe_step",
    "rk4",
]

# --------------------------------------------------------------------------------------------------
# Primitives: numpy's in Python (arrays and scalars alike), the math module's when compiled
# --------------------------------------------------------------------------------------------------


def exp(x: Any) -> Any:
    """e**x (numpy)."""
    return np.exp(x)


def log(x: Any) -> Any:
    """Natural logarithm (numpy)."""
    return np.log(x)


def expm1(x: Any) -> Any:
    """e**x - 1, exact near 0 (numpy)."""
    return np.expm1(x)


def maximum(a: Any, b: Any) -> Any:
    """Elementwise larger of a and b (numpy)."""
    return np.maximum(a, b)


def minimum(a: Any, b: Any) -> Any:
    """Elementwise smaller of a and b (numpy)."""
    return np.minimum(a, b)


def finite_or(value: Any, default: Any) -> Any:
    """value where it is finite, else default (numpy)."""
    return np.where(np.isfinite(value), value, default)


# (the overloads take their arguments without annotations: numba compares the two signatures)
@overload(exp, inline="always")
def _exp_compiled(x):
    return lambda x: math.exp(x)


@overload(log, inline="always")
def _log_compiled(x):
    return lambda x: math.log(x)


@overload(expm1, inline="always")
def _expm1_compiled(x):
    return lambda x: math.expm1(x)


@overload(maximum, inline="always")
def _maximum_compiled(a, b):
    return lambda a, b: max(a, b)


@overload(minimum, inline="always")
def _minimum_compiled(a, b):
    return lambda a, b: min(a, b)


@overload(finite_or, inline="always")
def _finite_or_compiled(value, default):
    return lambda value, default: value if math.isfinite(value) else default


#: Decorator of the equations: plain functions in Python, compiled and inlined into any numba function
#: that calls them (so they take its fast-math flags: exact in the filters, SWARM_FASTMATH in the swarm).
equation = register_jitable(inline="always")


_AIR_GAS_CONSTANT = 287.053  # J/(kg K), as atmosphere.air_density_kg_m3
_LOG_DENSITY_OFFSET = math.log(SEA_LEVEL_PRESSURE_PA / _AIR_GAS_CONSTANT)


class Coefficients(NamedTuple):
    """Numeric form of ThermalParams for the kernels: each field a float or an array (P,) for a swarm.

    The per-parameter-set fields come first (:data:`PARAMETER_FIELDS`, read by index in the
    equations); then the radiation convention, the heat map and its breakpoints (shared by a swarm;
    heat_values_w has shape (n, m) or (P, n, m)). Effects that are off take their neutral values.
    """

    c_w: Any  # J/degC
    r_ce: Any  # degC/W
    radiative_conductance: Any  # 1/(alpha R_e), W/deg^4 (0: radiation off)
    tau_w: Any  # s
    a: Any  # altitude-scaling exponents of g(z) (0, 0: g off)
    b: Any
    airspeed_gain_per_mps: Any  # 1/(m/s)
    airspeed_reference_mps: Any  # m/s
    airspeed_floor: Any  # smallest conductance factor
    airspeed_prop_wash_mps: Any  # m/s, the cooling flow on the ground
    density_exponent: Any
    density_reference_kg_m3: Any
    mass_flow_exponent: Any  # mass_flow_cooling, dimensionless
    mass_flow_reference_kg_m3: Any
    speed_gain: Any  # engine_speed_cooling, dimensionless
    speed_reference_rpm: Any  # rev/min
    sensor_lag_s: Any  # s, 0 = no lag
    mixture_fraction: Any  # mixture_cooling
    mixture_onset: Any
    mixture_gain: Any  # mixture_index, 1/(index unit)
    mixture_reference: Any  # index unit
    radiation_offset_c: float  # 273.15 when T^4 is in Kelvin, 0 for the paper's preset
    heat_values_w: Any  # (n, m) or (P, n, m), W
    x_breakpoints: Any
    y_breakpoints: Any


#: The per-parameter-set fields of :class:`Coefficients`, in order (a swarm kernel's matrix rows).
PARAMETER_FIELDS: tuple[str, ...] = Coefficients._fields[: Coefficients._fields.index("radiation_offset_c")]
C_W = PARAMETER_FIELDS.index("c_w")
R_CE = PARAMETER_FIELDS.index("r_ce")
RADIATIVE = PARAMETER_FIELDS.index("radiative_conductance")
TAU_W = PARAMETER_FIELDS.index("tau_w")
A = PARAMETER_FIELDS.index("a")
B = PARAMETER_FIELDS.index("b")
AIR_GAIN = PARAMETER_FIELDS.index("airspeed_gain_per_mps")
AIR_REFERENCE = PARAMETER_FIELDS.index("airspeed_reference_mps")
AIR_FLOOR = PARAMETER_FIELDS.index("airspeed_floor")
AIR_WASH = PARAMETER_FIELDS.index("airspeed_prop_wash_mps")
DENSITY_EXPONENT = PARAMETER_FIELDS.index("density_exponent")
DENSITY_REFERENCE = PARAMETER_FIELDS.index("density_reference_kg_m3")
MASS_FLOW_EXPONENT = PARAMETER_FIELDS.index("mass_flow_exponent")
MASS_FLOW_REFERENCE = PARAMETER_FIELDS.index("mass_flow_reference_kg_m3")
SPEED_GAIN = PARAMETER_FIELDS.index("speed_gain")
SPEED_REFERENCE = PARAMETER_FIELDS.index("speed_reference_rpm")
SENSOR_LAG = PARAMETER_FIELDS.index("sensor_lag_s")
MIX_FRACTION = PARAMETER_FIELDS.index("mixture_fraction")
MIX_ONSET = PARAMETER_FIELDS.index("mixture_onset")
MIX_GAIN = PARAMETER_FIELDS.index("mixture_gain")
MIX_REFERENCE = PARAMETER_FIELDS.index("mixture_reference")


# --------------------------------------------------------------------------------------------------
# Drive: what the inputs do to the heat in and the conductance (held over a step)
# --------------------------------------------------------------------------------------------------


@equation
def isa_log_pressure_ratio(altitude_m: Any) -> Any:
    """log p/p_SL of the ISA troposphere at a pressure altitude (m)."""
    return ISA_PRESSURE_EXPONENT * log(maximum(1.0 - LAPSE_RATE_K_PER_M * altitude_m / SEA_LEVEL_TEMPERATURE_K, 1e-6))


@equation
def conditions(heat_x: Any, altitude_m: Any, airspeed_mps: Any, oat_c: Any, x_low: float, x_high: float) -> tuple:
    """Per-time quantities shared by every parameter set.

    Returns (log p/p_SL (ISA at the pressure altitude), log T_SL/T_e (measured OAT), log air density
    (kg/m^3), airspeed clipped at 0 (m/s), load: the first heat-map axis normalised to 0..1 over its
    breakpoints [x_low, x_high]).
    """
    log_pressure_ratio = isa_log_pressure_ratio(altitude_m)
    oat_k = oat_c + KELVIN_OFFSET
    log_temperature_ratio = log(SEA_LEVEL_TEMPERATURE_K / oat_k)
    log_density = _LOG_DENSITY_OFFSET + log_pressure_ratio - log(oat_k)
    load = minimum(maximum((heat_x - x_low) / (x_high - x_low), 0.0), 1.0)
    return log_pressure_ratio, log_temperature_ratio, log_density, maximum(airspeed_mps, 0.0), load


@equation
def blend(v00: Any, v01: Any, v10: Any, v11: Any, fx: Any, fy: Any) -> Any:
    """Bilinear blend of a heat-map cell's corners at fractional position (fx, fy)."""
    return (1.0 - fx) * ((1.0 - fy) * v00 + fy * v01) + fx * ((1.0 - fy) * v10 + fy * v11)


@equation
def drive(
    log_pressure_ratio: Any,
    log_temperature_ratio: Any,
    log_density: Any,
    airspeed_mps: Any,
    load: Any,
    engine_speed: Any,
    mixture_index: Any,
    coef: Any,
) -> tuple[Any, Any, Any]:
    """(altitude gain g(z), heat factor of the effects, conductance G in W/degC) of one parameter set.

    engine_speed: the heat map's second input (rev/min when the model has engine_speed_cooling).
    The effects (docs/model.md): airspeed_cooling (its air speed weighted by mass_flow_cooling) and
    engine_speed_cooling add their conductances, density_cooling scales G; mixture_cooling and
    mixture_index scale the heat in. Neutral coefficients (an effect off) give factors of exactly 1.
    """
    altitude_gain = exp(coef[A] * log_pressure_ratio + coef[B] * log_temperature_ratio)
    # airspeed_cooling: the cooling flow is at least the propeller wash; mass_flow_cooling weights it by density
    mass_flow_weight = exp(coef[MASS_FLOW_EXPONENT] * (log_density - log(coef[MASS_FLOW_REFERENCE])))
    cooling_speed = maximum(airspeed_mps, coef[AIR_WASH]) * mass_flow_weight
    airspeed_factor = maximum(coef[AIR_FLOOR], 1.0 + coef[AIR_GAIN] * (cooling_speed - coef[AIR_REFERENCE]))
    # density_cooling
    density_factor = exp(coef[DENSITY_EXPONENT] * (log_density - log(coef[DENSITY_REFERENCE])))
    # engine_speed_cooling: the propeller's slipstream, a conductance beside the ram air's
    flow_factor = maximum(0.05, airspeed_factor + coef[SPEED_GAIN] * (engine_speed / coef[SPEED_REFERENCE] - 1.0))
    # mixture_cooling: power enrichment at high load
    onset = coef[MIX_ONSET]
    enrichment = minimum(maximum((load - onset) / (1.0 - onset), 0.0), 1.0)
    # mixture_index: a logged lean/rich index (not logged: NaN, factor 1)
    mixture = exp(coef[MIX_GAIN] * (finite_or(mixture_index, coef[MIX_REFERENCE]) - coef[MIX_REFERENCE]))
    heat_factor = (1.0 - coef[MIX_FRACTION] * enrichment) * mixture
    return altitude_gain, heat_factor, flow_factor * density_factor / coef[R_CE]


# --------------------------------------------------------------------------------------------------
# Heat balance and its RK4 step
# --------------------------------------------------------------------------------------------------


@equation
def dissipation(cht_c: Any, ambient_c: Any, conductance: Any, radiative_conductance: Any, offset_c: float) -> Any:
    """Heat leaving the head, W: convection G (T - T_e) plus radiation (T^4 - T_e^4)/(alpha R_e)
    (temperatures shifted by offset_c inside T^4: 273.15 for Kelvin, 0 for the paper's degC)."""
    t = cht_c + offset_c
    e = ambient_c + offset_c
    return conductance * (cht_c - ambient_c) + radiative_conductance * (t * t * t * t - e * e * e * e)


@equation
def derivatives(
    cht_c: Any,
    pade_w: Any,
    q_sl0_w: Any,
    heat_gain: Any,
    ambient_c: Any,
    conductance: Any,
    c_w: Any,
    tau_w: Any,
    radiative_conductance: Any,
    offset_c: float,
    gamma_q: Any,
    gamma_d: Any,
) -> tuple[Any, Any]:
    """(dT/dt degC/s, dw/dt W/s); heat_gain = g(z) x the effects' heat factor."""
    heat_in = gamma_q * heat_gain * (pade_w - q_sl0_w)
    lost = dissipation(cht_c, ambient_c, conductance, radiative_conductance, offset_c)
    # written with reciprocals so that a compiled RK4 computes each once per step, not per stage
    return (heat_in - lost * (1.0 / gamma_d)) * (1.0 / c_w), (2.0 / tau_w) * (2.0 * q_sl0_w - pade_w)


@equation
def rk4(
    cht_c: Any,
    pade_w: Any,
    q_sl0_w: Any,
    heat_gain: Any,
    ambient_c: Any,
    conductance: Any,
    c_w: Any,
    tau_w: Any,
    radiative_conductance: Any,
    offset_c: float,
    gamma_q: Any,
    gamma_d: Any,
    dt_s: float,
) -> tuple[Any, Any]:
    """One RK4 step of (T, w) over dt_s with the drive held."""
    k1t, k1w = derivatives(cht_c, pade_w, q_sl0_w, heat_gain, ambient_c, conductance, c_w, tau_w,
                           radiative_conductance, offset_c, gamma_q, gamma_d)  # fmt: skip
    h = 0.5 * dt_s
    k2t, k2w = derivatives(cht_c + h * k1t, pade_w + h * k1w, q_sl0_w, heat_gain, ambient_c, conductance, c_w,
                           tau_w, radiative_conductance, offset_c, gamma_q, gamma_d)  # fmt: skip
    k3t, k3w = derivatives(cht_c + h * k2t, pade_w + h * k2w, q_sl0_w, heat_gain, ambient_c, conductance, c_w,
                           tau_w, radiative_conductance, offset_c, gamma_q, gamma_d)  # fmt: skip
    k4t, k4w = derivatives(cht_c + dt_s * k3t, pade_w + dt_s * k3w, q_sl0_w, heat_gain, ambient_c, conductance, c_w,
                           tau_w, radiative_conductance, offset_c, gamma_q, gamma_d)  # fmt: skip
    sixth = dt_s / 6.0
    return (
        cht_c + sixth * (k1t + 2.0 * k2t + 2.0 * k3t + k4t),
        pade_w + sixth * (k1w + 2.0 * k2w + 2.0 * k3w + k4w),
    )


@equation
def lag_fraction(lag_s: Any, dt_s: float) -> Any:
    """Fraction of the gap the probe closes in dt_s (exact first-order lag); lag 0 gives exactly 1."""
    return -expm1(-dt_s / maximum(lag_s, 1e-300))


@equation
def probe_step(probe_c: Any, cht_c: Any, fraction: Any) -> Any:
    """Probe temperature after one step, given :func:`lag_fraction`."""
    return probe_c + fraction * (cht_c - probe_c)
