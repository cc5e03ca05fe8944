"""Flights found in the service's stream of samples and written to the engine's history (:class:`StateStore`).

A flight starts when rpm reaches ``FlightRules.running_rpm`` and ends when it has stayed below (or been
stale) for ``end_after_s``; a run shorter than ``min_flight_s`` is not kept. A running flight is
checkpointed every ``checkpoint_every_s``; a flight left running by a crash is recovered, and resumed when
the engine is still running at restart (one engine run stays one flight). See runtime/persistence.py for
the durability rules of the store.

Across flights: each finished flight keeps its wear index (:class:`~ecu_monitor.estimation.wear.FlightWear`
over the samples' CHT, reference model CHT and OAT); after it, the across-flight detector
(:func:`engine_wear`) runs over the engine's flights since its last cleared alert, and an alert it raises
is stored (:class:`~ecu_monitor.runtime.persistence.MaintenanceAlert`) once, until maintenance clears it.

Engine events (pipeline/events.py): :meth:`FlightRecorder.add_events` counts each event that starts while a
flight is open in that flight, by kind and cylinder (an event while the engine is not running is not a
flight's). The engine's overhaul hours and TBO (``engine:`` in the config) are kept in the history when it
is first reached (:meth:`~ecu_monitor.runtime.persistence.StateStore.set_engine_hours`).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

from ecu_monitor.errors import StorageError
from ecu_monitor.estimation.regions import REGION_HIGH, REGION_NAMES, power_fraction, region_of
from ecu_monitor.estimation.wear import FlightWear, WearReference, WearSettings, WearVerdict, wear_verdict
from ecu_monitor.pipeline.events import Event
from ecu_monitor.pipeline.output_table import STATE_CONCERN
from ecu_monitor.runtime.persistence import (
    TREND_STATS,
    FlightRecord,
    FlightRules,
    FlightSample,
    MaintenanceAlert,
    StateStore,
    trend_values,
)
from ecu_monitor.runtime.thermal_cycles import ReversalFilter, count_cycles, pack_reversals

__all__ = [
    "EngineWear",
    "FlightRecorder",
    "HeldInputs",
    "SignalMoments",
    "engine_wear",
    "flight_samples",
    "held_inputs",
]

_log = logging.getLogger(__name__)

#: States in which the estimator (and its reference model) is not running: no wear sample then.
_NOT_ESTIMATING = frozenset({"UNAVAILABLE", "SENSOR_FAULT"})
#: Longest gap between two samples that still counts as covered time, s (a longer gap adds nothing).
_MAX_SAMPLE_GAP_S = 2.0


class HeldInputs(NamedTuple):
    """What the recorder reads from the pipeline besides its rows, at one instant: engine speed, rev/min
    (None: stale), the reference model's CHT, OAT, airspeed and the power fraction of the heat map's power
    input (estimation/regions.py; nan: not available)."""

    rpm: float | None
    model_c: float = math.nan
    oat_c: float = math.nan
    airspeed_mps: float = math.nan
    power: float = math.nan


def held_inputs(pipeline: Any) -> HeldInputs:
    """The pipeline's held inputs and reference model CHT now (a Pipeline or a LiveMonitor; call under its lock)."""

    def value(name: str) -> float:
        held = pipeline.held_input(name)
        return math.nan if held is None else float(held)

    heat_map = pipeline.params.heat_map
    power = power_fraction(value(heat_map.x_axis), heat_map.x_breakpoints[0], heat_map.x_breakpoints[-1])
    rpm = pipeline.held_input("rpm")
    return HeldInputs(rpm, pipeline.reference_model_c(), value("oat_c"), value("airspeed_mps"), power)


def flight_samples(rows: Sequence[Any], held: HeldInputs, wall_offset_s: float) -> list[FlightSample]:
    """The recorder's samples of health rows (HealthSnapshot) whose held inputs were ``held``; wall time = the
    row's time + ``wall_offset_s``. A row's CHT is the reading, or the estimate where the probe is faulty."""
    trends = trend_values()
    return [
        FlightSample(
            time_s=row.time_s,
            wall_time_s=row.time_s + wall_offset_s,
            rpm=held.rpm,
            cht_c=_trusted_cht(row),
            trends={name: float(getattr(row, name)) for name in trends},
            state=str(row.state),
            cylinders=tuple(
                (_trusted_cht(c), {name: float(getattr(c, name)) for name in trends}, str(c.state))
                for c in row.cylinders
            ),
            cht_spread_c=float(row.cht_spread_c),
            hottest_cylinder=int(row.hottest_cylinder),
            spread_alarm=bool(row.spread_alarm),
            model_c=held.model_c,
            oat_c=held.oat_c,
            airspeed_mps=held.airspeed_mps,
            power=held.power,
            deviation=float(row.deviation),
        )
        for row in rows
    ]


