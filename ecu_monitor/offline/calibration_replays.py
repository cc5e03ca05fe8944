"""The user's nominal flights through the service's replay, for calibration: the detector's feed of each
flight, nominal and with degradations overlaid on its CHT (``ecu-monitor calibrate``; offline/calibration.py
sets the threshold and chooses the settings from these)."""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.bus.canlog import FrameArrays, load_flight, read_frames
from ecu_monitor.config import ServiceConfig
from ecu_monitor.errors import FlightLogError
from ecu_monitor.estimation.detection import DetectorSettings, cusum_path, overlay_degradation
from ecu_monitor.flightlog import FlightLog, choose_cht
from ecu_monitor.model import ThermalParams
from ecu_monitor.offline.replay import ReplayResult, frames_from_flight, replay_file, replay_frames
from ecu_monitor.pipeline.engine import model_input_names
from ecu_monitor.pipeline.outputs import ReferenceFeed

__all__ = [
    "AIRBORNE_MPS",
    "MIN_AIRBORNE_S",
    "ONSET_FRACTIONS",
    "OVERLAY_TARGETS_S",
    "OVERLAY_TIME_CONSTANT_S",
    "UNBOUNDED_THRESHOLD",
    "Feed",
    "FlightFeeds",
    "FlightStatistic",
    "OverlayRun",
    "airborne_onsets",
    "flight_feeds",
    "flight_statistic",
    "nominal_feeds",
    "overlay_replays",
    "statistic_paths",
]

#: The threshold of the "no alarm" CUSUM run for calibration (as research.evaluation.score).
UNBOUNDED_THRESHOLD = 1e300
#: Overlay gain k -> the time within which its onset must be detected, s (issue targets).
OVERLAY_TARGETS_S: dict[float, float] = {0.2: 300.0, 0.1: 600.0}
#: Time constant of the overlaid degradation, s (the head's response).
OVERLAY_TIME_CONSTANT_S = 240.0
#: Airspeed above which a sample counts as airborne, m/s (about 29 kt: above taxi speeds, below flight speeds).
AIRBORNE_MPS = 15.0
#: Onsets at these fractions of the span [max(take-off, end of warm-up), landing - 600 s].
ONSET_FRACTIONS: tuple[float, ...] = (0.1, 0.4, 0.7)
#: A flight takes part in the cross-validation when that span is at least this long, s.
MIN_AIRBORNE_S = 900.0


Feed = tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...]


@dataclass(frozen=True)
class FlightStatistic:
    """One nominal flight through the service's detector path.

    name: the file name. hours: span of the replay's health rows, h. paths: per clock segment, (block
    end times s, CUSUM statistic after each block) run without alarms. start_s: time of the first
    health row (replay's summary counts its "DEGRADED from t=" from there). alarm_times_s: where the
    configured threshold is crossed with a restart after each crossing (each crossing one false alarm);
    the live detector latches at the first one.
    """

    name: str
    hours: float
    paths: tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...]
    start_s: float
    alarm_times_s: NDArray[np.float64]

    @property
    def max_statistic(self) -> float:
        """Largest value of the statistic over the flight (0 when the warm-up covers it)."""
        values = [float(np.max(stat)) for _, stat in self.paths if stat.size]
        return max(values, default=0.0)

    def whole_hours(self, block_s: float) -> int:
        """Whole hours of statistic (after the warm-up) that calibrate_threshold uses."""
        per_hour = round(3600.0 / block_s)
        return sum(stat.size // per_hour for _, stat in self.paths)


def statistic_paths(
    result: ReplayResult, settings: DetectorSettings
) -> tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...]:
    """The CUSUM statistic without alarms over what the replay fed its detector: per clock segment,
    (block end times s, statistic). Same blocks, warm-up and baseline as the service's detector."""
    unbounded = dataclasses.replace(settings, threshold=UNBOUNDED_THRESHOLD)
    paths = []
    for time_s, symptom in result.detector_feed:
        ends, stat, _ = cusum_path(time_s, symptom, unbounded)
        paths.append((ends, stat))
    return tuple(paths)


