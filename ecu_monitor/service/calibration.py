"""Calibrating the detector's threshold on a user's own nominal flights (``ecu-monitor calibrate``).

Each flight goes through the replay's batch path (:func:`~ecu_monitor.service.replay.replay_file`:
the same decoding, supervision, estimator, symptom, warm-up and baseline as the service), and the
detector's input (:attr:`ReplayResult.detector_feed`) is run through
:func:`~ecu_monitor.estimation.detection.cusum_path` with no alarm (threshold 1e300, as
``ecu-monitor evaluate`` calibrates). :func:`~ecu_monitor.estimation.detection.calibrate_threshold`
then fits the hourly maxima of these paths for the asked false-alarm rate.

Before the threshold, :func:`choose_settings` chooses the detector's adaptive-baseline length from
:data:`BASELINE_CANDIDATES_S` by cross-validation on the same flights: for each candidate, each
flight in turn is held out, h is calibrated on the others, the held-out flight must raise no alarm
nominal, and degradations overlaid on it (:func:`~ecu_monitor.estimation.detection.overlay_degradation`,
k = 0.2 and 0.1, tau 240 s, onsets spread over its airborne part) must be detected within 300 s and
600 s. The rule: the fewest false alarms (none, if any candidate has none), then the most
detections within these times, then the most for k = 0.1, then the shorter baseline. With fewer than
:data:`MIN_CROSS_FLIGHTS` flights that have room for the overlays, the config's settings are kept
(today's behaviour).

Helpers write the result as a ``detector:`` YAML fragment, or as a full copy of the service config
with the detector settings replaced (relative paths made absolute, so the copy loads from anywhere).
"""

from __future__ import annotations

import dataclasses
import datetime
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from ecu_monitor.bus.canlog import FrameArrays, load_flight, read_frames
from ecu_monitor.errors import ConfigError, FlightLogError, ParameterError
from ecu_monitor.estimation.detection import (
    DetectorSettings,
    ThresholdCalibration,
    block_means,
    calibrate_threshold,
    cusum_path,
    overlay_degradation,
)
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.model import ThermalParams
from ecu_monitor.service.config import MODEL_PRESETS, ServiceConfig
from ecu_monitor.service.pipeline import model_input_names
from ecu_monitor.service.replay import ReplayResult, frames_from_flight, replay_file, replay_frames
from ecu_monitor.shipped import resolve_file, shipped_file

__all__ = [
    "AIRBORNE_MPS",
    "BASELINE_CANDIDATES_S",
    "MIN_AIRBORNE_S",
    "MIN_CROSS_FLIGHTS",
    "MIN_WHOLE_HOURS",
    "ONSET_FRACTIONS",
    "OVERLAY_TARGETS_S",
    "OVERLAY_TIME_CONSTANT_S",
    "UNBOUNDED_THRESHOLD",
    "CalibrationResult",
    "CandidateScore",
    "FlightFeeds",
    "FlightStatistic",
    "OverlayRun",
    "SettingsChoice",
    "airborne_onsets",
    "calibrate_flights",
    "calibration_method",
    "choose_settings",
    "config_copy_yaml",
    "cross_validation_blocker",
    "detector_fragment_yaml",
    "flight_feeds",
    "flight_statistic",
    "overlay_replays",
    "score_candidate",
    "statistic_paths",
]

#: calibrate_threshold needs at least this many whole hours of statistic.
MIN_WHOLE_HOURS = 2
#: The threshold of the "no alarm" CUSUM run for calibration (as research.evaluation.score).
UNBOUNDED_THRESHOLD = 1e300
#: Candidate lengths of the detector's adaptive baseline, s (cross-validated by :func:`choose_settings`).
BASELINE_CANDIDATES_S: tuple[float, ...] = (120.0, 300.0, 600.0, 1200.0)
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
#: Cross-validation needs at least this many such flights (one held out, h calibrated on the others).
MIN_CROSS_FLIGHTS = 3


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


@dataclass(frozen=True)
class CalibrationResult:
    """The calibrated threshold with what it rests on; ``method`` from :func:`calibration_method`."""

    calibration: ThresholdCalibration
    method: str
    flights: tuple[FlightStatistic, ...]
    current: DetectorSettings
    choice: SettingsChoice | None = None

    @property
    def hours(self) -> float:
        """Flight hours given (the spans of the flights)."""
        return sum(f.hours for f in self.flights)


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
    return _nominal(path, replay_file(path, config, params), math.nan, ()).statistic_for(config.detector)


