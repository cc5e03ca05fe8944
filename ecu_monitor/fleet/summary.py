"""One log of one engine -> its flights' summaries and engine events (one Dask task; no Dask here).

A flight log (canonical or foreign CSV, CAN log, MAVLink ``.tlog``) is replayed through the service's
pipeline in one compiled call (:mod:`ecu_monitor.offline.replay`, as ``ecu-monitor replay``) with its
engine's config, model and detector, and summarised as one flight: time in each operating region (the
regions of estimation/regions.py: ``high power`` is the time at power), max CHT per cylinder and time above
the model's CHT limit, gamma_Q / gamma_D (mean and last), the wear index (estimation/wear.py's
:class:`FlightWear` over what the replay fed its open-loop reference, the rule the daemon's flight history
keeps), the worst state, the time SUSPECT or DEGRADED and the engine events. A daemon's flight database
(``ecu-monitor.sqlite3``) gives its finished flights as the daemon summarised them.

A bad log raises :class:`~ecu_monitor.errors.UserInputError` (the fleet writes one failure row).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ecu_monitor.config import MODEL_PRESETS
from ecu_monitor.errors import ConfigError, FlightLogError
from ecu_monitor.fleet.spec import EngineSettings, LogJob

__all__ = ["DATABASE_SUFFIXES", "FLIGHT_FIELDS", "LogSummary", "engine_setup", "summarise_log"]

#: Suffixes of a daemon's flight database.
DATABASE_SUFFIXES = (".sqlite3", ".sqlite", ".db")
#: A UNIX clock starts later than this (2001-09-09), s: a log stamped so has a start time.
_UNIX_TIME_S = 1e9
#: Longest gap between two rows that still counts as covered time, s.
_MAX_ROW_GAP_S = 2.0

#: The columns of a flight row (the flights dataset, besides the serial) and their meaning.
FLIGHT_FIELDS: dict[str, str] = {
    "log": "the log's path relative to FLEET.yaml's folder (absolute outside it)",
    "key": "sha256 of the log's content and the engine's settings (24 hex digits)",
    "flight": "the flight's number in the log (1; a daemon database: its flight id)",
    "position": "the log's position in the engine's listing (globs in order, each sorted)",
    "start_utc": "UNIX time of the first row (s), when the log runs on a UNIX clock; else null",
    "duration_s": "time covered by the health rows, s",
    "ground_s": "time in the ground region, s",
    "low_power_s": "time at low power, s",
    "cruise_power_s": "time at cruise power, s",
    "high_power_s": "time at high power, s",
    "max_cht_c": "the highest CHT read on any cylinder, degC",
    "max_cht_cyl_c": "the highest CHT of each cylinder, degC (one for an engine with one CHT channel)",
    "time_above_limit_s": "time with the CHT above the model's limit, s",
    "gamma_q_mean": "mean heat-input factor gamma_Q estimate",
    "gamma_q_end": "last gamma_Q estimate",
    "gamma_d_mean": "mean dissipation factor gamma_D estimate",
    "gamma_d_end": "last gamma_D estimate",
    "wear_index": "the flight's wear index (estimation/wear.py), null with too few samples",
    "worst_state": "the worst health state of the flight",
    "degraded_s": "time SUSPECT or DEGRADED, s",
    "first_degraded_s": "first DEGRADED row, s from the start (null: never)",
    "events": "engine events in the flight",
}
_REGION_COLUMNS = {"ground": "ground_s", "low power": "low_power_s", "cruise power": "cruise_power_s",
                   "high power": "high_power_s"}  # fmt: skip


@dataclass
class LogSummary:
    """What one task returns: the log's flights (rows of FLIGHT_FIELDS) and events (rows of the events table)."""

    job: LogJob
    flights: list[dict[str, Any]] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)
    cpu_s: float = 0.0


@functools.lru_cache(maxsize=64)
def engine_setup(engine: EngineSettings) -> tuple[Any, tuple[Any, ...]]:
    """The engine's service config (its detector file merged in) and one model per CHT channel; cached per
    worker process, so each engine's config and DBC are read once."""
    from ecu_monitor.config import load_config, parse_config
    from ecu_monitor.model import load_model
    from ecu_monitor.yamlfile import load_yaml_file

    if engine.detector is None:
        config = load_config(engine.config)
    else:
        data = load_yaml_file(engine.config, "config file", ConfigError)
        fragment = load_yaml_file(engine.detector, "detector file", ConfigError)
        if not isinstance(data, dict) or not isinstance(fragment, dict):
            raise ConfigError(f"{engine.detector}: expected a mapping (what ecu-monitor calibrate --out writes)")
        for key, value in fragment.items():
            merge = key in ("wear", "cylinders") and isinstance(value, dict) and isinstance(data.get(key), dict)
            data[key] = {**data[key], **value} if merge else value
        config = parse_config(data, engine.config)
    if engine.model is None:
        return config, config.load_cylinder_params()
    config = config.replace(model=engine.model, cylinder_models=())
    params = config.load_params() if engine.model in MODEL_PRESETS else load_model(engine.model)
    return config, (params,) * len(config.cylinder_inputs)


