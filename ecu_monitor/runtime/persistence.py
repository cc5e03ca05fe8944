"""Flight history of each engine in an embedded SQLite database (``<state_dir>/ecu-monitor.sqlite3``).

What is kept, per engine (its serial from the config) and per flight: start and end (UTC), duration
(hours), maximum CHT, time above the CHT limit, the trend values (the output table's ``history`` rows,
pipeline/output_table.py: gamma_Q, gamma_D; start, end, mean, maximum and their slope within the flight
per hour, one column each: :func:`trend_columns`), the worst detector state and the time spent
SUSPECT/DEGRADED, and the thermal cycles of the CHT history counted by rainflow (ASTM E1049, the
``rainflow`` package) as a histogram of cycle ranges. An engine monitored per cylinder also keeps, in
the same row (``cylinders_json``, written in the same transactions), each cylinder's maximum CHT, gamma
statistics, worst state and time SUSPECT/DEGRADED, the largest CHT spread, the time with the spread
alarm and how long each cylinder was the hottest. Across flights (schema 3): each flight's wear index (how much
hotter than the nominal model the head ran, with its spread within the flight and the samples it rests on;
:mod:`ecu_monitor.estimation.wear`) and its time at high power; the ``maintenance_alerts`` table keeps each
alert the across-flight detector raised (engine, flight, when, the index, the CUSUM and its threshold, the
reference) until maintenance clears it. Engine events (schema 4): each flight's count of the engine events
that started in it (pipeline/events.py), by kind and cylinder (``events_json``); each engine's hours since
overhaul and time between overhauls as the config last gave them (``engine.overhaul_hours``,
``engine.tbo_hours``), with the engine's running hours when the overhaul hours were given
(:class:`EngineHours`). An older database gains the new columns and table when opened for writing; nothing
in it is lost.

Flights are found from the engine speed: a flight starts when rpm reaches ``FlightRules.running_rpm``
and ends when it has stayed below (or been stale) for ``end_after_s``; a run shorter than
``min_flight_s`` (a ground run, a blip) is not kept.

Durability (the database must survive ``kill -9`` and a power cut at any moment):

* WAL journal with ``synchronous=FULL``: a committed transaction is on disk before ``commit`` returns,
  a torn write is rolled back by SQLite at the next open;
* a finished flight is written in ONE transaction (status ``finished`` with every aggregate), so it is
  either entirely there or not at all;
* a running flight is checkpointed every ``checkpoint_every_s`` (its aggregates and the CHT reversal
  points needed for rainflow, status ``running``); at the next start a row left ``running`` by a crash
  is closed as ``recovered`` at its last checkpoint, cycles counted from the stored reversals. If the
  engine is still running when the restarted service sees it (its first running sample within
  ``checkpoint_every_s + end_after_s`` of that checkpoint), the recovered flight is resumed, not split:
  one engine run stays one flight. The outage itself adds to the duration, not to the time above the
  limit or the cycles (no samples), and the gamma statistics weigh the part before the restart as if
  sampled at the rate seen after it.

The CHT history is not stored sample by sample: an online hysteresis filter keeps only its turning
points (reversals) of at least ``cycle_hysteresis_c`` (5 degC by default: the sensor is quantised to
1 degC and noisy, so smaller wiggles are noise, not thermal cycles). Rainflow over these points counts
the cycles larger than the hysteresis as over the full history (tested against rainflow on the clean
signal), in bounded memory for a 16-hour flight.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import sqlite3
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from ecu_monitor.errors import ConfigError, EcuMonitorError, StorageError
from ecu_monitor.pipeline.output_table import HEALTH_VALUES
from ecu_monitor.runtime.thermal_cycles import (
    CYCLE_BIN_EDGES_C,
    ReversalFilter,
    count_cycles,
    unpack_reversals,
)

__all__ = [
    "CYCLE_BIN_EDGES_C",
    "DATABASE_NAME",
    "TREND_STATS",
    "EngineHours",
    "FlightRecord",
    "FlightRules",
    "FlightSample",
    "MaintenanceAlert",
    "ReversalFilter",
    "StateStore",
    "count_cycles",
    "iter_trend",
    "trend_columns",
    "trend_values",
]

_log = logging.getLogger(__name__)

#: File name of the database inside the state directory.
DATABASE_NAME = "ecu-monitor.sqlite3"
#: 2: flights.cylinders_json (engines monitored per cylinder); 3: the wear index, time at high power and the
#: maintenance_alerts table; 4: flights.events_json, the engines' overhaul hours. An older file gains what it
#: lacks (:data:`_ADDED_COLUMNS`, :data:`_ADDED_ENGINE_COLUMNS`).
_SCHEMA_VERSION = 4


@dataclass(frozen=True)
class FlightRules:
    """How flights are found in the sample stream and how often a running one is checkpointed."""

    running_rpm: float = 1000.0  # rev/min: the engine is running at or above this speed
    min_flight_s: float = 60.0  # s: shorter runs are not flights
    end_after_s: float = 10.0  # s: engine stopped (or rpm stale) this long ends the flight
    checkpoint_every_s: float = 30.0  # s of flight time between checkpoints of a running flight
    cycle_hysteresis_c: float = 5.0  # degC: smallest CHT reversal kept for rainflow

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            if not isinstance(value, int | float) or isinstance(value, bool) or not math.isfinite(value) or value < 0:
                raise ConfigError(f"persistence.{item.name}: expected a finite number >= 0, got {value!r}")
        if self.checkpoint_every_s <= 0:
            raise ConfigError(f"persistence.checkpoint_every_s: expected > 0, got {self.checkpoint_every_s!r}")


@dataclass(frozen=True)
class FlightSample:
    """One health period of the live service, as the recorder needs it.

    ``time_s`` is the service's monotonic time (s), ``wall_time_s`` the matching UTC unix time (s);
    ``rpm`` is None when the engine speed is stale; ``trends``: the value of each trend kept per flight
    (:func:`trend_values`: gamma_q, gamma_d, ...) by name; NaN values mean "not available". ``model_c`` is the
    pipeline's open-loop reference CHT (the nominal model), ``oat_c`` the outside air, ``airspeed_mps`` the
    airspeed, ``power`` the power fraction (estimation/regions.py) held at that instant and ``deviation`` the
    row's model-deviation symptom: the wear index, the flight phases (regions) and the time at high power. An
    engine monitored per cylinder adds ``cylinders``: (CHT degC, its trends, state) per cylinder in cylinder
    order, its ``cht_spread_c``, ``hottest_cylinder`` (0: none) and ``spread_alarm``.
    """

    time_s: float
    wall_time_s: float
    rpm: float | None
    cht_c: float
    trends: Mapping[str, float]
    state: str
    cylinders: tuple[tuple[float, Mapping[str, float], str], ...] = ()
    cht_spread_c: float = math.nan
    hottest_cylinder: int = 0
    spread_alarm: bool = False
    model_c: float = math.nan
    oat_c: float = math.nan
    airspeed_mps: float = math.nan
    power: float = math.nan
    deviation: float = math.nan


@dataclass(frozen=True)
class FlightRecord:
    """One flight row of the database (``status``: running, finished or recovered)."""

    id: int
    engine_serial: str
    status: str
    end_reason: str | None
    start_utc: float
    end_utc: float
    duration_s: float
    max_cht_c: float | None
    cht_limit_c: float
    time_above_limit_s: float
    worst_state: str
    time_degraded_s: float
    cycles_total: float
    #: the flight's wear index (estimation/wear.py; None: too few samples), the spread of its samples within
    #: the flight, how many samples; the time at high power (region ``high power``), s (None: power unknown)
    wear_index: float | None
    wear_spread: float | None
    wear_samples: int
    high_power_s: float | None
    cycles_histogram: dict[str, float]
    #: per flight phase (the regions of estimation/regions.py, by name): ``seconds``, ``wear_index``,
    #: ``deviation_mean`` (the model-deviation symptom, degC/s), ``gamma_q_mean``, ``gamma_d_mean`` (None: none)
    phases: dict[str, Any] = field(default_factory=dict)
    #: engines monitored per cylinder (else empty): ``spread_max_c``, ``spread_alarm_s`` (time with the
    #: spread alarm), ``hottest_s`` (seconds each cylinder was the hottest, by number) and ``per_cylinder``
    #: (one mapping each: ``number``, ``max_cht_c``, the trend columns, ``worst_state``, ``time_degraded_s``)
    cylinders: dict[str, Any] = field(default_factory=dict)
    #: each trend column (:func:`trend_columns`: ``gamma_q_start``, ``gamma_q_mean``, ...) by name (None:
    #: no value), also read as an attribute: ``record.gamma_q_mean``
    trends: dict[str, float | None] = field(default_factory=dict)
    #: the engine events that started in the flight: kind -> cylinder number (as text; "0": the engine) -> count
    events: dict[str, dict[str, int]] = field(default_factory=dict)

    def __getattr__(self, name: str) -> float | None:
        trends = self.__dict__.get("trends", {})
        if name in trends:
            return trends[name]
        raise AttributeError(f"FlightRecord has no field {name!r}")

    @property
    def hours(self) -> float:
        """Flight duration in hours."""
        return self.duration_s / 3600.0


#: The statistics the flight history keeps of each trend value over a flight.
TREND_STATS = ("start", "end", "mean", "max", "slope_per_h")


def trend_values() -> tuple[str, ...]:
    """The values whose trend each flight keeps: the output table's ``history`` rows."""
    return tuple(v.name for v in HEALTH_VALUES if v.history)


