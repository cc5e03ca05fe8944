"""Health tables (health.csv, Parquet, Arrow) written from whole columns: the bulk writer of the health rows.

The CSV's numbers are C's ``%.10g`` (Python's ``f"{v:.10g}"``) to the byte, but formatted on arrays:
:func:`decimal_digits` splits each float into its 10 significant digits and decimal exponent in a
compiled pass (exactly, as ``%.9e`` would; the few values whose float scaling leaves the rounding in
doubt, and the extreme magnitudes, are rounded by Python's own formatter), and a compiled loop writes
the rows' bytes (``%g``'s choice of fixed or exponent notation, trailing zeros stripped; text columns
from their labels). A nan or an infinity is an empty cell, as in every health.csv (the first column
spells them). Which columns, in which order: :mod:`ecu_monitor.pipeline.outputs`. Parquet and
Arrow IPC (``.parquet``, ``.arrow``, ``.feather``) need pyarrow, an optional extra
(``pip install 'ecu-monitor[arrow]'``): never part of the daemon's install.
"""

from __future__ import annotations

import functools
import importlib.util
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import ConfigError, FlightLogError
from ecu_monitor.userfiles import atomic_output

__all__ = [
    "TABLE_SUFFIXES",
    "TableColumn",
    "check_table_path",
    "csv_bytes",
    "decimal_digits",
    "format_g10",
    "write_health_table",
]

#: Output suffixes and their formats.
TABLE_SUFFIXES: dict[str, str] = {".csv": "csv", ".parquet": "parquet", ".arrow": "arrow", ".feather": "arrow"}


def decimal_digits(values: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int8]]:
    """(digits, exponent, kind) of each value as ``%.9e`` rounds it: ``digits`` the 10 significant
    digits as an integer in [1e9, 1e10) of |v|, ``exponent`` the decimal exponent of the first digit,
    ``kind`` 0 finite non-zero, 1 zero, 2 nan, 3 +inf, 4 -inf (digits and exponent 0 there).

    Compiled, one pass: |v| scaled into [1e9, 1e10) by one correctly rounded operation with an exact
    power of ten, then rounded; the scaled value is within 2e-6 of the exact product, so only a
    fraction within 1e-5 of one half (or a magnitude beyond 1e+-22) leaves the rounding in doubt:
    those few go through Python's exact formatter."""
    shape = np.shape(values)
    v = np.ascontiguousarray(values, dtype=np.float64).ravel()
    digits = np.zeros(v.size, dtype=np.int64)
    exponent = np.zeros(v.size, dtype=np.int64)
    kind = np.zeros(v.size, dtype=np.int8)
    doubtful = np.zeros(v.size, dtype=np.bool_)
    _compiled_writer().digits(v, _POWERS_OF_TEN, digits, exponent, kind, doubtful)
    for j in np.flatnonzero(doubtful).tolist():
        mantissa, _, power = f"{abs(float(v[j])):.9e}".partition("e")
        digits[j] = int(mantissa.replace(".", ""))
        exponent[j] = int(power)
    return digits.reshape(shape), exponent.reshape(shape), kind.reshape(shape)


#: 1e0 .. 1e22: the powers of ten a double holds exactly.
_POWERS_OF_TEN = np.array([10.0**k for k in range(23)])


def format_g10(values: Sequence[float] | NDArray[np.float64]) -> list[str]:
    """Each value as ``f"{v:.10g}"`` (for tests and small uses; the CSV writer works on bytes)."""
    v = np.asarray(values, dtype=np.float64)
    digits, exponent, kind = decimal_digits(v)
    table = _compiled_writer()
    negative = np.signbit(v)
    out = []
    scratch = np.empty(10, dtype=np.uint8)
    buffer = np.empty(32, dtype=np.uint8)
    for d, e, k, neg in zip(digits.tolist(), exponent.tolist(), kind.tolist(), negative.tolist(), strict=True):
        end = table.number(buffer, 0, d, e, k, neg, True, scratch)
        out.append(buffer[:end].tobytes().decode("ascii"))
    return out


@functools.cache
def _compiled_writer() -> _Writer:
    """The compiled kernels (module level, so numba caches them on disk)."""
    return _Writer(_digits_of, _number, _rows)


class _Writer:
    """The compiled pieces: ``digits`` splits values, ``number`` writes one value, ``rows`` the whole table."""

    def __init__(self, digits: Callable[..., None], number: Callable[..., int], rows: Callable[..., int]) -> None:
        self.digits = digits
        self.number = number
        self.rows = rows


