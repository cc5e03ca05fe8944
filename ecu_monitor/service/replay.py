"""Replay: the pipeline over a recorded log, as fast as the machine allows (batch path).

:func:`replay_frames` gives the rows :meth:`Pipeline.drain_rows` would give for the loop

    for msg in frames: pipeline.advance_to(msg.timestamp); pipeline.feed(msg)

but on whole arrays: frames read into numpy arrays (:func:`ecu_monitor.bus.canlog.read_frames`, the one
CAN-log reader), decoded by id with numpy (:meth:`Decoder.decode_batch`, the same checks as the live
decoder, a test proves them equal frame by frame), the fixed-step inputs built by
sample and hold with ``searchsorted``, the supervision state machine (:func:`~.supervision.supervise`,
the very function the live pipeline calls) compiled with numba, and the estimator, the open-loop
reference model and the isolation filter run through the estimation layer's compiled trace runners
over each stretch of steps the estimator runs. :func:`replay_live` is the same replay through the live
object, frame by frame (the reference the tests compare with).

A canonical flight CSV is replayed through the same path: :func:`frames_from_flight` turns its rows
into the frames the ECU would have sent (each mapped message at its DBC cycle time, carrying the
latest row, encoded with the config's DBC, counter and checksum).
"""

from __future__ import annotations

import contextlib
import itertools
import math
import os
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, NamedTuple

import can
import numpy as np
from numpy.typing import NDArray

from ecu_monitor.bus.canlog import CAN_LOG_SUFFIXES, FrameArrays, load_flight, read_frames, time_gaps
from ecu_monitor.bus.codec import INPUT_NAMES
from ecu_monitor.errors import FlightLogError
from ecu_monitor.estimation.cross_cylinder import cross_cylinder_symptoms
from ecu_monitor.estimation.isolation import IsolationSettings, run_isolation
from ecu_monitor.estimation.runner import run_estimator_on_calls
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.model import InputSeries, ThermalParams, coefficients
from ecu_monitor.model.compiled import simulate_held
from ecu_monitor.model.inputs import series_of
from ecu_monitor.service.batch_health import detect_states, detector_feed, headroom_batch, held_headroom
from ecu_monitor.service.batch_steps import (
    HeldInput,
    compiled_supervisor,
    estimator_stretches,
    hold_inputs,
    latest_before,
)
from ecu_monitor.service.config import CHT_INPUT, ServiceConfig
from ecu_monitor.service.cylinders import engine_columns
from ecu_monitor.service.flight_frames import frames_from_flight
from ecu_monitor.service.health_rows import (
    HEALTH_COLUMNS,
    HealthSnapshot,
    ReferenceFeed,
    ReplayResult,
    empty_columns,
    rows_to_columns,
    write_health_csv,
)
from ecu_monitor.service.pipeline import STATUS_INPUT, Pipeline, fed_mixture, model_input_names
from ecu_monitor.service.schedule import MAX_CLOCK_GAP_S, MAX_CLOCK_S, filter_period_steps
from ecu_monitor.service.supervision import STATES

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


def replay_live(
    config: ServiceConfig, params: ThermalParams | Sequence[ThermalParams], frames: Iterable[can.Message]
) -> ReplayResult:
    """The reference replay: the live pipeline fed frame by frame."""
    pipeline = Pipeline(config, params)
    rows: list[HealthSnapshot] = []
    for msg in frames:
        pipeline.advance_to(msg.timestamp)
        pipeline.feed(msg)
        rows.extend(pipeline.drain_rows())
    return ReplayResult(rows_to_columns(rows, len(pipeline.cylinder_params)), dict(pipeline.counters))


def replay_frames(
    config: ServiceConfig,
    params: ThermalParams | Sequence[ThermalParams],
    frames: FrameArrays,
    *,
    keep_reference: bool = False,
) -> ReplayResult:
    """The batch replay of ``frames`` (see the module docstring); rows equal to :func:`replay_live`.
    ``params``: the model of every cylinder, or one per cylinder (as :class:`Pipeline`). ``keep_reference``:
    also keep the open-loop reference per step (:attr:`ReplayResult.reference_feed`; off by default: four
    more per-step arrays, the rows unchanged)."""
    with _small_pages():
        return _replay_frames(config, params, frames, keep_reference)