def _trusted_cht(row: Any) -> float:
    cht = row.cht_meas_c if not row.sensor_fault and math.isfinite(row.cht_meas_c) else row.cht_est_c
    return float(cht) if math.isfinite(cht) else math.nan


class SignalMoments:
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


class _Phase:
    """One flight phase's (region's) part of the flight in progress: its time, wear index, symptom and gammas."""

    def __init__(self, wear: WearSettings) -> None:
        self.seconds = 0.0
        self.wear = FlightWear(wear)
        self.sums = {"deviation": [0.0, 0], "gamma_q": [0.0, 0], "gamma_d": [0.0, 0]}

    def add(self, sample: FlightSample) -> None:
        self.wear.add(sample.cht_c, sample.model_c, sample.oat_c)
        gamma_q, gamma_d = sample.trends.get("gamma_q", math.nan), sample.trends.get("gamma_d", math.nan)
        for name, value in (("deviation", sample.deviation), ("gamma_q", gamma_q), ("gamma_d", gamma_d)):
            if math.isfinite(value):
                self.sums[name][0] += value
                self.sums[name][1] += 1

    def values(self) -> dict[str, Any]:
        out: dict[str, Any] = {"seconds": self.seconds, "wear_index": self.wear.index, "wear_spread": self.wear.spread,
                               "wear_samples": self.wear.n}  # fmt: skip
        for name, (total, count) in self.sums.items():
            out[f"{name}_mean"] = total / count if count else None
            out[f"{name}_samples"] = count
        return out

    def restore(self, stored: dict[str, Any]) -> None:
        """Continue from the stored part (a flight cut by a restart)."""
        self.seconds = float(stored.get("seconds", 0.0))
        self.wear.restore(int(stored.get("wear_samples", 0)), stored.get("wear_index"), stored.get("wear_spread"))
        for name in self.sums:
            mean, count = stored.get(f"{name}_mean"), int(stored.get(f"{name}_samples", 0))
            if mean is not None and count:
                self.sums[name] = [mean * count, count]


class _CylinderFlight:
    """One cylinder's aggregates of the flight in progress (engines monitored per cylinder)."""

    def __init__(self, number: int) -> None:
        self.number = number
        self.max_cht_c = -math.inf
        self.worst_state = "NOMINAL"
        self.time_degraded_s = 0.0
        self.trends = _trend_moments()

    def add(self, t_s: float, dt: float, cht_c: float, trends: Mapping[str, float], state: str) -> None:
        if math.isfinite(cht_c):
            self.max_cht_c = max(self.max_cht_c, cht_c)
        if state in ("SUSPECT", "DEGRADED"):
            self.time_degraded_s += dt
        if STATE_CONCERN.get(state, 0) > STATE_CONCERN.get(self.worst_state, 0):
            self.worst_state = state
        for name, moments in self.trends.items():
            moments.add(t_s, trends[name])

    def values(self) -> dict[str, object]:
        out: dict[str, object] = {
            "number": self.number,
            "max_cht_c": self.max_cht_c if math.isfinite(self.max_cht_c) else None,
            "worst_state": self.worst_state,
            "time_degraded_s": self.time_degraded_s,
        }
        return {**out, **_trend_summary(self.trends)}

    @classmethod
    def restore(cls, stored: dict[str, Any], span_h: float) -> _CylinderFlight:
        """The aggregates of a flight cut by a restart, from its stored row."""
        cyl = cls(int(stored["number"]))
        cyl.max_cht_c = stored["max_cht_c"] if stored.get("max_cht_c") is not None else -math.inf
        cyl.worst_state = str(stored["worst_state"])
        cyl.time_degraded_s = float(stored["time_degraded_s"])
        _restore_trends(cyl.trends, stored, span_h)
        return cyl


def _trend_moments() -> dict[str, SignalMoments]:
    """The running statistics of each trend value (persistence.trend_values)."""
    return {name: SignalMoments() for name in trend_values()}


def _trend_summary(trends: dict[str, SignalMoments]) -> dict[str, float | None]:
    """The trend columns (persistence.trend_columns) of running statistics."""
    out: dict[str, float | None] = {}
    for name, moments in trends.items():
        out.update(zip((f"{name}_{stat}" for stat in TREND_STATS), moments.summary(), strict=True))
    return out


