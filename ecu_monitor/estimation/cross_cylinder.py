"""The cross-cylinder symptom: each cylinder's model-deviation symptom minus the median of the others'.

The cylinders of one engine share their inputs (throttle, rpm, altitude, airspeed, air temperature),
so most of what each cylinder's model gets wrong is common to all of them: the operating point's
unmodelled cooling (airspeed, density, mixture), the probe lag at a power change, the day. A
degradation of one cylinder (gamma_Q or gamma_D > 1 in one head) is not common. Subtracting the
median of the other cylinders' symptoms removes the common part::

    c_i(t) = s_i(t) - median_{j != i, j usable} s_j(t)          (degC/s for a degC/s symptom)

so the nominal c_i is much quieter than s_i and a lower CUSUM threshold detects a one-cylinder
degradation sooner at the same false-alarm rate (docs/detection_isolation.md, section 10; measured in
docs/results/cylinders.md). The median (not the mean) keeps one degraded or misbehaving cylinder out
of the others' reference: with four cylinders, one degraded cylinder moves the reference of the three
healthy ones by at most the spread of the healthy ones. What it cannot see: a degradation common to
every cylinder (it cancels), which the per-cylinder detectors on their own symptoms still watch.

A cylinder whose symptom is not usable (nan: not NOMINAL-able, not started) gets nan, and is left out
of the others' reference; with no usable other cylinder the result is nan (the detector skips it).
:func:`cross_cylinder_step` (one step, live) and :func:`cross_cylinder_symptoms` (whole arrays, batch
replay) give bit-identical results.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numba
import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import ParameterError

__all__ = ["cross_cylinder_step", "cross_cylinder_symptoms"]


def cross_cylinder_step(symptoms: Sequence[float]) -> list[float]:
    """Each cylinder's symptom minus the median of the other cylinders' finite symptoms (nan where the
    cylinder's own symptom is nan or no other cylinder has one); one instant, any number of cylinders."""
    usable = sorted((x, i) for i, x in enumerate(symptoms) if x == x)  # x == x: not nan
    ordered = [x for x, _ in usable]
    position = {i: p for p, (_, i) in enumerate(usable)}
    others = len(ordered) - 1
    out = [math.nan] * len(symptoms)
    if others < 1:
        return out
    mid = others // 2
    for i, p in position.items():
        # the others, sorted, are ``ordered`` without position p: their k-th is ordered[k + (k >= p)]
        upper = ordered[mid + (mid >= p)]
        if others % 2:
            reference = upper
        else:
            lower = ordered[mid - 1 + (mid - 1 >= p)]
            reference = (lower + upper) * 0.5
        out[i] = ordered[p] - reference
    return out


@numba.njit(cache=True)
def _cross(symptoms: NDArray[np.float64]) -> NDArray[np.float64]:  # pragma: no cover - compiled
    count, steps = symptoms.shape
    out = np.full((count, steps), np.nan)
    others = np.empty(count)
    for k in range(steps):
        for i in range(count):
            own = symptoms[i, k]
            if math.isnan(own):
                continue
            n = 0
            for j in range(count):
                x = symptoms[j, k]
                if j != i and not math.isnan(x):
                    others[n] = x
                    n += 1
            if n == 0:
                continue
            ordered = np.sort(others[:n])
            mid = n // 2
            reference = ordered[mid] if n % 2 else (ordered[mid - 1] + ordered[mid]) * 0.5
            out[i, k] = own - reference
    return out


def cross_cylinder_symptoms(symptoms: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`cross_cylinder_step` at every step of ``symptoms`` (cylinders x steps, nan = not usable),
    compiled; returns an array of the same shape."""
    values = np.ascontiguousarray(symptoms, dtype=np.float64)
    if values.ndim != 2:
        raise ParameterError(f"cross_cylinder_symptoms: expected (cylinders, steps), got shape {values.shape}")
    return _cross(values)
