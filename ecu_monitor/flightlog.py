"""Flight logs: the canonical flight CSV and the import of foreign logs (user guide: docs/flight_logs.md).

Everything the model, the estimators, identification and the gap diagnosis read from a flight goes
through a :class:`FlightLog`: named float64 columns of equal length on a strictly increasing
``time_s``. Two ways in here (CAN logs are read in the bus layer, :mod:`ecu_monitor.bus.canlog`,
whose ``load_flight`` loads any supported log), one way out:

* :func:`read_csv` - a canonical CSV, validated row by row;
* :func:`import_mapped_csv` - a foreign CSV export (e.g. a Garmin G1000 engine-data log) through a
  small YAML mapping of source column -> canonical name + unit;
* :func:`write_csv` - canonical columns first, in contract order, then the rest; every value written
  with the shortest text that reads back to the same float.

:func:`load_csv` dispatches a CSV on its layout. Every problem with
the input raises :class:`~ecu_monitor.errors.FlightLogError` (bad data) or
:class:`~ecu_monitor.errors.ConfigError` (bad mapping) with one line naming the file, the row (1-based
file line, the header of a canonical CSV is row 1) and the column. Problems that can be repaired
without guessing (a repeated timestamp, an isolated blank field, a truncated last row, a time gap)
are repaired, logged with ``logging.warning`` and kept in :attr:`FlightLog.notes`.

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
:data:`ecu_monitor.units.UNITS`; negative
``airspeed_mps`` and ``fuel_flow_lph`` (an air-data system reading -1 kt on the ramp) are clipped to
0 with a note. Unmapped source columns are ignored. Then the canonical rules above apply (blank
runs, repeated or backward time, limits, gaps); an ``optional`` column keeps blank runs longer than
:data:`MAX_BLANK_RUN` as NaN, and a cylinder blank in every row (a dead probe) is dropped with a note.

Engines and cylinders: a file holding several engines (``E1 RPM``, ``E2 RPM``) needs the engine
chosen (``engine=``); ``cht_c`` is made from the cylinders by :func:`choose_cht` (``mean`` by default,
``hottest`` per row, or one cylinder), ``egt_c`` is the mean EGT and ``egt_max_c`` the hottest.
:func:`describe_cht` says which from the data; :func:`cht_peak` and :func:`seconds_above` give the
hottest reading of a flight and the time above a CHT limit.

Layout detection (:func:`detect_layout`): a CSV whose first line names ``time_s`` is canonical;
otherwise the shipped mappings (``g1000``: Garmin G1000 exports of every firmware seen;
``ngafid_processed``: NGAFID processed exports) are tried on its header.
"""

from __future__ import annotations

import contextlib
import csv
import datetime as _dt
import io
import logging
import math
import os
import re
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, NamedTuple

import numpy as np
import yaml

from ecu_monitor.errors import ConfigError, FlightLogError, UserInputError
from ecu_monitor.shipped import resolve_file, shipped_dir
from ecu_monitor.units import QUANTITY_OF_COLUMN, UNITS

__all__ = [
    "CANONICAL_COLUMNS",
    "CHT_CHOICES",
    "CYLINDER_COLUMN",
    "ENGINE_COLUMNS",
    "GAP_WARN_S",
    "MAPPINGS_DIR",
    "MAX_BLANK_RUN",
    "OPTIONAL_COLUMNS",
    "PHYSICAL_LIMITS",
    "ChtPeak",
    "ColumnMap",
    "CsvMapping",
    "CylinderMap",
    "FlightLog",
    "TimeMap",
    "choose_cht",
    "cht_limit_warning",
    "cht_peak",
    "cylinder_columns",
    "describe_cht",
    "detect_layout",
    "import_mapped_csv",
    "load_csv",
    "load_mapping",
    "parse_cht_choice",
    "read_csv",
    "resolve_mapping",
    "seconds_above",
    "write_csv",
]

_log = logging.getLogger(__name__)

