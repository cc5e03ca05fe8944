"""The YAML mapping that describes a foreign CSV export: parsed and validated by :func:`load_mapping`,
used by :func:`ecu_monitor.flightlog.foreign.import_mapped_csv`.

Mapping YAML (:func:`import_mapped_csv`)
----------------------------------------
Example (after the shipped ``ecu_monitor/data/mappings/g1000.yaml``)::

    format: csv                # the only format so far
    delimiter: ","             # optional, default ","
    header_row: 3              # 1-based file line holding the column names
    skip_rows_after_header: 0  # lines between the header and the first data row
    units_row: 2               # optional: the file's own units line (above the header, or the first
                               # line after it, where it is taken only if none of its fields is a number)
    time:
      kind: date_time          # or: kind: seconds, column: "Time", unit: s (s, ms or min), and
                               #     row_step_s: 1.0 for files without that column (row k at k s)
      date_column: "Lcl Date"
      time_column: "Lcl Time"
      date_format: ["%Y-%m-%d", "%Y/%m/%d"]   # strptime; one format or several tried in order
      time_format: "%H:%M:%S"
    altimeter_setting: {column: "BaroA", unit: inHg}   # optional: altitude_m is baro-corrected with
                               # this setting and is made pressure altitude (standard datum)
    columns:                   # canonical (or any other identifier) -> source column(s) + unit
      altitude_m: {column: ["AltB", "AltInd"], unit: ft}     # a list: the first present is read
      rpm: {column: "E{engine} RPM", unit: rpm}             # {engine}: the engine chosen (1, 2, ...)
      oil_temp_c: {column: "E{engine} OilT", unit: degF, optional: true}   # may be absent
      egt_max_c: {columns: ["E1 EGT1", "E1 EGT2"], reduce: max, unit: degF}   # reduce: mean, max or min
    cylinders:                 # every cylinder kept: cht1_c .. chtN_c, egt1_c .. egtN_c ({n} = 1, 2, ...)
      cht: {column: "E{engine} CHT{n}", unit: degF}
      egt: {column: "E{engine} EGT{n}", unit: degF}

Keys are checked: an unknown key, a missing key, an unknown unit, a unit of the wrong kind for a
canonical column (``altitude_m`` in ``kt``), or a required source column absent from the CSV is a
``ConfigError`` naming the mapping file and the key. Source column names are matched after
stripping padding spaces; trailing empty columns are ignored. ``time_s`` is the time from the first
kept row; whole-second stamps shared by k rows are spread over their second (s, s + 1/k, ...), rows
identical to the row before are dropped. A known unit in the file's units row (``deg F``, ``gph``,
``kt``, ``ft Baro``, ``inch`` = inHg, ...) wins over the mapping's unit of the same quantity (with a
note); one of another quantity is an error. Units are converted with the one unit table,
:data:`ecu_monitor.units.UNITS`; a unit it does not know is given as ``unit: {scale: S, offset: O}``
(canonical = value * S + O, parsed by :func:`ecu_monitor.units.custom_unit` as in the service config;
not for time); negative
``airspeed_mps`` and ``fuel_flow_lph`` (an air-data system reading -1 kt on the ramp) are clipped to
0 with a note. Unmapped source columns are ignored. Then the canonical rules above apply (blank
runs, repeated or backward time, limits, gaps); an ``optional`` column keeps blank runs longer than
:data:`MAX_BLANK_RUN` as NaN, and a cylinder blank in every row (a dead probe) is dropped with a note.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from ecu_monitor.errors import ConfigError
from ecu_monitor.flightlog.log import _REQUIRED_ALWAYS, CYLINDER_COLUMN
from ecu_monitor.shipped import resolve_file, shipped_dir
from ecu_monitor.units import QUANTITY_OF_COLUMN, UNITS, Unit, custom_unit
from ecu_monitor.yamlfile import load_yaml_file

#: Shipped mapping files; ``--mapping NAME`` names one when no file NAME exists (:func:`resolve_mapping`).
MAPPINGS_DIR = shipped_dir("mapping")

#: Quantity each known column must be given in (other target names accept any unit).
_COLUMN_QUANTITY = {name: q for name, q in QUANTITY_OF_COLUMN.items() if name != "time_s"}

_REDUCERS: Mapping[str, Callable[..., Any]] = MappingProxyType({"mean": np.mean, "max": np.max, "min": np.min})
_IDENTIFIER = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")

#: Placeholders in a mapping's source column names: the engine number and the cylinder number.
ENGINE_PLACEHOLDER = "{engine}"
CYLINDER_PLACEHOLDER = "{n}"

_MAX_ENGINES = 8
_MAX_CYLINDERS = 24


@dataclass(frozen=True)
class TimeMap:
    """How the time axis is read: ``kind`` is ``date_time`` (two columns) or ``seconds`` (one).

    ``date_formats``/``time_formats`` are tried in order (several firmware versions); a file with
    the ``utc_offset_column`` (``+08:00``) is timed in UTC, so a flight across time zones or a clock
    change keeps a forward time; with ``row_step_s`` a file without the ``seconds`` column puts row
    k at ``k * row_step_s``.
    """

    kind: str
    columns: tuple[str, ...]
    date_formats: tuple[str, ...] = ("%Y-%m-%d",)
    time_formats: tuple[str, ...] = ("%H:%M:%S",)
    unit: str = "s"
    row_step_s: float | None = None
    utc_offset_column: str | None = None


@dataclass(frozen=True)
class ColumnMap:
    """One output column: ``target`` from ``sources`` in ``unit``.

    With ``reduce`` every source is read and reduced row-wise; without it the sources are
    alternatives and the first one present in the file is read (``AltB`` or ``AltInd``). An
    ``optional`` column may be absent from the file.
    """

    target: str
    sources: tuple[str, ...]
    unit: str | Unit  # a unit name, or a custom {scale, offset} unit
    reduce: str | None = None
    optional: bool = False


@dataclass(frozen=True)
class CylinderMap:
    """Per-cylinder columns: ``kind`` (``cht``/``egt``) from ``pattern`` with ``{n}`` = 1, 2, ... in ``unit``."""

    kind: str
    pattern: str
    unit: str | Unit  # a unit name, or a custom {scale, offset} unit


@dataclass(frozen=True)
class CsvMapping:
    """A validated mapping file."""

    path: str
    header_row: int
    skip_rows_after_header: int
    delimiter: str
    time: TimeMap
    columns: tuple[ColumnMap, ...]
    cylinders: tuple[CylinderMap, ...] = ()
    units_row: int | None = None
    altimeter_setting: tuple[str, str] | None = None  # (column, pressure unit): altitude_m is baro-corrected


class _Keys:
    """Reads one YAML mapping level, naming the file and the dotted key in every error."""

    def __init__(self, src: str, prefix: str, node: Any, allowed: Iterable[str]) -> None:
        self.src = src
        self.prefix = prefix
        if not isinstance(node, dict):
            where = f"key '{prefix}'" if prefix else "top level"
            raise ConfigError(f"{src}: {where}: expected a mapping, got {type(node).__name__}")
        allowed = tuple(allowed)
        for key in node:
            if key not in allowed:
                raise ConfigError(
                    f"{src}: key '{self.key(str(key))}': unknown key (expected one of {', '.join(allowed)})"
                )
        self.node = node

    def key(self, name: str) -> str:
        return f"{self.prefix}.{name}" if self.prefix else name

    def get(self, name: str, kind: type | tuple[type, ...], default: Any = ...) -> Any:
        if name not in self.node:
            if default is ...:
                raise ConfigError(f"{self.src}: key '{self.key(name)}': missing")
            return default
        value = self.node[name]
        if not isinstance(value, kind) or (isinstance(value, bool) and kind is int):
            names = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
            raise ConfigError(f"{self.src}: key '{self.key(name)}': expected {names}, got {value!r}")
        return value

    def names(self, name: str, default: Any = ...) -> tuple[str, ...]:
        """A string or a non-empty list of strings, as a tuple."""
        value = self.get(name, (str, list), default)
        if isinstance(value, str):
            return (value,)
        if isinstance(value, tuple):
            return value
        if not value or not all(isinstance(v, str) for v in value):
            raise self.fail(name, "expected a name or a non-empty list of names")
        return tuple(value)

    def fail(self, name: str, message: str) -> ConfigError:
        return ConfigError(f"{self.src}: key '{self.key(name)}': {message}")


def _check_unit(keys: _Keys, target: str | None) -> str | Unit:
    """A column's unit: a name of the unit table (returned as the name) or, except for time, a custom
    ``{scale: S, offset: O}`` (returned as a :class:`~ecu_monitor.units.Unit` of the column's quantity)."""
    wanted = _COLUMN_QUANTITY.get(target or "")
    if target is None:
        wanted = "time"
    elif CYLINDER_COLUMN.match(target):
        wanted = "temperature"
    value = keys.get("unit", (str, dict) if target is not None else str)
    if isinstance(value, dict):
        try:
            return custom_unit(value, wanted)
        except ValueError as exc:
            raise keys.fail("unit", str(exc)) from None
    unit = value
    if unit not in UNITS:
        raise keys.fail("unit", f"unknown unit {unit!r} (known: {', '.join(UNITS)}; or {{scale: S, offset: O}})")
    if wanted is not None and UNITS[unit].quantity != wanted:
        raise keys.fail("unit", f"{unit!r} is a {UNITS[unit].quantity} unit, '{target or 'time'}' needs {wanted}")
    return unit


def load_mapping(path: str | os.PathLike[str]) -> CsvMapping:
    """Parse and validate a mapping YAML file (format in the module docstring)."""
    path = Path(path)
    src = str(path)
    raw = load_yaml_file(path, "mapping file", ConfigError)
    top = _Keys(
        src,
        "",
        raw,
        (
            "format",
            "delimiter",
            "header_row",
            "skip_rows_after_header",
            "units_row",
            "time",
            "columns",
            "cylinders",
            "altimeter_setting",
        ),
    )
    fmt = top.get("format", str, "csv")
    if fmt != "csv":
        raise top.fail("format", f"unknown format {fmt!r} (known: csv)")
    delimiter = top.get("delimiter", str, ",")
    if len(delimiter) != 1:
        raise top.fail("delimiter", f"expected one character, got {delimiter!r}")
    header_row = top.get("header_row", int, 1)
    if header_row < 1:
        raise top.fail("header_row", f"expected a 1-based line number, got {header_row}")
    skip = top.get("skip_rows_after_header", int, 0)
    if skip < 0:
        raise top.fail("skip_rows_after_header", f"expected 0 or more, got {skip}")
    units_row = top.get("units_row", int, None)
    if units_row is not None and not (1 <= units_row < header_row or units_row == header_row + skip + 1):
        raise top.fail(
            "units_row",
            f"expected a line above the header (1..{header_row - 1}) or the first line after it"
            f" ({header_row + skip + 1}), got {units_row}",
        )

    t = _Keys(
        src,
        "time",
        top.get("time", dict),
        (
            "kind",
            "date_column",
            "time_column",
            "date_format",
            "time_format",
            "utc_offset_column",
            "column",
            "unit",
            "row_step_s",
        ),
    )
    kind = t.get("kind", str)
    if kind == "date_time":
        for key in ("column", "unit", "row_step_s"):
            if key in t.node:
                raise t.fail(key, "only for kind: seconds")
        time = TimeMap(
            kind,
            (t.get("date_column", str), t.get("time_column", str)),
            date_formats=t.names("date_format", ("%Y-%m-%d",)),
            time_formats=t.names("time_format", ("%H:%M:%S",)),
            utc_offset_column=t.get("utc_offset_column", str, None),
        )
    elif kind == "seconds":
        for key in ("date_column", "time_column", "date_format", "time_format", "utc_offset_column"):
            if key in t.node:
                raise t.fail(key, "only for kind: date_time")
        unit = _check_unit(t, None) if "unit" in t.node else "s"
        if not isinstance(unit, str):  # _check_unit gives time a named unit only
            raise t.fail("unit", "the time column takes a named unit (such as s or ms)")
        step = t.get("row_step_s", (int, float), None)
        if step is not None and not (math.isfinite(step) and step > 0):
            raise t.fail("row_step_s", f"expected a positive number of seconds, got {step!r}")
        time = TimeMap(kind, (t.get("column", str),), unit=unit, row_step_s=None if step is None else float(step))
    else:
        raise t.fail("kind", f"unknown time kind {kind!r} (known: date_time, seconds)")

    columns_node = top.get("columns", dict)
    if not columns_node:
        raise top.fail("columns", "no columns mapped")
    maps: list[ColumnMap] = []
    for target, spec in columns_node.items():
        name = str(target)
        if not _IDENTIFIER.match(name) or name == "time_s":
            raise ConfigError(f"{src}: key 'columns.{name}': output name must be an identifier other than time_s")
        c = _Keys(src, f"columns.{name}", spec, ("column", "columns", "reduce", "unit", "optional"))
        if ("column" in c.node) == ("columns" in c.node):
            raise c.fail("column", "give exactly one of 'column' or 'columns'")
        optional = c.get("optional", bool, False)
        if name in _REQUIRED_ALWAYS and optional:
            raise c.fail("optional", f"the canonical column '{name}' cannot be optional")
        if "column" in c.node:
            if "reduce" in c.node:
                raise c.fail("reduce", "only with 'columns'")
            sources = c.names("column")
            reduce = None
        else:
            listed = c.get("columns", list)
            if not listed or not all(isinstance(s, str) for s in listed):
                raise c.fail("columns", "expected a non-empty list of column names")
            sources = tuple(listed)
            reduce = c.get("reduce", str)
            if reduce not in _REDUCERS:
                raise c.fail("reduce", f"unknown reduction {reduce!r} (known: {', '.join(_REDUCERS)})")
        maps.append(ColumnMap(name, tuple(s.strip() for s in sources), _check_unit(c, name), reduce, optional))

    cylinders: list[CylinderMap] = []
    cyl_node = top.get("cylinders", dict, {})
    cyl_keys = _Keys(src, "cylinders", cyl_node, ("cht", "egt"))
    for kind_name in ("cht", "egt"):
        if kind_name not in cyl_keys.node:
            continue
        c = _Keys(src, f"cylinders.{kind_name}", cyl_keys.node[kind_name], ("column", "unit"))
        pattern = c.get("column", str).strip()
        if CYLINDER_PLACEHOLDER not in pattern:
            raise c.fail("column", f"the column name needs the cylinder number placeholder {CYLINDER_PLACEHOLDER}")
        cylinders.append(CylinderMap(kind_name, pattern, _check_unit(c, f"{kind_name}1_c")))

    altimeter = None
    if "altimeter_setting" in top.node:
        a = _Keys(src, "altimeter_setting", top.node["altimeter_setting"], ("column", "unit"))
        unit = a.get("unit", str)
        if unit not in UNITS or UNITS[unit].quantity != "pressure":
            raise a.fail(
                "unit",
                f"expected a pressure unit ({', '.join(k for k, u in UNITS.items() if u.quantity == 'pressure')})",
            )
        altimeter = (a.get("column", str).strip(), unit)

    mapped = {m.target for m in maps}
    has_cylinder_cht = any(c.kind == "cht" for c in cylinders)
    if has_cylinder_cht and "cht_c" in mapped:
        raise top.fail("columns", "cht_c is made from cylinders.cht (mean, hottest or one): do not map it as well")
    for name in _REQUIRED_ALWAYS[1:]:
        if name not in mapped and not (name == "cht_c" and has_cylinder_cht):
            raise top.fail("columns", f"canonical column '{name}' is not mapped")
    if "throttle_pct" not in mapped and "fuel_flow_lph" not in mapped:
        raise top.fail("columns", "map 'throttle_pct' or, for a log without throttle, 'fuel_flow_lph'")
    return CsvMapping(src, header_row, skip, delimiter, time, tuple(maps), tuple(cylinders), units_row, altimeter)


def resolve_mapping(name_or_path: str | os.PathLike[str]) -> Path:
    """A mapping file: a path that exists, else a shipped mapping's name (``g1000``)."""
    return resolve_file(name_or_path, "mapping")
