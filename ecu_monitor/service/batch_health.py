"""The health outputs of the replay's batch path on whole arrays, equal to the live pipeline's: the
detector's state per step (:func:`detect_states`, fed by :func:`detector_feed`) and the thermal
headroom (:func:`held_headroom` over :func:`headroom_batch`)."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.estimation.detection import cusum_blocks
from ecu_monitor.model import Drive, InputSeries, ThermalParams, coefficients, compute_drive, rk4_step, steady_state_cht
from ecu_monitor.model.inputs import series_of
from ecu_monitor.model.kernels import fingerprint, jit
from ecu_monitor.service.batch_steps import HeldInput
from ecu_monitor.service.config import ServiceConfig
from ecu_monitor.service.health_rows import HEADROOM_NOT_LIMITED_S
from ecu_monitor.service.supervision import ACTION_INITIALISE, ACTION_NONE, STATES


def detector_feed(
    code: NDArray[np.int64],
    symptom: NDArray[np.float64],
    call_of: NDArray[np.int64],
    stretches: list[tuple[int, int]],
) -> tuple[int, NDArray[np.float64]]:
    """(step of the first initialisation, where the detector starts; the symptom it is fed per step:
    nan before that step and wherever the supervisor is not NOMINAL). ``symptom``: one value per filter
    call; ``call_of``: the call of each step (-1: the estimator does not run, nan)."""
    first = stretches[0][0] if stretches else code.size
    fed = np.empty(code.size)
    _compiled_feed()(code, symptom, call_of, first, fed)
    return first, fed


def _feed_loop(
    code: NDArray[np.int64],
    symptom: NDArray[np.float64],
    call_of: NDArray[np.int64],
    first: int,
    out: NDArray[np.float64],
) -> None:
    for k in range(code.shape[0]):
        call = call_of[k]
        out[k] = symptom[call] if k >= first and code[k] == 0 and call >= 0 else np.nan


@functools.cache
def _compiled_feed() -> Callable[..., None]:
    loop: Callable[..., None] = jit(_feed_loop, fingerprint([__file__]))
    return loop


def detect_states(
    config: ServiceConfig,
    times: NDArray[np.float64],
    code: NDArray[np.int64],
    first: int,
    fed: NDArray[np.float64],
    stretches: list[tuple[int, int]],
) -> NDArray[np.int64]:
    """Final state codes: the detector's verdict where the supervisor says NOMINAL.

    ``first``, ``fed``: from :func:`detector_feed` (where the detector starts, what it is fed).

    Equal to the live pipeline's per-step Detector.update (started at the first initialisation, fed
    NaN off NOMINAL steps): the symptom is averaged here over the very blocks Detector forms (block
    m holds the steps from the one that closed block m-1 up to the step before the first at or after
    its end; a block no step falls in is an empty block, as live), and the detector's compiled CUSUM
    (:func:`cusum_blocks`, the update Detector makes when a block closes) runs over those means. A
    step in block b sees the statistic after blocks 0..b-1 closed (the live Detector closes a block
    at the first sample of the next), DEGRADED from the block after the first alarm on (latched).
    """
    if not stretches:
        return code.copy()
    s = config.detector
    n = times.size
    t0 = float(times[first])
    begin = t0 + s.warmup_s
    if float(times[-1]) < begin:
        return code.copy()
    count = math.floor((float(times[-1]) - begin) / s.block_s) + 2
    ends = np.cumsum(np.concatenate(([begin + s.block_s], np.full(count - 1, s.block_s))))
    closes = np.searchsorted(times, ends - 1e-9, side="left")
    closes = closes[closes < n]
    start = max(int(np.searchsorted(times, begin, side="left")), first)
    starts = np.array([start, *closes.tolist()], dtype=np.int64)
    starts = starts[np.concatenate(([True], np.diff(starts) > 0))]  # blocks with at least one step
    starts = starts[starts < n]
    finite = np.isfinite(fed)
    sums = np.add.reduceat(np.where(finite, fed, 0.0), starts)
    counts = np.add.reduceat(finite, starts, dtype=np.int64)
    block = np.searchsorted(ends - 1e-9, times[starts], side="right")  # the block each start opens
    means = np.full(int(block[-1]) + 1, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        means[block] = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    statistic, alarms = cusum_blocks(means, s)
    closed = block - 1  # the last block closed when the start's step arrives (-1: none yet)
    seen = np.where(closed >= 0, statistic[np.maximum(closed, 0)], 0.0)
    first_alarm = int(alarms[0]) if alarms.size else means.size
    block_state = np.where(
        closed >= first_alarm,
        STATES.index("DEGRADED"),
        np.where(seen >= s.suspect_fraction * s.threshold, STATES.index("SUSPECT"), STATES.index("NOMINAL")),
    )
    verdicts = np.zeros(n, dtype=np.int64)  # each step has the verdict of its block (before the first: 0)
    verdicts[starts[0] :] = np.repeat(block_state, np.diff(starts, append=n))
    return np.where(code == 0, verdicts, code)


def held_headroom(
    params: ThermalParams,
    times: NDArray[np.float64],
    inputs: dict[str, HeldInput],
    est: NDArray[np.float64],
    gamma_q: NDArray[np.float64],
    gamma_d: NDArray[np.float64],
    call_of: NDArray[np.int64],
    action: NDArray[np.int64],
    period: int,
    rows: NDArray[np.int64],
) -> NDArray[np.float64]:
    """Headroom held between its computations every ``period`` steps while the estimator runs (nan
    otherwise), as the live pipeline does, at the steps ``rows``; computed with :func:`headroom_batch`.
    ``est``, ``gamma_q``, ``gamma_d``: one value per filter call; ``call_of``: the call of each step
    (-1: none)."""
    n = times.size
    running = action != ACTION_NONE
    due = np.zeros(n, dtype=bool)
    due[period - 1 :: period] = True  # the steps k (1-based) with k % period == 0
    due &= running
    idx = np.flatnonzero(due)
    series = series_of({name: v.at(idx) for name, v in inputs.items()}, params.heat_axes, params.effects.mixture_index)
    call = call_of[idx]
    if call.size and int(call.min()) < 0:
        raise RuntimeError("replay: a headroom step outside the estimator's calls")
    computed = headroom_batch(params, series, est[call], gamma_q[call], gamma_d[call])
    # hold: last computation since the last (re)initialisation, nan after a stop or before the first
    marker = np.full(n, -1, dtype=np.int64)
    marker[idx] = idx
    resets = np.flatnonzero((action == ACTION_INITIALISE) & ~due)
    marker[resets] = resets  # an initialisation clears the held value
    stops = np.flatnonzero(~running)
    marker[stops] = stops
    np.maximum.accumulate(marker, out=marker)
    last = marker[rows]  # the step whose value each row holds: a computation, or a reset or stop (nan)
    out = np.full(rows.size, np.nan)
    if idx.size:
        pos = np.minimum(np.searchsorted(idx, last), idx.size - 1)
        computed_there = idx[pos] == last
        out[computed_there] = computed[pos[computed_there]]
    return out


def headroom_batch(
    params: ThermalParams,
    inputs: InputSeries,
    cht_c: NDArray[np.float64],
    gamma_q: NDArray[np.float64],
    gamma_d: NDArray[np.float64],
    *,
    cap_s: float = HEADROOM_NOT_LIMITED_S,
    step_s: float = 2.0,
) -> NDArray[np.float64]:
    """:func:`ecu_monitor.estimation.headroom.thermal_headroom` (heat path in steady state) on arrays:
    the same steady-state test and the same RK4 march with linear interpolation of the crossing, all
    rows at once (the model functions broadcast)."""
    m = np.asarray(cht_c).size
    if m == 0:
        return np.zeros(0)
    coeffs = coefficients(params)
    limit = params.cht_limit_c
    d = compute_drive(inputs, coeffs)
    columns = [np.broadcast_to(np.asarray(v, dtype=float), (m,)).copy() for v in d]
    drive = Drive(*columns)
    margin = limit - cht_c
    out = np.where(margin <= 0.0, 0.0, cap_s)
    # the steady state lies below the convective-only solution (radiation only takes heat out): where
    # that bound is below the limit the answer is "not limited" without Newton's iterations
    heat = gamma_q * gamma_d * drive.heat_gain * drive.altitude_gain * drive.q_sl0_w
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = drive.ambient_c + heat / drive.conductance_w_per_c
    need = np.flatnonzero((margin > 0.0) & ~((heat >= 0.0) & (bound < limit)))
    steady_fn: Any = steady_state_cht  # broadcasts over arrays of gammas
    sub_drive = Drive(*(v[need] for v in columns))
    steady = np.asarray(steady_fn(sub_drive, coeffs, gamma_q[need], gamma_d[need]), dtype=float)
    active = need[steady >= limit]
    temp = cht_c[active].astype(float)
    pade = 2.0 * columns[0][active]
    sub = Drive(*(v[active] for v in columns))
    gq, gd = gamma_q[active], gamma_d[active]
    elapsed = 0.0
    while active.size and elapsed < cap_s:
        stepped, stepped_pade = rk4_step(temp, pade, sub, coeffs, step_s, gq, gd)
        new_temp = np.asarray(stepped, dtype=float)
        pade = np.asarray(stepped_pade, dtype=float)
        hit = new_temp >= limit
        if np.any(hit):
            rising = new_temp[hit] > temp[hit]
            with np.errstate(invalid="ignore", divide="ignore"):
                fraction = np.where(rising, (limit - temp[hit]) / (new_temp[hit] - temp[hit]), 1.0)
            crossing = elapsed + fraction * step_s
            out[active[hit]] = np.where(crossing <= cap_s, crossing, cap_s)
            keep = ~hit
            active, temp, pade = active[keep], new_temp[keep], pade[keep]
            sub = Drive(*(np.asarray(v)[keep] for v in sub))
            gq, gd = gq[keep], gd[keep]
        else:
            temp = new_temp
        elapsed += step_s
    return out