#: The canonical columns, in contract order (docs/contracts.md section 1).
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
#: Engine-monitor columns an import may carry (all degC / kPa): mean and hottest EGT, manifold
#: pressure, oil temperature. Per-cylinder ``cht1_c .. chtN_c`` and ``egt1_c .. egtN_c`` sit beside them.
ENGINE_COLUMNS: tuple[str, ...] = ("egt_c", "egt_max_c", "manifold_pressure_kpa", "oil_temp_c")
#: How ``cht_c`` is made from the cylinders: their mean, the hottest per row, or one cylinder (1-based).
CHT_CHOICES: tuple[str, ...] = ("mean", "hottest")
#: A per-cylinder column name: ``cht3_c`` -> ("cht", "3").
CYLINDER_COLUMN = re.compile(r"^(cht|egt)([1-9][0-9]?)_c$")

#: Physically possible range of a column, inclusive; a value outside is an input error.
PHYSICAL_LIMITS: Mapping[str, tuple[float, float]] = MappingProxyType(
    {
        "rpm": (0.0, 30000.0),
        "throttle_pct": (-1.0, 101.0),
        "cht_c": (-60.0, 500.0),
        "cht_true_c": (-60.0, 500.0),
        "cht_max_c": (-60.0, 500.0),
        "oat_c": (-80.0, 70.0),
        "egt_c": (-60.0, 1300.0),
        "egt_max_c": (-60.0, 1300.0),
        "oil_temp_c": (-60.0, 250.0),
        "manifold_pressure_kpa": (0.0, 400.0),
    }
)
#: Longest run of blank fields that is filled by interpolation.
MAX_BLANK_RUN = 5
#: Time gaps longer than this are kept but reported.
GAP_WARN_S = 5.0

#: Shipped mapping files; ``--mapping NAME`` names one when no file NAME exists (:func:`resolve_mapping`).
MAPPINGS_DIR = shipped_dir("mapping")
_REQUIRED_ALWAYS = tuple(c for c in CANONICAL_COLUMNS if c != "throttle_pct")
_STRICT = frozenset(CANONICAL_COLUMNS + OPTIONAL_COLUMNS)


#: Quantity each known column must be given in (other target names accept any unit).
_COLUMN_QUANTITY = {name: q for name, q in QUANTITY_OF_COLUMN.items() if name != "time_s"}
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

_REDUCERS: Mapping[str, Callable[..., Any]] = MappingProxyType({"mean": np.mean, "max": np.max, "min": np.min})
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


