"""The time axis of a foreign export: date and clock columns (several firmware formats), UTC offsets,
whole-second stamps shared by several rows spread over their second."""

from __future__ import annotations

import datetime as _dt
import math
import re
from collections.abc import Mapping, Sequence

import numpy as np

from ecu_monitor.errors import FlightLogError
from ecu_monitor.flightlog.mapping import TimeMap
from ecu_monitor.flightlog.table import _note, _numbers, _Table
from ecu_monitor.units import UNITS

_EPOCH = _dt.datetime(1970, 1, 1)


def _spread_repeats(src: str, stamps: np.ndarray, lines: np.ndarray, notes: list[str]) -> np.ndarray:
    """Whole-second stamps: the k rows sharing one second are spread evenly over it (s, s + 1/k, ...)."""
    if stamps.size < 2 or not np.all(stamps == np.round(stamps)):
        return stamps
    new_group = np.concatenate(([True], np.diff(stamps) != 0.0))
    if np.all(new_group):
        return stamps
    group = np.cumsum(new_group) - 1
    starts = np.flatnonzero(new_group)
    sizes = np.diff(np.append(starts, stamps.size))
    position = np.arange(stamps.size) - starts[group]
    shared = int(stamps.size - starts.size)
    _note(
        notes,
        src,
        f"{shared} row(s) share a whole-second stamp with the row before: spread evenly over that second"
        f" (first at row {lines[int(np.argmin(new_group))]})",
    )
    return stamps + position / sizes[group]


def _parse_time(
    src: str, spec: TimeMap, table: _Table, index: Mapping[str, int], lines: np.ndarray, notes: list[str]
) -> np.ndarray:
    if spec.kind == "seconds":
        if spec.columns[0] not in index:  # only reached with row_step_s (checked by the caller)
            step = float(spec.row_step_s or 1.0)
            _note(notes, src, f"no column {spec.columns[0]!r}: row k is at k * {step:g} s")
            return step * np.arange(len(table.rows), dtype=np.float64)
        col = index[spec.columns[0]]
        values = _numbers(src, spec.columns[0], [r[col] for _, r in table.rows], lines)
        if np.any(np.isnan(values)):
            k = int(np.argmax(np.isnan(values)))
            raise FlightLogError(f"{src}: row {lines[k]}, column '{spec.columns[0]}': blank time")
        return _spread_repeats(src, (values - values[0]) * UNITS[spec.unit].scale, lines, notes)
    date_col, time_col = (index[c] for c in spec.columns)
    formats = [f"{d} {t}" for d in spec.date_formats for t in spec.time_formats]
    whole_seconds = spec.time_formats[0] == "%H:%M:%S"  # the fast path for H:MM:SS; other forms by strptime
    stamps = np.empty(len(table.rows), dtype=np.float64)
    midnights: dict[str, float] = {}
    for k, (line, row) in enumerate(table.rows):
        date, clock = row[date_col].strip(), row[time_col].strip()
        value = _stamp(date, clock, spec.date_formats, formats, midnights if whole_seconds else None)
        if value is None:
            raise FlightLogError(
                f"{src}: row {line}, columns '{spec.columns[0]}', '{spec.columns[1]}': {date + ' ' + clock!r}"
                f" matches none of the formats {', '.join(repr(f) for f in formats)}"
            )
        stamps[k] = value
    if spec.utc_offset_column is not None and spec.utc_offset_column in index:
        stamps = stamps - _utc_offsets(src, spec.utc_offset_column, table, index, lines, notes)
    return _spread_repeats(src, stamps - stamps[0], lines, notes)


_OFFSET = re.compile(r"^([+-])([0-9]{1,2}):?([0-9]{2})$")


def _utc_offsets(
    src: str, column: str, table: _Table, index: Mapping[str, int], lines: np.ndarray, notes: list[str]
) -> np.ndarray:
    """Local-minus-UTC offset of every row, s, from a ``+08:00`` column; a blank takes the row before's
    (leading blanks the first known)."""
    col = index[column]
    offsets = np.full(len(table.rows), math.nan)
    cache: dict[str, float] = {}
    for k, (line, row) in enumerate(table.rows):
        text = row[col].strip() if col < len(row) else ""
        if not text:
            continue
        value = cache.get(text)
        if value is None:
            match = _OFFSET.match(text)
            if match is None:
                raise FlightLogError(f"{src}: row {line}, column '{column}': {text!r} is not a UTC offset like +08:00")
            sign = -1.0 if match.group(1) == "-" else 1.0
            value = cache[text] = sign * (3600.0 * int(match.group(2)) + 60.0 * int(match.group(3)))
        offsets[k] = value
    known = ~np.isnan(offsets)
    if not np.any(known):
        _note(notes, src, f"column '{column}' is blank in every row: local time used")
        return np.zeros(len(table.rows))
    offsets = _fill_forward(offsets)
    changes = np.flatnonzero(np.diff(offsets) != 0.0)
    if changes.size:
        k = int(changes[0]) + 1
        _note(
            notes,
            src,
            f"column '{column}': the UTC offset changes {changes.size} time(s) (first at row {lines[k]},"
            f" {offsets[k - 1] / 3600.0:+g} h -> {offsets[k] / 3600.0:+g} h): time built in UTC",
        )
    return offsets


_HMS = re.compile(r"^([01]?[0-9]|2[0-3]):([0-5][0-9]):([0-5][0-9])$")


def _stamp(
    date: str,
    clock: str,
    date_formats: Sequence[str],
    formats: Sequence[str],
    midnights: dict[str, float] | None,
) -> float | None:
    """Seconds since 1970 of a local date and time (no time zone), or None if no format matches.

    With ``midnights`` (time format ``%H:%M:%S``) each date is parsed once and the clock is added to
    its midnight, so a long log costs one ``strptime`` per day rather than per row.
    """
    hms = _HMS.match(clock) if midnights is not None else None
    if hms is not None and midnights is not None:
        midnight = midnights.get(date)
        if midnight is None:
            for fmt in date_formats:
                try:
                    midnight = (_dt.datetime.strptime(date, fmt) - _EPOCH).total_seconds()
                except ValueError:
                    continue
                midnights[date] = midnight
                break
        if midnight is not None:
            h, m, sec = (int(g) for g in hms.groups())
            return midnight + 3600.0 * h + 60.0 * m + sec
    for fmt in formats:
        try:
            return (_dt.datetime.strptime(f"{date} {clock}", fmt) - _EPOCH).total_seconds()
        except ValueError:
            continue
    return None


def _fill_forward(values: np.ndarray) -> np.ndarray:
    """NaN take the value of the row before (leading NaN the first value); at least one must be known."""
    known = ~np.isnan(values)
    if np.all(known):
        return values
    filled_from = np.maximum.accumulate(np.where(known, np.arange(values.size), 0))
    filled_from[: int(np.argmax(known))] = int(np.argmax(known))
    return values[filled_from]