@contextlib.contextmanager
def _small_pages() -> Iterator[None]:
    """numpy without its ``madvise(MADV_HUGEPAGE)`` on new arrays, for the batch replay only.

    numpy asks the kernel for transparent huge pages on every array of 4 MB or more; where the kernel
    then compacts memory to find one at the first touch (THP ``defrag: madvise``, a common default),
    the replay's fresh per-step arrays (about 1.3 GB for a 16 h log, each touched a few times) cost more
    system time in compaction than huge pages save (16 h log: 3.0 -> 1.0 s of system time, quiet
    machine). A ``NUMPY_MADVISE_HUGEPAGE`` set by the user is left as it is."""
    setter = getattr(getattr(np, "_core", None), "multiarray", None)
    setter = getattr(setter, "_set_madvise_hugepage", None)
    if setter is None or "NUMPY_MADVISE_HUGEPAGE" in os.environ:
        yield
        return
    previous = setter(False)
    try:
        yield
    finally:
        setter(previous)


def _replay_frames(
    config: ServiceConfig, params: ThermalParams | Sequence[ThermalParams], frames: FrameArrays, keep_reference: bool
) -> ReplayResult:
    probe = Pipeline(config, params)  # validates the config against the model, builds the decoder
    models = probe.cylinder_params
    decoder = probe.decoder
    counters = dict(probe.counters)
    count = len(models)
    n = len(frames)
    if n == 0:
        return ReplayResult(empty_columns(count), counters)
    stamps = np.where(np.isfinite(frames.time_s) & (np.abs(frames.time_s) < MAX_CLOCK_S), frames.time_s, -np.inf)
    stamps *= 1e6  # floor(t 1e6 + 0.5) / 1e6: clock_tick, as advance_to (in place: 4 M frames, 32 MB each)
    stamps += 0.5
    np.floor(stamps, out=stamps)
    stamps /= 1e6
    np.maximum.accumulate(stamps, out=stamps)
    start = int(np.argmax(stamps > -np.inf))  # the clock starts at the first finite stamp (then stays finite)
    if not np.isfinite(stamps[start]):
        return ReplayResult(empty_columns(count), counters)
    stamps[:start] = stamps[start]  # frames before the clock starts count at its start
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
    references: list[ReferenceFeed] = []
    cross_feeds: list[list[tuple[NDArray[np.float64], NDArray[np.float64]]]] = [[] for _ in models]
    steps_total = 0
    for a, b in itertools.pairwise(bounds):
        seg_columns, steps, feed, seg_cross, reference = _replay_segment(
            config, models, probe, batch.values, stamps, a, b, keep_reference
        )
        parts.append(seg_columns)
        feeds.extend([feed] if feed is not None else [])
        references.extend([reference] if reference is not None else [])
        for cylinder, cross_feed in zip(cross_feeds, seg_cross, strict=False):
            cylinder.extend([cross_feed] if cross_feed is not None else [])
        steps_total += steps
    counters["steps"] = steps_total
    columns = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]} if parts else empty_columns(count)
    cross = tuple(tuple(c) for c in cross_feeds) if config.cross_detectors else ()
    return ReplayResult(columns, counters, tuple(feeds), tuple(time_gaps(stamps)), cross, tuple(references))


def _error_mask(frames: FrameArrays) -> NDArray[np.bool_]:
    return frames.ignored  # error and remote frames are not told apart in FrameArrays


