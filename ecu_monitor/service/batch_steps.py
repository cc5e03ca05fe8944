"""The fixed-step machinery of the replay's batch path: inputs sampled and held on the steps, the
pipeline's own supervision state machine compiled with numba, the stretches of steps where the
estimator runs."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.model.kernels import fingerprint, jit
from ecu_monitor.service import supervision
from ecu_monitor.service.supervision import ACTION_INITIALISE, ACTION_NONE, initial_supervisor, supervise


def _supervise_loop(
    times: NDArray[np.float64],
    any_stale: NDArray[np.bool_],
    new_reading: NDArray[np.bool_],
    reading: NDArray[np.float64],
    reading_bad: NDArray[np.bool_],
    model_c: NDArray[np.float64],
    stale_limit_s: float,
    stuck_after_s: float,
    stuck_change_c: float,
    out_code: NDArray[np.int64],
    out_action: NDArray[np.int64],
) -> None:
    sv = initial_supervisor()
    for k in range(times.shape[0]):
        sv, code, action = supervise(
            sv, times[k], any_stale[k], new_reading[k], reading[k], reading_bad[k], model_c[k],
            stale_limit_s, stuck_after_s, stuck_change_c,
        )  # fmt: skip
        out_code[k] = code
        out_action[k] = action


@functools.cache
def compiled_supervisor() -> Callable[..., None]:
    """:func:`_supervise_loop` over the pipeline's own :func:`supervise`, compiled with numba and cached
    on disk (keyed by the source of both modules): a replay in a new process loads it instead of
    compiling it again (1.5-4 s of CPU per ``ecu-monitor replay`` before)."""
    tag = fingerprint([supervision.__file__, __file__])
    initial = jit(supervision.initial_supervisor, tag)
    step = jit(supervision.supervise, tag, initial_supervisor=initial)
    loop: Callable[..., None] = jit(_supervise_loop, tag, supervise=step, initial_supervisor=initial)
    return loop


def _latest_before_loop(frame_stamps: NDArray[np.float64], times: NDArray[np.float64], out: NDArray[np.int64]) -> None:
    j = 0
    m = frame_stamps.shape[0]
    for k in range(times.shape[0]):
        t = times[k]
        while j < m and frame_stamps[j] < t:
            j += 1
        out[k] = j - 1


@functools.cache
def _compiled_latest_before() -> Callable[..., None]:
    loop: Callable[..., None] = jit(_latest_before_loop, fingerprint([__file__]))
    return loop


def latest_before(frame_stamps: NDArray[np.float64], times: NDArray[np.float64]) -> NDArray[np.int64]:
    """For each step time, the index of the last frame stamped strictly before it (-1: none):
    ``np.searchsorted(frame_stamps, times, side="left") - 1`` for non-decreasing ``frame_stamps`` and
    increasing ``times``, as one merge of the two (compiled) instead of a binary search per step."""
    out = np.empty(times.size, dtype=np.int64)
    _compiled_latest_before()(np.ascontiguousarray(frame_stamps), np.ascontiguousarray(times), out)
    return out


def _stale_loop(
    frame_stamps: NDArray[np.float64],
    latest: NDArray[np.int64],
    times: NDArray[np.float64],
    limit_s: float,
    out: NDArray[np.bool_],
) -> None:
    for k in range(times.shape[0]):
        j = latest[k]
        if j < 0:
            out[k] = True
        else:
            stamp = frame_stamps[j]
            out[k] = stamp != stamp or times[k] - stamp > limit_s


@functools.cache
def _compiled_stale() -> Callable[..., None]:
    loop: Callable[..., None] = jit(_stale_loop, fingerprint([__file__]))
    return loop


def _held_at_loop(values: NDArray[np.float64], latest: NDArray[np.int64], out: NDArray[np.float64]) -> None:
    for k in range(latest.shape[0]):
        j = latest[k]
        out[k] = values[j] if j >= 0 else np.nan


@functools.cache
def _compiled_held_at() -> Callable[..., None]:
    loop: Callable[..., None] = jit(_held_at_loop, fingerprint([__file__]))
    return loop


class HeldInput(NamedTuple):
    """An input sampled and held on the steps: the frames' values and stamps, and the index of the
    latest frame before each step (-1: none yet). The held values, their age and the arrivals are taken
    from ``latest`` where asked (:meth:`at`, :meth:`stale`, :meth:`new_frame`), not kept per step."""

    values: NDArray[np.float64]
    latest: NDArray[np.int64]
    frame_stamps: NDArray[np.float64]

    def at(self, steps: NDArray[np.intp] | slice) -> NDArray[np.float64]:
        """The value held at ``steps`` (nan before the first frame)."""
        j = np.ascontiguousarray(self.latest[steps])
        if not self.values.size:
            return np.full(j.shape, np.nan)
        value = np.empty(j.shape)
        _compiled_held_at()(np.ascontiguousarray(self.values), j, value)  # one pass, no temporaries
        return value

    @property
    def value(self) -> NDArray[np.float64]:
        """The value held at every step."""
        return self.at(slice(None))

    def stale(self, times: NDArray[np.float64], limit_s: float) -> NDArray[np.bool_]:
        """Per step: no frame yet, or the latest is more than ``limit_s`` older than the step (compiled:
        ``isnan(stamp) | (times - stamp > limit_s)`` without a per-step stamp array)."""
        out = np.empty(times.size, dtype=np.bool_)
        _compiled_stale()(np.ascontiguousarray(self.frame_stamps), np.ascontiguousarray(self.latest),
                          np.ascontiguousarray(times), float(limit_s), out)  # fmt: skip
        return out

    def new_frame(self) -> NDArray[np.bool_]:
        """Per step: a frame arrived since the step before (the frames seen grew)."""
        return np.diff(self.latest, prepend=-1) > 0


def hold_inputs(frame_stamps: NDArray[np.float64], values: NDArray[np.float64], j: NDArray[np.int64]) -> HeldInput:
    """``values`` held on the steps from ``j`` (index of the latest valid frame stamped strictly before
    the step, -1: none yet; a frame fed after advance_to(t) is stamped t). The arrays are shared, not
    copied: not to be written to."""
    return HeldInput(values, j, frame_stamps)


def estimator_stretches(action: NDArray[np.int64]) -> list[tuple[int, int]]:
    """[start, end) of each run of steps where the estimator runs (from an INITIALISE to before a NONE)."""
    starts = np.flatnonzero(action == ACTION_INITIALISE)
    stops = np.flatnonzero(action == ACTION_NONE)
    out = []
    for a in starts.tolist():
        after = stops[stops > a]
        out.append((a, int(after[0]) if after.size else action.size))
    return out
