"""Flight logs: the canonical flight CSV (DESIGN.md section 3) and the import of foreign logs.

Everything the model, the estimators, identification and the gap diagnosis read from a flight goes
through a :class:`FlightLog`: named float64 columns of equal length on a strictly increasing
``time_s``. Three ways in, one way out:

* :func:`read_csv` - a canonical CSV, validated row by row;
* :func:`import_mapped_csv` - a foreign CSV export (e.g. a Garmin G1000 engine-data log) through a
  small YAML mapping of source column -> canonical name + unit;
* :func:`import_can_log` - a python-can log (.asc, .blf, .log, .trc) decoded with DBC files and
  sampled-and-held onto a uniform time grid;
* :func:`write_csv` - canonical columns first, in contract order, then the rest; every value written
  with the shortest text that reads back to the same float.

:func:`load_flight` dispatches on the file suffix. Every problem with the input raises
:class:`~ecu_monitor.errors.FlightLogError` (bad data) or :class:`~ecu_monitor.errors.ConfigError` (bad
mapping) with one line naming the file, the row (1-based file line, the header of a canonical CSV is
row 1) and the column. Problems that can be repaired without guessing (a repeated timestamp, an
isolated blank field, a truncated last row, a time gap) are repaired, logged with
``logging.warning`` and kept in :attr:`FlightLog.notes`.

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
  mid-write) is dropped with a warning; a short row anywhere else is an error.
* Extra columns are carried along as floats (blank fields stay NaN) when numeric, and dropped with a
  debug message when they hold text or have no name (a trailing comma).

Mapping YAML (:func:`import_mapped_csv`)
----------------------------------------
Example (the shipped ``ecu_monitor/data/mappings/g1000.yaml``)::

    format: csv                # the only format so far
    delimiter: ","             # optional, default ","
    header_row: 3              # 1-based file line holding the column names
    skip_rows_after_header: 0  # lines between the header and the first data row (e.g. a units line)
    time:
      kind: date_time          # or: kind: seconds, column: "Time", unit: s   (s, ms or min)
      date_column: "Lcl Date"
      time_column: "Lcl Time"
      date_format: "%Y-%m-%d"  # optional (strptime), these are the defaults
      time_format: "%H:%M:%S"
    columns:                   # canonical (or any other identifier) -> source column(s) + unit
      altitude_m: {column: "AltB", unit: ft}
      cht_c: {columns: ["E1 CHT1", "E1 CHT2"], reduce: mean, unit: degF}   # reduce: mean, max or min

Keys are checked: an unknown key, a missing key, an unknown unit, a unit of the wrong kind for a
canonical column (``altitude_m`` in ``kt``), or a source column absent from the CSV is a
``ConfigError`` naming the mapping file and the key. Source column names are matched after
stripping padding spaces. ``time_s`` is the time from the first kept row. Units are converted with
:data:`UNITS`; negative ``airspeed_mps`` and ``fuel_flow_lph`` (an air-data system reading -1 kt on
the ramp) are clipped to 0 with a note. Unmapped source columns are ignored. Then the canonical
rules above apply (blank runs, repeated or backward time, limits, gaps).
"""

from __future__ import annotations

import csv
import datetime as _dt
import logging
import math
import os
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, NamedTuple

import numpy as np
import yaml

from ecu_monitor.errors import ConfigError, FlightLogError

__all__ = [
    "CANONICAL_COLUMNS",
    "CAN_LOG_SUFFIXES",
    "DEFAULT_ENGINE_DBC",
    "DEFAULT_SIGNAL_MAP",
    "GAP_WARN_S",
    "MAPPINGS_DIR",
    "MAX_BLANK_RUN",
    "OPTIONAL_COLUMNS",
    "PHYSICAL_LIMITS",
    "UNITS",
    "ColumnMap",
    "CsvMapping",
    "FlightLog",
    "TimeMap",
    "Unit",
    "import_can_log",
    "import_mapped_csv",
    "load_flight",
    "load_mapping",
    "read_csv",
    "resolve_mapping",
    "write_csv",
]

_log = logging.getLogger(__name__)

#: The canonical columns, in contract order (DESIGN.md section 3).
CANONICAL_COLUMNS: tuple[str, ...] = (
    "time_s",
    "throttle_pct",
    "rpm",
    "altitude_m",
    "airspeed_mps",
    "oat_c",
    "cht_c",
)
#: Known optional columns; ``cht_true_c`` is the virtual ECU's truth (unquantised, noiseless) CHT.
OPTIONAL_COLUMNS: tuple[str, ...] = ("fuel_flow_lph", "vspeed_mps", "cht_true_c")