def summarise_log(job: LogJob, engine: EngineSettings) -> LogSummary:
    """Replay and summarise one log (module docstring); UserInputError for a bad log."""
    import time

    started = time.process_time()
    suffix = job.path.suffix.lower()
    if suffix in DATABASE_SUFFIXES:
        summary = _database(job)
    else:
        summary = _replay(job, engine, suffix)
    summary.cpu_s = time.process_time() - started
    return summary


def _replay(job: LogJob, engine: EngineSettings, suffix: str) -> LogSummary:
    from ecu_monitor.bus.canlog import CAN_LOG_SUFFIXES, load_flight, read_frames
    from ecu_monitor.estimation.wear import FlightWear
    from ecu_monitor.offline.replay import frames_from_flight, replay_frames, replay_tlog
    from ecu_monitor.pipeline.engine import model_input_names

    config, models = engine_setup(engine)
    clock: float | None = None  # the log's first stamp, on its own clock
    logged: list[float | None] = []  # each cylinder's max CHT as a flight CSV logged it (cht1_c ..)
    if suffix == ".tlog":
        from ecu_monitor.bus.mavlink_log import iter_tlog

        clock = next((time_s for time_s, _ in iter_tlog(job.path)), None)
        result = replay_tlog(job.path, config, models, keep_feeds=True, keep_reference=True)
    elif suffix in CAN_LOG_SUFFIXES:
        result = replay_frames(config, models, read_frames(job.path), keep_feeds=True, keep_reference=True)
        clock = _first_can_stamp(job.path)
    elif suffix == ".csv":
        from ecu_monitor.flightlog import cylinder_columns

        log = load_flight(job.path, mapping=engine.mapping, engine=engine.engine)
        logged = [_finite_max(log[name]) for name in cylinder_columns(log, "cht")]
        needed = (*model_input_names(models[0], config.input_names), *config.cylinder_inputs)
        frames = frames_from_flight(log, config, needed)
        result = replay_frames(config, models, frames, keep_feeds=True, keep_reference=True)
    else:
        known = ", ".join((".csv", ".tlog", *CAN_LOG_SUFFIXES, *DATABASE_SUFFIXES))
        raise FlightLogError(f"{job.name}: unknown log format '{suffix}' (expected {known})")
    if len(result) == 0:
        raise FlightLogError(f"{job.name}: nothing to replay: no health period of the mapped inputs")
    wear = FlightWear(config.wear)
    for feed in result.reference_feed:
        wear.add_many(feed.cht_c, feed.model_c, feed.oat_c)
    start_utc = clock if clock is not None and clock > _UNIX_TIME_S else None
    flight = _flight_row(job, result, models[0].cht_limit_c, wear.index, start_utc, logged)
    t0 = float(result.columns["time_s"][0])
    events = [
        {"log": job.name, "key": job.key, "flight": 1, "time_s": e.time_s - t0, "kind": e.kind,
         "cylinder": int(e.cylinder), "value": float(e.value), "limit": float(e.limit),
         "duration_s": float(e.duration_s)}
        for e in result.events
    ]  # fmt: skip
    return LogSummary(job, [flight], events)