def _restore_trends(trends: dict[str, SignalMoments], stored: Mapping[str, Any], span_h: float) -> None:
    """Running statistics continued from the stored trend columns of a flight cut by a restart."""
    for name, moments in trends.items():
        first, mean, top = stored.get(f"{name}_start"), stored.get(f"{name}_mean"), stored.get(f"{name}_max")
        if first is not None and mean is not None and top is not None:
            moments.prior = (first, mean, top, stored.get(f"{name}_slope_per_h"), span_h)


class _OpenFlight:
    """Aggregates of the flight in progress."""

    def __init__(self, flight_id: int | None, sample: FlightSample, hysteresis: float, wear: WearSettings) -> None:
        self.flight_id = flight_id  # None until the history takes its row
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
        self.trends = _trend_moments()
        self.reversals = ReversalFilter(hysteresis)
        self.wear = FlightWear(wear)
        self.high_power_s: float | None = None  # None until a power value is seen
        self.phases = [_Phase(wear) for _ in REGION_NAMES]  # per region (estimation/regions.py)
        self.cylinders: list[_CylinderFlight] = []  # engines monitored per cylinder
        self.spread_max_c = -math.inf
        self.spread_alarm_s = 0.0
        self.hottest_s: dict[int, float] = {}
        self.events: dict[str, dict[str, int]] = {}  # kind -> cylinder (text) -> events started

    @classmethod
    def resume(
        cls, record: FlightRecord, reversals: list[float], sample: FlightSample, hysteresis: float, wear: WearSettings
    ) -> _OpenFlight:
        """Continue a flight cut by a restart: its aggregates from the row, its clock from its start (UTC)."""
        flight = cls(record.id, sample, hysteresis, wear)
        flight.start_time_s = sample.time_s - (sample.wall_time_s - record.start_utc)
        flight.start_utc = record.start_utc
        flight.last_checkpoint_s = sample.time_s
        flight.max_cht_c = record.max_cht_c if record.max_cht_c is not None else -math.inf
        flight.time_above_limit_s = record.time_above_limit_s
        flight.time_degraded_s = record.time_degraded_s
        flight.worst_state = record.worst_state
        flight.reversals.restore(reversals)
        flight.wear.restore(record.wear_samples, record.wear_index, record.wear_spread)
        flight.high_power_s = record.high_power_s
        for phase, name in zip(flight.phases, REGION_NAMES, strict=True):
            phase.restore(record.phases.get(name, {}))
        span_h = record.duration_s / 3600.0
        _restore_trends(flight.trends, record.trends, span_h)
        stored = record.cylinders
        if stored:
            flight.cylinders = [_CylinderFlight.restore(c, span_h) for c in stored.get("per_cylinder", [])]
            spread = stored.get("spread_max_c")
            flight.spread_max_c = float(spread) if spread is not None else -math.inf
            flight.spread_alarm_s = float(stored.get("spread_alarm_s", 0.0))
            flight.hottest_s = {int(k): float(v) for k, v in stored.get("hottest_s", {}).items()}
        flight.events = {kind: dict(counts) for kind, counts in record.events.items()}
        return flight

    def values(self, end_running: bool) -> dict[str, object]:
        """Columns of the flights row; the flight ends at the last running sample when ``end_running``."""
        duration_s = self.last_running_time_s - self.start_time_s
        points = self.reversals.points()
        total, histogram = count_cycles(points) if end_running else (0.0, {})
        return {
            "end_utc": self.start_utc + duration_s,
            "duration_s": max(duration_s, 0.0),
            "max_cht_c": self.max_cht_c if math.isfinite(self.max_cht_c) else None,
            "time_above_limit_s": self.time_above_limit_s,
            **_trend_summary(self.trends),
            "worst_state": self.worst_state,
            "time_degraded_s": self.time_degraded_s,
            "cycles_total": total,
            "cycles_json": json.dumps(histogram),
            "cylinders_json": self._cylinders_json(),
            "wear_index": self.wear.index,
            "wear_spread": self.wear.spread,
            "wear_samples": self.wear.n,
            "high_power_s": self.high_power_s,
            "phases_json": json.dumps(self._phases()),
            "events_json": json.dumps(self.events),
            "reversals": pack_reversals(points),
        }

    def _phases(self) -> dict[str, Any]:
        return {name: phase.values() for name, phase in zip(REGION_NAMES, self.phases, strict=True) if phase.seconds}

    def _cylinders_json(self) -> str | None:
        if not self.cylinders:
            return None
        return json.dumps({
            "spread_max_c": self.spread_max_c if math.isfinite(self.spread_max_c) else None,
            "spread_alarm_s": self.spread_alarm_s,
            "hottest_s": {str(k): v for k, v in sorted(self.hottest_s.items())},
            "per_cylinder": [c.values() for c in self.cylinders],
        })  # fmt: skip