def _nominal(
    path: str | os.PathLike[str], result: ReplayResult, log_start_s: float, overlays: tuple[OverlayRun, ...]
) -> FlightFeeds:
    time_s = result.columns["time_s"]
    if time_s.size == 0 or not result.detector_feed:
        raise FlightLogError(f"{path}: the service's estimator never started on this log (no usable CHT and inputs)")
    return FlightFeeds(
        Path(path).name, result.detector_feed, float(time_s[0]), float(time_s[-1]), log_start_s, overlays
    )


Feed = tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...]


@dataclass(frozen=True)
class OverlayRun:
    """A replay of a flight with a degradation overlaid: onset_s (s after the log's first sample),
    gain k, and what the replay fed the detector (per clock segment, (time s, symptom))."""

    onset_s: float
    gain: float
    feed: Feed


@dataclass(frozen=True)
class FlightFeeds:
    """One nominal flight through the service's replay: name (the file's), what the replay fed the
    detector (per clock segment, (time s, symptom)), the times of its first and last health rows, s,
    the log's first time, s, and the replays with overlays (empty when not asked or when the flight
    has no room for onsets, see :func:`airborne_onsets`)."""

    name: str
    feed: Feed
    first_row_s: float
    last_row_s: float
    log_start_s: float
    overlays: tuple[OverlayRun, ...]

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
) -> list[ReplayResult]:
    """Replays of ``log`` with each (onset s after the first sample, gain k) overlaid on its CHT
    (:func:`overlay_degradation`, :data:`OVERLAY_TIME_CONSTANT_S`). ``nominal``: the log's frames
    (:func:`frames_from_flight`, built here when None). Only the message that carries the CHT is
    re-encoded from the overlaid log (with every signal it holds) and merged back in time order, so an
    overlay costs one replay and one message's encoding, not the whole flight's."""
    if nominal is None:
        nominal = frames_from_flight(log, config, (*model_input_names(params), "cht_c"))
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
        results.append(replay_frames(config, params, merged.take(np.argsort(merged.time_s, kind="stable"))))
    return results


def flight_feeds(
    path: str | os.PathLike[str], config: ServiceConfig, params: ThermalParams, *, overlays: bool = True
) -> FlightFeeds:
    """Replay one nominal flight (canonical CSV or CAN log, decoded with the config's DBCs) nominal and,
    if ``overlays``, with each gain of :data:`OVERLAY_TARGETS_S` at each of :func:`airborne_onsets`."""
    if Path(path).suffix.lower() == ".csv":
        log = load_flight(path)
        frames = frames_from_flight(log, config, (*model_input_names(params), "cht_c"))
    else:  # the log's own frames for the nominal replay; its decoded signals for the overlays
        log = load_flight(path, dbc_paths=config.dbc_paths)
        frames = read_frames(path)
    result = replay_frames(config, params, frames)
    _nominal(path, result, math.nan, ())  # a log the estimator never starts on: one line, before the overlays
    runs: list[OverlayRun] = []
    if overlays:
        onsets = airborne_onsets(log, config.detector.warmup_s)
        pairs = [(float(t0), k) for t0 in onsets for k in OVERLAY_TARGETS_S]
        for (t0, k), res in zip(pairs, overlay_replays(log, config, params, pairs, frames), strict=True):
            runs.append(OverlayRun(t0, k, res.detector_feed))
    return _nominal(path, result, float(log.time_s[0]), tuple(runs))


