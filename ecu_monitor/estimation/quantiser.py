"""The quantised CHT sensor: the ECU reports the head temperature rounded to a step of c degC (1 degC).

An EKF needs a differentiable sensor model, so the round function is replaced by the paper's
sigmoid staircase (Eq. 27-28), generalised to a step ``c``::

    u    = x / c
    h(x) = c * ( floor(u) + s ),        s = sigma(a (u - floor(u) - b)),   sigma(z) = 1 / (1 + e^-z)
    dh/dx = a s (1 - s)

With a = 100 and b = 0.5, h is within 1e-20 degC of round(x) except within ~0.05 c of a half-step,
where it climbs from one level to the next with slope up to a/4 = 25. The slope is almost exactly
zero elsewhere: an EKF using this model learns from the measurement only while its estimate sits
near a level boundary (docs/estimators.md).

Everything here is scalar ``math`` on Python floats, so numba compiles the same functions into the
filters' compiled callers (``register_jitable``).
"""

from __future__ import annotations

import math

from numba.extending import register_jitable

__all__ = [
    "level_of",
    "quantise",
    "reset_value",
    "sensor_model",
    "sensor_slope",
    "sigmoid",
]


@register_jitable
def sigmoid(z: float) -> float:
    """Logistic function 1 / (1 + e^-z), evaluated without overflow for large |z|."""
    if z >= 0.0:
        return 1.0 / (1.0 + math.exp(-z))
    e = math.exp(z)
    return e / (1.0 + e)


@register_jitable
def sensor_model(x_c: float, a: float, b: float, c: float) -> float:
    """Sigmoid staircase h(x) (degC): the smooth stand-in for rounding x to a step of c degC."""
    u = x_c / c
    base = math.floor(u)
    return c * (base + sigmoid(a * (u - base - b)))


@register_jitable
def sensor_slope(x_c: float, a: float, b: float, c: float) -> float:
    """dh/dx of :func:`sensor_model` (dimensionless): a s (1 - s)."""
    u = x_c / c
    s = sigmoid(a * (u - math.floor(u) - b))
    return a * s * (1.0 - s)


@register_jitable
def quantise(x_c: float, c: float) -> float:
    """What the ECU reports: x rounded to the nearest multiple of c (halves away from the level below)."""
    return c * math.floor(x_c / c + 0.5)


@register_jitable
def level_of(z_c: float, c: float) -> float:
    """Index of the quantisation level of a reading (a float holding an integer)."""
    return float(math.floor(z_c / c + 0.5))


@register_jitable
def reset_value(level_new: float, level_old: float, c: float, boundary: bool) -> float:
    """Where CBEKF-AU re-initialises the estimate when the reading moves from level_old to level_new.

    midpoint (paper): the centre of the new interval, level_new * c.
    boundary (ours): the edge of the new interval the true temperature has just crossed, i.e.
    (level_new - 1/2) c when the reading rose and (level_new + 1/2) c when it fell. A jump of more
    than one level (noise, a gap) still uses the near edge of the new interval.
    """
    if not boundary:
        return level_new * c
    if level_new > level_old:
        return (level_new - 0.5) * c
    return (level_new + 0.5) * c
