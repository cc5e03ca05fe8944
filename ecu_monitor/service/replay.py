"""Replay: the pipeline over a recorded log, as fast as the machine allows (batch path).

:func:`replay_frames` gives the rows :meth:`Pipeline.drain_rows` would give for the loop

    for msg in frames: pipeline.advance_to(msg.timestamp); pipeline.feed(msg)

but on whole arrays: frames read into numpy arrays (:func:`ecu_monitor.bus.canlog.read_frames`, the one
CAN-log reader), decoded by id with numpy (:meth:`Decoder.decode_batch`, the same checks as the live
decoder, a test proves them equal frame by frame), the fixed-step inputs built by
sample and hold with ``searchsorted``, the supervision state machine (:func:`~.pipeline.supervise`,
the very function the live pipeline calls) compiled with numba, and the estimator, the open-loop
reference model and the isolation filter run through the estimation layer's compiled trace runners
over each stretch of steps the estimator runs. :func:`replay_live` is the same replay through the live
object, frame by frame (the reference the tests compare with).

A canonical flight CSV is replayed through the same path: :func:`frames_from_flight` turns its rows
into the frames the ECU would have sent (each mapped message at its DBC cycle time, carrying the
latest row, encoded with the config's DBC, counter and checksum).
"""

from __future__ import annotations

import functools
import itertools
import math
import os
import types
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import can
import numpy as np
from numpy.typing import NDArray

from ecu_monitor.bus.canlog import CAN_LOG_SUFFIXES, GAP_S, FrameArrays, load_flight, read_frames, time_gaps
from ecu_monitor.bus.codec import INPUT_NAMES, Encoder
from ecu_monitor.errors import FlightLogError
from ecu_monitor.estimation import run_estimator
from ecu_monitor.estimation.detection import Detector
from ecu_monitor.estimation.isolation import IsolationSettings, run_isolation
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.model import Drive, InputSeries, ThermalParams, coefficients, compute_drive, rk4_step, steady_state_cht
from ecu_monitor.model.compiled import simulate_compiled
from ecu_monitor.service import pipeline as _pipeline
from ecu_monitor.service.config import ServiceConfig
from ecu_monitor.service.pipeline import (
    ACTION_INITIALISE,
    ACTION_NONE,
    HEADROOM_NOT_LIMITED_S,
    MAX_CLOCK_GAP_S,
    MAX_CLOCK_S,
    STATES,
    STATUS_INPUT,
    HealthSnapshot,
    Pipeline,
    filter_period_steps,
    model_input_names,
)

__all__ = [
    "HEALTH_COLUMNS",
    "ReplayResult",
    "frames_from_flight",
    "headroom_batch",
    "replay_file",
    "replay_frames",
    "replay_live",
    "write_health_csv",
]

#: Columns of health.csv (one row per health-status period): HealthSnapshot fields; stale_inputs as
#: names joined by "+", sensor_fault as 0/1; empty cells for nan.
HEALTH_COLUMNS: tuple[str, ...] = (
    "time_s",
    "cht_meas_c",
    "cht_est_c",
    "deviation",
    "state",
    "gamma_q",
    "gamma_d",
    "headroom_s",
    "stale_inputs",
    "sensor_fault",
)