def flight_statistic(path: str | os.PathLike[str], config: ServiceConfig, params: ThermalParams) -> FlightStatistic:
    """Replay one flight (canonical CSV or python-can log) and collect its detector statistic."""
    return nominal_feeds(path, replay_file(path, config, params, keep_feeds=True), math.nan, ()).statistic_for(
        config.detector
    )


def nominal_feeds(
    path: str | os.PathLike[str], result: ReplayResult, log_start_s: float, overlays: tuple[OverlayRun, ...]
) -> FlightFeeds:
    time_s = result.columns["time_s"]
    if time_s.size == 0 or not result.detector_feed:
        raise FlightLogError(f"{path}: the service's estimator never started on this log (no usable CHT and inputs)")
    return FlightFeeds(
        Path(path).name,
        result.detector_feed,
        float(time_s[0]),
        float(time_s[-1]),
        log_start_s,
        overlays,
        result.reference_feed,
        result.detector_regions,
        result.start_fits,
    )


@dataclass(frozen=True)
class OverlayRun:
    """A replay of a flight with a degradation overlaid: onset_s (s after the log's first sample),
    gain k, and what the replay fed the detector (per clock segment, (time s, symptom)); reference: the
    replay's open-loop reference per clock segment, when kept (``keep_reference``; else empty)."""

    onset_s: float
    gain: float
    feed: Feed
    reference: tuple[ReferenceFeed, ...] = ()


@dataclass(frozen=True)
class FlightFeeds:
    """One nominal flight through the service's replay: name (the file's), what the replay fed the
    detector (per clock segment, (time s, symptom)), the times of its first and last health rows, s,
    the log's first time, s, and the replays with overlays (empty when not asked or when the flight
    has no room for onsets, see :func:`airborne_onsets`); reference: the nominal replay's open-loop
    reference per clock segment, when kept (``keep_reference``; else empty); regions: the operating region
    of each step of the feed (per clock segment); start_fits: the start fits at each clock segment's end
    (pipeline/step.py, START_FIT_NAMES order)."""

    name: str
    feed: Feed
    first_row_s: float
    last_row_s: float
    log_start_s: float
    overlays: tuple[OverlayRun, ...]
    reference: tuple[ReferenceFeed, ...] = ()
    regions: tuple[NDArray[np.int64], ...] = ()
    start_fits: tuple[NDArray[np.float64], ...] = ()

    def statistic_for(self, settings: DetectorSettings) -> FlightStatistic:
        """The flight's detector statistic with these settings (no new replay)."""
        unbounded = dataclasses.replace(settings, threshold=UNBOUNDED_THRESHOLD)
        paths = tuple(cusum_path(t, x, unbounded)[:2] for t, x in self.feed)
        alarms = [cusum_path(t, x, settings, restart=True)[2] for t, x in self.feed]
        return FlightStatistic(
            name=self.name,
            hours=(self.last_row_s - self.first_row_s) / 3600.0,
            paths=paths,
            start_s=self.first_row_s,
            alarm_times_s=np.concatenate(alarms) if alarms else np.empty(0),
        )


def airborne_onsets(log: FlightLog, warmup_s: float) -> NDArray[np.float64]:
    """Overlay onsets, s after the log's first sample: :data:`ONSET_FRACTIONS` of the span from the
    later of the take-off (first airspeed >= :data:`AIRBORNE_MPS`) and the end of the warm-up to 600 s
    before the landing (last such sample). Empty when the span is shorter than :data:`MIN_AIRBORNE_S`.
    Without an airspeed column the whole log counts as airborne."""
    t = log.time_s
    if t.size < 2:
        return np.empty(0)
    if log.has("airspeed_mps"):
        flying = np.flatnonzero(np.nan_to_num(log["airspeed_mps"], nan=0.0) >= AIRBORNE_MPS)
        if flying.size == 0:
            return np.empty(0)
        take_off, landing = float(t[flying[0]] - t[0]), float(t[flying[-1]] - t[0])
    else:
        take_off, landing = 0.0, float(t[-1] - t[0])
    begin = max(take_off, warmup_s)
    end = landing - max(OVERLAY_TARGETS_S.values())
    if end - begin < MIN_AIRBORNE_S:
        return np.empty(0)
    return begin + (end - begin) * np.asarray(ONSET_FRACTIONS, dtype=float)


