"""The supervision state machine, every step: which state the service reports and what the estimator
does (:func:`supervise`, a pure function of floats that numba compiles into the step, ``register_jitable``).

* UNAVAILABLE until every input the model needs is fresh and a plausible CHT reading is held; then
  the estimator starts from that reading;
* INPUT_STALE while any input has been silent longer than its ``stale_after_s``: the estimator keeps
  predicting on the model with the held inputs, no correction, so its variance grows; after
  ``stale_predict_limit_s`` it stops (UNAVAILABLE) and restarts once the inputs are back;
* SENSOR_FAULT while the CHT probe is reported open (ECU status), reads outside [min_c, max_c], or is
  stuck (no change for ``stuck_after_s`` while the open-loop model swings by ``stuck_change_c``): the
  filter runs open loop;
* otherwise the detector's verdict on the model-deviation symptom (NOMINAL / SUSPECT / DEGRADED).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from numba.extending import register_jitable

#: The codes of STATES, by name.
CODE_NOMINAL, CODE_SUSPECT, CODE_DEGRADED, CODE_STALE, CODE_FAULT, CODE_UNAVAILABLE = range(6)
#: Supervisor actions on the estimator at a step.
ACTION_NONE, ACTION_INITIALISE, ACTION_PREDICT, ACTION_UPDATE = range(4)


class SupervisorState(NamedTuple):
    """What :func:`supervise` carries from one step to the next (floats and bools only)."""

    running: bool  # the estimator is initialised
    stale_since_s: float  # nan while no input is stale
    changed_s: float  # time of the last change of a plausible CHT reading
    last_reading_c: float
    model_low_c: float  # open-loop model range since changed_s
    model_high_c: float


@register_jitable
def initial_supervisor() -> SupervisorState:
    """The supervisor before the first step."""
    return SupervisorState(False, math.nan, math.nan, math.nan, math.nan, math.nan)


@register_jitable
def supervise(
    sv: SupervisorState,
    time_s: float,
    any_stale: bool,
    new_reading: bool,
    reading_c: float,
    reading_bad: bool,
    model_c: float,
    stale_limit_s: float,
    stuck_after_s: float,
    stuck_change_c: float,
) -> tuple[SupervisorState, int, int]:
    """One step of the supervision state machine: (new state, state code, estimator action).

    reading_c: held CHT reading; reading_bad: it is implausible (open / out of range); model_c: the
    open-loop model's CHT at this step (for the stuck test; equal to reading_c at initialisation).
    Codes 0..2 mean "the detector decides" (returned as 0). Pure: the replay compiles it with numba.
    """
    if not sv.running:
        if any_stale or reading_bad or math.isnan(reading_c):
            return sv, CODE_UNAVAILABLE, ACTION_NONE
        start = SupervisorState(True, math.nan, time_s, reading_c, reading_c, reading_c)
        return start, CODE_NOMINAL, ACTION_INITIALISE
    if any_stale:
        since = time_s if math.isnan(sv.stale_since_s) else sv.stale_since_s
        if time_s - since > stale_limit_s:
            return initial_supervisor(), CODE_UNAVAILABLE, ACTION_NONE
        kept = SupervisorState(True, since, sv.changed_s, sv.last_reading_c, sv.model_low_c, sv.model_high_c)
        return kept, CODE_STALE, ACTION_PREDICT
    changed_s = sv.changed_s
    last = sv.last_reading_c
    low = min(sv.model_low_c, model_c)
    high = max(sv.model_high_c, model_c)
    if new_reading and not reading_bad and reading_c != last:
        changed_s = time_s
        last = reading_c
        low = model_c
        high = model_c
    out = SupervisorState(True, math.nan, changed_s, last, low, high)
    stuck = time_s - changed_s >= stuck_after_s and high - low >= stuck_change_c
    if reading_bad or stuck:
        return out, CODE_FAULT, ACTION_PREDICT
    return out, CODE_NOMINAL, ACTION_UPDATE if new_reading else ACTION_PREDICT