@numba.njit(cache=True, nogil=True)
def _digits_of(values: Any, powers: Any, digits: Any, exponent: Any, kind: Any, doubtful: Any) -> None:
    """decimal_digits' compiled pass (its docstring); ``doubtful`` marks the values left to Python."""
    for j in range(values.size):
        x = abs(values[j])
        if math.isnan(x):
            kind[j] = 2
            continue
        if math.isinf(x):
            kind[j] = 3 if values[j] > 0 else 4
            continue
        if x == 0.0:
            kind[j] = 1
            continue
        e = math.floor(math.log10(x))
        scaled = 0.0
        for _ in range(3):  # log10 may be one off next to a power of ten
            k = 9 - e
            if k > 22 or k < -22:
                break
            scaled = x * powers[k] if k >= 0 else x / powers[-k]
            if scaled < 1e9:
                e -= 1
            elif scaled >= 1e10:
                e += 1
            else:
                break
        if not 1e9 <= scaled < 1e10 or abs(scaled - math.floor(scaled) - 0.5) < 1e-5:
            doubtful[j] = True
            continue
        rounded = math.floor(scaled + 0.5)
        if rounded >= 10_000_000_000:  # 9999999999.5 -> 1.000000000e(e+1)
            rounded = 1_000_000_000
            e += 1
        digits[j] = rounded
        exponent[j] = e


@numba.njit(cache=True, nogil=True)
def _number(out: Any, pos: int, digits: int, exponent: int, kind: int, negative: bool, spelled: bool, d: Any) -> int:
    """Write one value at ``pos`` (``d``: 10 bytes of scratch); returns the new end. Non-finite:
    nothing, or with ``spelled`` nan, inf, -inf."""
    if kind >= 2:
        if not spelled:
            return pos
        if kind == 4:
            out[pos] = 45
            pos += 1
        word = (110, 97, 110) if kind == 2 else (105, 110, 102)  # nan, inf
        for ch in word:
            out[pos] = ch
            pos += 1
        return pos
    if negative:
        out[pos] = 45  # '-'
        pos += 1
    if kind == 1:
        out[pos] = 48
        return pos + 1
    rest = digits
    for i in range(9, -1, -1):
        d[i] = 48 + rest % 10
        rest //= 10
    last = 9
    while last > 0 and d[last] == 48:
        last -= 1
    if -4 <= exponent < 10:
        if exponent >= 0:
            for i in range(exponent + 1):
                out[pos] = d[i] if i <= 9 else 48
                pos += 1
            if last > exponent:
                out[pos] = 46  # '.'
                pos += 1
                for i in range(exponent + 1, last + 1):
                    out[pos] = d[i]
                    pos += 1
        else:
            out[pos] = 48
            out[pos + 1] = 46
            pos += 2
            for _ in range(-exponent - 1):
                out[pos] = 48
                pos += 1
            for i in range(last + 1):
                out[pos] = d[i]
                pos += 1
        return pos
    out[pos] = d[0]
    pos += 1
    if last > 0:
        out[pos] = 46
        pos += 1
        for i in range(1, last + 1):
            out[pos] = d[i]
            pos += 1
    out[pos] = 101  # 'e'
    out[pos + 1] = 45 if exponent < 0 else 43
    pos += 2
    e = -exponent if exponent < 0 else exponent
    width = 2 if e < 100 else 3
    for i in range(width - 1, -1, -1):
        out[pos + i] = 48 + e % 10
        e //= 10
    return pos + width


@numba.njit(cache=True, nogil=True)
def _rows(
    out: Any,
    layout: Any,
    digits: Any,
    exponent: Any,
    kind: Any,
    negative: Any,
    codes: Any,
    text: Any,
    text_start: Any,
    table_first: Any,
) -> int:
    """Every row after the header into ``out``; returns the bytes written. ``layout[c]`` >= 0: float
    column layout[c] (digits, exponent, kind, negative; the first column of the table spells nan/inf),
    < 0: text column -layout[c]-1 (codes into its table, entries table_first[j] + code of text_start)."""
    pos = 0
    scratch = np.empty(10, dtype=np.uint8)
    last = layout.size - 1
    for r in range(codes.shape[1] if codes.shape[0] else digits.shape[1]):
        for c in range(layout.size):
            col = layout[c]
            if col >= 0:
                pos = _number(out, pos, digits[col, r], exponent[col, r], kind[col, r], negative[col, r], c == 0,
                             scratch)  # fmt: skip
            else:
                entry = table_first[-col - 1] + codes[-col - 1, r]
                for i in range(text_start[entry], text_start[entry + 1]):
                    out[pos] = text[i]
                    pos += 1
            out[pos] = 10 if c == last else 44  # newline or comma
            pos += 1
    return pos


