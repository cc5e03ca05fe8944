"""Replay: the live pipeline over a recorded log, as fast as the machine allows.

The log is read into arrays (:func:`ecu_monitor.bus.canlog.read_frames`, the one CAN-log reader) and
decoded with numpy (:meth:`Decoder.decode_batch`, the live decoder's checks on whole arrays); then the
compiled loop (:meth:`Pipeline.run_frames`) runs the live loop over it: for each frame, the clock advanced
to its time and its values held, every step the one step the daemon runs. The loop hands over its rows a
block at a time; with ``out``, a second thread formats and writes them (health.csv) while the loop, which
releases the GIL, goes on. :func:`replay_live` feeds the same frames one by one through
:meth:`Pipeline.feed` and :meth:`Pipeline.advance_to` (``--live``).

A canonical flight CSV is replayed through the same path: :func:`frames_from_flight` turns its rows into
the frames the ECU would have sent.
"""

from __future__ import annotations

import contextlib
import itertools
import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import can
import numba
import numpy as np
from numpy.typing import NDArray

from ecu_monitor.bus.canlog import CAN_LOG_SUFFIXES, FrameArrays, load_flight, read_frames, time_gaps
from ecu_monitor.errors import FlightLogError
from ecu_monitor.model import ThermalParams
from ecu_monitor.offline.flight_frames import frames_from_flight
from ecu_monitor.pipeline.cylinders import engine_columns
from ecu_monitor.pipeline.engine import SLOT_DTYPE, Pipeline, model_input_names
from ecu_monitor.pipeline.events import Event, finished
from ecu_monitor.pipeline.output_table import output_fields
from ecu_monitor.pipeline.outputs import (
    HealthSnapshot,
    ReferenceFeed,
    ReplayResult,
    empty_columns,
    health_table_columns,
    rows_to_columns,
    write_health_csv,
)
from ecu_monitor.pipeline.schedule import MAX_CLOCK_S
from ecu_monitor.pipeline.step import Rows, Traces
from ecu_monitor.pipeline.supervision import CODE_FAULT, CODE_NOMINAL
from ecu_monitor.pipeline.table import table_stream

__all__ = [
    "ReplayResult",
    "frames_from_flight",
    "replay_file",
    "replay_frames",
    "replay_live",
    "replay_tlog",
    "tlog_messages",
    "write_health_csv",
]

_Feed = tuple[NDArray[np.float64], NDArray[np.float64]]


def replay_live(
    config: Any,
    params: ThermalParams | Sequence[ThermalParams],
    frames: Iterable[can.Message],
    on_rows: Callable[[Pipeline, list[HealthSnapshot], list[Event]], None] | None = None,
) -> ReplayResult:
    """The replay frame by frame through the live calls (``replay --live``). ``on_rows(pipeline, rows,
    events)`` is called with the rows and the event records (pipeline/events.py) each frame completes, the
    pipeline's held inputs as they are then (as the daemon reads them: ``replay --history`` records the
    flights with it)."""
    pipeline = Pipeline(config, params)
    rows: list[HealthSnapshot] = []
    events: list[Event] = []
    for msg in frames:
        pipeline.advance_to(msg.timestamp)
        pipeline.feed(msg)
        new = pipeline.drain_rows()
        fresh = pipeline.take_events()
        if (new or fresh) and on_rows is not None:
            on_rows(pipeline, new, fresh)
        rows.extend(new)
        events += fresh
    events += pipeline.close_events()
    return ReplayResult(rows_to_columns(rows, len(pipeline.cylinder_params)), dict(pipeline.counters),
                        events=tuple(finished(events)))  # fmt: skip


