"""Import of a foreign CSV export (Garmin G1000, NGAFID processed, ...) through a mapping
(:mod:`ecu_monitor.flightlog.mapping` describes the format): units, pressure altitude, repeated
headers and rows, then the canonical rules."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType

import numpy as np

from ecu_monitor.errors import ConfigError, FlightLogError
from ecu_monitor.flightlog.canonical import _column_order
from ecu_monitor.flightlog.cylinders import choose_cht, cylinder_columns
from ecu_monitor.flightlog.layout import _choose_engine, _fill, _sources_present
from ecu_monitor.flightlog.log import FlightLog
from ecu_monitor.flightlog.mapping import _MAX_CYLINDERS, _REDUCERS, ColumnMap, CsvMapping, CylinderMap, load_mapping
from ecu_monitor.flightlog.rules import _assemble
from ecu_monitor.flightlog.table import _check_widths, _is_number, _note, _numbers, _read_table, _Table
from ecu_monitor.flightlog.timestamps import _fill_forward, _parse_time
from ecu_monitor.units import UNITS, Unit, pressure_altitude_m

#: Unit text in a log's own units row (lower case, spaces removed) -> unit name; other texts are ignored.
_UNIT_TEXT: Mapping[str, str] = MappingProxyType(
    {
        "degf": "degF",
        "°f": "degF",
        "degc": "degC",
        "°c": "degC",
        "kt": "kt",
        "kts": "kt",
        "knots": "kt",
        "km/h": "km/h",
        "m/s": "m/s",
        "ft": "ft",
        "ftbaro": "ft",
        "ftmsl": "ft",
        "m": "m",
        "fpm": "fpm",
        "ft/min": "fpm",
        "gph": "usgal_per_h",
        "gal/h": "usgal_per_h",
        "lph": "l_per_h",
        "l/h": "l_per_h",
        "inch": "inHg",
        "inhg": "inHg",
        "kpa": "kPa",
        "hpa": "hPa",
        "mbar": "hPa",
        "psi": "psi",
        "rpm": "rpm",
        "%": "pct",
    }
)
#: Columns that cannot be negative: small negative readings (sensor offset on the ground) clip to 0.
_NON_NEGATIVE: tuple[str, ...] = ("airspeed_mps", "fuel_flow_lph")

#: Altimeter settings outside this range (kPa) are not a setting but an error.
_QNH_RANGE_KPA = (85.0, 110.0)


def _pressure_altitude(
    src: str, altitude_m: np.ndarray, qnh_kpa: np.ndarray, column: str, lines: np.ndarray, notes: list[str]
) -> np.ndarray:
    """Pressure altitude (standard datum, 101.325 kPa) from a baro-corrected altitude and the
    altimeter setting it was corrected with; a blank setting takes the row before's."""
    known = ~np.isnan(qnh_kpa)
    if not np.any(known):
        _note(notes, src, f"column '{column}' (altimeter setting) is blank in every row: altitude_m kept as logged")
        return altitude_m
    lo, hi = _QNH_RANGE_KPA
    bad = known & ((qnh_kpa < lo) | (qnh_kpa > hi))
    if np.any(bad):
        k = int(np.argmax(bad))
        raise FlightLogError(
            f"{src}: row {lines[k]}, column '{column}': altimeter setting {qnh_kpa[k]:g} kPa"
            f" is outside {lo:g}..{hi:g} kPa"
        )
    # pressure altitude h_p = h + (the pressure altitude of the setting QNH), standard atmosphere
    return altitude_m + pressure_altitude_m(_fill_forward(qnh_kpa))


def _drop_repeated_headers(src: str, table: _Table, notes: list[str]) -> None:
    """Exports joined end to end repeat their header lines: rows that start with ``#`` (metadata and
    units lines) or repeat the column names are dropped (in place)."""
    first_name = table.header[0] if table.header else ""

    def is_header(fields: list[str]) -> bool:
        head = fields[0].strip() if fields else ""
        if head.startswith("#"):
            return True
        return bool(head) and head == first_name and [f.strip() for f in fields] == table.header

    dropped = [line for line, fields in table.rows if is_header(fields)]
    if dropped:
        table.rows[:] = [row for row in table.rows if not is_header(row[1])]
        _note(notes, src, f"{len(dropped)} repeated header line(s) dropped (first at row {dropped[0]})")
        if not table.rows:
            raise FlightLogError(f"{src}: header lines only, no data rows")