def trend_columns() -> tuple[str, ...]:
    """The flights table's trend columns: ``<value>_<stat>`` for each of :func:`trend_values` and TREND_STATS."""
    return tuple(f"{name}_{stat}" for name in trend_values() for stat in TREND_STATS)


_FIXED_COLUMNS = (
    "id, engine_serial, status, end_reason, start_utc, end_utc, duration_s, max_cht_c, cht_limit_c, "
    "time_above_limit_s, worst_state, time_degraded_s, cycles_total, wear_index, wear_spread, wear_samples, "
    "high_power_s, cycles_json, cylinders_json, phases_json, events_json"
)
_FLIGHT_COLUMNS = ", ".join((_FIXED_COLUMNS, *trend_columns()))

#: Columns added to ``flights`` after version 1, with their SQL types: an older database gains them.
_ADDED_COLUMNS = (
    ("cylinders_json", "TEXT"),
    ("wear_index", "REAL"),
    ("wear_spread", "REAL"),
    ("wear_samples", "INTEGER NOT NULL DEFAULT 0"),
    ("high_power_s", "REAL"),
    ("phases_json", "TEXT"),
    ("events_json", "TEXT"),
)
#: Columns added to ``engines`` (schema 4): the overhaul hours as last given, the engine's running seconds
#: then, the time between overhauls.
_ADDED_ENGINE_COLUMNS = (("overhaul_hours", "REAL"), ("overhaul_running_s", "REAL"), ("tbo_hours", "REAL"))