#: Physically possible range of a column, inclusive; a value outside is an input error.
PHYSICAL_LIMITS: Mapping[str, tuple[float, float]] = MappingProxyType(
    {
        "rpm": (0.0, 30000.0),
        "throttle_pct": (-1.0, 101.0),
        "cht_c": (-60.0, 500.0),
        "cht_true_c": (-60.0, 500.0),
        "oat_c": (-80.0, 70.0),
    }
)
#: Longest run of blank fields that is filled by interpolation.
MAX_BLANK_RUN = 5
#: Time gaps longer than this are kept but reported.
GAP_WARN_S = 5.0

#: Suffixes read with python-can's ``LogReader``.
CAN_LOG_SUFFIXES: tuple[str, ...] = (".asc", ".blf", ".log", ".trc")
#: The repository's engine.dbc (present in a source checkout or an editable install).
DEFAULT_ENGINE_DBC = Path(__file__).resolve().parent.parent / "dbc" / "engine.dbc"
#: Shipped mapping files; ``--mapping NAME`` resolves to ``MAPPINGS_DIR / f"{NAME}.yaml"``.
MAPPINGS_DIR = Path(__file__).resolve().parent / "data" / "mappings"
#: Canonical column -> "Message.Signal" in dbc/engine.dbc.
DEFAULT_SIGNAL_MAP: Mapping[str, str] = MappingProxyType(
    {
        "throttle_pct": "ECU_Fast.ThrottlePos",
        "rpm": "ECU_Fast.EngineSpeed",
        "altitude_m": "AirData.PressureAltitude",
        "airspeed_mps": "AirData.CalibratedAirspeed",
        "oat_c": "ECU_Slow.OAT",
        "cht_c": "ECU_Slow.CHT",
        "fuel_flow_lph": "ECU_Fast.FuelFlow",
    }
)

_REQUIRED_ALWAYS = tuple(c for c in CANONICAL_COLUMNS if c != "throttle_pct")
_STRICT = frozenset(CANONICAL_COLUMNS + OPTIONAL_COLUMNS)


class Unit(NamedTuple):
    """A unit: its quantity and the affine map to the canonical unit, ``si = value * scale + offset``."""

    quantity: str
    scale: float
    offset: float


#: Unit name -> conversion to the canonical unit of its quantity (m, m/s, degC, L/h, rpm, %, s).
UNITS: Mapping[str, Unit] = MappingProxyType(
    {
        "m": Unit("length", 1.0, 0.0),
        "ft": Unit("length", 0.3048, 0.0),
        "m/s": Unit("speed", 1.0, 0.0),
        "mps": Unit("speed", 1.0, 0.0),
        "kt": Unit("speed", 1852.0 / 3600.0, 0.0),
        "km/h": Unit("speed", 1.0 / 3.6, 0.0),
        "fpm": Unit("speed", 0.3048 / 60.0, 0.0),
        "degC": Unit("temperature", 1.0, 0.0),
        "degF": Unit("temperature", 5.0 / 9.0, -32.0 * 5.0 / 9.0),
        "K": Unit("temperature", 1.0, -273.15),
        "usgal_per_h": Unit("volume_flow", 3.785411784, 0.0),
        "l_per_h": Unit("volume_flow", 1.0, 0.0),
        "rpm": Unit("rotational_speed", 1.0, 0.0),
        "pct": Unit("fraction", 1.0, 0.0),
        "s": Unit("time", 1.0, 0.0),
        "ms": Unit("time", 1e-3, 0.0),
        "min": Unit("time", 60.0, 0.0),
    }
)

#: Quantity each known column must be given in (other target names accept any unit).
_COLUMN_QUANTITY: Mapping[str, str] = MappingProxyType(
    {
        "throttle_pct": "fraction",
        "rpm": "rotational_speed",
        "altitude_m": "length",
        "airspeed_mps": "speed",
        "vspeed_mps": "speed",
        "oat_c": "temperature",
        "cht_c": "temperature",
        "cht_true_c": "temperature",
        "fuel_flow_lph": "volume_flow",
    }
)
#: Columns that cannot be negative: small negative readings (sensor offset on the ground) clip to 0.
_NON_NEGATIVE: tuple[str, ...] = ("airspeed_mps", "fuel_flow_lph")

_REDUCERS: Mapping[str, Callable[..., Any]] = MappingProxyType({"mean": np.mean, "max": np.max, "min": np.min})
#: Timestamp tolerance of the sample-and-hold grid (log formats store us or 10 us resolution).
_TIE_S = 1e-6
_IDENTIFIER = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


