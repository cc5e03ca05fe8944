"""The pipeline's clock and fixed-step schedule: the microsecond clock tick, the clock-restart gap,
the filter-call period."""

from __future__ import annotations

import math

from numba.extending import register_jitable

#: A clock jump longer than this (s) restarts the step schedule instead of running every step between.
MAX_CLOCK_GAP_S = 600.0
#: The filters (estimator, isolation filter, open-loop reference) are called every this many seconds
#: (on the steps k with k % period == 0, the 10 Hz Health_Status instants, and at initialisation) with
#: the inputs held at that instant; each call integrates the elapsed steps of dt_s (0.02 s) on the
#: model and applies the latest CHT reading if one arrived since the last call (the CHT frame comes
#: every 100 ms). The supervision, staleness and detector run every step.
FILTER_PERIOD_S = 0.1


def filter_period_steps(dt_s: float) -> int:
    """Steps of dt_s between two filter calls (at least 1)."""
    return max(1, round(FILTER_PERIOD_S / dt_s))


#: Clock readings beyond this magnitude (s) are ignored as corrupt.
MAX_CLOCK_S = 1e12


@register_jitable
def clock_tick(t_s: float) -> float:
    """A clock reading rounded to the microsecond (frame stamps and step times alike), so that a frame
    stamped on a step instant compares equal to it whatever the log format's time resolution."""
    return math.floor(t_s * 1e6 + 0.5) / 1e6