@dataclass(frozen=True)
class ReplayResult:
    """A replay's rows (one per health-status period) as columns, and the frame counters.

    columns: time_s, cht_meas_c, cht_est_c, deviation, gamma_q, gamma_d, headroom_s (float arrays),
    state (int codes into STATES), stale (int bit field, bit i = INPUT_NAMES[i]), sensor_fault (bool).
    detector_feed (batch path only): per clock segment whose estimator started, what the detector was
    fed: (step times s from its start, symptom per step, nan where the supervisor was not NOMINAL).
    gaps (batch path only): (last frame time before, first after) of every hole in the frames longer
    than :data:`~ecu_monitor.bus.canlog.GAP_S`; holes longer than the pipeline's MAX_CLOCK_GAP_S
    restart the clock (``counters["clock_restarts"]``): no step runs inside them.
    """

    columns: dict[str, NDArray[Any]]
    counters: dict[str, int]
    detector_feed: tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...] = ()
    gaps: tuple[tuple[float, float], ...] = ()

    def __len__(self) -> int:
        return int(self.columns["time_s"].size)

    @functools.cached_property
    def rows(self) -> list[HealthSnapshot]:
        """The rows as HealthSnapshot objects (what Pipeline.drain_rows gives)."""
        c = self.columns
        names = _stale_names()
        floats = [c[k].tolist() for k in _FLOAT_COLUMNS]
        return [
            HealthSnapshot(t, meas, est, dev, STATES[state], gq, gd, head, names[stale], fault)
            for t, meas, est, dev, gq, gd, head, state, stale, fault in zip(
                *floats, c["state"].tolist(), c["stale"].tolist(), c["sensor_fault"].tolist(), strict=True
            )
        ]

    def write_csv(self, path: str | os.PathLike[str]) -> int:
        """Write health.csv (as :func:`write_health_csv`, from the columns at once); returns the row count."""
        c = self.columns
        names = ["+".join(n) for n in _stale_names()]
        cells = [[f"{v:.10g}" for v in c[k].tolist()] for k in _FLOAT_COLUMNS]
        state = [STATES[v] for v in c["state"].tolist()]
        stale = [names[v] for v in c["stale"].tolist()]
        fault = [str(int(v)) for v in c["sensor_fault"].tolist()]
        t, meas, est, dev, gq, gd, head = cells
        lines = [",".join(HEALTH_COLUMNS)]
        lines += [",".join(row) for row in zip(t, meas, est, dev, state, gq, gd, head, stale, fault, strict=True)]
        return _write_lines(lines, path)


#: Float columns of ReplayResult.columns, in health.csv order.
_FLOAT_COLUMNS = ("time_s", "cht_meas_c", "cht_est_c", "deviation", "gamma_q", "gamma_d", "headroom_s")


@functools.cache
def _stale_names() -> tuple[tuple[str, ...], ...]:
    """Stale input names of every StaleInputs bit field value."""
    return tuple(tuple(n for i, n in enumerate(INPUT_NAMES) if bits >> i & 1) for bits in range(1 << len(INPUT_NAMES)))


def _empty_columns() -> dict[str, NDArray[Any]]:
    columns: dict[str, NDArray[Any]] = {k: np.zeros(0) for k in _FLOAT_COLUMNS}
    columns.update(state=np.zeros(0, dtype=np.int64), stale=np.zeros(0, dtype=np.int64),
                   sensor_fault=np.zeros(0, dtype=bool))  # fmt: skip
    return columns