def replay_frames(
    config: Any,
    params: ThermalParams | Sequence[ThermalParams],
    frames: FrameArrays,
    *,
    keep_feeds: bool = False,
    keep_reference: bool = False,
    out: str | os.PathLike[str] | None = None,
) -> ReplayResult:
    """The replay of ``frames`` in one compiled call (module docstring); rows equal to :func:`replay_live`.
    ``params``: the model of every cylinder, or one per cylinder. ``keep_feeds``: also keep what the
    detectors were fed per step (:attr:`ReplayResult.detector_feed`, ``cross_feeds``; calibrate's input);
    ``keep_reference``: also the open-loop reference per step (:attr:`ReplayResult.reference_feed`).
    ``out``: health.csv (or Parquet / Arrow by the suffix), written as the loop runs; nothing is written
    when no row is."""
    pipeline = Pipeline(config, params, rows="status")
    count = pipeline.cylinder_count
    counters = dict(pipeline.counters)
    n = len(frames)
    if n == 0:
        return ReplayResult(empty_columns(count), counters)
    # the decoder's stamps (its counter check resynchronises after a silence): the clock's, as the live feed
    stamps = np.where(np.isfinite(frames.time_s) & (np.abs(frames.time_s) < MAX_CLOCK_S), frames.time_s, -np.inf)
    stamps = np.floor(stamps * 1e6 + 0.5) / 1e6
    np.maximum.accumulate(stamps, out=stamps)
    start = int(np.argmax(stamps > -np.inf))
    if not np.isfinite(stamps[start]):
        return ReplayResult(empty_columns(count), counters)
    stamps[:start] = stamps[start]
    batch = pipeline.decoder.decode_batch(frames.arbitration_id, frames.is_extended, frames.dlc, frames.data, stamps,
                                          frames.ignored)  # fmt: skip
    for key, value in batch.counts.items():
        counters[key] = counters.get(key, 0) + value
    counters["bus_errors"] = int(np.count_nonzero(frames.ignored))
    first_value, slots, values = _values_by_frame(pipeline.names, batch.values, n)
    return _run(pipeline, config, frames.time_s, first_value, slots, values, counters, tuple(time_gaps(stamps)),
                keep_feeds, keep_reference, out)  # fmt: skip


def replay_tlog(
    path: str | os.PathLike[str],
    config: Any,
    params: ThermalParams | Sequence[ThermalParams],
    *,
    keep_feeds: bool = False,
    keep_reference: bool = False,
    out: str | os.PathLike[str] | None = None,
) -> ReplayResult:
    """The replay of a MAVLink telemetry log (``.tlog``, as ground stations record it) with a ``protocol:
    mavlink`` config: each message decoded (bus/mavlink.py) at its log time, then the same compiled loop as
    a CAN log's (``out`` as :func:`replay_frames`)."""
    from ecu_monitor.bus.mavlink_log import iter_tlog

    if config.protocol != "mavlink":
        raise FlightLogError(f"{path}: a MAVLink log needs a config with protocol: mavlink (the shipped mavlink.yaml)")
    pipeline = Pipeline(config, params, rows="status")
    times: list[float] = []
    first: list[int] = [0]
    slots: list[int] = []
    values: list[float] = []
    for time_s, msg in iter_tlog(path):
        decoded = pipeline.decoder.decode(msg) or ()
        times.append(time_s)
        for slot, value in decoded:
            slots.append(slot)
            values.append(value)
        first.append(len(slots))
    counters = dict(pipeline.counters)
    time_arr = np.array(times, dtype=np.float64)
    if time_arr.size == 0:
        return ReplayResult(empty_columns(pipeline.cylinder_count), counters)
    return _run(pipeline, config, time_arr, np.array(first, dtype=np.int64), np.array(slots, dtype=np.int64),
                np.array(values, dtype=np.float64), counters, (), keep_feeds, keep_reference, out)  # fmt: skip


def tlog_messages(path: str | os.PathLike[str]) -> Iterable[Any]:
    """The messages of a ``.tlog`` stamped with their log time (``timestamp``, s), for :func:`replay_live`."""
    from ecu_monitor.bus.mavlink_log import iter_tlog

    for time_s, msg in iter_tlog(path):
        msg.timestamp = time_s
        yield msg