def _replay_segment(
    config: ServiceConfig,
    params: tuple[ThermalParams, ...],
    probe: Pipeline,
    values: dict[str, tuple[NDArray[np.int64], NDArray[np.float64]]],
    stamps: NDArray[np.float64],
    first: int,
    end: int,
    keep_reference: bool,
) -> tuple[
    dict[str, NDArray[Any]],
    int,
    tuple[NDArray[np.float64], NDArray[np.float64]] | None,
    tuple[tuple[NDArray[np.float64], NDArray[np.float64]] | None, ...],
    ReferenceFeed | None,
]:
    dt = config.estimator.dt_s
    cylinder_inputs = config.cylinder_inputs
    count = len(cylinder_inputs)
    origin = float(stamps[first])
    last = float(stamps[end - 1])
    steps = max(0, math.floor((last - origin) / dt) + 2)
    # floor((origin + k dt) 1e6 + 0.5) / 1e6 for k = 1.., the float arithmetic of Pipeline.advance_to, in place
    times = np.arange(1, steps + 1, dtype=np.float64)
    times *= dt
    times += origin
    times *= 1e6
    times += 0.5
    np.floor(times, out=times)
    times /= 1e6
    times = times[: int(np.searchsorted(times, last, side="right"))]  # the steps up to the last frame
    n = times.size
    if n == 0:
        return empty_columns(count), 0, None, (), None
    held: dict[str, HeldInput] = {}
    message_of = {spec.name: spec.message for spec in config.inputs}
    message_of[STATUS_INPUT] = str(config.sensor_fault.status_message)
    # per message: its frames and the latest of them before each step (a DroneCAN field sent as NaN leaves
    # its value out of one message's frames: then that value has its own); the values held on the same
    # frames share one frame-stamp and latest array. Rows are sorted: the segment's frames are a slice.
    latest: dict[str, tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]] = {}
    for name, (rows, vals) in values.items():
        lo, hi = (0, rows.size) if (first, end) == (0, stamps.size) else np.searchsorted(rows, (first, end))
        frame_rows = rows[lo:hi]
        message = message_of[name]
        cached = latest.get(message)
        if cached is not None and np.array_equal(cached[0], frame_rows):
            held[name] = hold_inputs(cached[1], vals[lo:hi], cached[2])
            continue
        frame_stamps = stamps[frame_rows]
        j = latest_before(frame_stamps, times)
        held[name] = hold_inputs(frame_stamps, vals[lo:hi], j)
        if cached is None:
            latest[message] = (frame_rows, frame_stamps, j)
    mapped = [name for name in INPUT_NAMES if name in config.input_names] + (list(cylinder_inputs) if count > 1 else [])
    stale: dict[str, NDArray[np.bool_]] = {}
    tested: dict[tuple[int, float], NDArray[np.bool_]] = {}
    for name in mapped:
        key = (id(held[name].latest), config.input(name).stale_after_s)
        if key not in tested:
            tested[key] = held[name].stale(times, key[1])
        stale[name] = tested[key]
    fed = model_input_names(params[0], config.input_names)
    model_stale = np.zeros(n, dtype=bool)
    for name in fed:
        model_stale |= stale[name]
    inputs = {name: held[name] for name in fed}  # taken at the filter calls
    periods = {h.message: round(1.0 / (h.rate_hz * dt)) for h in config.health}
    rows = np.arange(periods["Health_Status"] - 1, n, periods["Health_Status"])  # steps k (1-based), k % period == 0
    status = held.get(STATUS_INPUT)
    cylinders = [
        _replay_cylinder(
            config.replace(detector=config.cylinder_detector(number)),
            model,
            times,
            inputs,
            held[name],
            model_stale | stale[name],
            status,
            periods,
            rows,
            keep_reference,
        )
        for number, (name, model) in enumerate(zip(cylinder_inputs, params, strict=True), start=1)
    ]
    cross_feeds: tuple[tuple[NDArray[np.float64], NDArray[np.float64]] | None, ...] = ()
    if config.cross_detectors:
        cylinders, cross_feeds = _cross_states(config, times, cylinders)
    bits = np.zeros(rows.size, dtype=np.int64)  # the stale bits of each health row
    for name in mapped:
        report = CHT_INPUT if name in cylinder_inputs else name
        bits |= stale[name][rows].astype(np.int64) << INPUT_NAMES.index(report)
    fault = STATES.index("SENSOR_FAULT")
    if count == 1:
        cyl = cylinders[0]
        out = {
            "time_s": times[rows],
            "cht_meas_c": cyl.reading,
            "cht_est_c": cyl.est,
            "deviation": cyl.deviation,
            "gamma_q": cyl.gamma_q,
            "gamma_d": cyl.gamma_d,
            "headroom_s": cyl.headroom,
            "state": cyl.state[rows].astype(np.int64),
            "stale": bits,
            "sensor_fault": cyl.code[rows] == fault,
        }
        return out, n, cyl.feed, (), cyl.reference
    out = {"time_s": times[rows], "stale": bits}
    for number, cyl in enumerate(cylinders, start=1):
        out.update({
            f"cyl{number}_cht_meas_c": cyl.reading,
            f"cyl{number}_cht_est_c": cyl.est,
            f"cyl{number}_deviation": cyl.deviation,
            f"cyl{number}_gamma_q": cyl.gamma_q,
            f"cyl{number}_gamma_d": cyl.gamma_d,
            f"cyl{number}_headroom_s": cyl.headroom,
            f"cyl{number}_state": cyl.state[rows].astype(np.int64),
        })  # fmt: skip
    out.update(engine_columns(out, count, config.spread_limit_c))
    return out, n, cylinders[0].feed, cross_feeds, cylinders[0].reference