def frames_from_flight(log: FlightLog, config: ServiceConfig, required: Iterable[str] | None = None) -> FrameArrays:
    """The frames the ECU would have sent for a flight log: every message the config's inputs use, at
    its DBC cycle time (default 100 ms), carrying the latest row at or before the frame time
    (converted from the canonical unit to the signal's unit), other signals 0, counter and checksum.

    ``required``: the columns the log must hold (default: every mapped input but fuel flow); a mapped
    input the log lacks and the model does not need (throttle for a fuel-flow heat map) stays unsent.

    No frame is sent inside a hole of the log (rows more than :data:`~ecu_monitor.bus.canlog.GAP_S`
    apart): the ECU was silent there, so the replay sees the inputs go stale (and, past the
    pipeline's clock-restart limit, a new segment), and the frames are proportional to the data. A
    log of fewer than 2 rows is a FlightLogError.
    """
    if len(log) < 2:
        raise FlightLogError(f"{log.source}: at least 2 rows are needed to replay (the log has {len(log)})")
    encoder = Encoder(config.dbc_paths)
    by_message: dict[str, list[tuple[str, str]]] = {}
    for spec in config.inputs:
        if not log.has(spec.name):
            continue
        by_message.setdefault(spec.message, []).append((spec.signal, spec.name))
    needed = set(required) if required is not None else {s.name for s in config.inputs} - {"fuel_flow_lph"}
    missing = [spec.name for spec in config.inputs if not log.has(spec.name) and spec.name in needed]
    if missing:
        raise FlightLogError(f"{log.source}: missing column(s) {', '.join(missing)} mapped in {config.source}")
    t = log.time_s
    holes = np.flatnonzero(np.diff(t) > GAP_S)
    runs = list(zip([0, *(holes + 1).tolist()], [*holes.tolist(), t.size - 1], strict=True))  # rows [a, b]
    parts: list[tuple[NDArray[np.float64], int, int, bool, NDArray[np.uint8]]] = []
    for order, (name, signals) in enumerate(by_message.items()):
        message = encoder.message(name)
        cycle_s = (message.cycle_time or 100) / 1000.0
        stamps = np.concatenate(
            [t[a] + cycle_s * np.arange(math.floor((t[b] - t[a]) / cycle_s + 1e-9) + 1) for a, b in runs]
        )
        count = stamps.size
        rows = np.searchsorted(t, stamps + 1e-9, side="right") - 1
        columns = {}
        for signal, column in signals:
            unit = config.input(column).signal_spec().conversion()
            columns[signal] = unit.from_canonical(np.asarray(log[column], dtype=float)[rows])
        data = np.zeros((count, 8), dtype=np.uint8)
        payloads = encoder.encode_rows(name, {**{sig.name: np.zeros(count) for sig in message.signals}, **columns})
        data[:, : message.length] = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(count, message.length)
        parts.append((stamps, order, int(message.frame_id), bool(message.is_extended_frame), data))
    time_s = np.concatenate([p[0] for p in parts])
    order_key = np.concatenate([np.full(p[0].size, p[1]) for p in parts])
    sort = np.lexsort((order_key, time_s))
    ids = np.concatenate([np.full(p[0].size, p[2]) for p in parts])
    ext = np.concatenate([np.full(p[0].size, p[3]) for p in parts])
    data = np.concatenate([p[4] for p in parts])
    lengths = np.concatenate(
        [np.full(p[0].size, encoder.message(n).length) for n, p in zip(by_message, parts, strict=True)]
    )
    return FrameArrays(time_s[sort], ids[sort].astype(np.int64), ext[sort], lengths[sort].astype(np.int64),
                       data[sort], np.zeros(time_s.size, dtype=bool))  # fmt: skip


def replay_live(config: ServiceConfig, params: ThermalParams, frames: Iterable[can.Message]) -> ReplayResult:
    """The reference replay: the live pipeline fed frame by frame."""
    pipeline = Pipeline(config, params)
    rows: list[HealthSnapshot] = []
    for msg in frames:
        pipeline.advance_to(msg.timestamp)
        pipeline.feed(msg)
        rows.extend(pipeline.drain_rows())
    return ReplayResult(_rows_to_columns(rows), dict(pipeline.counters))


def _rows_to_columns(rows: list[HealthSnapshot]) -> dict[str, NDArray[Any]]:
    if not rows:
        return _empty_columns()
    columns: dict[str, NDArray[Any]] = {k: np.array([getattr(r, k) for r in rows], dtype=float) for k in _FLOAT_COLUMNS}
    columns["state"] = np.array([STATES.index(r.state) for r in rows], dtype=np.int64)
    columns["stale"] = np.array(
        [sum(1 << i for i, n in enumerate(INPUT_NAMES) if n in r.stale_inputs) for r in rows], dtype=np.int64
    )
    columns["sensor_fault"] = np.array([r.sensor_fault for r in rows], dtype=bool)
    return columns


# --------------------------------------------------------------------------------------------------
# Batch path
# --------------------------------------------------------------------------------------------------


def _rebound(function: Callable[..., Any], **callees: Any) -> Callable[..., Any]:
    """A copy of ``function`` whose global names ``callees`` point at other (compiled) functions."""
    namespace = dict(function.__globals__)
    namespace.update(callees)
    return types.FunctionType(function.__code__, namespace, function.__name__, function.__defaults__)


