"""Flight history of each engine in an embedded SQLite database (``<state_dir>/ecu-monitor.sqlite3``).

What is kept, per engine (its serial from the config) and per flight: start and end (UTC), duration
(hours), maximum CHT, time above the CHT limit, the degradation estimates (gamma_Q, gamma_D: start, end,
mean, maximum and their slope within the flight per hour), the worst detector state and the time spent
SUSPECT/DEGRADED, and the thermal cycles of the CHT history counted by rainflow (ASTM E1049, the
``rainflow`` package) as a histogram of cycle ranges.

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

import itertools
import json
import logging
import math
import sqlite3
import time
from array import array
from collections.abc import Iterator
from dataclasses import dataclass, fields
from pathlib import Path

import rainflow

from ecu_monitor.errors import ConfigError, EcuMonitorError

__all__ = [
    "CYCLE_BIN_EDGES_C",
    "DATABASE_NAME",
    "FlightRecord",
    "FlightRecorder",
    "FlightRules",
    "FlightSample",
    "ReversalFilter",
    "StateStore",
    "count_cycles",
    "iter_trend",
]

_log = logging.getLogger(__name__)

#: File name of the database inside the state directory.
DATABASE_NAME = "ecu-monitor.sqlite3"
#: Lower edges of the cycle-range histogram bins, degC (the last bin is open-ended).
CYCLE_BIN_EDGES_C: tuple[float, ...] = (5.0, 10.0, 20.0, 50.0, 100.0)
#: Detector states ranked from best to worst (health.dbc DegradationState order of concern).
_STATE_RANK = {"NOMINAL": 0, "INPUT_STALE": 1, "UNAVAILABLE": 2, "SENSOR_FAULT": 3, "SUSPECT": 4, "DEGRADED": 5}
#: Longest gap between two samples that still counts as covered time, s (a longer gap adds nothing).
_MAX_SAMPLE_GAP_S = 2.0
_SCHEMA_VERSION = 1


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
    ``rpm`` is None when the engine speed is stale; NaN values mean "not available".
    """

    time_s: float
    wall_time_s: float
    rpm: float | None
    cht_c: float
    gamma_q: float
    gamma_d: float
    state: str


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
    gamma_q_start: float | None
    gamma_q_end: float | None
    gamma_q_mean: float | None
    gamma_q_max: float | None
    gamma_q_slope_per_h: float | None
    gamma_d_start: float | None
    gamma_d_end: float | None
    gamma_d_mean: float | None
    gamma_d_max: float | None
    gamma_d_slope_per_h: float | None
    worst_state: str
    time_degraded_s: float
    cycles_total: float
    cycles_histogram: dict[str, float]

    @property
    def hours(self) -> float:
        """Flight duration in hours."""
        return self.duration_s / 3600.0


def count_cycles(reversals: list[float]) -> tuple[float, dict[str, float]]:
    """Rainflow count (ASTM E1049, half cycles as 0.5) of a CHT series: (total cycles, histogram).

    The histogram maps a bin label ``"lo-hi"`` (degC of cycle range, ``"lo+"`` for the last) to cycles;
    cycles smaller than the first edge are not counted.
    """
    labels = [f"{lo:g}-{hi:g}" for lo, hi in itertools.pairwise(CYCLE_BIN_EDGES_C)]
    labels.append(f"{CYCLE_BIN_EDGES_C[-1]:g}+")
    histogram = dict.fromkeys(labels, 0.0)
    if len(reversals) < 2:
        return 0.0, histogram
    total = 0.0
    for cycle_range, _mean, count, _start, _end in rainflow.extract_cycles(reversals):
        if cycle_range < CYCLE_BIN_EDGES_C[0]:
            continue
        index = sum(1 for edge in CYCLE_BIN_EDGES_C if cycle_range >= edge) - 1
        histogram[labels[index]] += count
        total += count
    return total, histogram


