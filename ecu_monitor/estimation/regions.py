"""The operating region and flight phase of a sample: the one rule the detector's reference (per region,
learned by ``ecu-monitor calibrate``), the isolation's "not isolable" flag and the flight summaries use.

A sample's region is decided from what the service holds at that instant (causal: no look-ahead, so the
live step and an offline summary give the same answer)::

    start         the first START_S seconds after engine start (the head warms from cold)
    ground        airspeed below GROUND_AIRSPEED_MPS (taxi, run-up, idle)
    low power     airborne, power fraction below LOW_POWER (descent, idle glide)
    cruise power  airborne, power fraction from LOW_POWER to below HIGH_POWER
    high power    airborne, power fraction at or above HIGH_POWER (take-off, climb)

The power fraction is the position of the heat map's power input (its x axis: throttle_pct, or
fuel_flow_lph on a log without throttle) between the first and last x breakpoint, clipped to [0, 1].
A missing airspeed (nan) counts as airborne; a missing power input puts an airborne sample in ``cruise
power`` (the region whose reference is the broadest).

The functions are scalar, compiled by numba (the step calls them; ``.py_func`` is the plain Python);
:func:`regions_of` applies the same function to whole arrays (offline summaries).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.model.kernels import njit

__all__ = [
    "GROUND_AIRSPEED_MPS",
    "HIGH_POWER",
    "LOW_POWER",
    "REGION_COUNT",
    "REGION_CRUISE",
    "REGION_GROUND",
    "REGION_HIGH",
    "REGION_LOW",
    "REGION_NAMES",
    "REGION_START",
    "START_S",
    "isolable_region",
    "power_fraction",
    "region_of",
    "regions_of",
]

#: Seconds after engine start that belong to the start region (the head's warm-up from cold), s.
START_S = 300.0
#: Below this airspeed the aircraft is on the ground, m/s.
GROUND_AIRSPEED_MPS = 12.0
#: Airborne power fraction below which the engine is at low power (descent), 1.
LOW_POWER = 0.4
#: Airborne power fraction at and above which the engine is at high power (take-off, climb), 1.
HIGH_POWER = 0.75

REGION_START = 0
REGION_GROUND = 1
REGION_LOW = 2
REGION_CRUISE = 3
REGION_HIGH = 4
#: The regions' names, by index.
REGION_NAMES: tuple[str, ...] = ("start", "ground", "low power", "cruise power", "high power")
#: How many regions there are.
REGION_COUNT = len(REGION_NAMES)


@njit(nogil=False)
def power_fraction(x: float, x_low: float, x_high: float) -> float:
    """The power input ``x`` (the heat map's x-axis unit: throttle %, fuel flow L/h) as a fraction of the
    range [x_low, x_high] (its first and last breakpoint), clipped to [0, 1]; nan when x is nan or the
    range is empty."""
    if math.isnan(x) or not x_high > x_low:
        return math.nan
    f = (x - x_low) / (x_high - x_low)
    return min(1.0, max(0.0, f))


@njit(nogil=False)
def region_of(elapsed_s: float, airspeed_mps: float, power: float) -> int:
    """The region index (see :data:`REGION_NAMES`) of a sample ``elapsed_s`` seconds after engine start
    at airspeed ``airspeed_mps`` (m/s, nan = unknown: airborne) and power fraction ``power`` (1, from
    :func:`power_fraction`; nan = unknown: cruise power)."""
    if elapsed_s < START_S:
        return REGION_START
    if airspeed_mps < GROUND_AIRSPEED_MPS:  # nan compares False: airborne
        return REGION_GROUND
    if power < LOW_POWER:
        return REGION_LOW
    if power >= HIGH_POWER:
        return REGION_HIGH
    return REGION_CRUISE


@njit(nogil=False)
def isolable_region(region: int) -> bool:
    """Whether gamma_Q and gamma_D can be told apart in this region at all: only airborne at cruise or
    high power, where the heat into the head is large enough that a change of it (gamma_Q) and a change
    of the head's dissipation (gamma_D) leave different marks. At start, on the ground and at low power
    the heat input is small and the two are confounded."""
    return REGION_CRUISE <= region <= REGION_HIGH


def regions_of(elapsed_s: NDArray[Any], airspeed_mps: NDArray[Any], power: NDArray[Any]) -> NDArray[np.int64]:
    """:func:`region_of` of every sample of equal-length arrays (s, m/s, fraction)."""
    e = np.asarray(elapsed_s, dtype=float)
    v = np.asarray(airspeed_mps, dtype=float)
    p = np.asarray(power, dtype=float)
    out = np.empty(e.shape, dtype=np.int64)
    for i in range(e.size):
        out.flat[i] = region_of(float(e.flat[i]), float(v.flat[i]), float(p.flat[i]))
    return out