def _supervise_loop(
    supervise: Any,
    initial: Any,
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
    sv = initial()
    for k in range(times.shape[0]):
        sv, code, action = supervise(
            sv, times[k], any_stale[k], new_reading[k], reading[k], reading_bad[k], model_c[k],
            stale_limit_s, stuck_after_s, stuck_change_c,
        )  # fmt: skip
        out_code[k] = code
        out_action[k] = action


@functools.cache
def _compiled_supervisor() -> Callable[..., None]:
    """:func:`_supervise_loop` over the pipeline's own :func:`supervise`, compiled with numba."""
    import numba

    initial = numba.njit(cache=False)(_rebound(_pipeline.initial_supervisor))
    supervise = numba.njit(cache=False)(_rebound(_pipeline.supervise, initial_supervisor=initial))
    loop = numba.njit(cache=False)(_supervise_loop)

    def run(*args: Any) -> None:
        loop(supervise, initial, *args)

    return run


class _Held(NamedTuple):
    """An input sampled and held on the steps: value, stamp of the frame (nan: none), frames seen."""

    value: NDArray[np.float64]
    stamp: NDArray[np.float64]
    frames_seen: NDArray[np.int64]


def _hold(frame_stamps: NDArray[np.float64], values: NDArray[np.float64], j: NDArray[np.int64]) -> _Held:
    """Values held at each step from ``j`` (index of the latest valid frame stamped strictly before the
    step, -1: none yet; a frame fed after advance_to(t) is stamped t)."""
    if not values.size:
        nothing = np.full(j.size, np.nan)
        return _Held(nothing, nothing, j + 1)
    jj = np.maximum(j, 0)
    seen = j >= 0
    return _Held(np.where(seen, values[jj], np.nan), np.where(seen, frame_stamps[jj], np.nan), j + 1)


def replay_frames(config: ServiceConfig, params: ThermalParams, frames: FrameArrays) -> ReplayResult:
    """The batch replay of ``frames`` (see the module docstring); rows equal to :func:`replay_live`."""
    probe = Pipeline(config, params)  # validates the config against the model, builds the decoder
    decoder = probe.decoder
    counters = dict(probe.counters)
    n = len(frames)
    if n == 0:
        return ReplayResult(_empty_columns(), counters)
    clock = np.where(np.isfinite(frames.time_s) & (np.abs(frames.time_s) < MAX_CLOCK_S), frames.time_s, -np.inf)
    stamps = np.maximum.accumulate(np.floor(clock * 1e6 + 0.5) / 1e6)  # clock_tick, as advance_to
    started = np.isfinite(stamps)
    if not started.any():
        return ReplayResult(_empty_columns(), counters)
    stamps[~started] = stamps[started][0]  # frames before the clock starts count at its start
    batch = decoder.decode_batch(frames.arbitration_id, frames.is_extended, frames.dlc, frames.data, stamps,
                                 frames.ignored)  # fmt: skip
    for key, value in batch.counts.items():
        counters[key] = counters.get(key, 0) + value
    counters["bus_errors"] = int(np.count_nonzero(frames.ignored & _error_mask(frames)))
    # schedule: a clock jump longer than MAX_CLOCK_GAP_S restarts it (as Pipeline.advance_to does)
    restarts = np.flatnonzero(np.diff(stamps) > MAX_CLOCK_GAP_S) + 1
    bounds = [0, *restarts.tolist(), n]
    counters["clock_restarts"] = len(restarts)
    parts: list[dict[str, NDArray[Any]]] = []
    feeds: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
    steps_total = 0
    for a, b in itertools.pairwise(bounds):
        seg_columns, steps, feed = _replay_segment(config, params, probe, batch.values, stamps, a, b)
        parts.append(seg_columns)
        feeds.extend([feed] if feed is not None else [])
        steps_total += steps
    counters["steps"] = steps_total
    columns = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]} if parts else _empty_columns()
    return ReplayResult(columns, counters, tuple(feeds), tuple(time_gaps(stamps)))


def _error_mask(frames: FrameArrays) -> NDArray[np.bool_]:
    return frames.ignored  # error and remote frames are not told apart in FrameArrays


