"""Flight logs: the canonical flight CSV and the import of foreign logs (user guide: docs/flight_logs.md).

Everything the model, the estimators, identification and the gap diagnosis read from a flight goes
through a :class:`FlightLog`: named float64 columns of equal length on a strictly increasing
``time_s``. Two ways in here (CAN logs are read in the bus layer, :mod:`ecu_monitor.bus.canlog`,
whose ``load_flight`` loads any supported log), one way out:

* :func:`read_csv` - a canonical CSV, validated row by row (rules: :mod:`.canonical`);
* :func:`import_mapped_csv` - a foreign CSV export (e.g. a Garmin G1000 engine-data log) through a
  small YAML mapping of source column -> canonical name + unit (format: :mod:`.mapping`);
* :func:`write_csv` - canonical columns first, in contract order, then the rest; every value written
  with the shortest text that reads back to the same float.

:func:`load_csv` dispatches a CSV on its layout. Every problem with
the input raises :class:`~ecu_monitor.errors.FlightLogError` (bad data) or
:class:`~ecu_monitor.errors.ConfigError` (bad mapping) with one line naming the file, the row (1-based
file line, the header of a canonical CSV is row 1) and the column. Problems that can be repaired
without guessing (a repeated timestamp, an isolated blank field, a truncated last row, a time gap)
are repaired, logged with ``logging.warning`` and kept in :attr:`FlightLog.notes`.

Where each part lives (every name below is importable from ``ecu_monitor.flightlog``):

=================  =================================================================================
``log``            :class:`FlightLog` and the column vocabulary (canonical, optional, engine,
                   per-cylinder columns, physical limits, blank-run and gap thresholds)
``canonical``      :func:`read_csv`, :func:`write_csv`: the canonical CSV and its rules
``mapping``        :func:`load_mapping`, :func:`resolve_mapping`: the YAML mapping format
``foreign``        :func:`import_mapped_csv`: a foreign export through a mapping (units, baro altitude)
``layout``         :func:`detect_layout` (G1000, NGAFID processed, ...) and the engine of a multi-engine file
``timestamps``     the time axis of a foreign export (date/clock formats, UTC offsets, repeated seconds)
``cylinders``      per-cylinder columns and the choice of ``cht_c`` (:func:`choose_cht`, :func:`describe_cht`)
``cht_limit``      :func:`cht_peak`, :func:`seconds_above`, :func:`cht_limit_warning`
``table``          reading a delimited text file into header and rows, with one-line errors
``rules``          the canonical rules both readers apply (limits, time order, blanks, gaps)
``load``           :func:`load_csv`: one entry for any flight CSV
``identity``       :func:`log_airframe`: the airframe (G1000 system_id) or engine serial a log names
=================  =================================================================================
"""

from ecu_monitor.flightlog.canonical import read_csv, write_csv
from ecu_monitor.flightlog.cht_limit import ChtPeak, cht_limit_warning, cht_peak, seconds_above
from ecu_monitor.flightlog.cylinders import choose_cht, cylinder_columns, describe_cht, parse_cht_choice
from ecu_monitor.flightlog.foreign import import_mapped_csv
from ecu_monitor.flightlog.identity import log_airframe
from ecu_monitor.flightlog.layout import detect_layout
from ecu_monitor.flightlog.load import load_csv, require_distinct
from ecu_monitor.flightlog.log import (
    CANONICAL_COLUMNS,
    CHT_CHOICES,
    CYLINDER_COLUMN,
    ENGINE_COLUMNS,
    GAP_WARN_S,
    MAX_BLANK_RUN,
    OPTIONAL_COLUMNS,
    PHYSICAL_LIMITS,
    FlightLog,
)
from ecu_monitor.flightlog.mapping import (
    MAPPINGS_DIR,
    ColumnMap,
    CsvMapping,
    CylinderMap,
    TimeMap,
    load_mapping,
    resolve_mapping,
)

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
    "log_airframe",
    "parse_cht_choice",
    "read_csv",
    "require_distinct",
    "resolve_mapping",
    "seconds_above",
    "write_csv",
]