def _cross_states(
    config: ServiceConfig, times: NDArray[np.float64], cylinders: list[_CylinderTrace]
) -> tuple[list[_CylinderTrace], tuple[tuple[NDArray[np.float64], NDArray[np.float64]] | None, ...]]:
    """Each cylinder's state with its cross-cylinder detector's verdict folded in (the more severe of the
    two), as Pipeline._cross_step does per step: the detector is fed the cylinder's symptom minus the
    median of the others' (estimation/cross_cylinder.py) from the cylinder's first initialisation.
    Also what each cross detector was fed: (step times s, cross symptom) from its start, None if never."""
    cross = cross_cylinder_symptoms(np.stack([cyl.fed for cyl in cylinders]))
    out = []
    feeds: list[tuple[NDArray[np.float64], NDArray[np.float64]] | None] = []
    for number, (cyl, symptom) in enumerate(zip(cylinders, cross, strict=True), start=1):
        settings = config.cross_detector(number)
        if settings is None or not cyl.stretches:
            out.append(cyl)
            feeds.append(None)
            continue
        verdict = detect_states(config.replace(detector=settings), times, cyl.code, cyl.first, symptom, cyl.stretches)
        nominal = cyl.code == 0
        state = cyl.state.copy()
        state[nominal] = np.maximum(state[nominal], verdict[nominal])
        out.append(cyl._replace(state=state))
        feeds.append((times[cyl.first :], symptom[cyl.first :]))
    return out, tuple(feeds)


class _CylinderTrace(NamedTuple):
    """One cylinder's outputs over a clock segment of the batch replay: the health rows' values (reading
    to headroom) and the per-step states and detector feed."""

    reading: NDArray[np.float64]
    est: NDArray[np.float64]
    deviation: NDArray[np.float64]
    gamma_q: NDArray[np.float64]
    gamma_d: NDArray[np.float64]
    headroom: NDArray[np.float64]
    state: NDArray[np.int64]  # final state code (the detector's verdict where NOMINAL)
    code: NDArray[np.int64]  # the supervisor's code
    feed: tuple[NDArray[np.float64], NDArray[np.float64]] | None  # what its detector was fed
    fed: NDArray[np.float64]  # the symptom its detector was fed per step (nan: not fed)
    first: int  # the step its detector starts at (its first initialisation)
    stretches: list[tuple[int, int]]  # where its estimator runs
    reference: ReferenceFeed | None  # the open-loop reference from ``first`` (kept when asked)