def _drop_duplicate_rows(src: str, table: _Table, notes: list[str]) -> None:
    """A row identical in every field to the row before is a logging artefact: dropped (in place)."""
    kept = [table.rows[0]]
    first = 0
    for row in table.rows[1:]:
        if row[1] != kept[-1][1]:
            kept.append(row)
        elif not first:
            first = row[0]
    dropped = len(table.rows) - len(kept)
    if dropped:
        _note(notes, src, f"{dropped} row(s) identical to the row before dropped (first at row {first})")
        table.rows[:] = kept


def _file_units(mapping: CsvMapping, table: _Table) -> tuple[int, list[str]] | None:
    """(line, fields) of the file's units row, if the mapping names one and the file has it.

    A units row after the header is optional: it is taken (and removed from the data rows) only when
    none of its fields is a number.
    """
    if mapping.units_row is None:
        return None
    if mapping.units_row < mapping.header_row:
        fields = table.before.get(mapping.units_row)
        return None if fields is None else (mapping.units_row, fields)
    if table.rows and table.rows[0][0] == mapping.units_row:
        fields = [f.strip() for f in table.rows[0][1]]
        if not any(f and _is_number(f) for f in fields):
            table.rows.pop(0)
            return mapping.units_row, fields
    return None


def _source_unit(
    src: str,
    target: str,
    name: str,
    unit: str | Unit,
    units: tuple[int, list[str]] | None,
    index: Mapping[str, int],
) -> tuple[str | Unit, str | None]:
    """The unit column ``name`` is read in: the file's units row wins over the mapping when it names a
    known unit of the same quantity. Returns (unit, note or None)."""
    if units is None:
        return unit, None
    line, fields = units
    i = index[name]
    text = fields[i] if i < len(fields) else ""
    known = _UNIT_TEXT.get(text.lower().replace(" ", ""))
    if known is None or known == unit:
        return unit, None
    quantity = unit.quantity if isinstance(unit, Unit) else UNITS[unit].quantity
    if quantity == "custom":  # a custom unit of a column of no known quantity: the mapping's word stands
        return unit, None
    if UNITS[known].quantity != quantity:
        raise FlightLogError(
            f"{src}: row {line}, column '{name}': unit {text!r} is a {UNITS[known].quantity} unit,"
            f" '{target}' needs {quantity}"
        )
    mapped = f"{{scale: {unit.scale:g}, offset: {unit.offset:g}}}" if isinstance(unit, Unit) else unit
    return known, f"column '{name}': the file's units row says {text!r}: read as {known}, not the mapping's {mapped}"