class FlightRecorder:
    """Finds flights in the stream of samples and writes them to a :class:`StateStore`.

    ``add(sample)`` once per health period; ``close(reason)`` at service stop finishes a flight in
    progress (kept if long enough). Flights left running by a crash are recovered when the store is
    first reached. ``finished`` lists the ids committed by this recorder. ``wear`` and ``reference``: the
    across-flight detector's settings and the engine's nominal wear reference (None: learned from its first
    flights); ``alerts`` lists the alerts this recorder raised.

    ``store`` is a store, or a function that opens one. While the history cannot be opened or written
    (:class:`~ecu_monitor.errors.StorageError`: a read-only database, a full disk) the recorder goes on in
    memory: ``history_fault`` says why, the flight in progress and those finished meanwhile are kept, and
    every ``retry_s`` of sample time the store is tried again (reopened, when given as a function) and
    they are written.
    """

    def __init__(
        self,
        store: StateStore | Callable[[], StateStore],
        serial: str,
        cht_limit_c: float,
        rules: FlightRules | None = None,
        *,
        wear: WearSettings | None = None,
        reference: WearReference | None = None,
        retry_s: float = 30.0,
        hours: tuple[float | None, float | None] = (None, None),
    ) -> None:
        self._opener = None if isinstance(store, StateStore) else store
        self.store: StateStore | None = store if isinstance(store, StateStore) else None
        self.serial = serial
        self.cht_limit_c = float(cht_limit_c)
        self.rules = rules or FlightRules()
        self.retry_s = float(retry_s)
        self.wear = wear or WearSettings()
        self.reference = reference
        self.hours = hours  # the engine's overhaul hours and TBO as the config gives them (None: not given)
        self.alerts: list[MaintenanceAlert] = []
        self.finished: list[int] = []
        self.recovered: list[int] = []
        self.resumed: int | None = None
        #: why the history cannot be written now (the StorageError's line), or None
        self.history_fault: str | None = None
        self._flight: _OpenFlight | None = None
        #: finished flights not yet written: (flight, its final values, or None: delete its row)
        self._unsaved: list[tuple[_OpenFlight, dict[str, object] | None]] = []
        self._resumable: FlightRecord | None = None  # the flight a crash cut, resumed if the engine still runs
        self._started = False  # crash recovery done (once, at the first store reached)
        self._retry_at_s = -math.inf
        self._sync(-math.inf)

    @property
    def in_flight(self) -> bool:
        """True while a flight is open."""
        return self._flight is not None

    def add(self, sample: FlightSample) -> None:
        """Account one sample; opens, checkpoints and finishes flights as the rpm says."""
        if self.history_fault is not None and sample.time_s >= self._retry_at_s:
            self._sync(sample.time_s)
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
                self._finish("engine_stopped", sample.time_s)
            return
        self._accumulate(flight, sample)
        if sample.time_s - flight.last_checkpoint_s >= rules.checkpoint_every_s:
            if self.history_fault is None:
                self._write(flight, flight.values(end_running=False), sample.time_s)
            flight.last_checkpoint_s = sample.time_s

    def add_events(self, events: Sequence[Event]) -> None:
        """Count the engine events that started (their start records) in the open flight (module docstring)."""
        flight = self._flight
        if flight is None:
            return
        for event in events:
            if event.ongoing:
                counts = flight.events.setdefault(event.kind, {})
                counts[str(event.cylinder)] = counts.get(str(event.cylinder), 0) + 1

    # --- the store, and going on without it -----------------------------------------------------------

    def _connected(self) -> StateStore:
        """The store, opened and its crash recovery done (StorageError if it cannot be)."""
        if self.store is None:
            assert self._opener is not None
            self.store = self._opener()
        store = self.store
        if not self._started:
            self.recovered = store.recover(self.serial, self.rules.min_flight_s)
            store.ensure_engine(self.serial)
            store.set_engine_hours(self.serial, *self.hours)
            self._started = True
            if self.recovered:
                _log.warning("flights %s were left open by a crash: kept up to their last checkpoint", self.recovered)
            if self._flight is None:
                self._resumable = max(
                    (r for r in store.flights(self.serial) if r.id in self.recovered),
                    key=lambda r: r.end_utc,
                    default=None,
                )
        return store

    def _store_flight(self, flight: _OpenFlight, values: dict[str, object] | None) -> None:
        """Write a flight's row (inserted first if it has none yet); ``values`` None: delete it."""
        store = self._connected()
        if flight.flight_id is None:
            if values is None:
                return  # a short run never written: nothing to delete
            flight.flight_id = store.begin_flight(self.serial, flight.start_utc, self.cht_limit_c)
        if values is None:
            store.discard_flight(flight.flight_id)
        elif values:
            store.write_flight(flight.flight_id, values)

    def _write(self, flight: _OpenFlight, values: dict[str, object] | None, now_s: float) -> bool:
        """:meth:`_store_flight`; False (and the history marked down) when it cannot be written."""
        try:
            self._store_flight(flight, values)
        except StorageError as exc:
            self._down(exc, now_s)
            return False
        return True

    def _down(self, exc: StorageError, now_s: float) -> None:
        if str(exc) != self.history_fault:
            _log.error(
                "%s: monitoring goes on, flights kept in memory and written when it can be (tried every %.0f s)",
                exc,
                self.retry_s,
            )
        self.history_fault = str(exc)
        self._retry_at_s = now_s + self.retry_s
        if self._opener is not None and self.store is not None:
            self.store.close()  # reopened at the next try: a remounted or repaired file is seen afresh
            self.store = None

    def _sync(self, now_s: float) -> None:
        """Reach the store and write what waits in memory: finished flights, then the running one."""
        try:
            self._connected()
            while self._unsaved:
                flight, values = self._unsaved[0]
                self._store_flight(flight, values)
                self._unsaved.pop(0)
                if values is not None and flight.flight_id is not None:
                    self.finished.append(flight.flight_id)
                    _log.info("flight %d of engine %s written to the history", flight.flight_id, self.serial)
                    self._check_wear()
            if self._flight is not None:
                self._store_flight(self._flight, self._flight.values(end_running=False))
        except StorageError as exc:
            self._down(exc, now_s)
            return
        if self.history_fault is not None:
            _log.info("flight history writable again")
            self.history_fault = None

    # --- flights ---------------------------------------------------------------------------------------

    def _begin(self, sample: FlightSample) -> _OpenFlight:
        flight = _OpenFlight(None, sample, self.rules.cycle_hysteresis_c, self.wear)
        if self.history_fault is None:
            self._write(flight, {}, sample.time_s)
        _log.info("flight %s of engine %s started", flight.flight_id or "(in memory)", self.serial)
        return flight

    def _resume(self, sample: FlightSample) -> _OpenFlight | None:
        """The flight a restart cut, reopened when this first running sample continues its engine run."""
        cut, self._resumable = self._resumable, None
        if cut is None or self.store is None or self.history_fault is not None:
            return None
        gap_s = sample.wall_time_s - cut.end_utc
        if not 0.0 <= gap_s <= self.rules.checkpoint_every_s + self.rules.end_after_s:
            return None
        try:
            record, reversals = self.store.reopen_flight(cut.id)
        except StorageError as exc:
            self._down(exc, sample.time_s)
            return None
        self.resumed = record.id
        _log.info(
            "flight %d of engine %s resumed after a restart (%.0f s since its checkpoint)", cut.id, self.serial, gap_s
        )
        return _OpenFlight.resume(record, reversals, sample, self.rules.cycle_hysteresis_c, self.wear)

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
        if STATE_CONCERN.get(sample.state, 0) > STATE_CONCERN.get(flight.worst_state, 0):
            flight.worst_state = sample.state
        region = region_of(sample.time_s - flight.start_time_s, sample.airspeed_mps, sample.power)
        if math.isfinite(sample.power):
            flight.high_power_s = (flight.high_power_s or 0.0) + (dt if region == REGION_HIGH else 0.0)
        phase = flight.phases[region]
        phase.seconds += dt
        if sample.state not in _NOT_ESTIMATING:
            flight.wear.add(sample.cht_c, sample.model_c, sample.oat_c)
            phase.add(sample)
        for name, moments in flight.trends.items():
            moments.add(sample.time_s - flight.start_time_s, sample.trends[name])
        if sample.cylinders:
            if len(flight.cylinders) != len(sample.cylinders):
                flight.cylinders = [_CylinderFlight(n) for n in range(1, len(sample.cylinders) + 1)]
            t_s = sample.time_s - flight.start_time_s
            for cyl, (cht_c, trends, state) in zip(flight.cylinders, sample.cylinders, strict=True):
                cyl.add(t_s, dt, cht_c, trends, state)
            if math.isfinite(sample.cht_spread_c):
                flight.spread_max_c = max(flight.spread_max_c, sample.cht_spread_c)
            if sample.spread_alarm:
                flight.spread_alarm_s += dt
            if sample.hottest_cylinder:
                flight.hottest_s[sample.hottest_cylinder] = flight.hottest_s.get(sample.hottest_cylinder, 0.0) + dt

    def _finish(self, reason: str, now_s: float) -> int | None:
        flight = self._flight
        if flight is None:
            return None
        self._flight = None
        duration_s = flight.last_running_time_s - flight.start_time_s
        if duration_s < self.rules.min_flight_s:
            if self.history_fault is not None or not self._write(flight, None, now_s):
                self._unsaved.append((flight, None))
            _log.info("engine run of %.0f s not kept (shorter than %.0f s)", duration_s, self.rules.min_flight_s)
            return None
        values = flight.values(end_running=True)
        values.update(status="finished", end_reason=reason)
        if self.history_fault is not None or not self._write(flight, values, now_s):
            self._unsaved.append((flight, values))
            _log.info("flight of engine %s finished (%s, %.0f s): kept in memory", self.serial, reason, duration_s)
            return None
        assert flight.flight_id is not None
        self.finished.append(flight.flight_id)
        _log.info("flight %d of engine %s finished (%s, %.0f s)", flight.flight_id, self.serial, reason, duration_s)
        try:
            self._check_wear()
        except StorageError as exc:
            self._down(exc, now_s)
        return flight.flight_id

    def _check_wear(self) -> None:
        """Run the across-flight detector after a flight; store an alert it raises (once while open)."""
        store = self._connected()
        if store.alerts(self.serial, open_only=True):
            return
        result = engine_wear(store, self.serial, self.wear, self.reference)
        alert = result.alert()
        if alert is None:
            return
        alert = dataclasses.replace(alert, id=store.raise_alert(alert))
        self.alerts.append(alert)
        _log.warning("%s (CUSUM %.1f >= %.1f)", alert.text, alert.statistic, alert.threshold)

    def close(self, reason: str = "service_stop") -> int | None:
        """Finish the flight in progress (service stop); returns its id if it was written. Flights the
        history could not take by then are lost with the process: logged."""
        now_s = math.inf
        if self.history_fault is not None:
            self._sync(now_s)
        flight_id = self._finish(reason, now_s)
        lost = [f for f, values in self._unsaved if values is not None]
        if lost:
            _log.error("%d flight(s) not written to the history (%s)", len(lost), self.history_fault)
        return flight_id


