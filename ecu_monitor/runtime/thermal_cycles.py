"""Thermal cycles of the CHT history: an online reversal filter and the rainflow count (ASTM E1049).

The CHT history is not stored sample by sample: the hysteresis filter keeps only turning points of at
least the hysteresis (degC); rainflow over them counts the cycles larger than the hysteresis as over the
full history, in bounded memory for a 16-hour flight.
"""

from __future__ import annotations

import itertools
import math
from array import array

import rainflow

__all__ = ["CYCLE_BIN_EDGES_C", "ReversalFilter", "count_cycles", "pack_reversals", "unpack_reversals"]

#: Lower edges of the cycle-range histogram bins, degC (the last bin is open-ended).
CYCLE_BIN_EDGES_C: tuple[float, ...] = (5.0, 10.0, 20.0, 50.0, 100.0)


def count_cycles(reversals: list[float]) -> tuple[float, dict[str, float]]:
    """Rainflow count (ASTM E1049, half cycles as 0.5) of a CHT series: (total cycles, histogram).

    The histogram maps a bin label ``"lo-hi"`` (degC of cycle range, ``"lo+"`` for the last) to cycles;
    cycles smaller than the first edge are not counted.
    """
    labels = [f"{lo:g}-{hi:g}" for lo, hi in itertools.pairwise(CYCLE_BIN_EDGES_C)]
    labels.append(f"{CYCLE_BIN_EDGES_C[-1]:g}+")
    histogram = dict.fromkeys(labels, 0.0)
    if len(reversals) < 2:
        return 0.0, histogram
    total = 0.0
    for cycle_range, _mean, count, _start, _end in rainflow.extract_cycles(reversals):
        if cycle_range < CYCLE_BIN_EDGES_C[0]:
            continue
        index = sum(1 for edge in CYCLE_BIN_EDGES_C if cycle_range >= edge) - 1
        histogram[labels[index]] += count
        total += count
    return total, histogram


class ReversalFilter:
    """Online turning-point filter with hysteresis: keeps the reversals of a series, bounded memory."""

    def __init__(self, hysteresis: float) -> None:
        self.hysteresis = hysteresis
        self._points: list[float] = []
        self._direction = 0  # +1 rising, -1 falling, 0 not yet known
        self._candidate = math.nan

    def add(self, value: float) -> None:
        """Feed one sample (NaN is ignored)."""
        if not math.isfinite(value):
            return
        if not self._points:
            self._points.append(value)
            self._candidate = value
            return
        if self._direction == 0:
            if abs(value - self._points[0]) >= self.hysteresis:
                self._direction = 1 if value > self._points[0] else -1
            self._candidate = value
            return
        if (value - self._candidate) * self._direction > 0:
            self._candidate = value  # still going the same way: a new extreme
        elif abs(value - self._candidate) >= self.hysteresis:
            self._points.append(self._candidate)  # turned by more than the hysteresis: a reversal
            self._candidate = value
            self._direction = -self._direction

    def restore(self, points: list[float]) -> None:
        """Continue from the output of :meth:`points` (a flight resumed after a restart)."""
        self._points = list(points[:-1]) if len(points) >= 2 else list(points)
        self._candidate = points[-1] if points else math.nan
        self._direction = 0 if len(points) < 2 else (1 if points[-1] > points[-2] else -1)

    def points(self) -> list[float]:
        """The reversal points so far, ending with the latest extreme."""
        if not self._points:
            return []
        if self._direction == 0:
            return [self._points[0]]
        return [*self._points, self._candidate]


def unpack_reversals(blob: bytes | None) -> list[float]:
    """Reversal points (degC) from their stored bytes (float64 array); none for NULL."""
    values = array("d")
    if blob:
        values.frombytes(blob)
    return values.tolist()


def pack_reversals(points: list[float]) -> bytes:
    """Reversal points (degC) as stored bytes (float64 array)."""
    return array("d", points).tobytes()