class ReversalFilter:
    """Online turning-point filter with hysteresis: keeps the reversals of a series, bounded memory."""

    def __init__(self, hysteresis: float) -> None:
        self.hysteresis = hysteresis
        self._points: list[float] = []
        self._direction = 0  # +1 rising, -1 falling, 0 not yet known
        self._candidate = math.nan

    def add(self, value: float) -> None:
        """Feed one sample (NaN is ignored)."""
        if not math.isfinite(value):
            return
        if not self._points:
            self._points.append(value)
            self._candidate = value
            return
        if self._direction == 0:
            if abs(value - self._points[0]) >= self.hysteresis:
                self._direction = 1 if value > self._points[0] else -1
            self._candidate = value
            return
        if (value - self._candidate) * self._direction > 0:
            self._candidate = value  # still going the same way: a new extreme
        elif abs(value - self._candidate) >= self.hysteresis:
            self._points.append(self._candidate)  # turned by more than the hysteresis: a reversal
            self._candidate = value
            self._direction = -self._direction

    def restore(self, points: list[float]) -> None:
        """Continue from the output of :meth:`points` (a flight resumed after a restart)."""
        self._points = list(points[:-1]) if len(points) >= 2 else list(points)
        self._candidate = points[-1] if points else math.nan
        self._direction = 0 if len(points) < 2 else (1 if points[-1] > points[-2] else -1)

    def points(self) -> list[float]:
        """The reversal points so far, ending with the latest extreme."""
        if not self._points:
            return []
        if self._direction == 0:
            return [self._points[0]]
        return [*self._points, self._candidate]


class _Moments:
    """Start, end, mean, max and least-squares slope (per hour) of a signal over time, online."""

    def __init__(self) -> None:
        self.n = 0
        self.first = math.nan
        self.last = math.nan
        self.maximum = -math.inf
        self.first_t_h = self.last_t_h = 0.0
        self.sum_t = self.sum_v = self.sum_tt = self.sum_tv = 0.0
        #: (first, mean, max, slope per h or None, span h) of the part before a restart, or None
        self.prior: tuple[float, float, float, float | None, float] | None = None

    def add(self, t_s: float, value: float) -> None:
        if not math.isfinite(value):
            return
        if self.n == 0:
            self.first = value
        self.n += 1
        self.last = value
        self.maximum = max(self.maximum, value)
        t_h = t_s / 3600.0
        if self.n == 1:
            self.first_t_h = t_h
        self.last_t_h = t_h
        self.sum_t += t_h
        self.sum_v += value
        self.sum_tt += t_h * t_h
        self.sum_tv += t_h * value

    def summary(self) -> tuple[float | None, float | None, float | None, float | None, float | None]:
        if self.prior is not None:
            return self._summary_with_prior(self.prior)
        if self.n == 0:
            return None, None, None, None, None
        mean = self.sum_v / self.n
        denominator = self.n * self.sum_tt - self.sum_t**2
        slope = (self.n * self.sum_tv - self.sum_t * self.sum_v) / denominator if self.n >= 2 else None
        if slope is not None and (denominator <= 1e-18 or not math.isfinite(slope)):
            slope = None
        return self.first, self.last, mean, self.maximum, slope

    def _summary_with_prior(
        self, prior: tuple[float, float, float, float | None, float]
    ) -> tuple[float | None, float | None, float | None, float | None, float | None]:
        """The prior part as samples spread evenly over [0, span] at the rate seen since (at least one),
        on its own least-squares line, pooled with the samples since."""
        first, mean_p, max_p, slope_p, span_h = prior
        if self.n == 0:
            return first, None, mean_p, max_p, slope_p
        span_new_h = self.last_t_h - self.first_t_h
        rate = (self.n - 1) / span_new_h if self.n >= 2 and span_new_h > 0 else 0.0  # samples per hour
        n_p = max(1.0, rate * span_h)
        sum_t = n_p * span_h / 2.0
        sum_tt = n_p * span_h**2 / 3.0
        sum_v = n_p * mean_p
        sum_tv = sum_t * mean_p + (slope_p or 0.0) * (sum_tt - sum_t**2 / n_p)
        n = n_p + self.n
        st, sv, stt, stv = sum_t + self.sum_t, sum_v + self.sum_v, sum_tt + self.sum_tt, sum_tv + self.sum_tv
        denominator = n * stt - st**2
        slope = (n * stv - st * sv) / denominator if denominator > 1e-18 else None
        if slope is not None and not math.isfinite(slope):
            slope = None
        return first, self.last, sv / n, max(max_p, self.maximum), slope