def _run(
    pipeline: Pipeline,
    config: Any,
    frame_time_s: NDArray[np.float64],
    first_value: NDArray[np.int64],
    slots: NDArray[np.int16],
    values: NDArray[np.float64],
    counters: dict[str, int],
    gaps: tuple[tuple[float, float], ...],
    keep_feeds: bool,
    keep_reference: bool,
    out: str | os.PathLike[str] | None,
) -> ReplayResult:
    """The compiled loop over decoded frames, and the replay's result from its output table, a block of
    rows at a time (written to ``out`` by a second thread while the loop goes on)."""
    count = pipeline.cylinder_count
    traces = keep_feeds or keep_reference
    blocks: list[dict[str, NDArray[Any]]] = []
    with table_stream(out) if out is not None else contextlib.nullcontext(None) as write:

        def on_rows(rows: Rows, n: int) -> None:
            blocks.append(_columns(rows, n, count, config.spread_limit_c, pipeline.stale_bits))
            if write is not None:
                write(health_table_columns(blocks[-1], count))

        kept = pipeline.run_frames(frame_time_s, first_value, slots, values, on_rows, traces=traces)
    events = tuple(finished(pipeline.close_events()))
    for key in ("steps", "clock_restarts", "events_dropped"):
        counters[key] = pipeline.counters[key]
    columns = empty_columns(count)
    if blocks:
        columns = {name: np.concatenate([b[name] for b in blocks]) for name in blocks[0]}
    feeds: tuple[_Feed, ...] = ()
    cross: tuple[tuple[_Feed, ...], ...] = ()
    reference: tuple[ReferenceFeed, ...] = ()
    regions: tuple[NDArray[np.int64], ...] = ()
    fits: tuple[NDArray[np.float64], ...] = ()
    if traces:
        feeds, cross, reference, regions, fits = _feeds(kept, count, config, keep_reference)
    return ReplayResult(columns, counters, feeds, gaps, cross, reference, detector_regions=regions, events=events,
                        start_fits=fits)  # fmt: skip


def _values_by_frame(
    names: tuple[str, ...], decoded: dict[str, tuple[NDArray[np.int64], NDArray[np.float64]]], n: int
) -> tuple[NDArray[np.int64], NDArray[np.int16], NDArray[np.float64]]:
    """The decoded values in frame order: (index of each frame's first value, n + 1; slot, as
    :data:`SLOT_DTYPE`; value). Within a frame, the values keep the order of ``names`` (a compiled merge of
    the per-name runs, each in frame order, read where the decoder left them: no joined copy)."""
    if not names:
        return np.zeros(n + 1, dtype=np.int64), np.zeros(0, dtype=SLOT_DTYPE), np.zeros(0)
    frames = tuple(np.ascontiguousarray(decoded[name][0], dtype=np.int64) for name in names)
    values = tuple(np.ascontiguousarray(decoded[name][1], dtype=np.float64) for name in names)
    return _by_frame(frames, values, n)


@numba.njit(cache=True, nogil=True)
def _by_frame(
    frames: tuple[NDArray[np.int64], ...], values: tuple[NDArray[np.float64], ...], n: int
) -> tuple[NDArray[np.int64], NDArray[np.int16], NDArray[np.float64]]:  # pragma: no cover - compiled
    """Merge the runs ``frames[j]`` (slot j's frames, ascending; its values ``values[j]``) into frame order:
    a counting sort, slot by slot (each run read once, from its tuple once)."""
    first = np.zeros(n + 1, dtype=np.int64)
    for j in range(len(frames)):  # first[f + 1]: frame f's count, then the running sum: f's first value
        run = frames[j]
        for c in range(run.size):
            first[run[c] + 1] += 1
    for f in range(n):
        first[f + 1] += first[f]
    out_slots = np.empty(first[n], dtype=SLOT_DTYPE)
    out_values = np.empty(first[n])
    for j in range(len(frames)):  # first[f]: where frame f's next value goes, moved on as it is filled
        run = frames[j]
        vals = values[j]
        for c in range(run.size):
            at = first[run[c]]
            out_slots[at] = j
            out_values[at] = vals[c]
            first[run[c]] = at + 1
    for f in range(n, 0, -1):  # each first[f] now holds frame f + 1's start: shifted back by one
        first[f] = first[f - 1]
    first[0] = 0
    return first, out_slots, out_values


