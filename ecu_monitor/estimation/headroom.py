"""Thermal headroom: the time left at the current power request before the CHT reaches its limit.

From the current estimate (CHT, the Pade state of the heat path and the current gamma estimates) the
model is integrated forward with the inputs held (the pilot keeps the present throttle, speed and
altitude) by the model's own RK4 step (``step_s``, 2 s by default: the thermal time constant is
~85 s, the heat-path delay 6 s, so RK4 at 2 s is accurate to well under 0.1 degC). The crossing time
is interpolated linearly inside the step. With heat held constant the CHT approaches its steady
state monotonically (first-order wall, all-pass first-order delay), so when the steady state is
below the limit the answer is "not limited" (``cap_s``) without integrating.

Used by the service (Health_Isolation.ThermalHeadroom, ChtLimitMargin) and checked against the truth
plant in :mod:`ecu_monitor.research.evaluation`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from ecu_monitor.errors import EstimationError
from ecu_monitor.model import (
    Coefficients,
    Drive,
    InputSeries,
    ThermalParams,
    coefficients,
    compute_drive,
    rk4_step,
    steady_state_cht,
)

__all__ = ["Headroom", "thermal_headroom"]


class Headroom(NamedTuple):
    """time_to_limit_s: seconds until CHT reaches the limit at the held inputs (0 if already there,
    cap_s if not within cap_s). steady_state_cht_c: where CHT settles at these inputs, degC.
    margin_c: limit minus current CHT, degC. limited: the limit is reached within cap_s."""

    time_to_limit_s: float
    steady_state_cht_c: float
    margin_c: float
    limited: bool


def thermal_headroom(
    cht_c: float,
    pade_w: float | None,
    inputs: InputSeries,
    params: ThermalParams,
    *,
    gamma_q: float = 1.0,
    gamma_d: float = 1.0,
    limit_c: float | None = None,
    cap_s: float,
    step_s: float = 2.0,
    coeffs: Coefficients | None = None,
    drive: Drive | None = None,
) -> Headroom:
    """Headroom at the held ``inputs`` (floats) from the state (cht_c degC, pade_w W; None = the
    heat path in steady state at these inputs). ``limit_c`` defaults to ``params.cht_limit_c``;
    pass ``coeffs`` (= coefficients(params)) to skip recomputing them at every call, and ``drive``
    (the model's drive at ``inputs``, floats) when it is at hand."""
    _check(cht_c, gamma_q, gamma_d, cap_s, step_s)
    coeffs = coeffs if coeffs is not None else coefficients(params)
    limit = params.cht_limit_c if limit_c is None else float(limit_c)
    if drive is None:
        drive = _drive_at(inputs, coeffs)
    steady = float(steady_state_cht(drive, coeffs, gamma_q, gamma_d))
    margin = limit - cht_c
    if margin <= 0.0:
        return Headroom(0.0, steady, margin, True)
    if steady < limit:
        return Headroom(cap_s, steady, margin, False)
    temp = float(cht_c)
    pade = 2.0 * drive.q_sl0_w if pade_w is None else float(pade_w)
    elapsed = 0.0
    while elapsed < cap_s:
        new_temp, pade = rk4_step(temp, pade, drive, coeffs, step_s, gamma_q, gamma_d)
        new_temp = float(new_temp)
        if new_temp >= limit:
            fraction = (limit - temp) / (new_temp - temp) if new_temp > temp else 1.0
            crossing = elapsed + fraction * step_s
            if crossing <= cap_s:
                return Headroom(crossing, steady, margin, True)
            break
        temp = new_temp
        elapsed += step_s
    return Headroom(cap_s, steady, margin, False)


def _check(cht_c: float, gamma_q: float, gamma_d: float, cap_s: float, step_s: float) -> None:
    if not (math.isfinite(cht_c) and math.isfinite(gamma_q) and math.isfinite(gamma_d)) or gamma_d <= 0.0:
        raise EstimationError(f"thermal_headroom: bad state (cht {cht_c!r}, gamma_q {gamma_q!r}, gamma_d {gamma_d!r})")
    if not (cap_s > 0.0 and step_s > 0.0):
        raise EstimationError("thermal_headroom: cap_s and step_s must be positive")


def _drive_at(inputs: InputSeries, coeffs: Coefficients) -> Drive:
    """The model's drive at one operating point, as floats."""
    return Drive(*(float(v) for v in compute_drive(inputs, coeffs)))