# --------------------------------------------------------------------------------------------------
# Validation shared by the canonical and the mapped readers
# --------------------------------------------------------------------------------------------------


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
        if _is_strict(name):
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
    back the same floats; NaN is written as a blank field. The file is written to a temporary name
    and renamed, so an interrupted write never leaves a half file under ``path``.
    """
    path = Path(path)
    order = _column_order(log)
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
# Cylinders
# --------------------------------------------------------------------------------------------------


def cylinder_columns(log: FlightLog, kind: str = "cht") -> list[str]:
    """The per-cylinder columns of ``kind`` (``cht`` or ``egt``) that ``log`` carries, in cylinder order."""
    found = []
    for name in log.names:
        match = CYLINDER_COLUMN.match(name)
        if match is not None and match.group(1) == kind:
            found.append((int(match.group(2)), name))
    return [name for _, name in sorted(found)]


def _cylinder_number(column: str) -> int:
    match = CYLINDER_COLUMN.match(column)
    if match is None:
        raise ValueError(f"not a cylinder column: {column!r}")
    return int(match.group(2))


def _cylinder_list(columns: Sequence[str]) -> str:
    numbers = [_cylinder_number(c) for c in columns]
    if numbers == list(range(numbers[0], numbers[-1] + 1)) and len(numbers) > 2:
        return f"{numbers[0]}-{numbers[-1]}"
    return ", ".join(map(str, numbers))


def parse_cht_choice(text: str | int) -> str | int:
    """``"mean"``, ``"hottest"`` or a 1-based cylinder number (``"2"`` -> 2); anything else is an error."""
    if isinstance(text, int) and not isinstance(text, bool):
        number = text
    else:
        word = str(text).strip().lower()
        if word in CHT_CHOICES:
            return word
        if not word.isdigit():
            raise UserInputError(f"CHT choice {text!r}: expected mean, hottest or a cylinder number (1, 2, ...)")
        number = int(word)
    if number < 1:
        raise UserInputError(f"CHT choice {text!r}: cylinders are numbered from 1")
    return number


def choose_cht(log: FlightLog, choice: str | int) -> FlightLog:
    """``log`` with ``cht_c`` made from its cylinders ``cht1_c ..``: their mean, the hottest per row, or one.

    ``choice`` is ``"mean"``, ``"hottest"`` or a 1-based cylinder number (see :func:`parse_cht_choice`).
    """
    choice = parse_cht_choice(choice)
    columns = cylinder_columns(log, "cht")
    if not columns:
        raise FlightLogError(f"{log.source}: no per-cylinder CHT columns (cht1_c ..) to choose cht_c from")
    if isinstance(choice, int):
        column = f"cht{choice}_c"
        if not log.has(column):
            raise FlightLogError(
                f"{log.source}: cylinder {choice} chosen for cht_c, the log has cylinder(s) {_cylinder_list(columns)}"
            )
        return log.with_columns(cht_c=log[column])
    stack = np.vstack([log[c] for c in columns])
    return log.with_columns(cht_c=stack.mean(axis=0) if choice == "mean" else stack.max(axis=0))


def describe_cht(log: FlightLog) -> str:
    """Which cylinders ``cht_c`` carries, read from the data (e.g. ``"mean of cylinders 1-4"``)."""
    columns = cylinder_columns(log, "cht")
    if not columns or not log.has("cht_c"):
        return "cht_c is the log's own channel (no per-cylinder columns)"
    cht = log["cht_c"]
    if len(columns) == 1:
        candidates = [(f"cylinder {_cylinder_number(columns[0])} (the only one)", log[columns[0]])]
    else:
        stack = np.vstack([log[c] for c in columns])
        every = _cylinder_list(columns)
        candidates = [
            (f"mean of cylinders {every}", stack.mean(axis=0)),
            (f"hottest of cylinders {every} (per row)", stack.max(axis=0)),
            *((f"cylinder {_cylinder_number(c)} of {every}", log[c]) for c in columns),
        ]
    for text, values in candidates:
        if np.allclose(cht, values, rtol=0.0, atol=1e-9, equal_nan=True):
            return text
    return "cht_c is the log's own channel (not made from cht1_c ..)"


@dataclass(frozen=True)
class ChtPeak:
    """The highest CHT of a log: ``value_c`` (degC) in ``column`` (``cht3_c``, or ``cht_c`` when the log
    has no per-cylinder columns), ``cylinder`` (1-based, None for ``cht_c``) at ``time_s`` (s)."""

    value_c: float
    column: str
    cylinder: int | None
    time_s: float


def _cht_channels(log: FlightLog) -> list[str]:
    return cylinder_columns(log, "cht") or ["cht_c"]


def cht_peak(log: FlightLog) -> ChtPeak:
    """The hottest reading of any cylinder (of ``cht_c`` if the log has no per-cylinder columns)."""
    best: ChtPeak | None = None
    for column in _cht_channels(log):
        values = log[column]
        if np.all(np.isnan(values)):
            continue
        k = int(np.nanargmax(values))
        if best is None or values[k] > best.value_c:
            cylinder = _cylinder_number(column) if column != "cht_c" else None
            best = ChtPeak(float(values[k]), column, cylinder, float(log.time_s[k]))
    if best is None:
        raise FlightLogError(f"{log.source}: no CHT value to take a peak of")
    return best


def seconds_above(log: FlightLog, limit_c: float) -> float:
    """Time during which the hottest cylinder (``cht_c`` without per-cylinder columns) reads above
    ``limit_c``, s: the sum of the sample intervals that start above it."""
    stack = np.vstack([log[c] for c in _cht_channels(log)])
    hottest = np.max(np.where(np.isnan(stack), -np.inf, stack), axis=0)
    steps = np.diff(log.time_s, append=log.time_s[-1])
    return float(np.sum(steps[hottest > limit_c]))


def cht_limit_warning(log: FlightLog, limit_c: float) -> str | None:
    """One line saying how far ``log`` exceeds the engine's CHT limit ``limit_c`` (degC), or None.

    For identification and the service's configuration: a model whose limit sits below what the
    engine routinely reads would report no headroom for most of a normal flight.
    """
    if not math.isfinite(limit_c):
        raise FlightLogError(f"{log.source}: CHT limit must be a finite number of degC, got {limit_c!r}")
    peak = cht_peak(log)
    if peak.value_c <= limit_c:
        return None
    above = seconds_above(log, limit_c)
    where = "cht_c" if peak.cylinder is None else f"cylinder {peak.cylinder}"
    share = 100.0 * above / log.duration_s if log.duration_s > 0 else 100.0
    return (
        f"{log.source}: CHT reaches {peak.value_c:.1f} degC ({where} at {peak.time_s:.0f} s), above the limit"
        f" {limit_c:g} degC for {above:.0f} s ({share:.0f} % of the flight)"
    )


# --------------------------------------------------------------------------------------------------
# Mapped foreign CSV
# --------------------------------------------------------------------------------------------------

#: Placeholders in a mapping's source column names: the engine number and the cylinder number.
ENGINE_PLACEHOLDER = "{engine}"
CYLINDER_PLACEHOLDER = "{n}"
_EPOCH = _dt.datetime(1970, 1, 1)
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
    unit: str
    reduce: str | None = None
    optional: bool = False


@dataclass(frozen=True)
class CylinderMap:
    """Per-cylinder columns: ``kind`` (``cht``/``egt``) from ``pattern`` with ``{n}`` = 1, 2, ... in ``unit``."""

    kind: str
    pattern: str
    unit: str


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


def _check_unit(keys: _Keys, target: str | None) -> str:
    unit = keys.get("unit", str)
    if unit not in UNITS:
        raise keys.fail("unit", f"unknown unit {unit!r} (known: {', '.join(UNITS)})")
    wanted = _COLUMN_QUANTITY.get(target or "")
    if target is None:
        wanted = "time"
    elif CYLINDER_COLUMN.match(target):
        wanted = "temperature"
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
        f" ({'; '.join(problems)}); give a mapping file (--mapping FILE)"
    )


def _spread_repeats(src: str, stamps: np.ndarray, lines: np.ndarray, notes: list[str]) -> np.ndarray:
    """Whole-second stamps: the k rows sharing one second are spread evenly over it (s, s + 1/k, ...)."""
    if stamps.size < 2 or not np.all(stamps == np.round(stamps)):
        return stamps
    new_group = np.concatenate(([True], np.diff(stamps) != 0.0))
    if np.all(new_group):
        return stamps
    group = np.cumsum(new_group) - 1
    starts = np.flatnonzero(new_group)
    sizes = np.diff(np.append(starts, stamps.size))
    position = np.arange(stamps.size) - starts[group]
    shared = int(stamps.size - starts.size)
    _note(
        notes,
        src,
        f"{shared} row(s) share a whole-second stamp with the row before: spread evenly over that second"
        f" (first at row {lines[int(np.argmin(new_group))]})",
    )
    return stamps + position / sizes[group]


def _parse_time(
    src: str, spec: TimeMap, table: _Table, index: Mapping[str, int], lines: np.ndarray, notes: list[str]
) -> np.ndarray:
    if spec.kind == "seconds":
        if spec.columns[0] not in index:  # only reached with row_step_s (checked by the caller)
            step = float(spec.row_step_s or 1.0)
            _note(notes, src, f"no column {spec.columns[0]!r}: row k is at k * {step:g} s")
            return step * np.arange(len(table.rows), dtype=np.float64)
        col = index[spec.columns[0]]
        values = _numbers(src, spec.columns[0], [r[col] for _, r in table.rows], lines)
        if np.any(np.isnan(values)):
            k = int(np.argmax(np.isnan(values)))
            raise FlightLogError(f"{src}: row {lines[k]}, column '{spec.columns[0]}': blank time")
        return _spread_repeats(src, (values - values[0]) * UNITS[spec.unit].scale, lines, notes)
    date_col, time_col = (index[c] for c in spec.columns)
    formats = [f"{d} {t}" for d in spec.date_formats for t in spec.time_formats]
    whole_seconds = spec.time_formats[0] == "%H:%M:%S"  # the fast path for H:MM:SS; other forms by strptime
    stamps = np.empty(len(table.rows), dtype=np.float64)
    midnights: dict[str, float] = {}
    for k, (line, row) in enumerate(table.rows):
        date, clock = row[date_col].strip(), row[time_col].strip()
        value = _stamp(date, clock, spec.date_formats, formats, midnights if whole_seconds else None)
        if value is None:
            raise FlightLogError(
                f"{src}: row {line}, columns '{spec.columns[0]}', '{spec.columns[1]}': {date + ' ' + clock!r}"
                f" matches none of the formats {', '.join(repr(f) for f in formats)}"
            )
        stamps[k] = value
    if spec.utc_offset_column is not None and spec.utc_offset_column in index:
        stamps = stamps - _utc_offsets(src, spec.utc_offset_column, table, index, lines, notes)
    return _spread_repeats(src, stamps - stamps[0], lines, notes)


_OFFSET = re.compile(r"^([+-])([0-9]{1,2}):?([0-9]{2})$")


def _utc_offsets(
    src: str, column: str, table: _Table, index: Mapping[str, int], lines: np.ndarray, notes: list[str]
) -> np.ndarray:
    """Local-minus-UTC offset of every row, s, from a ``+08:00`` column; a blank takes the row before's
    (leading blanks the first known)."""
    col = index[column]
    offsets = np.full(len(table.rows), math.nan)
    cache: dict[str, float] = {}
    for k, (line, row) in enumerate(table.rows):
        text = row[col].strip() if col < len(row) else ""
        if not text:
            continue
        value = cache.get(text)
        if value is None:
            match = _OFFSET.match(text)
            if match is None:
                raise FlightLogError(f"{src}: row {line}, column '{column}': {text!r} is not a UTC offset like +08:00")
            sign = -1.0 if match.group(1) == "-" else 1.0
            value = cache[text] = sign * (3600.0 * int(match.group(2)) + 60.0 * int(match.group(3)))
        offsets[k] = value
    known = ~np.isnan(offsets)
    if not np.any(known):
        _note(notes, src, f"column '{column}' is blank in every row: local time used")
        return np.zeros(len(table.rows))
    offsets = _fill_forward(offsets)
    changes = np.flatnonzero(np.diff(offsets) != 0.0)
    if changes.size:
        k = int(changes[0]) + 1
        _note(
            notes,
            src,
            f"column '{column}': the UTC offset changes {changes.size} time(s) (first at row {lines[k]},"
            f" {offsets[k - 1] / 3600.0:+g} h -> {offsets[k] / 3600.0:+g} h): time built in UTC",
        )
    return offsets


_HMS = re.compile(r"^([01]?[0-9]|2[0-3]):([0-5][0-9]):([0-5][0-9])$")


def _stamp(
    date: str,
    clock: str,
    date_formats: Sequence[str],
    formats: Sequence[str],
    midnights: dict[str, float] | None,
) -> float | None:
    """Seconds since 1970 of a local date and time (no time zone), or None if no format matches.

    With ``midnights`` (time format ``%H:%M:%S``) each date is parsed once and the clock is added to
    its midnight, so a long log costs one ``strptime`` per day rather than per row.
    """
    hms = _HMS.match(clock) if midnights is not None else None
    if hms is not None and midnights is not None:
        midnight = midnights.get(date)
        if midnight is None:
            for fmt in date_formats:
                try:
                    midnight = (_dt.datetime.strptime(date, fmt) - _EPOCH).total_seconds()
                except ValueError:
                    continue
                midnights[date] = midnight
                break
        if midnight is not None:
            h, m, sec = (int(g) for g in hms.groups())
            return midnight + 3600.0 * h + 60.0 * m + sec
    for fmt in formats:
        try:
            return (_dt.datetime.strptime(f"{date} {clock}", fmt) - _EPOCH).total_seconds()
        except ValueError:
            continue
    return None


#: Standard atmosphere: pressure altitude h_p = h + (1 - (QNH / p0) ** _BARO_EXP) * _BARO_SCALE_M.
_P0_KPA = 101.325
_BARO_EXP = 0.190263
_BARO_SCALE_M = 44307.694
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
    return altitude_m + (1.0 - (_fill_forward(qnh_kpa) / _P0_KPA) ** _BARO_EXP) * _BARO_SCALE_M


def _fill_forward(values: np.ndarray) -> np.ndarray:
    """NaN take the value of the row before (leading NaN the first value); at least one must be known."""
    known = ~np.isnan(values)
    if np.all(known):
        return values
    filled_from = np.maximum.accumulate(np.where(known, np.arange(values.size), 0))
    filled_from[: int(np.argmax(known))] = int(np.argmax(known))
    return values[filled_from]


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
    src: str, target: str, name: str, unit: str, units: tuple[int, list[str]] | None, index: Mapping[str, int]
) -> tuple[str, str | None]:
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
    if UNITS[known].quantity != UNITS[unit].quantity:
        raise FlightLogError(
            f"{src}: row {line}, column '{name}': unit {text!r} is a {UNITS[known].quantity} unit,"
            f" '{target}' needs {UNITS[unit].quantity}"
        )
    return known, f"column '{name}': the file's units row says {text!r}: read as {known}, not the mapping's {unit}"


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
        found = []
        for n in range(1, _MAX_CYLINDERS + 1):
            name = _fill(cyl.pattern, chosen, n)
            if name not in index:
                break
            found.append((n, name))
        if not found and cyl.kind == "cht":
            raise ConfigError(
                f"{mapping.path}: key 'cylinders.cht.column': column {_fill(cyl.pattern, chosen, 1)!r} not in {src}"
            )
        cylinder_reads.append((cyl, found))
    units = _file_units(mapping, table)
    if not table.rows:
        raise FlightLogError(f"{src}: only a units row after the header, no data rows")
    _drop_repeated_headers(src, table, notes)
    _check_widths(src, table)
    _drop_duplicate_rows(src, table, notes)
    lines = np.array([line for line, _ in table.rows], dtype=np.int64)
    time = _parse_time(src, mapping.time, table, index, lines, notes)

    def read(target: str, name: str, unit: str) -> np.ndarray:
        unit, note = _source_unit(src, target, name, unit, units, index)
        if note:
            _note(notes, src, note)
        col = index[name]
        values = _numbers(src, name, [r[col] for _, r in table.rows], lines)
        u = UNITS[unit]
        return values * u.scale + u.offset

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


# --------------------------------------------------------------------------------------------------
# Dispatch
# --------------------------------------------------------------------------------------------------


def load_csv(
    path: str | os.PathLike[str],
    mapping: str | os.PathLike[str] | None = None,
    *,
    engine: int | None = None,
    cht: str | int | None = None,
) -> FlightLog:
    """Load a flight CSV: canonical (:func:`read_csv`), or foreign through ``mapping`` (a path or a
    shipped mapping's name, see :func:`resolve_mapping`; None or ``"auto"`` detects the layout with
    :func:`detect_layout`). ``engine`` picks the engine of a multi-engine CSV; ``cht`` makes ``cht_c``
    from the cylinders (``mean``, ``hottest`` or a cylinder number; foreign CSVs default to ``mean``).
    For any suffix, CAN logs included, use :func:`ecu_monitor.bus.canlog.load_flight`."""
    path = Path(path)
    if mapping is None or str(mapping) == "auto":
        layout = detect_layout(path)
        if layout is None:
            if engine not in (None, 1):
                raise FlightLogError(f"{path}: a canonical flight CSV holds one engine, engine {engine} asked for")
            log = read_csv(path)
            return log if cht is None else choose_cht(log, cht)
        return import_mapped_csv(path, layout, engine=engine, cht=cht)
    return import_mapped_csv(path, resolve_mapping(mapping), engine=engine, cht=cht)