def _columns(
    rows: Rows, n: int, count: int, spread_limit_c: float | None,
    stale_bits: Callable[[NDArray[np.int64]], NDArray[np.int64]],
) -> dict[str, NDArray[Any]]:  # fmt: skip
    """The replay's columns (ReplayResult.columns) of the first ``n`` rows of its output table (copies)."""
    results = rows.cylinders[:n]
    out: dict[str, NDArray[Any]] = {"time_s": rows.time_s[:n].copy(), "stale_inputs": stale_bits(rows.stale[:n])}
    if count == 1:
        r = results[:, 0]
        out.update({name: r[name].copy() for name, _ in output_fields()})
        out["sensor_fault"] = r["state"] == CODE_FAULT
        return out
    for i in range(count):
        r = results[:, i]
        out.update({f"cyl{i + 1}_{name}": r[name].copy() for name, _ in output_fields()})
    out.update(engine_columns(out, count, spread_limit_c))
    return out


def _feeds(kept: Traces, count: int, config: Any, keep_reference: bool) -> tuple[
    tuple[_Feed, ...], tuple[tuple[_Feed, ...], ...], tuple[ReferenceFeed, ...], tuple[NDArray[np.int64], ...],
    tuple[NDArray[np.float64], ...],
]:  # fmt: skip
    """Per clock segment whose detectors started: what the first cylinder's detector was fed, what each
    cylinder's cross-cylinder detector was fed, the open-loop reference, the first cylinder's regions and its
    start fits at the segment's end."""
    n = int(kept.count[0])
    time_s = kept.time_s[:n]
    segments = np.flatnonzero(np.diff(kept.restart[:n])) + 1
    bounds = [0, *segments.tolist(), n]
    feeds: list[_Feed] = []
    regions: list[NDArray[np.int64]] = []
    fits: list[NDArray[np.float64]] = []
    reference: list[ReferenceFeed] = []
    cross: list[list[_Feed]] = [[] for _ in range(count)]
    for a, b in itertools.pairwise(bounds):
        for i in range(count):
            on = np.flatnonzero(kept.detector_on[a:b, i])
            if not on.size:
                continue
            first = a + int(on[0])
            out = kept.cylinders[first:b, i]
            if i == 0:
                feeds.append((time_s[first:b].copy(), out["fed"].copy()))
                regions.append(out["region"].astype(np.int64))
                fits.append(out["start_fit"][-1].copy())
                if keep_reference:
                    off = out["code"] != CODE_NOMINAL
                    values = (out["cht_meas_c"], kept.model_c[first:b, 0], kept.oat_c[first:b])
                    reference.append(ReferenceFeed(time_s[first:b].copy(), *(np.where(off, np.nan, v) for v in values)))
            if config.cross_detector(i + 1) is not None:
                cross[i].append((time_s[first:b].copy(), out["cross_fed"].copy()))
    cross_feeds = tuple(tuple(c) for c in cross) if config.cross_detectors else ()
    return tuple(feeds), cross_feeds, tuple(reference), tuple(regions), tuple(fits)


def replay_file(
    path: str | os.PathLike[str],
    config: Any,
    params: ThermalParams | Sequence[ThermalParams],
    *,
    keep_feeds: bool = False,
    out: str | os.PathLike[str] | None = None,
) -> ReplayResult:
    """Replay a python-can log, a MAVLink log or a canonical flight CSV (``out`` as :func:`replay_frames`)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".tlog":
        return replay_tlog(path, config, params, keep_feeds=keep_feeds, out=out)
    if suffix in CAN_LOG_SUFFIXES:
        return replay_frames(config, params, read_frames(path), keep_feeds=keep_feeds, out=out)
    if suffix == ".csv":
        first = params if isinstance(params, ThermalParams) else params[0]
        needed = (*model_input_names(first, config.input_names), *config.cylinder_inputs)
        return replay_frames(config, params, frames_from_flight(load_flight(path), config, needed),
                             keep_feeds=keep_feeds, out=out)  # fmt: skip
    raise FlightLogError(f"{path}: unknown log format '{suffix}' (expected .csv, .tlog, {', '.join(CAN_LOG_SUFFIXES)})")