class TableColumn(NamedTuple):
    """One column of a health table: ``values`` floats (``labels`` None: ``%.10g``, nan and inf empty),
    or integer codes into ``labels`` (the cell text of each code; a bool column has labels ("0", "1"))."""

    name: str
    values: NDArray[Any]
    labels: tuple[str, ...] | None = None


def csv_bytes(table: Sequence[TableColumn]) -> bytes:
    """The CSV of ``table`` (header line, then one line per row) as bytes."""
    header, body = _csv_parts(table)
    return header + body.tobytes()


def _csv_parts(table: Sequence[TableColumn]) -> tuple[bytes, NDArray[np.uint8]]:
    """The CSV of ``table``: its header line, and the rows in a byte array written in place (a file
    takes them from there: a 16 h table's 42 MB are not copied twice more into bytes)."""
    header = (",".join(c.name for c in table) + "\n").encode("ascii")
    n = int(np.size(table[0].values))
    if n == 0:
        return header, np.zeros(0, dtype=np.uint8)
    floats = [c for c in table if c.labels is None]
    texts = [c for c in table if c.labels is not None]
    layout = np.array([floats.index(c) if c.labels is None else -texts.index(c) - 1 for c in table], dtype=np.int64)
    values = np.stack([np.asarray(c.values, dtype=np.float64) for c in floats]) if floats else np.zeros((0, n))
    digits, exponent, kind = decimal_digits(values)
    negative = np.signbit(values)
    codes = np.stack([np.asarray(c.values, dtype=np.int64) for c in texts]) if texts else np.zeros((0, n), np.int64)
    labels = [t.encode("ascii") for c in texts for t in c.labels or ()]
    text = np.frombuffer(b"".join(labels) or b"\0", dtype=np.uint8).copy()
    text_start = np.concatenate(([0], np.cumsum([len(t) for t in labels]))).astype(np.int64)
    table_first = np.concatenate(([0], np.cumsum([len(c.labels or ()) for c in texts]))).astype(np.int64)[:-1]
    longest_text = sum(max((len(t) for t in c.labels or ("",)), default=0) for c in texts)
    out = np.empty(n * (24 * len(floats) + longest_text + len(table)), dtype=np.uint8)
    end = _compiled_writer().rows(out, layout, digits, exponent, kind, negative, codes, text, text_start, table_first)
    return header, out[:end]


def check_table_path(path: str | os.PathLike[str]) -> str:
    """The format of output ``path`` by its suffix (:data:`TABLE_SUFFIXES`); ConfigError, one line,
    for an unknown suffix or, for Parquet / Arrow, a missing pyarrow (checked before any work)."""
    suffix = Path(path).suffix.lower()
    form = TABLE_SUFFIXES.get(suffix)
    if form is None:
        raise ConfigError(f"{path}: unknown output format '{suffix}' (expected {', '.join(TABLE_SUFFIXES)})")
    if form != "csv" and importlib.util.find_spec("pyarrow") is None:
        raise ConfigError(
            f"{path}: writing {form.capitalize()} needs pyarrow: pip install 'ecu-monitor[arrow]' (or write .csv)"
        )
    return form


def write_health_table(table: Sequence[TableColumn], path: str | os.PathLike[str]) -> int:
    """Write ``table`` to ``path``: CSV, or Parquet / Arrow IPC by its suffix (:data:`TABLE_SUFFIXES`);
    returns the row count. FlightLogError if it cannot be written, ConfigError for an unknown suffix
    or a missing pyarrow."""
    form = check_table_path(path)
    if form == "csv":
        header, body = _csv_parts(table)
        with atomic_output(path, FlightLogError) as handle:
            handle.write(header)
            handle.write(body.data)
    else:
        _write_arrow(table, path, form)
    return int(np.size(table[0].values))


def _write_arrow(table: Sequence[TableColumn], path: str | os.PathLike[str], form: str) -> None:
    """Parquet or Arrow IPC: float columns as float64 (nan kept), ("0", "1") columns as bool, other
    labelled columns as dictionary-encoded strings; the names of the CSV."""
    import pyarrow as pa  # check_table_path found it

    arrays = {}
    for c in table:
        if c.labels is None:
            arrays[c.name] = pa.array(np.asarray(c.values, dtype=np.float64))
        elif c.labels == ("0", "1"):
            arrays[c.name] = pa.array(np.asarray(c.values, dtype=bool))
        else:
            codes = pa.array(np.asarray(c.values, dtype=np.int32))
            arrays[c.name] = pa.DictionaryArray.from_arrays(codes, pa.array(list(c.labels)))
    with atomic_output(path, FlightLogError) as handle:
        if form == "parquet":
            import pyarrow.parquet as pq

            pq.write_table(pa.table(arrays), handle)
        else:
            import pyarrow.feather as feather

            feather.write_feather(pa.table(arrays), handle)
