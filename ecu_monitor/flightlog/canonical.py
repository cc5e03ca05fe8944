"""The canonical flight CSV: :func:`read_csv` (validated row by row) and :func:`write_csv`.

Canonical CSV rules (:func:`read_csv`)
--------------------------------------
* Required columns: ``time_s, throttle_pct, rpm, altitude_m, airspeed_mps, oat_c, cht_c``;
  ``throttle_pct`` may be absent if ``fuel_flow_lph`` is present (an engine monitor without throttle).
* Every field of a canonical or optional column must be a number (``nan`` counts as blank).
* ``time_s`` must never go backwards; a repeated timestamp keeps its first row (warning with count).
* Blank fields are filled by linear interpolation in time when a run is at most
  :data:`MAX_BLANK_RUN` rows long (at the start or end of the log the nearest value is held); a
  longer run, or a column blank in every row, is an error.
* Values outside :data:`PHYSICAL_LIMITS` are an error; time gaps longer than :data:`GAP_WARN_S` are
  kept with a warning.
* An empty file or a header without rows is an error; a last row with too few fields (a log cut
  mid-write) is dropped with a warning, a whole last row without a line break at its end (maybe cut
  inside its last number) is kept with a warning; a short row anywhere else is an error.
* Extra columns are carried along as floats (blank fields stay NaN) when numeric, and dropped with a
  debug message when they hold text or have no name (a trailing comma).
"""

from __future__ import annotations

import itertools
import logging
import os
from pathlib import Path

import numpy as np

from ecu_monitor.errors import FlightLogError
from ecu_monitor.flightlog.cylinders import cylinder_columns
from ecu_monitor.flightlog.log import (
    _REQUIRED_ALWAYS,
    _STRICT,
    CANONICAL_COLUMNS,
    ENGINE_COLUMNS,
    OPTIONAL_COLUMNS,
    FlightLog,
)
from ecu_monitor.flightlog.rules import _assemble, _is_strict
from ecu_monitor.flightlog.table import BLOCK_ROWS, _check_widths, _floats, _numbers, _read_rows
from ecu_monitor.userfiles import atomic_output

_log = logging.getLogger(__name__)


def read_csv(path: str | os.PathLike[str]) -> FlightLog:
    """Read and validate a canonical flight CSV (rules in the module docstring)."""
    path = Path(path)
    src = str(path)
    notes: list[str] = []
    rows = _read_rows(path, notes)
    header = rows.header
    present = set(header)
    for name in _REQUIRED_ALWAYS:
        if name not in present:
            hint = "" if present & _STRICT else " (not a canonical flight CSV: import it with a mapping)"
            raise FlightLogError(f"{src}: row 1, column '{name}': required column missing{hint}")
    if "throttle_pct" not in present and "fuel_flow_lph" not in present:
        raise FlightLogError(
            f"{src}: row 1, column 'throttle_pct': required column missing"
            " (a log without throttle must carry fuel_flow_lph)"
        )
    seen: set[str] = set()
    for name in header:
        if not name:
            continue  # an unnamed column (trailing comma of a spreadsheet export) is dropped below
        if name in seen:
            raise FlightLogError(f"{src}: row 1, column '{name}': duplicate column name")
        seen.add(name)
    for i, name in enumerate(header):
        if not name:
            _log.debug("%s: column %d has no name: dropped", src, i + 1)
    # streamed: BLOCK_ROWS rows of text at a time into arrays sized by the file's lines (no text kept)
    kept = {i: name for i, name in enumerate(header) if name}
    cols = {name: np.empty(rows.most, dtype=np.float64) for name in kept.values()}
    lines = np.empty(rows.most, dtype=np.int64)
    at = 0
    while block := list(itertools.islice(rows.rows, BLOCK_ROWS)):
        _check_widths(src, len(header), block)
        end = at + len(block)
        if end > lines.size:  # more rows than lines counted (mixed line ends): grow
            lines = np.resize(lines, 2 * end)
            cols = {name: np.resize(values, 2 * end) for name, values in cols.items()}
        lines[at:end] = [line for line, _ in block]
        for i, name in list(kept.items()):
            fields = [row[i] for _, row in block]
            if _is_strict(name):
                cols[name][at:end] = _numbers(src, name, fields, lines[at:end])
                continue
            arr = _floats(fields)
            if arr is None:
                _log.debug("%s: column '%s' holds text: dropped", src, name)
                del kept[i], cols[name]
            else:
                cols[name][at:end] = arr
        at = end
    lines = lines[:at]
    cols = {name: values[:at] for name, values in cols.items()}
    time = cols.pop("time_s")
    if np.any(np.isnan(time)):
        k = int(np.argmax(np.isnan(time)))
        raise FlightLogError(f"{src}: row {lines[k]}, column 'time_s': blank time")
    return _assemble(src, time, cols, lines, notes)


def _fmt(value: float) -> str:
    return "" if value != value else repr(value)  # NaN -> blank; repr is the shortest exact text


def _column_order(log: FlightLog) -> list[str]:
    """Canonical columns in contract order, optional ones, the cylinders, the engine columns, the rest."""
    order = [c for c in CANONICAL_COLUMNS + OPTIONAL_COLUMNS if log.has(c)]
    order += cylinder_columns(log, "cht") + cylinder_columns(log, "egt")
    order += [c for c in ENGINE_COLUMNS if log.has(c)]
    return order + [c for c in log.columns if c not in order]


def write_csv(log: FlightLog, path: str | os.PathLike[str]) -> None:
    """Write ``log`` as a canonical CSV: canonical columns in contract order, optional ones, the
    cylinders (``cht1_c..``, ``egt1_c..``), the engine columns, the rest.

    Values are written with Python's shortest round-trip representation, so :func:`read_csv` gives
    back the same floats; NaN is written as a blank field. Written atomically
    (:func:`ecu_monitor.userfiles.atomic_output`): an interrupted write never leaves a half file.
    """
    order = _column_order(log)
    data = [log[c].tolist() for c in order]
    with atomic_output(path, FlightLogError, text=True) as fh:
        fh.write(",".join(order) + "\n")
        fh.writelines(",".join(map(_fmt, row)) + "\n" for row in zip(*data, strict=True))