def import_mapped_csv(
    path: str | os.PathLike[str],
    mapping_path: str | os.PathLike[str],
    *,
    engine: int | None = None,
    cht: str | int | None = None,
) -> FlightLog:
    """Import a foreign CSV through a mapping YAML (format and rules in the module docstring).

    ``engine`` picks the engine of a multi-engine file (1-based; required when the file holds
    several). ``cht`` says how ``cht_c`` is made from the cylinders (``mean`` by default,
    ``hottest`` or a cylinder number), for a mapping with ``cylinders.cht``.
    """
    mapping = load_mapping(mapping_path)
    path = Path(path)
    src = str(path)
    notes: list[str] = []
    units_row = mapping.units_row
    units_before = units_row if units_row is not None and units_row < mapping.header_row else None
    table = _read_table(
        path,
        notes,
        header_row=mapping.header_row,
        skip_after=mapping.skip_rows_after_header,
        delimiter=mapping.delimiter,
        keep_before=units_before,
    )
    index = {name: i for i, name in reversed(list(enumerate(table.header)))}  # first of duplicates
    chosen = _choose_engine(src, mapping, index, engine)
    for i, name in enumerate(mapping.time.columns):
        if name not in index and mapping.time.row_step_s is None:
            key = {"seconds": "column", "date_time": ("date_column", "time_column")[i]}[mapping.time.kind]
            raise ConfigError(f"{mapping.path}: key 'time.{key}': column {name!r} not in {src}")
    reads: list[tuple[ColumnMap, tuple[str, ...]]] = []
    for cm in mapping.columns:
        present = _sources_present(cm, chosen, index)
        if present is None:
            if cm.optional:
                continue
            key = "column" if cm.reduce is None else "columns"
            names = [_fill(s, chosen) for s in cm.sources]
            missing = names if cm.reduce is None else [n for n in names if n not in index]
            shown = " or ".join(map(repr, missing))
            raise ConfigError(f"{mapping.path}: key 'columns.{cm.target}.{key}': column {shown} not in {src}")
        reads.append((cm, present))
    cylinder_reads: list[tuple[CylinderMap, list[tuple[int, str]]]] = []
    for cyl in mapping.cylinders:
        found = [(n, _fill(cyl.pattern, chosen, n)) for n in range(1, _MAX_CYLINDERS + 1)]
        found = [(n, name) for n, name in found if name in index]
        if not found and cyl.kind == "cht":
            raise ConfigError(
                f"{mapping.path}: key 'cylinders.cht.column': column {_fill(cyl.pattern, chosen, 1)!r} not in {src}"
            )
        last = found[-1][0] if found else 0
        absent = [n for n in range(1, last) if n not in {k for k, _ in found}]
        if absent:  # an export without one cylinder's column: the others are kept, as for a dead probe
            absent_columns = ", ".join(repr(_fill(cyl.pattern, chosen, n)) for n in absent)
            targets = ", ".join(f"{cyl.kind}{n}_c" for n in absent)
            _note(notes, src, f"no column {absent_columns} among cylinders 1-{last}: {targets} absent, the others kept")
        cylinder_reads.append((cyl, found))
    units = _file_units(mapping, table)
    if not table.rows:
        raise FlightLogError(f"{src}: only a units row after the header, no data rows")
    _drop_repeated_headers(src, table, notes)
    _check_widths(src, len(table.header), table.rows)
    _drop_duplicate_rows(src, table, notes)
    lines = np.array([line for line, _ in table.rows], dtype=np.int64)
    time = _parse_time(src, mapping.time, table, index, lines, notes)

    def read(target: str, name: str, unit: str | Unit) -> np.ndarray:
        unit, note = _source_unit(src, target, name, unit, units, index)
        if note:
            _note(notes, src, note)
        col = index[name]
        values = _numbers(src, name, [r[col] for _, r in table.rows], lines)
        return (unit if isinstance(unit, Unit) else UNITS[unit]).to_canonical(values)

    cols: dict[str, np.ndarray] = {}
    soft: set[str] = set()
    for cm, sources in reads:
        parts = [read(cm.target, name, cm.unit) for name in sources]
        values = parts[0] if cm.reduce is None else _REDUCERS[cm.reduce](np.vstack(parts), axis=0)
        if cm.target in _NON_NEGATIVE:
            negative = values < 0.0
            if np.any(negative):
                _note(
                    notes,
                    src,
                    f"column '{cm.target}': {int(np.count_nonzero(negative))} negative value(s)"
                    f" (lowest {np.nanmin(values):.3g}) clipped to 0",
                )
                values = np.where(negative, 0.0, values)
        cols[cm.target] = values
        if cm.optional:
            soft.add(cm.target)
    for cyl, found in cylinder_reads:
        for n, name in found:
            cols[f"{cyl.kind}{n}_c"] = read(f"{cyl.kind}{n}_c", name, cyl.unit)
    if mapping.altimeter_setting is not None and "altitude_m" in cols:
        column, unit = mapping.altimeter_setting
        if column in index:
            qnh_kpa = read("altimeter_setting", column, unit)
            cols["altitude_m"] = _pressure_altitude(src, cols["altitude_m"], qnh_kpa, column, lines, notes)
        else:
            _note(notes, src, f"no column {column!r} (altimeter setting): altitude_m kept as logged")
    log = _assemble(src, time, cols, lines, notes, strict=lambda name: name not in soft, soft=frozenset(soft))
    derived: dict[str, np.ndarray] = {}
    egts = cylinder_columns(log, "egt")
    if egts:
        stack = np.vstack([log[c] for c in egts])
        derived.update({"egt_c": stack.mean(axis=0), "egt_max_c": stack.max(axis=0)})
    log = log.with_columns(**{k: v for k, v in derived.items() if not log.has(k)})
    if cylinder_columns(log, "cht"):
        log = choose_cht(log, "mean" if cht is None else cht)
    elif any(cyl.kind == "cht" for cyl in mapping.cylinders):
        raise FlightLogError(f"{src}: every CHT cylinder column is blank in every row: no cht_c")
    elif cht is not None:
        log = choose_cht(log, cht)  # raises: no per-cylinder columns
    return FlightLog({c: log[c] for c in _column_order(log)}, log.source, log.notes)
