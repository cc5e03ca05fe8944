"""MAVLink telemetry logs (``.tlog``, as ground stations and MAVProxy record them) -> flight logs.

A .tlog is the link's byte stream with each message preceded by the time it was received, microseconds
since 1970 as a big-endian 64-bit integer; pymavlink reads it (``mavutil.mavlink_connection(path)``,
each message stamped with that time in ``_timestamp``), here through the MAVLink 2 dialect of
:func:`ecu_monitor.bus.mavlink.mavlink_module`, which reads MAVLink 1 frames too.

* :func:`iter_tlog`: ``(time_s, message)`` in log order (the log's own clock, s since 1970; damaged
  bytes are skipped by pymavlink's robust parser and counted by the decoder), the source the replay
  will feed the service's step with;
* :func:`read_tlog`: the log decoded by :class:`~ecu_monitor.bus.mavlink.MavlinkDecoder` (specs: the
  default mapping :data:`~ecu_monitor.bus.mavlink.DEFAULT_FIELDS`, or a config's inputs) and sampled
  and held onto a uniform grid (default 0.1 s) into a :class:`~ecu_monitor.flightlog.FlightLog` of
  canonical columns, as :func:`ecu_monitor.bus.canlog.import_can_log` does for a CAN log: rows from the
  first instant every column has a value to the last message; ``time_s`` counts from that instant;
  no row inside a hole of the log (no message for more than :data:`~ecu_monitor.flightlog.GAP_WARN_S`:
  a link lost, a log paused), so the flight log keeps the hole as a time gap. With the default mapping
  a column takes the first candidate field the log carries (``altitude_m``: SCALED_PRESSURE's pressure
  altitude, else VFR_HUD.alt) and a column no candidate of which is in the log is left out; the
  columns every flight log needs (``rpm, altitude_m, airspeed_mps, oat_c, cht_c``) missing is a
  FlightLogError naming them.

ArduPilot's dataflash logs (``.bin``, written on the autopilot's SD card) are not read here: pymavlink
reads them (``mavutil.mavlink_connection("x.bin")`` gives a ``DFReader_binary``, messages EFI, ECYL,
ARSP, BARO ... with their own field names), but no library we found writes one, so there is no test file
to build the mapping on (docs/service.md, "MAVLink").
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ecu_monitor.bus.codec import SignalSpec
from ecu_monitor.bus.mavlink import DEFAULT_FIELDS, MAVLINK_REASONS, MavlinkDecoder, mavlink_module
from ecu_monitor.errors import FlightLogError
from ecu_monitor.flightlog import CANONICAL_COLUMNS, GAP_WARN_S, FlightLog

__all__ = ["TLOG_SUFFIXES", "iter_tlog", "read_tlog"]

_log = logging.getLogger(__name__)

#: Suffixes read as MAVLink telemetry logs.
TLOG_SUFFIXES: tuple[str, ...] = (".tlog",)
_TIE_S = 1e-5  # a message this close after a grid instant counts as at it (stamps of 1.7e9 s carry ~2e-7 s of rounding)
#: Columns a flight log must have (throttle may be missing: the heat map may use fuel flow instead).
_REQUIRED = tuple(c for c in CANONICAL_COLUMNS if c not in ("time_s", "throttle_pct"))


def iter_tlog(path: str | os.PathLike[str]) -> Iterator[tuple[float, Any]]:
    """``(time_s, message)`` of every message of a .tlog in log order (time: the log's stamp, s since
    1970), BAD_DATA pieces included (a decoder counts them); FlightLogError if the file cannot be read."""
    src = str(path)
    if not Path(src).is_file():
        raise FlightLogError(f"{src}: no such file")
    mavlink_module()
    from pymavlink import mavutil

    try:
        log = mavutil.mavlogfile(src, robust_parsing=True)
    except OSError as exc:
        raise FlightLogError(f"{src}: cannot read: {exc.strerror or exc}") from None
    try:
        while True:
            try:
                msg = log.recv_msg()
            except (mavutil.mavlink.MAVError, ValueError, IndexError) as exc:  # a cut last frame, garbage
                _log.warning("%s: reading stopped at byte %d: %s", src, log.f.tell(), exc)
                return
            if msg is None:
                return
            yield float(msg._timestamp), msg
    finally:
        log.close()


def read_tlog(
    path: str | os.PathLike[str],
    specs: Sequence[SignalSpec] | None = None,
    *,
    source_system: int | None = None,
    source_component: int | None = None,
    dt_s: float = 0.1,
) -> FlightLog:
    """A .tlog as a flight log (module docstring). ``specs``: the columns and their fields (None: the
    default mapping); ``source_system`` / ``source_component``: read only that sender (None: any)."""
    src = str(path)
    if not (math.isfinite(dt_s) and dt_s > 0.0):
        raise FlightLogError(f"{src}: sample step must be a positive number, got {dt_s!r}")
    candidates = _candidate_specs() if specs is None else [(spec.name, spec) for spec in specs]
    decoder = MavlinkDecoder([spec for _, spec in candidates], source_system, source_component)
    found: list[list[tuple[float, float]]] = [[] for _ in candidates]
    stamps: list[float] = []
    for time_s, msg in iter_tlog(src):
        stamps.append(time_s)
        decoded = decoder.decode(msg)
        if decoded:
            for slot, value in decoded:
                found[slot].append((time_s, value))
    if not stamps:
        raise FlightLogError(f"{src}: no MAVLink message in the file")
    notes: list[str] = []
    counts = decoder.counters
    if counts["malformed"]:
        reasons = ", ".join(f"{r} {counts[r]}" for r in MAVLINK_REASONS if counts[r])
        _note(notes, src, f"{counts['malformed']} damaged piece(s) of the stream skipped ({reasons})")
    if counts["filtered_source"]:
        _note(notes, src, f"{counts['filtered_source']} message(s) of other senders left out")
    for warning in decoder.warnings:
        _note(notes, src, warning)
    columns = _choose(candidates, found)
    missing = [c for c in _REQUIRED if c not in columns]
    if missing:
        wanted = "; ".join(f"{c}: {_fields_of(c, candidates)}" for c in missing)
        raise FlightLogError(
            f"{src}: no {', '.join(missing)} in the log ({len(stamps)} messages read; looked for {wanted})"
        )
    clock = np.maximum.accumulate(np.asarray(stamps, dtype=np.float64))
    start = max(float(times[0]) for times, _ in columns.values())
    n = math.floor((float(clock[-1]) - start + _TIE_S) / dt_s) + 1
    offsets = np.round(dt_s * np.arange(max(n, 1), dtype=np.float64), 9)
    grid = start + offsets
    keep = np.ones(grid.size, dtype=bool)
    holes = np.flatnonzero(np.diff(clock) > GAP_WARN_S)
    for i in holes.tolist():
        keep &= ~((grid > clock[i] + dt_s) & (grid < clock[i + 1]))
    if holes.size:
        longest = float(np.max(np.diff(clock)[holes]))
        _note(
            notes,
            src,
            f"{holes.size} hole(s) in the log longer than {GAP_WARN_S:g} s (longest {longest:.1f} s): no rows",
        )
    out: dict[str, np.ndarray] = {"time_s": offsets[keep]}
    for name, (times, values) in columns.items():
        out[name] = values[np.searchsorted(times, grid[keep] + _TIE_S, side="right") - 1]
    return FlightLog(out, src, tuple(notes))


def _candidate_specs() -> list[tuple[str, SignalSpec]]:
    """(column, spec) of every candidate of the default mapping, each spec under its own name."""
    out = []
    for column, options in DEFAULT_FIELDS.items():
        for k, (ref, unit) in enumerate(options):
            message, field = ref.split(".", 1)
            out.append((column, SignalSpec(column if k == 0 else f"{column}#{k}", message, field, unit)))
    return out


def _choose(
    candidates: list[tuple[str, SignalSpec]], found: list[list[tuple[float, float]]]
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """column -> (times, values) of the first candidate of each column with values, in time order."""
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for (column, _), pairs in zip(candidates, found, strict=True):
        if column in out or not pairs:
            continue
        times = np.maximum.accumulate(np.fromiter((p[0] for p in pairs), dtype=np.float64, count=len(pairs)))
        out[column] = (times, np.fromiter((p[1] for p in pairs), dtype=np.float64, count=len(pairs)))
    return out


def _fields_of(column: str, candidates: list[tuple[str, SignalSpec]]) -> str:
    return " or ".join(f"{spec.message}.{spec.signal}" for name, spec in candidates if name == column)


def _note(notes: list[str], source: str, message: str) -> None:
    notes.append(message)
    _log.warning("%s: %s", source, message)
