"""The canonical rules applied by both readers: physical limits, time order, repeated timestamps,
blank runs (interpolated when short) and time gaps."""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np

from ecu_monitor.errors import FlightLogError
from ecu_monitor.flightlog.log import (
    _STRICT,
    CYLINDER_COLUMN,
    GAP_WARN_S,
    MAX_BLANK_RUN,
    MAX_FLIGHT_S,
    MAX_MEDIAN_STEP_S,
    PHYSICAL_LIMITS,
    FlightLog,
)
from ecu_monitor.flightlog.table import _note

_log = logging.getLogger(__name__)


def _limits(name: str) -> tuple[float, float] | None:
    """Physical range of a column; a cylinder column has the range of its mean (``cht3_c`` as ``cht_c``)."""
    match = CYLINDER_COLUMN.match(name)
    return PHYSICAL_LIMITS.get(f"{match.group(1)}_c" if match else name)


def _is_strict(name: str) -> bool:
    """Columns that must be numeric, with short blank runs interpolated and long ones an error."""
    return name in _STRICT or CYLINDER_COLUMN.match(name) is not None


def _assemble(
    src: str,
    time: np.ndarray,
    cols: dict[str, np.ndarray],
    lines: np.ndarray,
    notes: list[str],
    *,
    strict: Callable[[str], bool] = _is_strict,
    soft: frozenset[str] = frozenset(),
) -> FlightLog:
    """Apply the canonical rules (limits, time order, repeats, blanks, gaps) and build the log.

    Blank fields: a ``strict`` column has short runs interpolated and a long run or an all-blank
    column is an error, except a cylinder column, which is dropped with a note when blank in every row
    (a dead probe); a ``soft`` column (an optional column of a mapping) has short runs interpolated,
    long runs kept as NaN and is dropped with a note when blank in every row; any other column keeps
    its blanks as NaN.
    """
    for name, values in cols.items():
        lo_hi = _limits(name)
        if lo_hi is None:
            continue
        lo, hi = lo_hi
        bad = (values < lo) | (values > hi)  # NaN compares False
        if np.any(bad):
            k = int(np.argmax(bad))
            raise FlightLogError(
                f"{src}: row {lines[k]}, column '{name}': {values[k]:g} is outside the physical range {lo:g}..{hi:g}"
            )
    if time.size > 1:
        previous_max = np.maximum.accumulate(time)[:-1]
        back = time[1:] < previous_max
        if np.any(back):
            k = int(np.argmax(back)) + 1
            raise FlightLogError(
                f"{src}: row {lines[k]}, column 'time_s': time goes backwards"
                f" ({time[k]:g} s after {previous_max[k - 1]:g} s)"
            )
        keep = np.concatenate(([True], np.diff(time) > 0.0))
        repeats = int(keep.size - np.count_nonzero(keep))
        if repeats:
            first = int(lines[int(np.argmin(keep))])
            _note(notes, src, f"{repeats} repeated timestamp(s) dropped, first row of each kept (first at row {first})")
            time = time[keep]
            lines = lines[keep]
            cols = {k: v[keep] for k, v in cols.items()}
        _check_time_unit(src, time)
    out: dict[str, np.ndarray] = {"time_s": time}
    for name, values in cols.items():
        blank = np.isnan(values)
        if not np.any(blank):
            out[name] = values
            continue
        is_strict = strict(name)
        if np.all(blank):
            if is_strict and CYLINDER_COLUMN.match(name) is None:
                raise FlightLogError(f"{src}: rows {lines[0]}-{lines[-1]}, column '{name}': blank in every row")
            if is_strict or name in soft:
                _note(notes, src, f"column '{name}': blank in every row: dropped")
            else:
                _log.debug("%s: column '%s' is blank in every row: dropped", src, name)
            continue
        if not (is_strict or name in soft):
            out[name] = values  # extra columns keep their gaps as NaN
            continue
        start, length = _longest_run(blank)
        if is_strict and length > MAX_BLANK_RUN:
            raise FlightLogError(
                f"{src}: row {lines[start]}, column '{name}': {length} consecutive blank fields"
                f" (rows {lines[start]}-{lines[start + length - 1]}); at most {MAX_BLANK_RUN} are interpolated"
            )
        fill = blank & (_run_lengths(blank) <= MAX_BLANK_RUN)
        filled = values.copy()
        filled[fill] = np.interp(time[fill], time[~blank], values[~blank])
        out[name] = filled
        kept = int(np.count_nonzero(blank & ~fill))
        _note(
            notes,
            src,
            f"column '{name}': {int(np.count_nonzero(fill))} blank field(s) interpolated"
            f" (first at row {lines[int(np.argmax(blank))]})"
            + (f", {kept} in runs longer than {MAX_BLANK_RUN} kept blank" if kept else ""),
        )
    if time.size > 1:
        steps = np.diff(time)
        gaps = steps > GAP_WARN_S
        if np.any(gaps):
            k = int(np.argmax(steps))
            _note(
                notes,
                src,
                f"{int(np.count_nonzero(gaps))} time gap(s) longer than {GAP_WARN_S:g} s kept"
                f" (longest {steps[k]:g} s before row {lines[k + 1]})",
            )
    return FlightLog(out, src, tuple(notes))


def _check_time_unit(src: str, time: np.ndarray) -> None:
    """FlightLogError if ``time`` (s, increasing) cannot be a flight's time in seconds, saying what it
    would be in milliseconds."""
    if time.size < 2:
        return
    median = float(np.median(np.diff(time)))
    span = float(time[-1] - time[0])
    if median <= MAX_MEDIAN_STEP_S and span <= MAX_FLIGHT_S:
        return
    raise FlightLogError(
        f"{src}: column 'time_s': rows every {median:g} s over {span / 3600.0:.3g} h is no flight in seconds"
        f" (at most {MAX_MEDIAN_STEP_S:g} s apart, {MAX_FLIGHT_S / 3600.0:g} h); in milliseconds it would be rows"
        f" every {median / 1000.0:g} s over {span / 60000.0:.3g} min: give time_s in seconds"
    )


def _run_lengths(mask: np.ndarray) -> np.ndarray:
    """For each element of ``mask``, the length of the run of True it belongs to (0 where False)."""
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.diff(padded)
    starts = np.flatnonzero(edges == 1)
    stops = np.flatnonzero(edges == -1)
    out = np.zeros(mask.size, dtype=np.int64)
    for a, b in zip(starts, stops, strict=True):
        out[a:b] = b - a
    return out


def _longest_run(mask: np.ndarray) -> tuple[int, int]:
    """(start index, length) of the longest run of True in ``mask``."""
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.diff(padded)
    starts = np.flatnonzero(edges == 1)
    stops = np.flatnonzero(edges == -1)
    lengths = stops - starts
    k = int(np.argmax(lengths))
    return int(starts[k]), int(lengths[k])