def cross_validation_blocker(flights: Sequence[FlightFeeds], settings: DetectorSettings) -> str | None:
    """Why the flights cannot be cross-validated (checked on the nominal replays, before any overlay
    is replayed), or None: fewer than :data:`MIN_CROSS_FLIGHTS` flights, or a fold whose other flights
    give fewer than :data:`MIN_WHOLE_HOURS` whole hours of statistic."""
    if len(flights) < MIN_CROSS_FLIGHTS:
        return f"{len(flights)} flight(s) given, cross-validation needs {MIN_CROSS_FLIGHTS}"
    per_hour = round(3600.0 / settings.block_s)
    whole = [sum(x.size // per_hour for _, x in _blocks(f.feed, settings)) for f in flights]
    for i, f in enumerate(flights):
        others = sum(whole) - whole[i]
        if others < MIN_WHOLE_HOURS:
            return (
                f"without {f.name} the other flights give {others} whole hour(s) of detector statistic;"
                f" cross-validation needs {MIN_WHOLE_HOURS} in each fold"
            )
    return None


def _blocks(feed: Feed, settings: DetectorSettings) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    return [block_means(t, x, settings) for t, x in feed]


@dataclass(frozen=True)
class CandidateScore:
    """One candidate's cross-validation: per held-out flight (in the order given) the threshold
    calibrated on the others and the first alarm on its nominal replay (s after the log's start, nan =
    none); per gain the detection delays of the overlays, s (inf = never, nan = an alarm before the
    onset)."""

    settings: DetectorSettings
    flights: tuple[str, ...]
    thresholds: tuple[float, ...]
    false_alarm_s: tuple[float, ...]
    delays: dict[float, tuple[float, ...]]

    @property
    def false_alarms(self) -> int:
        """Held-out nominal flights that went DEGRADED."""
        return int(np.sum(np.isfinite(self.false_alarm_s)))

    def hits(self, gain: float) -> int:
        """Overlays of ``gain`` detected within their target time."""
        return int(np.sum(np.asarray(self.delays[gain]) <= OVERLAY_TARGETS_S[gain]))

    def total(self, gain: float) -> int:
        """Overlays of ``gain`` tried."""
        return len(self.delays[gain])

    def median_delay(self, gain: float) -> float:
        """Median delay of the overlays of ``gain`` detected after their onset, s (inf: none)."""
        d = np.asarray(self.delays[gain], dtype=float)
        d = d[np.isfinite(d)]
        return float(np.median(d)) if d.size else math.inf

    @property
    def key(self) -> tuple[int, int, int, float]:
        """The rule's order (larger is better): no false alarm, detections in time, k = 0.1's, shorter baseline."""
        weakest = min(OVERLAY_TARGETS_S)
        hits = sum(self.hits(g) for g in OVERLAY_TARGETS_S)
        return (-self.false_alarms, hits, self.hits(weakest), -self.settings.baseline_s)


def score_candidate(flights: Sequence[FlightFeeds], settings: DetectorSettings, rate_per_100h: float) -> CandidateScore:
    """Leave-one-flight-out score of ``settings`` (its threshold ignored) over ``flights``.
    ParameterError when the flights left in a fold give fewer than :data:`MIN_WHOLE_HOURS` whole hours."""
    unbounded = dataclasses.replace(settings, threshold=UNBOUNDED_THRESHOLD)
    paths = [[cusum_path(t, x, unbounded)[1] for t, x in f.feed] for f in flights]
    thresholds, false_alarm_s = [], []
    delays: dict[float, list[float]] = {g: [] for g in OVERLAY_TARGETS_S}
    for i, held in enumerate(flights):
        others = [p for j, ps in enumerate(paths) if j != i for p in ps]
        whole = sum(p.size // round(3600.0 / settings.block_s) for p in others)
        if whole < MIN_WHOLE_HOURS:
            raise ParameterError(
                f"without {held.name} the other flights give {whole} whole hour(s) of detector statistic;"
                f" cross-validation needs {MIN_WHOLE_HOURS} in each fold"
            )
        h = calibrate_threshold(others, rate_per_100h, sample_period_s=settings.block_s).threshold
        tuned = dataclasses.replace(settings, threshold=h)
        thresholds.append(h)
        false_alarm_s.append(_first_alarm(held.feed, tuned) - held.log_start_s)
        for run in held.overlays:
            alarm = _first_alarm(run.feed, tuned) - held.log_start_s
            if alarm < run.onset_s:
                delays[run.gain].append(math.nan)
            else:
                delays[run.gain].append(alarm - run.onset_s)  # inf when never
    names = tuple(f.name for f in flights)
    return CandidateScore(
        settings, names, tuple(thresholds), tuple(false_alarm_s), {g: tuple(d) for g, d in delays.items()}
    )


def _first_alarm(feed: Feed, settings: DetectorSettings) -> float:
    """Time of the latched detector's first alarm over a feed, s (inf: none)."""
    times = [float(a[0]) for t, x in feed if (a := cusum_path(t, x, settings)[2]).size]
    return min(times, default=math.inf)


@dataclass(frozen=True)
class SettingsChoice:
    """What :func:`choose_settings` decided: the settings (threshold not yet calibrated), why, and the
    scores of the candidates (empty when not cross-validated)."""

    settings: DetectorSettings
    reason: str
    scores: tuple[CandidateScore, ...]
    cross_validated: bool


def choose_settings(
    flights: Sequence[FlightFeeds],
    current: DetectorSettings,
    rate_per_100h: float,
    baselines_s: Sequence[float] = BASELINE_CANDIDATES_S,
) -> SettingsChoice:
    """Choose the baseline length among ``baselines_s`` (other settings as ``current``) by
    leave-one-flight-out over the flights with overlays (:func:`score_candidate`). Rule: no false
    alarm on any held-out nominal flight, then the most overlays detected within their target time,
    then the most for k = 0.1, then the shorter baseline; when every candidate raises one, the fewest
    false alarms first (and the reason warns). Keeps ``current`` (and says why) with fewer than
    :data:`MIN_CROSS_FLIGHTS` flights, too few hours in a fold, or fewer than :data:`MIN_CROSS_FLIGHTS`
    flights with room for overlays."""
    blocker = cross_validation_blocker(flights, current)
    if blocker is not None:
        return SettingsChoice(current, f"{blocker}: kept the config's baseline_s {current.baseline_s:g} s", (), False)
    usable = [f for f in flights if f.overlays]
    if len(usable) < MIN_CROSS_FLIGHTS:
        return SettingsChoice(
            current,
            f"{len(usable)} flight(s) with at least {MIN_AIRBORNE_S / 60:g} min airborne after the warm-up"
            f" (cross-validation needs {MIN_CROSS_FLIGHTS}): kept the config's baseline_s {current.baseline_s:g} s",
            (),
            False,
        )
    try:
        scores = tuple(
            score_candidate(usable, dataclasses.replace(current, baseline_s=float(b)), rate_per_100h)
            for b in baselines_s
        )
    except ParameterError as exc:
        return SettingsChoice(current, f"{exc}: kept the config's baseline_s {current.baseline_s:g} s", (), False)
    best = max(scores, key=lambda s: s.key)
    rule = (
        "the fewest false alarms on the held-out flights, then the most overlays detected within target"
        " (k = 0.2 within 300 s, k = 0.1 within 600 s), then the most for k = 0.1, then the shorter baseline"
    )
    reason = f"baseline_s {best.settings.baseline_s:g} s by the rule: {rule}"
    if best.false_alarms:
        reason += (
            f". WARNING: every candidate raised a false alarm on at least {best.false_alarms} held-out flight(s)"
            f" (h from {len(usable) - 1} flights per fold): the model's error is large for this detector, or the"
            " flights too few; improve the model (identify, gap) or add nominal flights, and check on a flight"
            " kept out"
        )
    return SettingsChoice(best.settings, reason, scores, True)


def calibrate_flights(
    flights: Sequence[FlightStatistic],
    rate_per_100h: float,
    settings: DetectorSettings,
    choice: SettingsChoice | None = None,
) -> CalibrationResult:
    """Threshold for ``rate_per_100h`` false alarms per 100 flight hours from the flights' statistics.

    ParameterError (one line) when the flights give fewer than :data:`MIN_WHOLE_HOURS` whole hours.
    """
    if not (math.isfinite(rate_per_100h) and 0.0 < rate_per_100h < 100.0):
        raise ParameterError(f"--rate: expected false alarms per 100 h in (0, 100), got {rate_per_100h!r}")
    whole = sum(f.whole_hours(settings.block_s) for f in flights)
    if whole < MIN_WHOLE_HOURS:
        given = sum(f.hours for f in flights)
        raise ParameterError(
            f"{len(flights)} flight(s) give {given:.2f} flight hours, {whole} whole hour(s) of detector statistic "
            f"after the {settings.warmup_s:g} s warm-up of each flight; calibration needs at least {MIN_WHOLE_HOURS}"
            " whole hours: add nominal flights"
        )
    paths = [stat for f in flights for _, stat in f.paths]
    calibration = calibrate_threshold(paths, rate_per_100h, sample_period_s=settings.block_s)
    return CalibrationResult(calibration, calibration_method(calibration), tuple(flights), settings, choice)


def calibration_method(calibration: ThresholdCalibration, minimum: float = 1.0) -> str:
    """Which bound set the threshold: the Gumbel quantile, the empirical bound, or the floor."""
    c = calibration
    if c.threshold == c.gumbel_threshold and c.gumbel_threshold >= c.empirical_max:
        return "Gumbel quantile of the hourly maxima"
    if c.threshold == c.empirical_max:
        if c.hours * c.target_per_100h / 100.0 < 1.0:
            return "empirical bound: 1.1 x the largest statistic seen (fewer hours than one expected alarm)"
        return f"empirical {1.0 - c.target_per_100h / 100.0:.4g} quantile of the hourly maxima"
    return f"floor of {minimum:g} (the statistic barely leaves 0 on these flights)"


def _header(result: CalibrationResult, rate_per_100h: float, sources: Sequence[str]) -> list[str]:
    c = result.calibration
    today = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        f"# detector threshold calibrated by `ecu-monitor calibrate` on {today}",
        f"# for {rate_per_100h:g} false alarm(s) per 100 flight hours on {len(result.flights)} nominal flight(s),"
        f" {result.hours:.2f} flight hours ({c.hours} whole hours of statistic):",
    ]
    lines += [f"#   {source}" for source in sources]
    lines += [
        f"# method: {result.method}; Gumbel quantile {c.gumbel_threshold:.3f}, empirical bound {c.empirical_max:.3f}",
        f"# previous threshold: {result.current.threshold:g}",
    ]
    if result.choice is not None:
        how = "cross-validated" if result.choice.cross_validated else "not cross-validated"
        lines.append(f"# detector settings ({how}): {result.choice.reason}")
    if c.hours * rate_per_100h / 100.0 < 1.0:
        lines.append(
            f"# fewer than {100.0 / rate_per_100h:g} hours (one expected alarm): the rate is not demonstrated;"
            " the threshold is kept at or above 1.1 x the largest statistic seen on them"
        )
    return lines


def detector_fragment_yaml(
    result: CalibrationResult, symptom: str, rate_per_100h: float, sources: Sequence[str]
) -> str:
    """A ``detector:`` YAML fragment with comments, to merge into a service config: the symptom, the new
    threshold and every other detector setting it was calibrated with (a threshold holds only for the
    baseline, delay, reference, warm-up and block it was computed with; merging the whole block keeps
    them together)."""
    settings = dataclasses.replace(result.current, threshold=_rounded(result.calibration.threshold))
    body = yaml.safe_dump(
        {"detector": {"symptom": symptom, **dataclasses.asdict(settings)}},
        sort_keys=False,
        default_flow_style=False,
    )
    return "\n".join(_header(result, rate_per_100h, sources)) + "\n" + body


def config_copy_yaml(
    config_path: str | os.PathLike[str],
    result: CalibrationResult,
    rate_per_100h: float,
    sources: Sequence[str],
    model_path: str | os.PathLike[str] | None = None,
) -> str:
    """The service config at ``config_path`` with ``detector.threshold`` replaced (and ``model`` set to
    ``model_path`` if given, the model the threshold was calibrated with). Relative file paths (dbc,
    health_dbc, model, state_dir) are made absolute so the copy loads from any folder; names of shipped
    DBCs stay names. The original's comments are not kept (the YAML is re-emitted)."""
    src = resolve_file(config_path, "config")
    try:
        data = yaml.safe_load(src.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ConfigError(f"{src}: cannot read config file ({exc})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{src}: top level: expected a mapping")
    base = src.resolve().parent

    def absolute(value: Any) -> Any:
        if not isinstance(value, str):
            return value
        path = Path(os.path.expanduser(value))
        return str(path if path.is_absolute() else (base / path).resolve())

    def dbc(value: Any) -> Any:
        """A shipped DBC's name stays a name (unless a file of that name sits beside the config)."""
        if isinstance(value, str) and not (base / value).exists() and shipped_file("dbc", value) is not None:
            return value
        return absolute(value)

    if "dbc" in data:
        data["dbc"] = [dbc(v) for v in data["dbc"]] if isinstance(data["dbc"], list) else dbc(data["dbc"])
    if "health_dbc" in data:
        data["health_dbc"] = dbc(data["health_dbc"])
    if "state_dir" in data:
        data["state_dir"] = absolute(data["state_dir"])
    if model_path is not None:
        data["model"] = str(Path(model_path).resolve())
    elif isinstance(data.get("model"), str) and data["model"] not in MODEL_PRESETS:
        data["model"] = absolute(data["model"])
    detector = data.get("detector")
    detector = dict(detector) if isinstance(detector, dict) else {}
    detector["threshold"] = _rounded(result.calibration.threshold)
    detector["baseline_s"] = result.current.baseline_s
    data["detector"] = detector
    header = _header(result, rate_per_100h, sources)
    header.append(
        f"# copy of {src.resolve()} with detector.threshold and baseline_s replaced (comments of the original not kept)"
    )
    return "\n".join(header) + "\n" + yaml.safe_dump(data, sort_keys=False, default_flow_style=None)


def _rounded(value: float) -> float:
    """The threshold as written: 4 significant decimals up (never below the calibrated value)."""
    return math.ceil(value * 1e4) / 1e4
