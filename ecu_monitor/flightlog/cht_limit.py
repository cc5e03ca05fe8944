"""The hottest CHT of a flight and the time it spends above an engine's CHT limit."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ecu_monitor.errors import FlightLogError
from ecu_monitor.flightlog.cylinders import _cylinder_number, cylinder_columns
from ecu_monitor.flightlog.log import FlightLog


@dataclass(frozen=True)
class ChtPeak:
    """The highest CHT of a log: ``value_c`` (degC) in ``column`` (``cht3_c``, or ``cht_c`` when the log
    has no per-cylinder columns), ``cylinder`` (1-based, None for ``cht_c``) at ``time_s`` (s)."""

    value_c: float
    column: str
    cylinder: int | None
    time_s: float


def _cht_channels(log: FlightLog) -> list[str]:
    return cylinder_columns(log, "cht") or ["cht_c"]


def cht_peak(log: FlightLog) -> ChtPeak:
    """The hottest reading of any cylinder (of ``cht_c`` if the log has no per-cylinder columns)."""
    best: ChtPeak | None = None
    for column in _cht_channels(log):
        values = log[column]
        if np.all(np.isnan(values)):
            continue
        k = int(np.nanargmax(values))
        if best is None or values[k] > best.value_c:
            cylinder = _cylinder_number(column) if column != "cht_c" else None
            best = ChtPeak(float(values[k]), column, cylinder, float(log.time_s[k]))
    if best is None:
        raise FlightLogError(f"{log.source}: no CHT value to take a peak of")
    return best


def seconds_above(log: FlightLog, limit_c: float) -> float:
    """Time during which the hottest cylinder (``cht_c`` without per-cylinder columns) reads above
    ``limit_c``, s: the sum of the sample intervals that start above it."""
    stack = np.vstack([log[c] for c in _cht_channels(log)])
    hottest = np.max(np.where(np.isnan(stack), -np.inf, stack), axis=0)
    steps = np.diff(log.time_s, append=log.time_s[-1])
    return float(np.sum(steps[hottest > limit_c]))


def cht_limit_warning(log: FlightLog, limit_c: float) -> str | None:
    """One line saying how far ``log`` exceeds the engine's CHT limit ``limit_c`` (degC), or None.

    For identification and the service's configuration: a model whose limit sits below what the
    engine routinely reads would report no headroom for most of a normal flight.
    """
    if not math.isfinite(limit_c):
        raise FlightLogError(f"{log.source}: CHT limit must be a finite number of degC, got {limit_c!r}")
    peak = cht_peak(log)
    if peak.value_c <= limit_c:
        return None
    above = seconds_above(log, limit_c)
    where = "cht_c" if peak.cylinder is None else f"cylinder {peak.cylinder}"
    share = 100.0 * above / log.duration_s if log.duration_s > 0 else 100.0
    return (
        f"{log.source}: CHT reaches {peak.value_c:.1f} degC ({where} at {peak.time_s:.0f} s), above the limit"
        f" {limit_c:g} degC for {above:.0f} s ({share:.0f} % of the flight)"
    )
