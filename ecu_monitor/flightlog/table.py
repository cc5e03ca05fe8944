"""Reading a delimited text file into a header and rows, with one-line errors naming file and row;
the notes (repairs logged as warnings) that both readers keep."""

from __future__ import annotations

import codecs
import contextlib
import csv
import logging
import math
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, NamedTuple

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


#: Data rows parsed at a time by a streaming reader: bounds the text held at once (rows x fields of str).
BLOCK_ROWS = 4096


def _scan(path: Path, notes: list[str]) -> tuple[str, int]:
    """The file's text encoding, UTF-8 (a byte-order mark skipped) else Latin-1 with a note, and its
    number of lines (its rows, unless quoted fields hold line breaks). Reads the file in 1 MiB pieces,
    keeping none of it."""
    src = str(path)
    decoder: Any = codecs.getincrementaldecoder("utf-8")()
    offset = feeds = returns = 0
    with _reading(src), path.open("rb") as fh:
        while True:
            chunk = fh.read(1 << 20)
            feeds += chunk.count(b"\n")
            returns += chunk.count(b"\r")
            if decoder is not None:
                try:
                    decoder.decode(chunk, final=not chunk)
                except UnicodeDecodeError as exc:
                    _note(notes, src, f"not UTF-8 text ({exc.reason} at byte {offset + exc.start}): read as Latin-1")
                    decoder = None
            if not chunk:
                return ("utf-8-sig" if decoder is not None else "latin-1"), (feeds or returns) + 1
            offset += len(chunk)


class _Table(NamedTuple):
    header: list[str]
    rows: list[tuple[int, list[str]]]  # (1-based file line, fields as in the file, padding kept)
    before: dict[int, list[str]]  # lines above the header asked for (1-based line -> stripped fields)


class _Rows(NamedTuple):
    """A delimited file being read: its header, the lines above it asked for, and an iterator of its data
    rows (1-based file line, fields as in the file, padding kept), read as they are asked for."""

    header: list[str]
    before: dict[int, list[str]]
    rows: Iterator[tuple[int, list[str]]]
    most: int  # the file's lines after the header: as many rows, unless quoted fields hold line breaks


def _read_rows(
    path: Path,
    notes: list[str],
    *,
    header_row: int = 1,
    skip_after: int = 0,
    delimiter: str = ",",
    keep_before: int | None = None,
) -> _Rows:
    """Open a delimited text file and read up to its header; the data rows follow one at a time, so a
    reader holds only the rows it has not yet converted. The file's rules: blank rows and the
    ``skip_after`` rows after the header skipped, trailing empty fields past the header dropped, a
    truncated last row dropped with a note, a header without rows an error."""
    src = str(path)
    encoding, lines = _scan(path, notes)
    with _reading(src):
        fh = path.open(encoding=encoding, newline="")
    before: dict[int, list[str]] = {}
    reader = csv.reader(fh, delimiter=delimiter)
    header: list[str] | None = None
    try:
        for fields in reader:
            line = reader.line_num
            if line < header_row:
                if line == keep_before:
                    before[line] = [f.strip() for f in fields]
                continue
            header = [f.strip() for f in fields]
            while header and not header[-1]:
                header.pop()  # trailing empty columns (a spreadsheet's or a firmware's trailing commas)
            break
    except csv.Error as exc:
        fh.close()
        raise FlightLogError(f"{src}: row {reader.line_num}: malformed CSV: {exc}") from exc
    except BaseException:
        fh.close()
        raise
    if header is None or not any(header):
        fh.close()
        what = "empty file" if header_row == 1 else f"file ends before header row {header_row}"
        raise FlightLogError(f"{src}: {what}, expected a header row")
    rows = _data_rows(path, fh, reader, len(header), header_row, skip_after, notes)
    return _Rows(header, before, rows, max(lines - reader.line_num, 0))


def _data_rows(
    path: Path, fh: Any, reader: Any, width: int, header_row: int, skip_after: int, notes: list[str]
) -> Iterator[tuple[int, list[str]]]:
    """The data rows of :func:`_read_rows`, one behind the file (the last row is checked for truncation)."""
    src = str(path)
    pending: tuple[int, list[str]] | None = None
    given = 0
    try:
        with fh:
            for fields in reader:
                line = reader.line_num
                if line <= header_row + skip_after or not "".join(fields).strip():
                    continue
                if len(fields) > width and not "".join(fields[width:]).strip():
                    del fields[width:]
                if pending is not None:
                    yield pending
                    given += 1
                pending = (line, fields)  # fields keep their padding: readers strip what they use
    except csv.Error as exc:
        raise FlightLogError(f"{src}: row {reader.line_num}: malformed CSV: {exc}") from exc
    if pending is None:
        raise FlightLogError(f"{src}: row {header_row}: header only, no data rows")
    last_line, last_fields = pending
    if len(last_fields) < width:
        _note(notes, src, f"row {last_line}: truncated last row ({len(last_fields)} of {width} fields) dropped")
        if not given:
            raise FlightLogError(f"{src}: row {last_line}: the only data row is truncated")
        return
    if _ends_mid_line(path):
        _note(notes, src, f"row {last_line}: no line break after the last row: it may be cut mid-field (kept)")
    yield pending


def _read_table(path: Path, notes: list[str], **layout: Any) -> _Table:
    """The whole file at once (:func:`_read_rows` with its ``layout`` keywords, every row kept): for readers
    that edit the rows."""
    header, before, rows, _ = _read_rows(path, notes, **layout)
    return _Table(header, list(rows), before)


def _ends_mid_line(path: Path) -> bool:
    """True if the file's last byte is not a line break: its last row was cut while being written (a
    field may hold only the first digits of its value)."""
    with _reading(str(path)), path.open("rb") as fh:
        fh.seek(-1, os.SEEK_END)
        return fh.read(1) not in (b"\n", b"\r")


def _check_widths(src: str, width: int, rows: Sequence[tuple[int, list[str]]]) -> None:
    """Every data row must have as many fields as the header (called once the header is checked)."""
    for line, fields in rows:
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