@dataclass(frozen=True)
class EngineWear:
    """The across-flight detector over one engine's flights since its last cleared alert (oldest first)."""

    serial: str
    flights: tuple[FlightRecord, ...]
    verdict: WearVerdict

    def alert(self) -> MaintenanceAlert | None:
        """The alert the verdict raises (id 0: not stored yet), None without one."""
        at, reference = self.verdict.alert_at, self.verdict.reference
        if at is None or reference is None:
            return None
        flight = self.flights[at]
        return MaintenanceAlert(
            id=0,
            engine_serial=self.serial,
            flight_id=flight.id,
            raised_utc=time.time(),
            wear_index=float(flight.wear_index or 0.0),
            statistic=float(self.verdict.statistic[at] or 0.0),
            threshold=self.verdict.threshold,
            reference_mean=reference.mean,
            reference_sd=reference.sd,
            reference_flights=reference.flights,
            reference_learned=self.verdict.learned,
            cleared_utc=None,
        )


def engine_wear(
    store: StateStore, serial: str, settings: WearSettings, reference: WearReference | None = None
) -> EngineWear:
    """The across-flight detector over ``serial``'s finished and recovered flights since its last cleared alert."""
    cleared = [a.cleared_utc for a in store.alerts(serial) if a.cleared_utc is not None]
    since = max(cleared, default=-math.inf)
    flights = tuple(r for r in store.flights(serial) if r.start_utc > since)
    return EngineWear(serial, flights, wear_verdict([r.wear_index for r in flights], settings, reference))