@dataclass(frozen=True)
class EngineHours:
    """An engine's hours: ``running_h`` its running hours in the history (the flights' durations: rpm at
    or above ``running_rpm``; a ground run shorter than a flight is not counted), ``since_overhaul_h`` its
    time since overhaul (the ``engine.overhaul_hours`` last given, plus the running hours since; None:
    never given), ``tbo_h`` its time between overhauls (None: not given)."""

    running_h: float
    since_overhaul_h: float | None
    tbo_h: float | None

    @property
    def due(self) -> bool:
        """The overhaul is due: the time since overhaul has reached the TBO."""
        return self.since_overhaul_h is not None and self.tbo_h is not None and self.since_overhaul_h >= self.tbo_h

    def text(self) -> str:
        """The maintainer's line: running hours, time since overhaul, what is left to the TBO."""
        line = f"{self.running_h:.1f} h running recorded"
        if self.since_overhaul_h is not None:
            line += f", {self.since_overhaul_h:.1f} h since overhaul"
        if self.tbo_h is not None:
            line += f", TBO {self.tbo_h:g} h"
            if self.since_overhaul_h is not None:
                left = self.tbo_h - self.since_overhaul_h
                line += ": OVERHAUL DUE" if self.due else f" ({left:.1f} h left)"
        return line


@dataclass(frozen=True)
class MaintenanceAlert:
    """An alert of the across-flight detector (estimation/wear.py), kept until maintenance clears it.

    ``flight_id`` the flight after which it was raised, ``raised_utc`` when (unix s), ``wear_index`` that
    flight's index, ``statistic`` the CUSUM then and ``threshold`` its h, the reference (mean, sd, flights;
    ``reference_learned``: from the engine's own first flights), ``cleared_utc`` None while open.
    """

    id: int
    engine_serial: str
    flight_id: int
    raised_utc: float
    wear_index: float
    statistic: float
    threshold: float
    reference_mean: float
    reference_sd: float
    reference_flights: int
    reference_learned: bool
    cleared_utc: float | None

    @property
    def text(self) -> str:
        """One line for the pilot and the maintainer (the history's ALERT line, the publishers' text)."""
        return (
            f"MAINTENANCE {self.engine_serial}: head {100.0 * self.wear_index:+.1f}% hotter than nominal"
            f" (ref {100.0 * self.reference_mean:+.1f}%) after flight {self.flight_id}"
        )