def _replay_cylinder(
    config: ServiceConfig,
    params: ThermalParams,
    times: NDArray[np.float64],
    inputs: dict[str, HeldInput],
    cht: HeldInput,
    any_stale: NDArray[np.bool_],
    status: HeldInput | None,
    periods: dict[str, int],
    rows: NDArray[np.int64],
    keep_reference: bool,
) -> _CylinderTrace:
    """One cylinder over a clock segment: supervision, estimator, isolation filter, detector, headroom;
    the values of the health rows taken at the steps ``rows``."""
    mixture = fed_mixture(params, config.input_names)
    if mixture is None and params.effects.mixture_index is not None:
        # the config maps no mixture index: its factor is 1, as live (NaN index; the pipeline warns)
        params = replace(params, effects=params.effects.replace("mixture_index", None))
    dt = config.estimator.dt_s
    n = times.size
    reading = cht.value
    new_reading = cht.new_frame()
    sf = config.sensor_fault
    with np.errstate(invalid="ignore"):
        reading_bad = ~np.isnan(reading) & ((reading < sf.min_c) | (reading > sf.max_c))
    if status is not None and status.values.size:
        # the sensor's status held at each step is one of the open-circuit values (tested on its frames)
        open_frames = np.zeros(status.values.size, dtype=bool)
        for value in sf.open_values:
            open_frames |= status.values == value
        reading_bad |= ~np.isnan(reading) & (status.latest >= 0) & open_frames[np.maximum(status.latest, 0)]
    run = compiled_supervisor()
    code = np.empty(n, dtype=np.int64)
    action = np.empty(n, dtype=np.int64)
    args = (config.stale_predict_limit_s, sf.stuck_after_s, sf.stuck_change_c, code, action)
    # pass 1: where the estimator runs (independent of the stuck test, which needs the open-loop model)
    run(times, any_stale, new_reading, reading, reading_bad, reading, *args)
    stretches = estimator_stretches(action)
    period = filter_period_steps(dt)
    # per stretch: the filter call steps (the steps k, 1-based, with k % period == 0, and the
    # initialisation), the steps each call's inputs hold for, the inputs held at the calls. The filters'
    # outputs are kept per call; call_of maps each step to its call (numbered over the segment, -1:
    # the estimator does not run), so nothing is made per step that the rows and the detector do not need
    call_of = np.full(n, -1, dtype=np.int64)
    plans: list[tuple[NDArray[np.int64], NDArray[np.int64], dict[str, NDArray[np.float64]], InputSeries]] = []
    stuck_model = reading.copy()  # the open-loop model the stuck test compares with (the reading where none)
    reference_parts: list[NDArray[np.float64]] = []
    calls_before = 0
    for a, b in stretches:
        at_calls = np.concatenate(([a], np.arange(period * ((a + 1) // period + 1) - 1, b, period)))
        held_steps = np.diff(at_calls, append=b)
        call_of[a:b] = np.repeat(np.arange(calls_before, calls_before + at_calls.size), held_steps)
        calls_before += at_calls.size
        at_inputs = {name: held.at(at_calls) for name, held in inputs.items()}
        # the model's inputs at the calls (the mixture index only if the config maps its columns)
        at_series = series_of(at_inputs, params.heat_axes, mixture)
        plans.append((at_calls, held_steps, at_inputs, at_series))
        # the open-loop reference: the nominal model from the first reading, the filters' inputs held
        reference = simulate_held(at_series, held_steps, coefficients(params), dt, float(reading[a]))
        reference_parts.append(reference)
        per_step = np.repeat(reference, held_steps)
        known = ~np.isnan(per_step)
        stuck_model[a:b][known] = per_step[known]
    # pass 2: with the open-loop model, the states and the estimator's actions
    run(times, any_stale, new_reading, reading, reading_bad, stuck_model, *args)
    del stuck_model
    if estimator_stretches(action) != stretches:  # the stuck test never starts or stops the estimator
        raise RuntimeError("replay: supervision passes disagree on where the estimator runs")
    parts: dict[str, list[NDArray[np.float64]]] = {k: [] for k in ("est", "deviation", "gamma_q", "gamma_d", "iso")}
    for (a, b), (at_calls, _, at_inputs, at_series) in zip(stretches, plans, strict=True):
        # a reading is applied at a call if one arrived since the previous call (in the steps after
        # max(call - period, a) up to the call: the latest reading's index grew) and the step is NOMINAL
        later = at_calls[1:]
        window = cht.latest[later] > cht.latest[np.maximum(later - period, a)]
        z = np.concatenate(([reading[a]], np.where(window & (code[later] == 0), reading[later], np.nan)))
        trace = run_estimator_on_calls(times[a:b], at_calls - a, at_series, z, params, config.estimator_name,
                                       config.estimator)  # fmt: skip
        parts["est"].append(trace.cht_est_c)
        parts["deviation"].append(trace.deviation)
        # the isolation filter on the call steps: each call integrates the steps since the previous one
        # (run_isolation's sub-steps) with that call's inputs, as the live filter does
        calls_log = FlightLog({"time_s": times[at_calls], **at_inputs, "cht_c": z}, source="replay")
        iso = run_isolation(calls_log, params, IsolationSettings(dt_s=dt))
        parts["gamma_q"].append(iso.gamma_q)
        parts["gamma_d"].append(iso.gamma_d)
        parts["iso"].append(iso.deviation)
    at_call = {k: np.concatenate(v) if v else np.zeros(0) for k, v in parts.items()}
    symptom = at_call["deviation"] if config.detector_symptom == "estimator" else at_call["iso"]
    first, fed = detector_feed(code, symptom, call_of, stretches)
    state = detect_states(config, times, code, first, fed, stretches)
    feed = (times[first:], fed[first:]) if stretches else None
    headroom = held_headroom(params, times, inputs, at_call["est"], at_call["gamma_q"], at_call["gamma_d"], call_of,
                             action, periods.get("Health_Isolation", periods["Health_Status"]), rows)  # fmt: skip
    kept = None
    if keep_reference and stretches:
        off = code[first:] != 0
        oat = inputs["oat_c"].at(np.arange(first, n)) if "oat_c" in inputs else np.full(n - first, np.nan)
        model_c = _per_call(np.concatenate(reference_parts), call_of[first:])
        values = (reading[first:], model_c, oat)
        kept = ReferenceFeed(times[first:], *(np.where(off, np.nan, v) for v in values))
    at_rows = call_of[rows]
    est, deviation, gamma_q, gamma_d = (_per_call(at_call[k], at_rows) for k in ("est", "deviation", "gamma_q",
                                                                                  "gamma_d"))  # fmt: skip
    return _CylinderTrace(reading[rows], est, deviation, gamma_q, gamma_d, headroom, state, code, feed, fed,
                          first, stretches, kept)  # fmt: skip


def _per_call(values: NDArray[np.float64], call: NDArray[np.int64]) -> NDArray[np.float64]:
    """``values`` (one per filter call) at the steps whose calls are ``call`` (-1: none, nan)."""
    if not values.size:
        return np.full(call.shape, np.nan)
    out = values[np.maximum(call, 0)]
    out[call < 0] = np.nan
    return out


def replay_file(
    path: str | os.PathLike[str], config: ServiceConfig, params: ThermalParams | Sequence[ThermalParams]
) -> ReplayResult:
    """Replay a python-can log or a canonical flight CSV through the batch path."""
    suffix = Path(path).suffix.lower()
    if suffix in CAN_LOG_SUFFIXES:
        return replay_frames(config, params, read_frames(path))
    if suffix == ".csv":
        first = params if isinstance(params, ThermalParams) else params[0]
        needed = (*model_input_names(first, config.input_names), *config.cylinder_inputs)
        return replay_frames(config, params, frames_from_flight(load_flight(path), config, needed))
    raise FlightLogError(f"{path}: unknown log format '{suffix}' (expected .csv, {', '.join(CAN_LOG_SUFFIXES)})")