def overlay_replays(
    log: FlightLog,
    config: ServiceConfig,
    params: ThermalParams,
    overlays: Sequence[tuple[float, float]],
    nominal: FrameArrays | None = None,
    *,
    keep_reference: bool = False,
) -> list[ReplayResult]:
    """Replays of ``log`` with each (onset s after the first sample, gain k) overlaid on its CHT
    (:func:`overlay_degradation`, :data:`OVERLAY_TIME_CONSTANT_S`). ``nominal``: the log's frames
    (:func:`frames_from_flight`, built here when None). Only the message that carries the CHT is
    re-encoded from the overlaid log (with every signal it holds) and merged back in time order, so an
    overlay costs one replay and one message's encoding, not the whole flight's. ``keep_reference``: as
    :func:`replay_frames`."""
    if nominal is None:
        nominal = frames_from_flight(log, config, (*model_input_names(params, config.input_names), "cht_c"))
    cht_message = config.input("cht_c").message
    with_cht = [spec.name for spec in config.inputs if spec.message == cht_message and log.has(spec.name)]
    probe = FlightLog({"time_s": log.time_s[:2], "cht_c": log["cht_c"][:2]})
    cht_id = int(frames_from_flight(probe, config, ["cht_c"]).arbitration_id[0])
    others = nominal.take(nominal.arbitration_id != cht_id)
    t = log.time_s
    results = []
    for onset_s, gain in overlays:
        cht = overlay_degradation(t, log["cht_c"], log["oat_c"], float(t[0] + onset_s), gain, OVERLAY_TIME_CONSTANT_S)
        part = FlightLog({"time_s": t, **{n: (cht if n == "cht_c" else log[n]) for n in with_cht}})
        patched = frames_from_flight(part, config, ["cht_c"])
        merged = FrameArrays(*(np.concatenate([a, b]) for a, b in zip(others, patched, strict=True)))
        ordered = merged.take(np.argsort(merged.time_s, kind="stable"))
        results.append(replay_frames(config, params, ordered, keep_feeds=True, keep_reference=keep_reference))
    return results


def flight_feeds(
    path: str | os.PathLike[str],
    config: ServiceConfig,
    params: ThermalParams,
    *,
    overlays: bool = True,
    cylinder: int | None = None,
    keep_reference: bool = False,
) -> FlightFeeds:
    """Replay one nominal flight (canonical CSV or CAN log, decoded with the config's DBCs) nominal and,
    if ``overlays``, with each gain of :data:`OVERLAY_TARGETS_S` at each of :func:`airborne_onsets`.
    ``cylinder``: the log's ``cht<cylinder>_c`` is its CHT (``config`` then maps that cylinder's probe
    as ``cht_c``, see :func:`ecu_monitor.offline.calibration.cylinder_config`). ``keep_reference``: keep
    each replay's open-loop reference too (:func:`replay_frames`; for offline analyses)."""
    if Path(path).suffix.lower() == ".csv":
        log = load_flight(path)
        if cylinder is not None:
            log = choose_cht(log, cylinder)
        frames = frames_from_flight(log, config, (*model_input_names(params, config.input_names), "cht_c"))
    else:  # the log's own frames for the nominal replay; its decoded signals for the overlays
        log = load_flight(path, dbc_paths=config.dbc_paths)
        if cylinder is not None:
            log = choose_cht(log, cylinder)
        frames = read_frames(path)
    result = replay_frames(config, params, frames, keep_feeds=True, keep_reference=keep_reference)
    nominal_feeds(path, result, math.nan, ())  # a log the estimator never starts on: one line, before the overlays
    runs: list[OverlayRun] = []
    if overlays:
        onsets = airborne_onsets(log, config.detector.warmup_s)
        pairs = [(float(t0), k) for t0 in onsets for k in OVERLAY_TARGETS_S]
        replays = overlay_replays(log, config, params, pairs, frames, keep_reference=keep_reference)
        for (t0, k), res in zip(pairs, replays, strict=True):
            runs.append(OverlayRun(t0, k, res.detector_feed, res.reference_feed))
    return nominal_feeds(path, result, float(log.time_s[0]), tuple(runs))