def _flight_row(
    job: LogJob,
    result: Any,
    cht_limit_c: float,
    wear_index: float | None,
    start_utc: float | None,
    logged: Sequence[float | None] = (),
) -> dict[str, Any]:
    """The flight row of a replay (FLIGHT_FIELDS); ``start_utc``: the log's first stamp on a UNIX clock;
    ``logged``: each cylinder's max CHT in the log, when it has more cylinders than the replay monitors."""
    from ecu_monitor.estimation.regions import REGION_NAMES
    from ecu_monitor.pipeline.output_table import STATE_CONCERN, STATES

    c = result.columns
    time_s = np.asarray(c["time_s"], dtype=np.float64)
    dt = _row_seconds(time_s)
    count = result.cylinder_count
    cht_names = ["cht_meas_c"] if count == 1 else [f"cyl{n}_cht_meas_c" for n in range(1, count + 1)]
    per_cylinder = [_finite_max(c[name]) for name in cht_names]
    if len(logged) > len(per_cylinder):  # a CSV with every cylinder replayed on one channel (their mean)
        per_cylinder = list(logged)
    hottest = max((v for v in per_cylinder if v is not None), default=None)
    cht = np.asarray(c["cht_meas_c"], dtype=np.float64)
    states = np.asarray(c["state"])
    seen = {STATES[int(code)] for code in np.unique(states)}
    worst = max(seen, key=lambda s: STATE_CONCERN.get(s, 0)) if seen else "UNAVAILABLE"
    concern = np.isin(states, [STATES.index("SUSPECT"), STATES.index("DEGRADED")])
    degraded = np.flatnonzero(states == STATES.index("DEGRADED"))
    regions = dict.fromkeys(_REGION_COLUMNS.values(), 0.0)
    for (feed_time, _), region in zip(result.detector_feed, result.detector_regions, strict=False):
        seconds = _row_seconds(np.asarray(feed_time, dtype=np.float64))
        for index, name in enumerate(REGION_NAMES):
            if name in _REGION_COLUMNS:
                regions[_REGION_COLUMNS[name]] += float(seconds[region == index].sum())
    start = float(time_s[0])
    return {
        "log": job.name,
        "key": job.key,
        "flight": 1,
        "position": job.position,
        "start_utc": start_utc,
        "duration_s": float(dt.sum()),
        **regions,
        "max_cht_c": hottest,
        "max_cht_cyl_c": per_cylinder,
        "time_above_limit_s": float(dt[np.nan_to_num(cht, nan=-np.inf) > cht_limit_c].sum()),
        "gamma_q_mean": _finite_mean(c["gamma_q"]),
        "gamma_q_end": _finite_last(c["gamma_q"]),
        "gamma_d_mean": _finite_mean(c["gamma_d"]),
        "gamma_d_end": _finite_last(c["gamma_d"]),
        "wear_index": wear_index,
        "worst_state": worst,
        "degraded_s": float(dt[concern].sum()),
        "first_degraded_s": float(time_s[degraded[0]] - start) if degraded.size else None,
        "events": len(result.events),
    }


def _database(job: LogJob) -> LogSummary:
    """The finished flights of a daemon's flight database, as the daemon summarised them."""
    from ecu_monitor.runtime.persistence import DATABASE_NAME, StateStore

    if job.path.name != DATABASE_NAME:
        raise FlightLogError(f"{job.name}: a daemon's flight database is named {DATABASE_NAME}")
    with StateStore(job.path.parent, readonly=True) as store:
        records = [r for r in store.flights() if r.status != "running"]
    if not records:
        raise FlightLogError(f"{job.name}: no finished flight in this database")
    rows = []
    for r in records:
        phases = r.phases or {}
        per_cylinder = [c.get("max_cht_c") for c in (r.cylinders or {}).get("per_cylinder", [])]
        rows.append({
            "log": job.name,
            "key": job.key,
            "flight": int(r.id),
            "position": job.position,
            "start_utc": float(r.start_utc),
            "duration_s": float(r.duration_s),
            **{column: float((phases.get(name) or {}).get("seconds", 0.0)) for name, column in _REGION_COLUMNS.items()},
            "max_cht_c": r.max_cht_c,
            "max_cht_cyl_c": per_cylinder or [r.max_cht_c],
            "time_above_limit_s": float(r.time_above_limit_s),
            "gamma_q_mean": r.trends.get("gamma_q_mean"),
            "gamma_q_end": r.trends.get("gamma_q_end"),
            "gamma_d_mean": r.trends.get("gamma_d_mean"),
            "gamma_d_end": r.trends.get("gamma_d_end"),
            "wear_index": r.wear_index,
            "worst_state": r.worst_state,
            "degraded_s": float(r.time_degraded_s),
            "first_degraded_s": None,
            "events": 0,
        })  # fmt: skip
    return LogSummary(job, rows, [])


def _first_can_stamp(path: Path) -> float | None:
    """The stamp of a CAN log's first frame on the logger's own clock (read_frames counts from 0), s."""
    import can

    with can.LogReader(str(path)) as reader:
        for message in reader:
            return float(message.timestamp)
    return None


def _row_seconds(time_s: np.ndarray) -> np.ndarray:
    """Seconds each row covers: the step to the next row (the last: the median step), gaps over 2 s count 0."""
    if time_s.size < 2:
        return np.zeros(time_s.size)
    step = np.diff(time_s)
    step = np.append(step, np.median(step))
    return np.where((step > 0.0) & (step <= _MAX_ROW_GAP_S), step, 0.0)


def _finite_max(values: Sequence[float] | np.ndarray) -> float | None:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(v.max()) if v.size else None


def _finite_mean(values: Sequence[float] | np.ndarray) -> float | None:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else None


def _finite_last(values: Sequence[float] | np.ndarray) -> float | None:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(v[-1]) if v.size else None
