"""Reading a delimited text file into a header and rows, with one-line errors naming file and row;
the notes (repairs logged as warnings) that both readers keep."""

from __future__ import annotations

import contextlib
import csv
import io
import logging
import math
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ecu_monitor.errors import FlightLogError

_log = logging.getLogger(__name__)


@contextlib.contextmanager
def _reading(src: str) -> Iterator[None]:
    """Turn the errors of opening and reading a file into one-line FlightLogErrors."""
    try:
        yield
    except FileNotFoundError:
        raise FlightLogError(f"{src}: no such file") from None
    except OSError as exc:
        raise FlightLogError(f"{src}: cannot read: {exc.strerror or exc}") from exc


def _read_text(path: Path, notes: list[str]) -> str:
    """The whole file as text: UTF-8 (a byte-order mark skipped), else Latin-1 with a note."""
    src = str(path)
    with _reading(src):
        data = path.read_bytes()
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        _note(notes, src, f"not UTF-8 text ({exc.reason} at byte {exc.start}): read as Latin-1")
        return data.decode("latin-1")


class _Table(NamedTuple):
    header: list[str]
    rows: list[tuple[int, list[str]]]  # (1-based file line, fields as in the file, padding kept)
    before: dict[int, list[str]]  # lines above the header asked for (1-based line -> stripped fields)


def _read_table(
    path: Path,
    notes: list[str],
    *,
    header_row: int = 1,
    skip_after: int = 0,
    delimiter: str = ",",
    keep_before: int | None = None,
) -> _Table:
    src = str(path)
    before: dict[int, list[str]] = {}
    text = _read_text(path, notes)
    try:
        with io.StringIO(text, newline="") as fh:
            reader = csv.reader(fh, delimiter=delimiter)
            header: list[str] | None = None
            rows: list[tuple[int, list[str]]] = []
            for fields in reader:
                line = reader.line_num
                if line < header_row:
                    if line == keep_before:
                        before[line] = [f.strip() for f in fields]
                    continue
                if header is None:
                    header = [f.strip() for f in fields]
                    while header and not header[-1]:
                        header.pop()  # trailing empty columns (a spreadsheet's or a firmware's trailing commas)
                    continue
                if line <= header_row + skip_after or not "".join(fields).strip():
                    continue
                width = len(header)
                if len(fields) > width and not "".join(fields[width:]).strip():
                    del fields[width:]
                rows.append((line, fields))  # fields keep their padding: readers strip what they use
    except csv.Error as exc:
        raise FlightLogError(f"{src}: row {reader.line_num}: malformed CSV: {exc}") from exc
    if header is None or not any(header):
        what = "empty file" if header_row == 1 else f"file ends before header row {header_row}"
        raise FlightLogError(f"{src}: {what}, expected a header row")
    if not rows:
        raise FlightLogError(f"{src}: row {header_row}: header only, no data rows")
    width = len(header)
    last_line, last_fields = rows[-1]
    if len(last_fields) < width:
        rows.pop()
        _note(notes, src, f"row {last_line}: truncated last row ({len(last_fields)} of {width} fields) dropped")
        if not rows:
            raise FlightLogError(f"{src}: row {last_line}: the only data row is truncated")
    elif _ends_mid_line(path):
        _note(notes, src, f"row {last_line}: no line break after the last row: it may be cut mid-field (kept)")
    return _Table(header, rows, before)


def _ends_mid_line(path: Path) -> bool:
    """True if the file's last byte is not a line break: its last row was cut while being written (a
    field may hold only the first digits of its value)."""
    with _reading(str(path)), path.open("rb") as fh:
        fh.seek(-1, os.SEEK_END)
        return fh.read(1) not in (b"\n", b"\r")


def _check_widths(src: str, table: _Table) -> None:
    """Every data row must have as many fields as the header (called once the header is checked)."""
    width = len(table.header)
    for line, fields in table.rows:
        if len(fields) != width:
            raise FlightLogError(f"{src}: row {line}: {len(fields)} fields, the header has {width}")


def _note(notes: list[str], source: str, message: str) -> None:
    notes.append(message)
    _log.warning("%s: %s", source, message)


def _float(text: str) -> float:
    """A padded field as a float; blank -> NaN (ValueError for text)."""
    try:
        return float(text)
    except ValueError:
        if text.strip():
            raise
        return math.nan


def _floats(fields: Sequence[str]) -> np.ndarray | None:
    """Floats of one column (blank -> NaN), or None if a field holds text."""
    try:
        return np.array([_float(f) for f in fields], dtype=np.float64)
    except ValueError:
        return None


def _numbers(src: str, name: str, fields: Sequence[str], lines: Sequence[int] | np.ndarray) -> np.ndarray:
    """Floats of a column that must be numeric and finite; the error names the first bad row."""
    arr = _floats(fields)
    if arr is None:
        bad = next(i for i, f in enumerate(fields) if f.strip() and not _is_number(f))
        raise FlightLogError(f"{src}: row {lines[bad]}, column '{name}': {fields[bad].strip()!r} is not a number")
    if np.any(np.isinf(arr)):
        k = int(np.argmax(np.isinf(arr)))
        raise FlightLogError(f"{src}: row {lines[k]}, column '{name}': {fields[k].strip()!r} is not finite")
    return arr


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