def _replay_segment(
    config: ServiceConfig,
    params: ThermalParams,
    probe: Pipeline,
    values: dict[str, tuple[NDArray[np.int64], NDArray[np.float64]]],
    stamps: NDArray[np.float64],
    first: int,
    end: int,
) -> tuple[dict[str, NDArray[Any]], int, tuple[NDArray[np.float64], NDArray[np.float64]] | None]:
    dt = config.estimator.dt_s
    origin = float(stamps[first])
    last = float(stamps[end - 1])
    count = max(0, math.floor((last - origin) / dt) + 2)
    k = np.arange(1, count + 1, dtype=np.float64)
    times = np.floor((origin + k * dt) * 1e6 + 0.5) / 1e6  # the same float arithmetic as Pipeline.advance_to
    times = times[times <= last]
    n = times.size
    if n == 0:
        return _empty_columns(), 0, None
    held: dict[str, _Held] = {}
    message_of = {spec.name: spec.message for spec in config.inputs}
    message_of[STATUS_INPUT] = str(config.sensor_fault.status_message)
    latest: dict[str, NDArray[np.int64]] = {}  # per message: the latest frame before each step
    for name, (rows, vals) in values.items():
        inside = (rows >= first) & (rows < end)
        frame_stamps = stamps[rows[inside]]
        message = message_of[name]
        if message not in latest:
            latest[message] = np.searchsorted(frame_stamps, times, side="left") - 1
        held[name] = _hold(frame_stamps, vals[inside], latest[message])
    mapped = [name for name in INPUT_NAMES if name in config.input_names]
    stale = {
        name: np.isnan(held[name].stamp) | (times - held[name].stamp > config.input(name).stale_after_s)
        for name in mapped
    }
    needed = {*model_input_names(params), "cht_c"}
    any_stale = np.zeros(n, dtype=bool)
    for name in needed:
        any_stale |= stale[name]
    cht = held["cht_c"]
    reading = cht.value
    new_reading = np.diff(cht.frames_seen, prepend=0) > 0
    sf = config.sensor_fault
    with np.errstate(invalid="ignore"):
        reading_bad = ~np.isnan(reading) & ((reading < sf.min_c) | (reading > sf.max_c))
    if STATUS_INPUT in held:
        status = held[STATUS_INPUT].value
        is_open = np.zeros(n, dtype=bool)
        for value in sf.open_values:
            is_open |= status == value
        reading_bad |= ~np.isnan(reading) & is_open
    run = _compiled_supervisor()
    code = np.empty(n, dtype=np.int64)
    action = np.empty(n, dtype=np.int64)
    args = (config.stale_predict_limit_s, sf.stuck_after_s, sf.stuck_change_c, code, action)
    # pass 1: where the estimator runs (independent of the stuck test, which needs the open-loop model)
    run(times, any_stale, new_reading, reading, reading_bad, reading, *args)
    stretches = _stretches(action)
    period = filter_period_steps(dt)
    inputs = {name: held[name].value for name in model_input_names(params)}
    model_c = np.full(n, np.nan)
    calls: list[np.ndarray] = []  # for each stretch: the filter call step of every step (held outputs)
    for a, b in stretches:
        # filter calls on the steps k (1-based) with k % period == 0, and at the initialisation
        call = np.maximum(a, period * ((np.arange(a, b) + 1) // period) - 1)
        calls.append(call)
        # the open-loop reference: the nominal model from the first reading, the filters' inputs
        series = InputSeries(*(inputs[name][call] for name in inputs))
        reference = simulate_compiled(series, coefficients(params), dt, float(reading[a])).cht_c
        model_c[a:b] = reference[call - a]
    # pass 2: with the open-loop model, the states and the estimator's actions
    run(times, any_stale, new_reading, reading, reading_bad, np.where(np.isnan(model_c), reading, model_c), *args)
    if _stretches(action) != stretches:  # the stuck test never starts or stops the estimator
        raise RuntimeError("replay: supervision passes disagree on where the estimator runs")
    est = np.full(n, np.nan)
    deviation = np.full(n, np.nan)
    gamma_q = np.full(n, np.nan)
    gamma_d = np.full(n, np.nan)
    iso_dev = np.full(n, np.nan)
    arrivals = np.concatenate(([0], np.cumsum(new_reading)))  # readings arrived in steps [0, j)
    for (a, b), call in zip(stretches, calls, strict=True):
        steps = np.arange(a, b)
        is_call = (call == steps) & (steps > a)
        window = arrivals[steps + 1] - arrivals[np.maximum(steps - period, a) + 1] > 0
        use = is_call & window & (code[a:b] == 0)
        z = np.where(use, reading[a:b], np.nan)
        z[0] = reading[a]
        log = _stretch_log(times, {k: v[call] for k, v in inputs.items()}, z, a, b)
        trace = run_estimator(log, params, config.estimator_name, config.estimator)
        est[a:b] = trace.cht_est_c[call - a]
        deviation[a:b] = trace.deviation[call - a]
        # the isolation filter on the call steps only: each row integrates the steps since the previous
        # call (run_isolation's sub-steps) with that call's inputs, as the live filter does
        at_calls = np.unique(call)
        at_inputs = {k: v[at_calls] for k, v in inputs.items()}
        calls_log = FlightLog({"time_s": times[at_calls], **at_inputs, "cht_c": z[at_calls - a]}, source="replay")
        iso = run_isolation(calls_log, params, IsolationSettings(dt_s=dt))
        which = np.searchsorted(at_calls, call)
        gamma_q[a:b] = iso.gamma_q[which]
        gamma_d[a:b] = iso.gamma_d[which]
        iso_dev[a:b] = iso.deviation[which]
    periods = {h.message: round(1.0 / (h.rate_hz * dt)) for h in config.health}
    step_numbers = np.arange(1, n + 1)
    symptom = deviation if config.detector_symptom == "estimator" else iso_dev
    first, fed = _detector_feed(code, symptom, stretches)
    state = _detect(config, times, code, first, fed, stretches)
    feed = (times[first:], fed[first:]) if stretches else None
    headroom = _headroom(params, times, inputs, est, gamma_q, gamma_d, action, step_numbers,
                         periods.get("Health_Isolation", periods["Health_Status"]))  # fmt: skip
    rows = np.flatnonzero(step_numbers % periods["Health_Status"] == 0)
    bits = np.zeros(n, dtype=np.int64)
    for name in mapped:
        bits |= stale[name].astype(np.int64) << INPUT_NAMES.index(name)
    out = {
        "time_s": times[rows],
        "cht_meas_c": reading[rows],
        "cht_est_c": est[rows],
        "deviation": deviation[rows],
        "gamma_q": gamma_q[rows],
        "gamma_d": gamma_d[rows],
        "headroom_s": headroom[rows],
        "state": state[rows].astype(np.int64),
        "stale": bits[rows],
        "sensor_fault": code[rows] == STATES.index("SENSOR_FAULT"),
    }
    return out, n, feed


def _detector_feed(
    code: NDArray[np.int64], symptom: NDArray[np.float64], stretches: list[tuple[int, int]]
) -> tuple[int, NDArray[np.float64]]:
    """(step of the first initialisation, where the detector starts; the symptom it is fed per step:
    nan before that step and wherever the supervisor is not NOMINAL)."""
    first = stretches[0][0] if stretches else code.size
    fed = np.where(code == 0, symptom, np.nan)
    fed[:first] = np.nan
    return first, fed


def _detect(
    config: ServiceConfig,
    times: NDArray[np.float64],
    code: NDArray[np.int64],
    first: int,
    fed: NDArray[np.float64],
    stretches: list[tuple[int, int]],
) -> NDArray[np.int64]:
    """Final state codes: the detector's verdict where the supervisor says NOMINAL.

    ``first``, ``fed``: from :func:`_detector_feed` (where the detector starts, what it is fed).

    Equal to the live pipeline's per-step Detector.update (started at the first initialisation, fed
    NaN off NOMINAL steps): the symptom is averaged here over the very blocks Detector forms (block
    m holds the steps from the one that closed block m-1 up to the step before the first at or after
    its end), and a real Detector gets one sample per block, the block's mean, at the block's first
    step (the mean of one sample is itself), so its CUSUM runs exactly as live, once per block.
    """
    state = code.copy()
    if not stretches:
        return state
    s = config.detector
    n = times.size
    t0 = float(times[first])
    begin = t0 + s.warmup_s
    if float(times[-1]) < begin:
        return state
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
    counts = np.add.reduceat(finite.astype(np.int64), starts)
    detector = Detector(s)
    detector.update(t0, math.nan)
    block_state = np.empty(starts.size, dtype=np.int64)
    for i, (lo, total, k) in enumerate(zip(starts.tolist(), sums.tolist(), counts.tolist(), strict=True)):
        out = detector.update(float(times[lo]), total / k if k else math.nan)
        block_state[i] = STATES.index(out.state)
    verdicts = np.zeros(n, dtype=np.int64)
    which = np.searchsorted(starts, np.arange(n), side="right") - 1
    verdicts[which >= 0] = block_state[which[which >= 0]]
    nominal = code == 0
    state[nominal] = verdicts[nominal]
    return state


def _headroom(
    params: ThermalParams,
    times: NDArray[np.float64],
    inputs: dict[str, NDArray[np.float64]],
    est: NDArray[np.float64],
    gamma_q: NDArray[np.float64],
    gamma_d: NDArray[np.float64],
    action: NDArray[np.int64],
    step_numbers: NDArray[np.int64],
    period: int,
) -> NDArray[np.float64]:
    """Headroom held between its computations every ``period`` steps while the estimator runs (nan
    otherwise), as the live pipeline does; computed with :func:`headroom_batch`."""
    n = times.size
    running = action != ACTION_NONE
    due = running & (step_numbers % period == 0)
    idx = np.flatnonzero(due)
    axes = list(inputs)
    computed = headroom_batch(
        params, InputSeries(*(inputs[name][idx] for name in axes)), est[idx], gamma_q[idx], gamma_d[idx]
    )
    # hold: last computation since the last (re)initialisation, nan after a stop or before the first
    value = np.full(n, np.nan)
    value[idx] = computed
    marker = np.full(n, -1, dtype=np.int64)
    marker[idx] = idx
    resets = np.flatnonzero((action == ACTION_INITIALISE) & ~due)
    marker[resets] = resets  # an initialisation clears the held value (value there is nan)
    stops = np.flatnonzero(~running)
    marker[stops] = stops
    np.maximum.accumulate(marker, out=marker)
    return np.where(marker >= 0, value[np.maximum(marker, 0)], np.nan)


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


def _stretches(action: NDArray[np.int64]) -> list[tuple[int, int]]:
    """[start, end) of each run of steps where the estimator runs (from an INITIALISE to before a NONE)."""
    starts = np.flatnonzero(action == ACTION_INITIALISE)
    stops = np.flatnonzero(action == ACTION_NONE)
    out = []
    for a in starts.tolist():
        after = stops[stops > a]
        out.append((a, int(after[0]) if after.size else action.size))
    return out


def _stretch_log(
    times: NDArray[np.float64], inputs: dict[str, NDArray[np.float64]], z: NDArray[np.float64], a: int, b: int
) -> FlightLog:
    columns = {"time_s": times[a:b], **{name: col[a:b] for name, col in inputs.items()}, "cht_c": z}
    return FlightLog(columns, source="replay")


def replay_file(path: str | os.PathLike[str], config: ServiceConfig, params: ThermalParams) -> ReplayResult:
    """Replay a python-can log or a canonical flight CSV through the batch path."""
    suffix = Path(path).suffix.lower()
    if suffix in CAN_LOG_SUFFIXES:
        return replay_frames(config, params, read_frames(path))
    if suffix == ".csv":
        needed = (*model_input_names(params), "cht_c")
        return replay_frames(config, params, frames_from_flight(load_flight(path), config, needed))
    raise FlightLogError(f"{path}: unknown log format '{suffix}' (expected .csv, {', '.join(CAN_LOG_SUFFIXES)})")


def write_health_csv(rows: Iterable[HealthSnapshot], path: str | os.PathLike[str]) -> int:
    """Write health.csv (:data:`HEALTH_COLUMNS`, nan as an empty cell); returns the number of rows.
    FlightLogError if the file cannot be written."""
    lines = [",".join(HEALTH_COLUMNS)]
    for r in rows:
        lines.append(
            f"{r.time_s:.10g},{r.cht_meas_c:.10g},{r.cht_est_c:.10g},{r.deviation:.10g},{r.state},{r.gamma_q:.10g},"
            f"{r.gamma_d:.10g},{r.headroom_s:.10g},{'+'.join(r.stale_inputs)},{int(r.sensor_fault)}"
        )
    return _write_lines(lines, path)


def _write_lines(lines: list[str], path: str | os.PathLike[str]) -> int:
    text = "\n".join(lines).replace(",nan", ",").replace(",-inf", ",").replace(",inf", ",") + "\n"
    try:
        with open(path, "w", newline="", encoding="utf-8") as handle:
            handle.write(text)
    except OSError as exc:
        raise FlightLogError(f"{path}: cannot write ({exc.strerror or exc})") from None
    return len(lines) - 1
