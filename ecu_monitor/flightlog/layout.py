"""Which layout a CSV has and which engine of a multi-engine file is read.

Layout detection (:func:`detect_layout`): a CSV whose first line names ``time_s`` is canonical;
otherwise the shipped mappings (``g1000``: Garmin G1000 exports of every firmware seen;
``ngafid_processed``: NGAFID processed exports) are tried on its header.
A file holding several engines (``E1 RPM``, ``E2 RPM``) needs the engine chosen (``engine=``).
"""

from __future__ import annotations

import csv
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

from ecu_monitor.errors import FlightLogError
from ecu_monitor.flightlog.mapping import (
    _MAX_ENGINES,
    CYLINDER_PLACEHOLDER,
    ENGINE_PLACEHOLDER,
    MAPPINGS_DIR,
    ColumnMap,
    CsvMapping,
    CylinderMap,
    load_mapping,
)
from ecu_monitor.flightlog.table import _reading


def _fill(name: str, engine: int, cylinder: int | None = None) -> str:
    name = name.replace(ENGINE_PLACEHOLDER, str(engine))
    return name if cylinder is None else name.replace(CYLINDER_PLACEHOLDER, str(cylinder))


def _sources_present(cm: ColumnMap, engine: int, index: Mapping[str, int]) -> tuple[str, ...] | None:
    """The file's columns ``cm`` reads for ``engine``, or None if the file lacks them."""
    names = tuple(_fill(s, engine) for s in cm.sources)
    if cm.reduce is None:
        first = next((n for n in names if n in index), None)
        return None if first is None else (first,)
    return names if all(n in index for n in names) else None


def _engine_columns(mapping: CsvMapping) -> tuple[list[ColumnMap], list[CylinderMap]]:
    """The required columns and the CHT cylinders whose names hold the engine placeholder."""
    cols = [cm for cm in mapping.columns if not cm.optional and any(ENGINE_PLACEHOLDER in s for s in cm.sources)]
    cyls = [c for c in mapping.cylinders if c.kind == "cht" and ENGINE_PLACEHOLDER in c.pattern]
    return cols, cyls


def _engines(mapping: CsvMapping, index: Mapping[str, int]) -> list[int]:
    """Engine numbers for which the file holds every required engine column (empty: no engine placeholder)."""
    cols, cyls = _engine_columns(mapping)
    if not cols and not cyls:
        return []
    return [
        e
        for e in range(1, _MAX_ENGINES + 1)
        if all(_sources_present(cm, e, index) for cm in cols) and all(_fill(c.pattern, e, 1) in index for c in cyls)
    ]


def _choose_engine(src: str, mapping: CsvMapping, index: Mapping[str, int], engine: int | None) -> int:
    engines = _engines(mapping, index)
    if engine is not None and engine < 1:
        raise FlightLogError(f"{src}: engine {engine}: engines are numbered from 1")
    if not engines:
        cols, cyls = _engine_columns(mapping)
        if not cols and not cyls and engine not in (None, 1):
            raise FlightLogError(f"{src}: engine {engine} asked for, the file holds one engine")
        return 1 if engine is None else engine  # missing columns are reported by name below
    if engine is None:
        if len(engines) > 1:
            cols, cyls = _engine_columns(mapping)
            sample = cols[0].sources[0] if cols else cyls[0].pattern
            shown = ", ".join(repr(_fill(sample, e, 1)) for e in engines)
            raise FlightLogError(f"{src}: {len(engines)} engines ({shown}): choose one with --engine N")
        return engines[0]
    if engine not in engines:
        raise FlightLogError(f"{src}: no engine {engine} in the file (engines: {', '.join(map(str, engines))})")
    return engine


def _layout_problem(mapping: CsvMapping, header: Sequence[str]) -> str | None:
    """Why ``mapping`` does not fit a file with this header (None when it fits)."""
    index = {name: i for i, name in enumerate(header)}
    if mapping.time.row_step_s is None:
        for name in mapping.time.columns:
            if name not in index:
                return f"no column {name!r}"
    engines = _engines(mapping, index) or [1]
    for cm in mapping.columns:
        if not cm.optional and _sources_present(cm, engines[0], index) is None:
            return f"no column {' or '.join(repr(_fill(s, engines[0])) for s in cm.sources)}"
    for cyl in mapping.cylinders:
        if cyl.kind == "cht" and _fill(cyl.pattern, engines[0], 1) not in index:
            return f"no column {_fill(cyl.pattern, engines[0], 1)!r}"
    return None


def detect_layout(path: str | os.PathLike[str]) -> Path | None:
    """The shipped mapping whose layout fits the CSV at ``path``; None for a canonical flight CSV.

    A file whose first line names ``time_s`` is canonical. Otherwise every shipped mapping (sorted by
    name) is tried on the file's header line; the first that finds its time and required columns wins.
    No fit is a :class:`FlightLogError` saying why each layout does not fit.
    """
    path = Path(path)
    src = str(path)
    mappings = [load_mapping(p) for p in sorted(MAPPINGS_DIR.glob("*.yaml"))]
    depth = max([1, *(m.header_row for m in mappings)])
    delimiters = {m.delimiter for m in mappings} | {","}
    with _reading(src), path.open(newline="", encoding="utf-8-sig", errors="replace") as fh:
        head = [fh.readline() for _ in range(depth)]
    if not head[0].strip():
        raise FlightLogError(f"{src}: empty file, expected a header row")
    split = {d: [[f.strip() for f in next(csv.reader([line], delimiter=d), [])] for line in head] for d in delimiters}
    if "time_s" in split[","][0]:
        return None
    problems = []
    for mapping in mappings:
        problem = _layout_problem(mapping, split[mapping.delimiter][mapping.header_row - 1])
        if problem is None:
            return Path(mapping.path)
        problems.append(f"{Path(mapping.path).stem}: {problem}")
    raise FlightLogError(
        f"{src}: not a canonical flight CSV (no column 'time_s') and no known layout fits"
        f" ({'; '.join(problems)}); import it with a mapping file first:"
        f" ecu-monitor import {src} --mapping MAPPING.yaml --out flight.csv (docs/flight_logs.md)"
    )
