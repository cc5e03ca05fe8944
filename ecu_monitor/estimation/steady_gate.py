"""The steady-operation gate of the detector: the CUSUM holds through power transients and on the ground."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import ConfigError

__all__ = ["GateSettings", "SteadyGate", "steady_mask"]


@dataclass(frozen=True)
class GateSettings:
    """When the test may accumulate: not within ``window_s`` of a throttle change larger than
    ``throttle_change_pct`` (range of the throttle over the trailing window, %-points), and not below
    ``min_airspeed_mps`` (on the ground). The largest nominal excursions of the symptom follow large
    power changes (probe lag, mixture and airspeed effects the model lacks) and the ground idle."""

    throttle_change_pct: float = 10.0
    window_s: float = 120.0
    min_airspeed_mps: float = 10.0

    def __post_init__(self) -> None:
        for name in ("throttle_change_pct", "window_s", "min_airspeed_mps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
                raise ConfigError(f"gate.{name}: expected a number >= 0, got {value!r}")
            object.__setattr__(self, name, float(value))


class SteadyGate:
    """Live form of :func:`steady_mask`: ``update(t_s, throttle_pct, airspeed_mps) -> steady``.

    Keeps monotonic queues of the throttle over the trailing window (amortised O(1) per sample)."""

    def __init__(self, settings: GateSettings) -> None:
        self.settings = settings
        self._max: deque[tuple[float, float]] = deque()
        self._min: deque[tuple[float, float]] = deque()

    def update(self, t_s: float, throttle_pct: float, airspeed_mps: float) -> bool:
        """True when the inputs have been steady over the window and the aircraft is flying."""
        g = self.settings
        while self._max and self._max[-1][1] <= throttle_pct:
            self._max.pop()
        self._max.append((t_s, throttle_pct))
        while self._min and self._min[-1][1] >= throttle_pct:
            self._min.pop()
        self._min.append((t_s, throttle_pct))
        while self._max[0][0] < t_s - g.window_s:
            self._max.popleft()
        while self._min[0][0] < t_s - g.window_s:
            self._min.popleft()
        spread = self._max[0][1] - self._min[0][1]
        return bool(spread <= g.throttle_change_pct and airspeed_mps >= g.min_airspeed_mps)


def steady_mask(
    time_s: NDArray[np.float64],
    throttle_pct: NDArray[np.float64],
    airspeed_mps: NDArray[np.float64],
    settings: GateSettings,
) -> NDArray[np.bool_]:
    """Per-sample steady flag over a flight (what :class:`SteadyGate` returns sample by sample)."""
    gate = SteadyGate(settings)
    return np.array(
        [gate.update(float(t), float(x), float(v)) for t, x, v in zip(time_s, throttle_pct, airspeed_mps, strict=True)],
        dtype=np.bool_,
    )