_FLIGHT_COLUMNS = (
    "id, engine_serial, status, end_reason, start_utc, end_utc, duration_s, max_cht_c, cht_limit_c, "
    "time_above_limit_s, gamma_q_start, gamma_q_end, gamma_q_mean, gamma_q_max, gamma_q_slope_per_h, "
    "gamma_d_start, gamma_d_end, gamma_d_mean, gamma_d_max, gamma_d_slope_per_h, worst_state, time_degraded_s, "
    "cycles_total, cycles_json"
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
    gamma_q_start REAL, gamma_q_end REAL, gamma_q_mean REAL, gamma_q_max REAL, gamma_q_slope_per_h REAL,
    gamma_d_start REAL, gamma_d_end REAL, gamma_d_mean REAL, gamma_d_max REAL, gamma_d_slope_per_h REAL,
    worst_state TEXT NOT NULL,
    time_degraded_s REAL NOT NULL,
    cycles_total REAL NOT NULL,
    cycles_json TEXT NOT NULL,
    reversals BLOB,
    updated_utc REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS flights_by_engine ON flights (engine_serial, start_utc);
"""


class StateStore:
    """The SQLite database of flights in ``state_dir`` (created if missing). Context manager; ``close()``.

    One connection, used from one thread at a time (the daemon's supervisor thread). Errors opening or
    writing the database raise :class:`~ecu_monitor.errors.EcuMonitorError` subclasses: a state
    directory that cannot be created is a ConfigError (user input).
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
            else:
                self.state_dir.mkdir(parents=True, exist_ok=True)
                self._conn = sqlite3.connect(str(self.path), timeout=10.0, isolation_level=None)
                self._conn.execute("PRAGMA journal_mode=WAL")
                self._conn.execute("PRAGMA synchronous=FULL")
                self._conn.execute("PRAGMA foreign_keys=ON")
                with self._transaction():
                    self._create_schema()
        except OSError as exc:
            raise ConfigError(f"{self.state_dir}: state_dir: cannot use it ({exc.strerror})") from None
        except sqlite3.Error as exc:
            raise ConfigError(f"{self.path}: cannot open the flight database ({exc})") from None
        self._closed = False

    def _create_schema(self) -> None:
        for statement in _SCHEMA.split(";"):
            if statement.strip():
                self._conn.execute(statement)
        self._conn.execute(
            "INSERT OR IGNORE INTO meta (key, value) VALUES ('schema_version', ?)", (str(_SCHEMA_VERSION),)
        )

    class _Txn:
        def __init__(self, conn: sqlite3.Connection) -> None:
            self.conn = conn

        def __enter__(self) -> sqlite3.Connection:
            self.conn.execute("BEGIN IMMEDIATE")
            return self.conn

        def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
            if exc_type is None:
                self.conn.execute("COMMIT")
            else:
                self.conn.execute("ROLLBACK")

    def _transaction(self) -> StateStore._Txn:
        return StateStore._Txn(self._conn)

    # --- writing -------------------------------------------------------------------------------------

    def ensure_engine(self, serial: str) -> None:
        """Register an engine serial (idempotent)."""
        with self._transaction() as conn:
            conn.execute("INSERT OR IGNORE INTO engines (serial, first_seen_utc) VALUES (?, ?)", (serial, time.time()))

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
                total, histogram = count_cycles(_unpack(blob))
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
        return _record(row[:-1]), _unpack(row[-1])

    # --- reading -------------------------------------------------------------------------------------

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
        rows = self._conn.execute(f"SELECT {_FLIGHT_COLUMNS} FROM flights{clause} ORDER BY start_utc, id", params)
        return [_record(row) for row in rows.fetchall()]

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


def _unpack(blob: bytes | None) -> list[float]:
    values = array("d")
    if blob:
        values.frombytes(blob)
    return values.tolist()


def _pack(points: list[float]) -> bytes:
    return array("d", points).tobytes()


def _record(row: tuple[object, ...]) -> FlightRecord:
    names = [item.name for item in fields(FlightRecord)]
    values: dict[str, object] = dict(zip(names[:-1], row[:-1], strict=True))
    values["cycles_histogram"] = json.loads(str(row[-1])) if row[-1] else {}
    return FlightRecord(**values)  # type: ignore[arg-type]


class _OpenFlight:
    """Aggregates of the flight in progress."""

    def __init__(self, flight_id: int, sample: FlightSample, hysteresis: float) -> None:
        self.flight_id = flight_id
        self.start_time_s = sample.time_s
        self.start_utc = sample.wall_time_s
        self.last_running_time_s = sample.time_s
        self.last_running_utc = sample.wall_time_s
        self.last_time_s = sample.time_s
        self.last_checkpoint_s = sample.time_s
        self.max_cht_c = -math.inf
        self.time_above_limit_s = 0.0
        self.time_degraded_s = 0.0
        self.worst_state = "NOMINAL"
        self.gamma_q = _Moments()
        self.gamma_d = _Moments()
        self.reversals = ReversalFilter(hysteresis)

    @classmethod
    def resume(
        cls, record: FlightRecord, reversals: list[float], sample: FlightSample, hysteresis: float
    ) -> _OpenFlight:
        """Continue a flight cut by a restart: its aggregates from the row, its clock from its start (UTC)."""
        flight = cls(record.id, sample, hysteresis)
        flight.start_time_s = sample.time_s - (sample.wall_time_s - record.start_utc)
        flight.start_utc = record.start_utc
        flight.last_checkpoint_s = sample.time_s
        flight.max_cht_c = record.max_cht_c if record.max_cht_c is not None else -math.inf
        flight.time_above_limit_s = record.time_above_limit_s
        flight.time_degraded_s = record.time_degraded_s
        flight.worst_state = record.worst_state
        flight.reversals.restore(reversals)
        span_h = record.duration_s / 3600.0
        for moments, first, mean, top, slope in (
            (flight.gamma_q, record.gamma_q_start, record.gamma_q_mean, record.gamma_q_max, record.gamma_q_slope_per_h),
            (flight.gamma_d, record.gamma_d_start, record.gamma_d_mean, record.gamma_d_max, record.gamma_d_slope_per_h),
        ):
            if first is not None and mean is not None and top is not None:
                moments.prior = (first, mean, top, slope, span_h)
        return flight

    def values(self, end_running: bool) -> dict[str, object]:
        """Columns of the flights row; the flight ends at the last running sample when ``end_running``."""
        duration_s = self.last_running_time_s - self.start_time_s
        q_first, q_last, q_mean, q_max, q_slope = self.gamma_q.summary()
        d_first, d_last, d_mean, d_max, d_slope = self.gamma_d.summary()
        points = self.reversals.points()
        total, histogram = count_cycles(points) if end_running else (0.0, {})
        return {
            "end_utc": self.start_utc + duration_s,
            "duration_s": max(duration_s, 0.0),
            "max_cht_c": self.max_cht_c if math.isfinite(self.max_cht_c) else None,
            "time_above_limit_s": self.time_above_limit_s,
            "gamma_q_start": q_first,
            "gamma_q_end": q_last,
            "gamma_q_mean": q_mean,
            "gamma_q_max": q_max,
            "gamma_q_slope_per_h": q_slope,
            "gamma_d_start": d_first,
            "gamma_d_end": d_last,
            "gamma_d_mean": d_mean,
            "gamma_d_max": d_max,
            "gamma_d_slope_per_h": d_slope,
            "worst_state": self.worst_state,
            "time_degraded_s": self.time_degraded_s,
            "cycles_total": total,
            "cycles_json": json.dumps(histogram),
            "reversals": _pack(points),
        }


class FlightRecorder:
    """Finds flights in the stream of samples and writes them to a :class:`StateStore`.

    ``add(sample)`` once per health period; ``close(reason)`` at service stop finishes a flight in
    progress (kept if long enough). Flights left running by a crash are recovered when the recorder is
    created. ``finished`` lists the ids committed by this recorder.
    """

    def __init__(self, store: StateStore, serial: str, cht_limit_c: float, rules: FlightRules | None = None) -> None:
        self.store = store
        self.serial = serial
        self.cht_limit_c = float(cht_limit_c)
        self.rules = rules or FlightRules()
        self.finished: list[int] = []
        self.recovered = store.recover(serial, self.rules.min_flight_s)
        store.ensure_engine(serial)
        self._flight: _OpenFlight | None = None
        #: the flight a crash cut, resumed if the engine is still running when samples come back
        self._resumable = max(
            (r for r in store.flights(serial) if r.id in self.recovered), key=lambda r: r.end_utc, default=None
        )
        self.resumed: int | None = None

    @property
    def in_flight(self) -> bool:
        """True while a flight is open."""
        return self._flight is not None

    def add(self, sample: FlightSample) -> None:
        """Account one sample; opens, checkpoints and finishes flights as the rpm says."""
        rules = self.rules
        running = sample.rpm is not None and math.isfinite(sample.rpm) and sample.rpm >= rules.running_rpm
        flight = self._flight
        if flight is None:
            if not running:
                self._resumable = None  # the engine was seen stopped: the cut flight is over
                return
            flight = self._flight = self._resume(sample) or self._begin(sample)
        if not running:
            if sample.time_s - flight.last_running_time_s >= rules.end_after_s:
                self._finish("engine_stopped")
            return
        self._accumulate(flight, sample)
        if sample.time_s - flight.last_checkpoint_s >= rules.checkpoint_every_s:
            self.store.write_flight(flight.flight_id, flight.values(end_running=False))
            flight.last_checkpoint_s = sample.time_s

    def _begin(self, sample: FlightSample) -> _OpenFlight:
        flight_id = self.store.begin_flight(self.serial, sample.wall_time_s, self.cht_limit_c)
        _log.info("flight %d of engine %s started", flight_id, self.serial)
        return _OpenFlight(flight_id, sample, self.rules.cycle_hysteresis_c)

    def _resume(self, sample: FlightSample) -> _OpenFlight | None:
        """The flight a restart cut, reopened when this first running sample continues its engine run."""
        cut, self._resumable = self._resumable, None
        if cut is None:
            return None
        gap_s = sample.wall_time_s - cut.end_utc
        if not 0.0 <= gap_s <= self.rules.checkpoint_every_s + self.rules.end_after_s:
            return None
        record, reversals = self.store.reopen_flight(cut.id)
        self.resumed = record.id
        _log.info(
            "flight %d of engine %s resumed after a restart (%.0f s since its checkpoint)", cut.id, self.serial, gap_s
        )
        return _OpenFlight.resume(record, reversals, sample, self.rules.cycle_hysteresis_c)

    def _accumulate(self, flight: _OpenFlight, sample: FlightSample) -> None:
        dt = sample.time_s - flight.last_time_s
        dt = dt if 0.0 < dt <= _MAX_SAMPLE_GAP_S else 0.0
        flight.last_time_s = sample.time_s
        flight.last_running_time_s = sample.time_s
        flight.last_running_utc = sample.wall_time_s
        if math.isfinite(sample.cht_c):
            flight.max_cht_c = max(flight.max_cht_c, sample.cht_c)
            flight.reversals.add(sample.cht_c)
            if sample.cht_c > self.cht_limit_c:
                flight.time_above_limit_s += dt
        if sample.state in ("SUSPECT", "DEGRADED"):
            flight.time_degraded_s += dt
        if _STATE_RANK.get(sample.state, 0) > _STATE_RANK.get(flight.worst_state, 0):
            flight.worst_state = sample.state
        flight.gamma_q.add(sample.time_s - flight.start_time_s, sample.gamma_q)
        flight.gamma_d.add(sample.time_s - flight.start_time_s, sample.gamma_d)

    def _finish(self, reason: str) -> int | None:
        flight = self._flight
        if flight is None:
            return None
        self._flight = None
        duration_s = flight.last_running_time_s - flight.start_time_s
        if duration_s < self.rules.min_flight_s:
            self.store.discard_flight(flight.flight_id)
            _log.info("engine run of %.0f s not kept (shorter than %.0f s)", duration_s, self.rules.min_flight_s)
            return None
        values = flight.values(end_running=True)
        values.update(status="finished", end_reason=reason)
        self.store.write_flight(flight.flight_id, values)
        self.finished.append(flight.flight_id)
        _log.info("flight %d of engine %s finished (%s, %.0f s)", flight.flight_id, self.serial, reason, duration_s)
        return flight.flight_id

    def close(self, reason: str = "service_stop") -> int | None:
        """Finish the flight in progress (service stop); returns its id if it was kept."""
        return self._finish(reason)


def iter_trend(records: list[FlightRecord]) -> Iterator[tuple[float, FlightRecord]]:
    """(cumulative engine hours at the end of each flight, flight), oldest first."""
    hours = 0.0
    for record in records:
        hours += record.hours
        yield hours, record
