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


class HeldInput(NamedTuple):
    """An input sampled and held on the steps: the frames' values, the index of the latest frame before
    each step (-1: none yet), its stamp per step (nan: none) and the frames seen per step. The held
    values are taken at the steps asked for (:meth:`at`), not made for every step."""

    values: NDArray[np.float64]
    latest: NDArray[np.int64]
    stamp: NDArray[np.float64]
    frames_seen: NDArray[np.int64]

    def at(self, steps: NDArray[np.intp] | slice) -> NDArray[np.float64]:
        """The value held at ``steps`` (nan before the first frame)."""
        j = self.latest[steps]
        if not self.values.size:
            return np.full(j.shape, np.nan)
        value = self.values[np.maximum(j, 0)]
        value[j < 0] = np.nan
        return value

    @property
    def value(self) -> NDArray[np.float64]:
        """The value held at every step."""
        return self.at(slice(None))


def hold_inputs(
    frame_stamps: NDArray[np.float64], values: NDArray[np.float64], j: NDArray[np.int64], like: HeldInput | None = None
) -> HeldInput:
    """``values`` held on the steps from ``j`` (index of the latest valid frame stamped strictly before
    the step, -1: none yet; a frame fed after advance_to(t) is stamped t).

    ``like``: an input already held from the same frames and the same ``j`` (another field of the
    message); its stamp and frames_seen arrays are shared, not made again (16 h: 23 MB each). The
    returned arrays are not to be written to."""
    if not values.size:
        return HeldInput(values, j, np.full(j.size, np.nan), j + 1)
    if like is not None:
        return HeldInput(values, j, like.stamp, like.frames_seen)
    stamp = frame_stamps[np.maximum(j, 0)]
    stamp[j < 0] = np.nan
    return HeldInput(values, j, stamp, j + 1)


def estimator_stretches(action: NDArray[np.int64]) -> list[tuple[int, int]]:
    """[start, end) of each run of steps where the estimator runs (from an INITIALISE to before a NONE)."""
    starts = np.flatnonzero(action == ACTION_INITIALISE)
    stops = np.flatnonzero(action == ACTION_NONE)
    out = []
    for a in starts.tolist():
        after = stops[stops > a]
        out.append((a, int(after[0]) if after.size else action.size))
    return out