_ALERT_COLUMNS = (
    "id, engine_serial, flight_id, raised_utc, wear_index, statistic, threshold, reference_mean, reference_sd, "
    "reference_flights, reference_learned, cleared_utc"
)

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS engines (serial TEXT PRIMARY KEY, first_seen_utc REAL NOT NULL);
CREATE TABLE IF NOT EXISTS flights (
    id INTEGER PRIMARY KEY,
    engine_serial TEXT NOT NULL REFERENCES engines(serial),
    status TEXT NOT NULL CHECK (status IN ('running', 'finished', 'recovered')),
    end_reason TEXT,
    start_utc REAL NOT NULL,
    end_utc REAL NOT NULL,
    duration_s REAL NOT NULL CHECK (duration_s >= 0),
    max_cht_c REAL,
    cht_limit_c REAL NOT NULL,
    time_above_limit_s REAL NOT NULL,
    @@TRENDS@@
    worst_state TEXT NOT NULL,
    time_degraded_s REAL NOT NULL,
    cycles_total REAL NOT NULL,
    cycles_json TEXT NOT NULL,
    cylinders_json TEXT,
    wear_index REAL,
    wear_spread REAL,
    wear_samples INTEGER NOT NULL DEFAULT 0,
    high_power_s REAL,
    phases_json TEXT,
    events_json TEXT,
    reversals BLOB,
    updated_utc REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS flights_by_engine ON flights (engine_serial, start_utc);
CREATE TABLE IF NOT EXISTS maintenance_alerts (
    id INTEGER PRIMARY KEY,
    engine_serial TEXT NOT NULL REFERENCES engines(serial),
    flight_id INTEGER NOT NULL,
    raised_utc REAL NOT NULL,
    wear_index REAL NOT NULL,
    statistic REAL NOT NULL,
    threshold REAL NOT NULL,
    reference_mean REAL NOT NULL,
    reference_sd REAL NOT NULL,
    reference_flights INTEGER NOT NULL,
    reference_learned INTEGER NOT NULL,
    cleared_utc REAL
);
""".replace("@@TRENDS@@", "".join(f"{name} REAL, " for name in trend_columns()))


class StateStore:
    """The SQLite database of flights in ``state_dir`` (created if missing). Context manager; ``close()``.

    One connection, used from one thread at a time (the daemon's supervisor thread). A state directory
    that cannot be created is a ConfigError (user input); a database that cannot be opened for writing
    or written (read-only, disk full) a :class:`~ecu_monitor.errors.StorageError`, the transaction rolled
    back; ``readonly=True`` (``history``) opens it with ``mode=ro``.
    """

    def __init__(self, state_dir: str | Path, *, readonly: bool = False) -> None:
        self.state_dir = Path(state_dir)
        self.path = self.state_dir / DATABASE_NAME
        try:
            if readonly:
                if not self.path.exists():
                    raise ConfigError(f"{self.path}: no flight database here")
                uri = f"file:{self.path}?mode=ro"
                self._conn = sqlite3.connect(uri, uri=True, timeout=10.0, isolation_level=None)
                self._conn.execute("SELECT count(*) FROM sqlite_master")  # a file that is no database: here
            else:
                self.state_dir.mkdir(parents=True, exist_ok=True)
                self._conn = sqlite3.connect(str(self.path), timeout=10.0, isolation_level=None)
                self._closed = False
                try:
                    self._conn.execute("PRAGMA journal_mode=WAL")
                    self._conn.execute("PRAGMA synchronous=FULL")
                    self._conn.execute("PRAGMA foreign_keys=ON")
                    with self._transaction():
                        self._create_schema()
                except (sqlite3.Error, StorageError):
                    self.close()
                    raise
        except OSError as exc:
            raise ConfigError(f"{self.state_dir}: state_dir: cannot use it ({exc.strerror})") from None
        except sqlite3.Error as exc:
            if readonly:
                raise ConfigError(f"{self.path}: cannot open the flight database ({exc})") from None
            raise self._storage_error(exc) from None
        self._closed = False

    def _storage_error(self, exc: sqlite3.Error) -> StorageError:
        """The one-line error of a database the service cannot write (read-only, disk full, ...)."""
        return StorageError(f"{self.path}: cannot write the flight history ({exc})")

    def _create_schema(self) -> None:
        for statement in _SCHEMA.split(";"):
            if statement.strip():
                self._conn.execute(statement)
        columns = {row[1] for row in self._conn.execute("PRAGMA table_info(flights)")}
        for name, sql_type in _ADDED_COLUMNS:  # an older database: flights gain what they lack
            if name not in columns:
                self._conn.execute(f"ALTER TABLE flights ADD COLUMN {name} {sql_type}")
        for name in trend_columns():  # a database older than a trend value: its columns, empty
            if name not in columns:
                self._conn.execute(f"ALTER TABLE flights ADD COLUMN {name} REAL")
        engine_columns = {row[1] for row in self._conn.execute("PRAGMA table_info(engines)")}
        for name, sql_type in _ADDED_ENGINE_COLUMNS:
            if name not in engine_columns:
                self._conn.execute(f"ALTER TABLE engines ADD COLUMN {name} {sql_type}")
        self._conn.execute(
            "INSERT OR REPLACE INTO meta (key, value) VALUES ('schema_version', ?)", (str(_SCHEMA_VERSION),)
        )

    class _Txn:
        """One write transaction; a failure of SQLite (read-only, disk full) rolls back and raises
        StorageError."""

        def __init__(self, store: StateStore) -> None:
            self.store = store
            self.conn = store._conn

        def __enter__(self) -> sqlite3.Connection:
            try:
                self.conn.execute("BEGIN IMMEDIATE")
            except sqlite3.Error as exc:
                raise self.store._storage_error(exc) from None
            return self.conn

        def __exit__(self, exc_type: object, exc: BaseException | None, tb: object) -> None:
            if exc is None:
                try:
                    self.conn.execute("COMMIT")
                    return
                except sqlite3.Error as error:
                    exc = error
            if self.conn.in_transaction:
                with contextlib.suppress(sqlite3.Error):
                    self.conn.execute("ROLLBACK")
            if isinstance(exc, sqlite3.Error):
                raise self.store._storage_error(exc) from None

    def _transaction(self) -> StateStore._Txn:
        return StateStore._Txn(self)

    # --- writing -------------------------------------------------------------------------------------

    def ensure_engine(self, serial: str) -> None:
        """Register an engine serial (idempotent)."""
        with self._transaction() as conn:
            conn.execute("INSERT OR IGNORE INTO engines (serial, first_seen_utc) VALUES (?, ?)", (serial, time.time()))

    def set_engine_hours(self, serial: str, overhaul_hours: float | None, tbo_hours: float | None) -> None:
        """Keep an engine's ``engine.overhaul_hours`` and ``engine.tbo_hours`` (registered first): overhaul
        hours that differ from the stored ones (an overhaul, a logbook entry) are stored with the engine's
        running seconds now, from which its time since overhaul counts on; None keeps the stored ones."""
        with self._transaction() as conn:
            conn.execute("INSERT OR IGNORE INTO engines (serial, first_seen_utc) VALUES (?, ?)", (serial, time.time()))
            stored = conn.execute("SELECT overhaul_hours FROM engines WHERE serial = ?", (serial,)).fetchone()[0]
            if overhaul_hours is not None and stored != overhaul_hours:
                conn.execute(
                    "UPDATE engines SET overhaul_hours = ?, overhaul_running_s = ? WHERE serial = ?",
                    (overhaul_hours, self._running_s(serial), serial),
                )
            conn.execute("UPDATE engines SET tbo_hours = ? WHERE serial = ?", (tbo_hours, serial))

    def _running_s(self, serial: str) -> float:
        """The engine's running seconds in the history: the sum of its flights' durations (running ones too)."""
        query = "SELECT coalesce(sum(duration_s), 0) FROM flights WHERE engine_serial = ?"
        return float(self._conn.execute(query, (serial,)).fetchone()[0])

    def engine_hours(self, serial: str) -> EngineHours:
        """The engine's hours (:class:`EngineHours`)."""
        running_s = self._running_s(serial)
        row = None
        present = {r[1] for r in self._conn.execute("PRAGMA table_info(engines)")}
        if "overhaul_hours" in present:  # else a read-only older database
            query = "SELECT overhaul_hours, overhaul_running_s, tbo_hours FROM engines WHERE serial = ?"
            row = self._conn.execute(query, (serial,)).fetchone()
        overhaul, at_s, tbo = row if row is not None else (None, None, None)
        since = None if overhaul is None else overhaul + (running_s - (at_s or 0.0)) / 3600.0
        return EngineHours(running_s / 3600.0, since, tbo)

    def begin_flight(self, serial: str, start_utc: float, cht_limit_c: float) -> int:
        """Insert a running flight; returns its id."""
        with self._transaction() as conn:
            conn.execute("INSERT OR IGNORE INTO engines (serial, first_seen_utc) VALUES (?, ?)", (serial, start_utc))
            cursor = conn.execute(
                "INSERT INTO flights (engine_serial, status, start_utc, end_utc, duration_s, cht_limit_c, "
                "time_above_limit_s, worst_state, time_degraded_s, cycles_total, cycles_json, updated_utc) "
                "VALUES (?, 'running', ?, ?, 0, ?, 0, 'NOMINAL', 0, 0, '{}', ?)",
                (serial, start_utc, start_utc, cht_limit_c, time.time()),
            )
            if cursor.lastrowid is None:
                raise EcuMonitorError("flight database: insert gave no row id")
            return int(cursor.lastrowid)

    def write_flight(self, flight_id: int, values: dict[str, object]) -> None:
        """Update a flight's columns in one transaction (a checkpoint or the final commit)."""
        names = sorted(values)
        assignments = ", ".join(f"{name} = ?" for name in names)
        with self._transaction() as conn:
            conn.execute(
                f"UPDATE flights SET {assignments}, updated_utc = ? WHERE id = ?",
                [values[name] for name in names] + [time.time(), flight_id],
            )

    def discard_flight(self, flight_id: int) -> None:
        """Delete a flight row (a run too short to be a flight)."""
        with self._transaction() as conn:
            conn.execute("DELETE FROM flights WHERE id = ?", (flight_id,))

    def recover(self, serial: str | None, min_flight_s: float) -> list[int]:
        """Close flights left ``running`` by a crash as ``recovered`` at their last checkpoint.

        Cycles are counted from the checkpointed reversal points; rows shorter than ``min_flight_s`` are
        deleted. ``serial=None`` recovers every engine. Returns the ids kept.
        """
        kept = []
        with self._transaction() as conn:
            query = "SELECT id, duration_s, reversals FROM flights WHERE status = 'running'"
            rows = conn.execute(query + (" AND engine_serial = ?" if serial else ""), (serial,) if serial else ())
            for flight_id, duration_s, blob in rows.fetchall():
                if duration_s < min_flight_s:
                    conn.execute("DELETE FROM flights WHERE id = ?", (flight_id,))
                    continue
                total, histogram = count_cycles(unpack_reversals(blob))
                conn.execute(
                    "UPDATE flights SET status = 'recovered', end_reason = 'service_crashed', cycles_total = ?, "
                    "cycles_json = ? WHERE id = ?",
                    (total, json.dumps(histogram), flight_id),
                )
                kept.append(int(flight_id))
        return kept

    def reopen_flight(self, flight_id: int) -> tuple[FlightRecord, list[float]]:
        """Set a recovered flight back to ``running`` (its engine run goes on after a restart); returns
        the row as it was and its stored reversal points."""
        with self._transaction() as conn:
            row = conn.execute(
                f"SELECT {_FLIGHT_COLUMNS}, reversals FROM flights WHERE id = ?", (flight_id,)
            ).fetchone()
            if row is None:
                raise EcuMonitorError(f"flight database: no flight {flight_id} to resume")
            conn.execute("UPDATE flights SET status = 'running', end_reason = NULL WHERE id = ?", (flight_id,))
        return _record(row[:-1]), unpack_reversals(row[-1])

    def raise_alert(self, alert: MaintenanceAlert) -> int:
        """Store a maintenance alert (its ``id`` is ignored); returns its id."""
        names = _ALERT_COLUMNS.split(", ")[1:]
        values = [getattr(alert, name) for name in names]
        with self._transaction() as conn:
            cursor = conn.execute(
                f"INSERT INTO maintenance_alerts ({', '.join(names)}) VALUES ({', '.join('?' * len(names))})", values
            )
            if cursor.lastrowid is None:
                raise EcuMonitorError("flight database: insert gave no row id")
            return int(cursor.lastrowid)

    def clear_alerts(self, serial: str, when_utc: float) -> int:
        """Clear an engine's open alerts (maintenance done); returns how many."""
        with self._transaction() as conn:
            cursor = conn.execute(
                "UPDATE maintenance_alerts SET cleared_utc = ? WHERE engine_serial = ? AND cleared_utc IS NULL",
                (when_utc, serial),
            )
            return int(cursor.rowcount)

    # --- reading -------------------------------------------------------------------------------------

    def alerts(self, serial: str | None = None, open_only: bool = False) -> list[MaintenanceAlert]:
        """Maintenance alerts of one engine (or all), oldest first; ``open_only``: those not cleared."""
        if not self._has_table("maintenance_alerts"):  # a read-only older database
            return []
        where = ["cleared_utc IS NULL"] if open_only else []
        params: tuple[object, ...] = ()
        if serial is not None:
            where.append("engine_serial = ?")
            params = (serial,)
        clause = f" WHERE {' AND '.join(where)}" if where else ""
        rows = self._conn.execute(
            f"SELECT {_ALERT_COLUMNS} FROM maintenance_alerts{clause} ORDER BY raised_utc, id", params
        )
        return [
            MaintenanceAlert(*row[:10], bool(row[10]), row[11])  # type: ignore[arg-type]
            for row in rows.fetchall()
        ]

    def _has_table(self, name: str) -> bool:
        query = "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = ?"
        return self._conn.execute(query, (name,)).fetchone() is not None

    def engines(self) -> list[str]:
        """Engine serials, sorted."""
        return [row[0] for row in self._conn.execute("SELECT serial FROM engines ORDER BY serial")]

    def flights(self, serial: str | None = None, include_running: bool = False) -> list[FlightRecord]:
        """Flights of one engine (or all), oldest first."""
        where = [] if include_running else ["status != 'running'"]
        params: tuple[object, ...] = ()
        if serial is not None:
            where.append("engine_serial = ?")
            params = (serial,)
        clause = f" WHERE {' AND '.join(where)}" if where else ""
        query = f"SELECT {self._flight_columns()} FROM flights{clause} ORDER BY start_utc, id"
        rows = self._conn.execute(query, params)
        return [_record(row) for row in rows.fetchall()]

    def _flight_columns(self) -> str:
        """_FLIGHT_COLUMNS, with a column an older database opened read-only lacks read as NULL (0 for a count)."""
        present = {row[1] for row in self._conn.execute("PRAGMA table_info(flights)")}
        return ", ".join(
            name if name in present else f"{0 if name == 'wear_samples' else 'NULL'} AS {name}"
            for name in _FLIGHT_COLUMNS.split(", ")
        )

    def integrity_ok(self) -> bool:
        """``PRAGMA integrity_check`` says ok."""
        return bool(self._conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok")

    def close(self) -> None:
        """Close the connection (idempotent)."""
        if not getattr(self, "_closed", True):
            self._conn.close()
            self._closed = True

    def __enter__(self) -> StateStore:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _record(row: tuple[object, ...]) -> FlightRecord:
    """A FlightRecord from a row of :data:`_FLIGHT_COLUMNS`."""
    names = [item.name for item in fields(FlightRecord)][:-5]  # then cycles_histogram, phases, cylinders, trends,
    fixed, trends = row[: len(names) + 4], row[len(names) + 4 :]  # events
    values: dict[str, object] = dict(zip(names, fixed[:-4], strict=True))
    for name, text in zip(("cycles_histogram", "cylinders", "phases", "events"), fixed[-4:], strict=True):
        values[name] = json.loads(str(text)) if text else {}
    values["trends"] = dict(zip(trend_columns(), trends, strict=True))
    return FlightRecord(**values)  # type: ignore[arg-type]


def iter_trend(records: list[FlightRecord]) -> Iterator[tuple[float, FlightRecord]]:
    """(cumulative engine hours at the end of each flight, flight), oldest first."""
    hours = 0.0
    for record in records:
        hours += record.hours
        yield hours, record
