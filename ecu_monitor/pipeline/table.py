"""Health tables (health.csv, Parquet, Arrow) written from whole columns: the bulk writer of the health rows.

The CSV's numbers are Python's ``%.10g`` (C's), a block of rows formatted by one ``%`` operation (the
text held at once is one block's; no cell needs quoting: numbers and labels only); a nan or an infinity is
an empty cell, as in every health.csv (the first column spells them); text columns from their labels.
Which columns, in which order: :mod:`ecu_monitor.pipeline.outputs`. Parquet and Arrow IPC (``.parquet``,
``.arrow``, ``.feather``) need pyarrow, an optional extra (``pip install 'ecu-monitor[arrow]'``): never
part of the daemon's install.
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, NamedTuple, TextIO

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import ConfigError, FlightLogError
from ecu_monitor.userfiles import atomic_output

__all__ = [
    "TABLE_SUFFIXES",
    "TableColumn",
    "check_table_path",
    "csv_bytes",
    "table_stream",
    "write_health_table",
]

#: Output suffixes and their formats.
TABLE_SUFFIXES: dict[str, str] = {".csv": "csv", ".parquet": "parquet", ".arrow": "arrow", ".feather": "arrow"}


class TableColumn(NamedTuple):
    """One column of a health table: ``values`` floats (``labels`` None: ``%.10g``, nan and inf empty),
    or integer codes into ``labels`` (the cell text of each code; a bool column has labels ("0", "1"))."""

    name: str
    values: NDArray[Any]
    labels: tuple[str, ...] | None = None


def csv_bytes(table: Sequence[TableColumn]) -> bytes:
    """The CSV of ``table`` (header line, then one line per row) as bytes."""
    text = io.StringIO()
    _write_csv(table, text)
    return text.getvalue().encode("ascii")


#: Rows formatted and written at a time (one ``%`` operation: the GIL is held for its length).
_BLOCK_ROWS = 2048


def _write_csv(table: Sequence[TableColumn], handle: TextIO) -> None:
    """Header, then the rows (:func:`_write_csv_rows`)."""
    handle.write(_csv_header(table))
    _write_csv_rows(table, handle)


def _csv_header(table: Sequence[TableColumn]) -> str:
    """The header line; FlightLogError if a label would read as a number."""
    for column in table:
        if column.labels is not None and any(str(t).startswith(_NOT_FINITE) for t in column.labels):
            raise FlightLogError(f"health.csv: a label starting with one of {_NOT_FINITE} reads as a number")
    return ",".join(c.name for c in table) + "\n"


def _write_csv_rows(table: Sequence[TableColumn], handle: TextIO) -> None:
    """The rows, a block at a time: one ``%`` format of the block (``%.10g`` a number, ``%s`` a label), then
    every non-finite number after the first column blanked. A cell is "nan", "inf" or "-inf" only when it
    is such a number (no label starts with them: :func:`_csv_header` checks)."""
    line = ",".join("%.10g" if c.labels is None else "%s" for c in table) + "\n"
    labels = [None if c.labels is None else np.asarray(c.labels, dtype=object) for c in table]
    rows = int(np.size(table[0].values))
    for start in range(0, rows, _BLOCK_ROWS):
        stop = min(start + _BLOCK_ROWS, rows)
        cells = np.empty((stop - start, len(table)), dtype=object)
        for j, (column, texts) in enumerate(zip(table, labels, strict=True)):
            if texts is None:
                cells[:, j] = np.asarray(column.values[start:stop], dtype=np.float64)
            else:
                cells[:, j] = texts[np.asarray(column.values[start:stop], dtype=np.int64)]
        text = (line * (stop - start)) % tuple(cells.ravel().tolist())
        for word in _NOT_FINITE:
            text = text.replace("," + word, ",")
        handle.write(text)


@contextlib.contextmanager
def table_stream(path: str | os.PathLike[str]) -> Iterator[Callable[[Sequence[TableColumn]], None]]:
    """Write a health table a block of rows at a time: ``write(block)`` for each block, in row order (the
    same columns each time). A CSV is formatted and written by a second thread while the caller goes on
    (the replay's compiled loop releases the GIL, so the two use two cores); Parquet and Arrow are written
    whole at the end. The file is there only if the ``with`` block ends without an error and a block had
    rows (a table without rows: nothing written). FlightLogError if it cannot be written."""
    form = check_table_path(path)
    blocks: list[Sequence[TableColumn]] = []
    if form != "csv":
        yield blocks.append
        if blocks and any(np.size(b[0].values) for b in blocks):
            write_health_table(_joined(blocks), path)
        return
    with contextlib.ExitStack() as stack:  # on the way out: the writes waited for, then the file closed
        handle: TextIO | None = None
        pool: ThreadPoolExecutor | None = None
        pending: list[Future[None]] = []

        def write(block: Sequence[TableColumn]) -> None:
            nonlocal handle, pool
            if not np.size(block[0].values):
                return
            if handle is None or pool is None:  # the first rows: the file (atomic), its header, the writer
                handle = stack.enter_context(atomic_output(path, FlightLogError, text=True))
                handle.write(_csv_header(block))
                pool = stack.enter_context(ThreadPoolExecutor(1, thread_name_prefix="health-csv"))
            pending.append(pool.submit(_write_csv_rows, block, handle))

        yield write
        for future in pending:
            future.result()


def _joined(blocks: Sequence[Sequence[TableColumn]]) -> list[TableColumn]:
    """The blocks' columns end to end."""
    first = blocks[0]
    return [c._replace(values=np.concatenate([b[j].values for b in blocks])) for j, c in enumerate(first)]


#: How %.10g spells the non-finite numbers (blank cells in health.csv, except in the first column).
_NOT_FINITE = ("nan", "inf", "-inf")


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
        with atomic_output(path, FlightLogError, text=True) as handle:
            _write_csv(table, handle)
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