# --------------------------------------------------------------------------------------------------
# FlightLog
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class FlightLog:
    """An immutable flight log: float64 columns of equal length on a strictly increasing ``time_s``.

    The arrays are read-only copies. ``notes`` holds the warnings raised while the log was read
    (repairs made to the input); they are not part of the data.
    """

    columns: Mapping[str, np.ndarray]
    source: str = "<memory>"
    notes: tuple[str, ...] = field(default=(), repr=False)

    def __post_init__(self) -> None:
        if "time_s" not in self.columns:
            raise FlightLogError(f"{self.source}: no 'time_s' column")
        frozen: dict[str, np.ndarray] = {}
        length: int | None = None
        for name, values in self.columns.items():
            try:
                arr = np.array(values, dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise FlightLogError(f"{self.source}: column '{name}' is not numeric: {exc}") from exc
            if arr.ndim != 1:
                raise FlightLogError(f"{self.source}: column '{name}' is not one-dimensional")
            if length is None:
                length = arr.size
            elif arr.size != length:
                raise FlightLogError(f"{self.source}: column '{name}' has {arr.size} values, expected {length}")
            arr.flags.writeable = False
            frozen[name] = arr
        t = frozen["time_s"]
        if t.size == 0:
            raise FlightLogError(f"{self.source}: no samples")
        if not np.all(np.isfinite(t)):
            raise FlightLogError(f"{self.source}: column 'time_s' holds non-finite values")
        if t.size > 1 and not np.all(np.diff(t) > 0.0):
            k = int(np.argmax(np.diff(t) <= 0.0))
            raise FlightLogError(
                f"{self.source}: column 'time_s' is not strictly increasing at sample {k + 1}"
                f" ({t[k + 1]!r} after {t[k]!r})"
            )
        object.__setattr__(self, "columns", MappingProxyType(frozen))
        object.__setattr__(self, "notes", tuple(self.notes))

    def __len__(self) -> int:
        return int(self.columns["time_s"].size)

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise FlightLogError(f"{self.source}: no column '{name}' (columns: {', '.join(self.columns)})") from None

    def has(self, name: str) -> bool:
        """True if the log carries column ``name``."""
        return name in self.columns

    @property
    def names(self) -> tuple[str, ...]:
        """Column names, in storage order."""
        return tuple(self.columns)

    @property
    def time_s(self) -> np.ndarray:
        """Sample times, s (strictly increasing)."""
        return self.columns["time_s"]

    @property
    def duration_s(self) -> float:
        """Last minus first sample time, s."""
        t = self.time_s
        return float(t[-1] - t[0])

    def select(self, start_s: float, stop_s: float) -> FlightLog:
        """The samples with ``start_s <= time_s <= stop_s``; times stay absolute."""
        t = self.time_s
        keep = (t >= start_s) & (t <= stop_s)
        if not np.any(keep):
            raise FlightLogError(
                f"{self.source}: no samples between {start_s} s and {stop_s} s (log spans {t[0]} s to {t[-1]} s)"
            )
        return FlightLog({k: v[keep] for k, v in self.columns.items()}, self.source, self.notes)

    def with_columns(self, **cols: Any) -> FlightLog:
        """A copy with columns added or replaced (each must have ``len(self)`` values)."""
        merged: dict[str, Any] = dict(self.columns)
        merged.update(cols)
        return FlightLog(merged, self.source, self.notes)

    def resample(self, dt_s: float) -> FlightLog:
        """Linear interpolation of every column onto ``t0, t0 + dt_s, ...`` up to the last sample."""
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise FlightLogError(f"{self.source}: resample step must be a positive number, got {dt_s!r}")
        t = self.time_s
        n = math.floor((t[-1] - t[0]) / dt_s + 1e-9) + 1
        grid = t[0] + dt_s * np.arange(n, dtype=np.float64)
        cols = {k: (grid if k == "time_s" else np.interp(grid, t, v)) for k, v in self.columns.items()}
        return FlightLog(cols, self.source, self.notes)


# --------------------------------------------------------------------------------------------------
# Reading text tables
# --------------------------------------------------------------------------------------------------


class _Table(NamedTuple):
    header: list[str]
    rows: list[tuple[int, list[str]]]  # (1-based file line, stripped fields)


def _read_table(
    path: Path, notes: list[str], *, header_row: int = 1, skip_after: int = 0, delimiter: str = ","
) -> _Table:
    src = str(path)
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.reader(fh, delimiter=delimiter)
            header: list[str] | None = None
            rows: list[tuple[int, list[str]]] = []
            for fields in reader:
                line = reader.line_num
                if line < header_row:
                    continue
                if header is None:
                    header = [f.strip() for f in fields]
                    continue
                if line <= header_row + skip_after or not any(f.strip() for f in fields):
                    continue
                rows.append((line, [f.strip() for f in fields]))
    except FileNotFoundError:
        raise FlightLogError(f"{src}: no such file") from None
    except OSError as exc:
        raise FlightLogError(f"{src}: cannot read: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise FlightLogError(f"{src}: not a UTF-8 text file ({exc.reason} at byte {exc.start})") from exc
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
    return _Table(header, rows)


def _check_widths(src: str, table: _Table) -> None:
    """Every data row must have as many fields as the header (called once the header is checked)."""
    width = len(table.header)
    for line, fields in table.rows:
        if len(fields) != width:
            raise FlightLogError(f"{src}: row {line}: {len(fields)} fields, the header has {width}")


def _note(notes: list[str], source: str, message: str) -> None:
    notes.append(message)
    _log.warning("%s: %s", source, message)


def _floats(fields: Sequence[str]) -> np.ndarray | None:
    """Floats of one column (blank -> NaN), or None if a field holds text."""
    try:
        return np.array([float(f) if f else math.nan for f in fields], dtype=np.float64)
    except ValueError:
        return None


def _numbers(src: str, name: str, fields: Sequence[str], lines: Sequence[int] | np.ndarray) -> np.ndarray:
    """Floats of a column that must be numeric and finite; the error names the first bad row."""
    arr = _floats(fields)
    if arr is None:
        bad = next(i for i, f in enumerate(fields) if f and not _is_number(f))
        raise FlightLogError(f"{src}: row {lines[bad]}, column '{name}': {fields[bad]!r} is not a number")
    if np.any(np.isinf(arr)):
        k = int(np.argmax(np.isinf(arr)))
        raise FlightLogError(f"{src}: row {lines[k]}, column '{name}': {fields[k]!r} is not finite")
    return arr


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


# --------------------------------------------------------------------------------------------------
# Validation shared by the canonical and the mapped readers
# --------------------------------------------------------------------------------------------------


def _assemble(
    src: str, time: np.ndarray, cols: dict[str, np.ndarray], lines: np.ndarray, notes: list[str]
) -> FlightLog:
    """Apply the canonical rules (limits, time order, repeats, blanks, gaps) and build the log."""
    for name, values in cols.items():
        lo_hi = PHYSICAL_LIMITS.get(name)
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
    out: dict[str, np.ndarray] = {"time_s": time}
    for name, values in cols.items():
        blank = np.isnan(values)
        if not np.any(blank):
            out[name] = values
            continue
        if np.all(blank):
            if name in _STRICT:
                raise FlightLogError(f"{src}: rows {lines[0]}-{lines[-1]}, column '{name}': blank in every row")
            _log.debug("%s: column '%s' is blank in every row: dropped", src, name)
            continue
        if name not in _STRICT:
            out[name] = values  # extra columns keep their gaps as NaN
            continue
        start, length = _longest_run(blank)
        if length > MAX_BLANK_RUN:
            raise FlightLogError(
                f"{src}: row {lines[start]}, column '{name}': {length} consecutive blank fields"
                f" (rows {lines[start]}-{lines[start + length - 1]}); at most {MAX_BLANK_RUN} are interpolated"
            )
        filled = values.copy()
        filled[blank] = np.interp(time[blank], time[~blank], values[~blank])
        out[name] = filled
        _note(
            notes,
            src,
            f"column '{name}': {int(np.count_nonzero(blank))} blank field(s) interpolated"
            f" (first at row {lines[int(np.argmax(blank))]})",
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


def _longest_run(mask: np.ndarray) -> tuple[int, int]:
    """(start index, length) of the longest run of True in ``mask``."""
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.diff(padded)
    starts = np.flatnonzero(edges == 1)
    stops = np.flatnonzero(edges == -1)
    lengths = stops - starts
    k = int(np.argmax(lengths))
    return int(starts[k]), int(lengths[k])


# --------------------------------------------------------------------------------------------------
# Canonical CSV
# --------------------------------------------------------------------------------------------------


def read_csv(path: str | os.PathLike[str]) -> FlightLog:
    """Read and validate a canonical flight CSV (rules in the module docstring)."""
    path = Path(path)
    src = str(path)
    notes: list[str] = []
    table = _read_table(path, notes)
    header = table.header
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
    _check_widths(src, table)
    lines = np.array([line for line, _ in table.rows], dtype=np.int64)
    cols: dict[str, np.ndarray] = {}
    for i, name in enumerate(header):
        if not name:
            _log.debug("%s: column %d has no name: dropped", src, i + 1)
            continue
        fields = [row[i] for _, row in table.rows]
        if name in _STRICT:
            cols[name] = _numbers(src, name, fields, lines)
            continue
        arr = _floats(fields)
        if arr is None:
            _log.debug("%s: column '%s' holds text: dropped", src, name)
        else:
            cols[name] = arr
    time = cols.pop("time_s")
    if np.any(np.isnan(time)):
        k = int(np.argmax(np.isnan(time)))
        raise FlightLogError(f"{src}: row {lines[k]}, column 'time_s': blank time")
    return _assemble(src, time, cols, lines, notes)


def _fmt(value: float) -> str:
    return "" if value != value else repr(value)  # NaN -> blank; repr is the shortest exact text


def write_csv(log: FlightLog, path: str | os.PathLike[str]) -> None:
    """Write ``log`` as a canonical CSV: canonical columns in contract order, optional ones, the rest.

    Values are written with Python's shortest round-trip representation, so :func:`read_csv` gives
    back the same floats; NaN is written as a blank field. The file is written to a temporary name
    and renamed, so an interrupted write never leaves a half file under ``path``.
    """
    path = Path(path)
    known = CANONICAL_COLUMNS + OPTIONAL_COLUMNS
    order = [c for c in known if log.has(c)] + [c for c in log.columns if c not in known]
    data = [log[c].tolist() for c in order]
    tmp = path.with_name(path.name + ".tmp")
    try:
        with tmp.open("w", newline="", encoding="utf-8") as fh:
            fh.write(",".join(order) + "\n")
            fh.writelines(",".join(map(_fmt, row)) + "\n" for row in zip(*data, strict=True))
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise FlightLogError(f"{path}: cannot write: {exc.strerror or exc}") from exc


# --------------------------------------------------------------------------------------------------
# Mapped foreign CSV
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TimeMap:
    """How the time axis is read: ``kind`` is ``date_time`` (two columns) or ``seconds`` (one)."""

    kind: str
    columns: tuple[str, ...]
    date_format: str = "%Y-%m-%d"
    time_format: str = "%H:%M:%S"
    unit: str = "s"


@dataclass(frozen=True)
class ColumnMap:
    """One output column: ``target`` from ``sources`` (reduced with ``reduce`` if several) in ``unit``."""

    target: str
    sources: tuple[str, ...]
    unit: str
    reduce: str | None = None


@dataclass(frozen=True)
class CsvMapping:
    """A validated mapping file."""

    path: str
    header_row: int
    skip_rows_after_header: int
    delimiter: str
    time: TimeMap
    columns: tuple[ColumnMap, ...]


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

    def fail(self, name: str, message: str) -> ConfigError:
        return ConfigError(f"{self.src}: key '{self.key(name)}': {message}")


def _check_unit(keys: _Keys, target: str | None) -> str:
    unit = keys.get("unit", str)
    if unit not in UNITS:
        raise keys.fail("unit", f"unknown unit {unit!r} (known: {', '.join(UNITS)})")
    wanted = _COLUMN_QUANTITY.get(target or "")
    if target is None:
        wanted = "time"
    if wanted is not None and UNITS[unit].quantity != wanted:
        raise keys.fail("unit", f"{unit!r} is a {UNITS[unit].quantity} unit, '{target or 'time'}' needs {wanted}")
    return unit


def load_mapping(path: str | os.PathLike[str]) -> CsvMapping:
    """Parse and validate a mapping YAML file (format in the module docstring)."""
    path = Path(path)
    src = str(path)
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{src}: no such mapping file") from None
    except OSError as exc:
        raise ConfigError(f"{src}: cannot read: {exc.strerror or exc}") from exc
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{src}: not valid YAML{where}: {getattr(exc, 'problem', exc)}") from exc
    top = _Keys(src, "", raw, ("format", "delimiter", "header_row", "skip_rows_after_header", "time", "columns"))
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

    t = _Keys(
        src,
        "time",
        top.get("time", dict),
        ("kind", "date_column", "time_column", "date_format", "time_format", "column", "unit"),
    )
    kind = t.get("kind", str)
    if kind == "date_time":
        if "column" in t.node or "unit" in t.node:
            raise t.fail("column" if "column" in t.node else "unit", "only for kind: seconds")
        time = TimeMap(
            kind,
            (t.get("date_column", str), t.get("time_column", str)),
            date_format=t.get("date_format", str, "%Y-%m-%d"),
            time_format=t.get("time_format", str, "%H:%M:%S"),
        )
    elif kind == "seconds":
        for key in ("date_column", "time_column", "date_format", "time_format"):
            if key in t.node:
                raise t.fail(key, "only for kind: date_time")
        unit = _check_unit(t, None) if "unit" in t.node else "s"
        time = TimeMap(kind, (t.get("column", str),), unit=unit)
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
        c = _Keys(src, f"columns.{name}", spec, ("column", "columns", "reduce", "unit"))
        if ("column" in c.node) == ("columns" in c.node):
            raise c.fail("column", "give exactly one of 'column' or 'columns'")
        if "column" in c.node:
            if "reduce" in c.node:
                raise c.fail("reduce", "only with 'columns'")
            sources: tuple[str, ...] = (c.get("column", str),)
            reduce = None
        else:
            listed = c.get("columns", list)
            if not listed or not all(isinstance(s, str) for s in listed):
                raise c.fail("columns", "expected a non-empty list of column names")
            sources = tuple(listed)
            reduce = c.get("reduce", str)
            if reduce not in _REDUCERS:
                raise c.fail("reduce", f"unknown reduction {reduce!r} (known: {', '.join(_REDUCERS)})")
        maps.append(ColumnMap(name, tuple(s.strip() for s in sources), _check_unit(c, name), reduce))
    mapped = {m.target for m in maps}
    for name in _REQUIRED_ALWAYS[1:]:
        if name not in mapped:
            raise top.fail("columns", f"canonical column '{name}' is not mapped")
    if "throttle_pct" not in mapped and "fuel_flow_lph" not in mapped:
        raise top.fail("columns", "map 'throttle_pct' or, for a log without throttle, 'fuel_flow_lph'")
    return CsvMapping(src, header_row, skip, delimiter, time, tuple(maps))


def resolve_mapping(name_or_path: str | os.PathLike[str]) -> Path:
    """A mapping file path; a bare name without suffix (``g1000``) names a shipped mapping."""
    path = Path(name_or_path)
    if path.exists() or path.suffix or len(path.parts) > 1:
        return path
    shipped = MAPPINGS_DIR / f"{path.name}.yaml"
    if shipped.exists():
        return shipped
    known = sorted(p.stem for p in MAPPINGS_DIR.glob("*.yaml"))
    raise ConfigError(f"{name_or_path}: no such mapping file or shipped mapping (shipped: {', '.join(known)})")


def _parse_time(src: str, spec: TimeMap, table: _Table, index: Mapping[str, int], lines: np.ndarray) -> np.ndarray:
    cols = [index[c] for c in spec.columns]
    if spec.kind == "seconds":
        values = _numbers(src, spec.columns[0], [r[cols[0]] for _, r in table.rows], lines)
        if np.any(np.isnan(values)):
            k = int(np.argmax(np.isnan(values)))
            raise FlightLogError(f"{src}: row {lines[k]}, column '{spec.columns[0]}': blank time")
        unit = UNITS[spec.unit]
        values = values * unit.scale
        return values - values[0]
    fmt = f"{spec.date_format} {spec.time_format}"
    stamps = np.empty(len(table.rows), dtype=np.float64)
    cache: dict[str, float] = {}
    for k, (line, row) in enumerate(table.rows):
        text = f"{row[cols[0]]} {row[cols[1]]}"
        value = cache.get(text)
        if value is None:
            try:
                value = _dt.datetime.strptime(text, fmt).timestamp()
            except ValueError:
                raise FlightLogError(
                    f"{src}: row {line}, column '{spec.columns[1]}': {text!r} does not match {fmt!r}"
                ) from None
            cache[text] = value
        stamps[k] = value
    return stamps - stamps[0]


def import_mapped_csv(path: str | os.PathLike[str], mapping_path: str | os.PathLike[str]) -> FlightLog:
    """Import a foreign CSV through a mapping YAML (format and rules in the module docstring)."""
    mapping = load_mapping(mapping_path)
    path = Path(path)
    src = str(path)
    notes: list[str] = []
    table = _read_table(
        path,
        notes,
        header_row=mapping.header_row,
        skip_after=mapping.skip_rows_after_header,
        delimiter=mapping.delimiter,
    )
    index = {name: i for i, name in reversed(list(enumerate(table.header)))}  # first of duplicates
    for i, name in enumerate(mapping.time.columns):
        if name not in index:
            key = {"seconds": "column", "date_time": ("date_column", "time_column")[i]}[mapping.time.kind]
            raise ConfigError(f"{mapping.path}: key 'time.{key}': column {name!r} not in {src}")
    for cm in mapping.columns:
        for name in cm.sources:
            if name not in index:
                key = "column" if cm.reduce is None else "columns"
                raise ConfigError(f"{mapping.path}: key 'columns.{cm.target}.{key}': column {name!r} not in {src}")
    _check_widths(src, table)
    lines = np.array([line for line, _ in table.rows], dtype=np.int64)
    time = _parse_time(src, mapping.time, table, index, lines)
    cols: dict[str, np.ndarray] = {}
    for cm in mapping.columns:
        parts = []
        for name in cm.sources:
            parts.append(_numbers(src, name, [r[index[name]] for _, r in table.rows], lines))
        values = parts[0] if cm.reduce is None else _REDUCERS[cm.reduce](np.vstack(parts), axis=0)
        unit = UNITS[cm.unit]
        values = values * unit.scale + unit.offset
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
    return _assemble(src, time, cols, lines, notes)


# --------------------------------------------------------------------------------------------------
# CAN logs
# --------------------------------------------------------------------------------------------------


def _load_dbc(path: str | os.PathLike[str]) -> Any:
    import cantools

    try:
        return cantools.database.load_file(str(path), strict=True)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such DBC file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    except (cantools.database.UnsupportedDatabaseFormatError, cantools.database.Error) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"{path}: not a valid DBC file: {first}") from exc


def import_can_log(
    path: str | os.PathLike[str],
    dbc_paths: Sequence[str | os.PathLike[str]],
    signal_map: Mapping[str, str] | None = None,
    *,
    dt_s: float = 0.1,
) -> FlightLog:
    """Decode a python-can log (.asc, .blf, .log, .trc) with DBC files into a flight log.

    ``signal_map`` maps output column -> ``"Message.Signal"`` (default :data:`DEFAULT_SIGNAL_MAP`, for
    dbc/engine.dbc). Every mapped signal is sampled and held onto a uniform grid of step ``dt_s``
    (default 0.1 s, the slowest frame rate) from the first instant every mapped signal has been seen
    to the last frame; ``time_s`` counts from that instant. Frames of unknown ids, error and remote
    frames are ignored; frames that fail to decode are skipped and counted in a warning.
    """
    import can
    import cantools

    src = str(path)
    if not dbc_paths:
        raise ConfigError(f"{src}: no DBC file given to decode the CAN log")
    if not (math.isfinite(dt_s) and dt_s > 0.0):
        raise FlightLogError(f"{src}: sample step must be a positive number, got {dt_s!r}")
    dbs = [(str(p), _load_dbc(p)) for p in dbc_paths]
    dbc_names = ", ".join(name for name, _ in dbs)
    smap = dict(DEFAULT_SIGNAL_MAP if signal_map is None else signal_map)
    if not smap:
        raise ConfigError(f"{src}: empty signal map")
    by_id: dict[tuple[int, bool], tuple[Any, list[tuple[str, str]]]] = {}
    for column, ref in smap.items():
        msg_name, _, sig_name = str(ref).partition(".")
        if column == "time_s" or not _IDENTIFIER.match(column):
            raise ConfigError(f"signal map: key '{column}': output name must be an identifier other than time_s")
        message = next((m for _, db in dbs for m in db.messages if m.name == msg_name), None)
        if message is None:
            raise ConfigError(f"signal map: key '{column}': no message '{msg_name}' in {dbc_names}")
        if sig_name not in {s.name for s in message.signals}:
            raise ConfigError(f"signal map: key '{column}': message '{msg_name}' has no signal '{sig_name}'")
        key = (message.frame_id, bool(message.is_extended_frame))
        by_id.setdefault(key, (message, []))[1].append((column, sig_name))

    times: dict[str, list[float]] = {c: [] for c in smap}
    values: dict[str, list[float]] = {c: [] for c in smap}
    frames = bad = skipped = 0
    first_bad = ""
    last_t = -math.inf
    try:
        with can.LogReader(src) as reader:
            for msg in reader:
                frames += 1
                if msg.is_error_frame or msg.is_remote_frame:
                    skipped += 1
                    continue
                entry = by_id.get((msg.arbitration_id, bool(msg.is_extended_id)))
                last_t = max(last_t, msg.timestamp)
                if entry is None:
                    continue
                message, wanted = entry
                try:
                    decoded = message.decode(bytes(msg.data), decode_choices=False)
                except (cantools.database.DecodeError, ValueError, KeyError) as exc:
                    bad += 1
                    first_bad = first_bad or f"{message.name} at t={msg.timestamp:.3f} s: {exc}"
                    continue
                for column, sig in wanted:
                    times[column].append(msg.timestamp)
                    values[column].append(float(decoded[sig]))
    except FileNotFoundError:
        raise FlightLogError(f"{src}: no such file") from None
    except OSError as exc:
        raise FlightLogError(f"{src}: cannot read: {exc.strerror or exc}") from exc
    except (ValueError, can.io.blf.BLFParseError) as exc:
        raise FlightLogError(f"{src}: unreadable CAN log after {frames} frames: {exc}") from exc

    notes: list[str] = []
    if bad:
        _note(notes, src, f"{bad} frame(s) failed to decode and were skipped (first: {first_bad})")
    if skipped:
        _note(notes, src, f"{skipped} error/remote frame(s) ignored")
    for column, ts in times.items():
        if not ts:
            raise FlightLogError(
                f"{src}: signal '{smap[column]}' for column '{column}' never seen ({frames} frames read)"
            )
    arrays: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for column in smap:
        t = np.asarray(times[column], dtype=np.float64)
        v = np.asarray(values[column], dtype=np.float64)
        order = np.argsort(t, kind="stable")
        arrays[column] = (t[order], v[order])
    start = max(t[0] for t, _ in arrays.values())
    n = math.floor((last_t - start) / dt_s + 1e-9) + 1
    offsets = np.round(dt_s * np.arange(n, dtype=np.float64), 9)
    grid = start + offsets
    out: dict[str, np.ndarray] = {"time_s": offsets}
    stale_limit = max(1.0, 10.0 * dt_s)
    for column, (t, v) in arrays.items():
        # a frame stamped within _TIE_S after a grid instant counts as at that instant (timestamp rounding)
        out[column] = v[np.searchsorted(t, grid + _TIE_S, side="right") - 1]
        stale = int(np.count_nonzero(np.diff(t) > stale_limit))
        if stale:
            _note(notes, src, f"'{smap[column]}': {stale} silence(s) longer than {stale_limit:g} s held over")
    return FlightLog(out, src, tuple(notes))


# --------------------------------------------------------------------------------------------------
# Dispatch
# --------------------------------------------------------------------------------------------------


def _load_csv(
    path: Path, mapping: str | os.PathLike[str] | None, dbc_paths: Sequence[Any] | None, signal_map: Any
) -> FlightLog:
    if dbc_paths or signal_map:
        raise FlightLogError(f"{path}: DBC files apply to CAN logs, not to a CSV")
    if mapping is None:
        return read_csv(path)
    return import_mapped_csv(path, resolve_mapping(mapping))


def _load_can(
    path: Path, mapping: str | os.PathLike[str] | None, dbc_paths: Sequence[Any] | None, signal_map: Any
) -> FlightLog:
    if mapping is not None:
        raise FlightLogError(f"{path}: a CSV mapping does not apply to a CAN log (give DBC files)")
    return import_can_log(path, list(dbc_paths) if dbc_paths else [DEFAULT_ENGINE_DBC], signal_map)


_LOADERS: Mapping[str, Callable[[Path, Any, Any, Any], FlightLog]] = MappingProxyType(
    {".csv": _load_csv, **dict.fromkeys(CAN_LOG_SUFFIXES, _load_can)}
)


def load_flight(
    path: str | os.PathLike[str],
    *,
    mapping: str | os.PathLike[str] | None = None,
    dbc_paths: Sequence[str | os.PathLike[str]] | None = None,
    signal_map: Mapping[str, str] | None = None,
) -> FlightLog:
    """Load any supported flight log by suffix.

    ``.csv``: canonical (:func:`read_csv`), or foreign through ``mapping`` (a path or a shipped
    mapping's name, see :func:`resolve_mapping`). ``.asc/.blf/.log/.trc``: :func:`import_can_log` with
    ``dbc_paths`` (default: the repository's dbc/engine.dbc) and ``signal_map`` (default
    :data:`DEFAULT_SIGNAL_MAP`).
    """
    path = Path(path)
    loader = _LOADERS.get(path.suffix.lower())
    if loader is None:
        raise FlightLogError(
            f"{path}: unknown log type {path.suffix or '(no suffix)'!r} (known: {', '.join(_LOADERS)})"
        )
    return loader(path, mapping, dbc_paths, signal_map)
