"""Calibrating the detector's threshold on a user's own nominal flights (``ecu-monitor calibrate``).

Each flight goes through the replay's batch path (:func:`~ecu_monitor.offline.replay.replay_file`:
the same decoding, supervision, estimator, symptom, warm-up and baseline as the service), and the
detector's input (:attr:`ReplayResult.detector_feed`) is run through
:func:`~ecu_monitor.estimation.detection.cusum_path` with no alarm (threshold 1e300, as
``ecu-monitor evaluate`` calibrates). :func:`~ecu_monitor.estimation.detection.calibrate_threshold`
then fits the hourly maxima of these paths for the asked false-alarm rate.

Before the threshold, :func:`choose_settings` chooses the detector's adaptive baseline, its length
from :data:`BASELINE_CANDIDATES_S`, its delay from :data:`DELAY_CANDIDATES_S`, and whether it freezes
while a change is suspected (``baseline_freeze``), by cross-validation on the same flights: for each candidate, each
flight in turn is held out, h is calibrated on the others, the held-out flight must raise no alarm
nominal, and degradations overlaid on it (:func:`~ecu_monitor.estimation.detection.overlay_degradation`,
k = 0.2 and 0.1, tau 240 s, onsets spread over its airborne part) must be detected within 300 s and
600 s. The rule: the fewest false alarms (none, if any candidate has none), then the most
detections within these times, then the most for k = 0.1, then the shorter baseline, then the
longer delay, then no freeze. With fewer than :data:`MIN_CROSS_FLIGHTS` flights that have room for the overlays,
the config's settings are kept (today's behaviour).

Helpers write the result as a ``detector:`` YAML fragment, or as a full copy of the service config
with the detector settings replaced (relative paths made relative to the copy, so they move together).
"""

from __future__ import annotations

import dataclasses
import datetime
import hashlib
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from ecu_monitor.config import (
    CHT_INPUT,
    CYLINDER_HEALTH_MESSAGES,
    CYLINDER_INPUT,
    ServiceConfig,
    detector_section,
)
from ecu_monitor.errors import ConfigError, ParameterError
from ecu_monitor.estimation.detection import (
    DetectorSettings,
    ThresholdCalibration,
    block_means,
    calibrate_threshold,
    cusum_path,
)
from ecu_monitor.estimation.wear import FlightWear, WearReference, WearSettings, reference_from_flights
from ecu_monitor.model import ThermalParams
from ecu_monitor.offline.calibration_replays import (
    AIRBORNE_MPS,
    MIN_AIRBORNE_S,
    ONSET_FRACTIONS,
    OVERLAY_TARGETS_S,
    OVERLAY_TIME_CONSTANT_S,
    UNBOUNDED_THRESHOLD,
    Feed,
    FlightFeeds,
    FlightStatistic,
    OverlayRun,
    airborne_onsets,
    flight_feeds,
    flight_statistic,
    overlay_replays,
    statistic_paths,
)
from ecu_monitor.shipped import resolve_file
from ecu_monitor.yamlfile import load_yaml_file

__all__ = [
    "AIRBORNE_MPS",
    "BASELINE_CANDIDATES_S",
    "DELAY_CANDIDATES_S",
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
    "candidate_settings",
    "choose_settings",
    "config_copy_yaml",
    "cross_validation_blocker",
    "cylinder_config",
    "cylinders_fragment_yaml",
    "detector_fragment_yaml",
    "flight_feeds",
    "flight_statistic",
    "model_fingerprint",
    "overlay_replays",
    "score_candidate",
    "statistic_paths",
    "uncalibrated_detectors",
    "wear_fragment",
    "wear_reference",
    "without_foreign_reference",
]

#: calibrate_threshold needs at least this many whole hours of statistic.
MIN_WHOLE_HOURS = 2
#: Candidate lengths of the detector's adaptive baseline, s (cross-validated by :func:`choose_settings`).
BASELINE_CANDIDATES_S: tuple[float, ...] = (120.0, 300.0, 600.0, 1200.0)
#: Candidate delays of the baseline, s (each with every length, frozen while S > 0 or not). On a real
#: engine (N550ND) the freeze candidates let k = 0.1 be seen within 600 s at 25 of 28 airborne onsets
#: against 16 without them, with no false alarm (docs/results/detection_real.md).
DELAY_CANDIDATES_S: tuple[float, ...] = (0.0, 60.0)
#: Cross-validation needs at least this many such flights (one held out, h calibrated on the others).
MIN_CROSS_FLIGHTS = 3


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
    def key(self) -> tuple[int, int, int, float, float, int]:
        """The rule's order (larger is better): no false alarm, detections in time, k = 0.1's, shorter
        baseline, longer delay, no freeze."""
        weakest = min(OVERLAY_TARGETS_S)
        hits = sum(self.hits(g) for g in OVERLAY_TARGETS_S)
        s = self.settings
        return (
            -self.false_alarms,
            hits,
            self.hits(weakest),
            -s.baseline_s,
            s.baseline_delay_s,
            -int(s.baseline_freeze),
        )


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


def candidate_settings(
    current: DetectorSettings,
    baselines_s: Sequence[float] = BASELINE_CANDIDATES_S,
    delays_s: Sequence[float] = DELAY_CANDIDATES_S,
) -> list[DetectorSettings]:
    """The settings :func:`choose_settings` cross-validates: ``current`` with each baseline length and
    delay, the baseline learning always or frozen while a change is suspected (a length 0, the plain
    test, once)."""
    out: list[DetectorSettings] = []
    for b in baselines_s:
        for d in delays_s if b > 0.0 else (current.baseline_delay_s,):
            for freeze in (False, True) if b > 0.0 else (False,):
                candidate = dataclasses.replace(
                    current, baseline_s=float(b), baseline_delay_s=float(d), baseline_freeze=freeze
                )
                if candidate not in out:
                    out.append(candidate)
    return out


def choose_settings(
    flights: Sequence[FlightFeeds],
    current: DetectorSettings,
    rate_per_100h: float,
    baselines_s: Sequence[float] = BASELINE_CANDIDATES_S,
    delays_s: Sequence[float] = DELAY_CANDIDATES_S,
) -> SettingsChoice:
    """Choose the baseline among :func:`candidate_settings` (lengths ``baselines_s`` x delays
    ``delays_s`` x frozen while a change is suspected or not; other settings as ``current``) by
    leave-one-flight-out over the flights with overlays (:func:`score_candidate`). Rule: no false
    alarm on any held-out nominal flight, then the most overlays detected within their target time,
    then the most for k = 0.1, then the shorter baseline, then the longer delay, then no freeze; when every candidate
    raises one, the fewest false alarms first (and the reason warns). Keeps ``current`` (and says why) with fewer than
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
            score_candidate(usable, candidate, rate_per_100h)
            for candidate in candidate_settings(current, baselines_s, delays_s)
        )
    except ParameterError as exc:
        return SettingsChoice(current, f"{exc}: kept the config's baseline_s {current.baseline_s:g} s", (), False)
    best = max(scores, key=lambda s: s.key)
    rule = (
        "the fewest false alarms on the held-out flights, then the most overlays detected within target"
        " (k = 0.2 within 300 s, k = 0.1 within 600 s), then the most for k = 0.1, then the shorter baseline,"
        " then the longer delay, then no freeze"
    )
    chosen = best.settings
    frozen = "frozen while a change is suspected" if chosen.baseline_freeze else "always learning"
    reason = f"baseline_s {chosen.baseline_s:g} s, delay {chosen.baseline_delay_s:g} s, {frozen}, by the rule: {rule}"
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
        shortest_min = (settings.warmup_s + 3600.0) / 60.0
        raise ParameterError(
            f"{len(flights)} flight(s) give {given:.2f} flight hours, {whole} whole hour(s) of detector statistic "
            f"after the {settings.warmup_s:g} s warm-up of each flight; calibration needs at least {MIN_WHOLE_HOURS}"
            f" whole hours: add nominal flights giving {MIN_WHOLE_HOURS - whole} more (a flight gives one whole hour"
            f" per full hour after its warm-up: none under {shortest_min:g} min)"
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


def wear_reference(
    feeds: Sequence[FlightFeeds], settings: WearSettings
) -> tuple[list[float | None], WearReference | None]:
    """Each nominal flight's wear index (the across-flight detector's one rule, :class:`FlightWear`, over what
    its replay fed the open-loop reference; the replays kept it) and their reference (None: fewer than 3)."""
    indices: list[float | None] = []
    for flight in feeds:
        wear = FlightWear(settings)
        for segment in flight.reference:
            wear.add_many(segment.cht_c, segment.model_c, segment.oat_c)
        indices.append(wear.index)
    return indices, reference_from_flights(indices)


def wear_fragment(reference: WearReference) -> dict[str, Any]:
    """The ``wear:`` section that stores the engine's nominal wear reference in a service config."""
    return {"wear": {"reference": {"mean": round(reference.mean, 6), "sd": round(reference.sd, 6),
                                   "flights": reference.flights}}}  # fmt: skip


def model_fingerprint(params: ThermalParams) -> str:
    """16 hex digits of the sha256 of the model's parameters (its model.yaml content, key order and
    file formatting aside): what ``detector.calibrated_for`` records, so a replay or the service can
    tell whether the threshold was calibrated for the model in use."""
    text = json.dumps(params.to_dict(), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def without_foreign_reference(config: ServiceConfig, models: Sequence[ThermalParams]) -> ServiceConfig | None:
    """``config`` with its engine reference off when its detector was not calibrated for the model (the reference
    is another engine's, e.g. the shipped virtual ECU's: tested against, a healthy engine reads DEGRADED);
    None when it keeps it (calibrated for the model, or no reference)."""
    from ecu_monitor.offline.calibration_reference import with_reference

    if not config.detector.reference_on or config.cylinder_detectors or not uncalibrated_detectors(config, models):
        return None
    return config.replace(detector=with_reference(config.detector, (), (), 0.0))


def uncalibrated_detectors(config: ServiceConfig, models: Sequence[ThermalParams]) -> list[str]:
    """One line per detector of ``config`` not calibrated for its model (``models``: one per cylinder, or the
    one model), by the model's :func:`model_fingerprint` against ``calibrated_for``; empty when all are."""
    out = []
    if config.cylinder_detectors and len(models) > 1:  # one detector per cylinder: each checked against its model
        for number, (model, calibrated_for) in enumerate(
            zip(models, config.cylinder_calibrated_for, strict=True), start=1
        ):
            if calibrated_for != model_fingerprint(model):
                out.append(
                    f"cylinder {number}'s detector threshold {config.cylinder_detector(number).threshold:g} was not"
                    f" calibrated for its model ({calibrated_for or 'no calibrated_for'}, this model is"
                    f" {model_fingerprint(model)}); calibrate it on nominal flights: ecu-monitor calibrate"
                )
        return out
    fingerprint = model_fingerprint(models[0])
    calibrated = config.detector_calibrated_for
    if calibrated != fingerprint:
        why = (
            f"{config.source} has no detector.calibrated_for"
            if calibrated is None
            else f"it was calibrated for model {calibrated}, this model is {fingerprint}"
        )
        out.append(
            f"the detector threshold {config.detector.threshold:g} was not calibrated for this model ({why});"
            " calibrate it on nominal flights: ecu-monitor calibrate"
        )
    return out


def detector_fragment_yaml(
    result: CalibrationResult,
    symptom: str,
    rate_per_100h: float,
    sources: Sequence[str],
    calibrated_for: str,
    wear: WearReference | None = None,
) -> str:
    """A ``detector:`` YAML fragment with comments, to merge into a service config: the symptom, the new
    threshold and every other detector setting it was calibrated with (a threshold holds only for the
    baseline, delay, reference, warm-up and block it was computed with; merging the whole block keeps
    them together), and ``calibrated_for``, the :func:`model_fingerprint` of the model used. With ``wear``,
    the engine's nominal wear reference after it (:func:`wear_fragment`): what ``ecu-monitor calibrate --out``
    writes, a detector file a config or a fleet names."""
    settings = dataclasses.replace(result.current, threshold=_rounded(result.calibration.threshold))
    body = yaml.safe_dump(
        {"detector": {"symptom": symptom, **_settings_yaml(settings), "calibrated_for": calibrated_for}},
        sort_keys=False,
        default_flow_style=False,
    )
    text = "\n".join(_header(result, rate_per_100h, sources)) + "\n" + body
    if wear is not None:
        text += (
            "# the engine's nominal wear index over these flights: the across-flight detector's reference\n"
            + yaml.safe_dump(wear_fragment(wear), sort_keys=False, default_flow_style=False)
        )
    return text


def config_copy_yaml(
    config_path: str | os.PathLike[str],
    out_path: str | os.PathLike[str],
    result: CalibrationResult,
    rate_per_100h: float,
    sources: Sequence[str],
    calibrated_for: str,
    model_path: str | os.PathLike[str] | None = None,
    cylinders: Sequence[tuple[CalibrationResult, str]] = (),
    cylinder_models: Sequence[str | os.PathLike[str]] = (),
    cross: Sequence[tuple[CalibrationResult | None, str]] = (),
    wear: WearReference | None = None,
) -> str:
    """The service config at ``config_path``, to be written to ``out_path``, with ``detector.threshold``
    replaced, ``detector.calibrated_for`` set (the :func:`model_fingerprint` of the model used) and
    ``model`` set to ``model_path`` if given, the model the threshold was calibrated with. With
    ``cylinders`` (per cylinder its result and model fingerprint; ``result`` is then the first
    cylinder's), ``cylinders.detectors`` is written instead and ``detector`` kept, and ``cylinders.models``
    set to ``cylinder_models`` if given; with ``cross`` (the same, for the cross-cylinder detectors)
    ``cylinders.cross_detectors`` too. With ``wear``, the engine's nominal wear reference is stored
    (``wear.reference``, :func:`wear_fragment`).

    File paths (dbc, health_dbc, model, state_dir; ``model_path`` and ``cylinder_models`` as given on the
    command line, from the working directory) given relative are written relative to the folder of
    ``out_path``, so the copy and its files move together to the machine that runs it; absolute paths,
    ``~/...`` and names of shipped files stay as given. A ``virtual`` bus (one process's buses: a test or
    a replay) gets a comment saying to set the engine's bus. The original's comments are not kept (the
    YAML is re-emitted)."""
    src = resolve_file(config_path, "config")
    data = load_yaml_file(src, "config file", ConfigError)
    if not isinstance(data, dict):
        raise ConfigError(f"{src}: top level: expected a mapping")
    base = src.resolve().parent
    out_dir = Path(out_path).resolve().parent
    here = Path.cwd()

    def portable(value: Any, given_in: Path = base) -> Any:
        if not isinstance(value, str) or value.startswith("~") or Path(value).is_absolute():
            return value
        return os.path.relpath((given_in / value).resolve(), out_dir)

    def named(value: Any, given_in: Path = base) -> Any:
        """A shipped file's name (a DBC, a model preset) stays a name unless a file of that name is there."""
        if isinstance(value, str) and not (given_in / value).exists():
            return value
        return portable(value, given_in)

    if "dbc" in data:
        data["dbc"] = [named(v) for v in data["dbc"]] if isinstance(data["dbc"], list) else named(data["dbc"])
    if "health_dbc" in data:
        data["health_dbc"] = named(data["health_dbc"])
    if "state_dir" in data:
        data["state_dir"] = portable(data["state_dir"])
    if wear is not None:
        section = data.get("wear")
        data["wear"] = {**(section if isinstance(section, dict) else {}), **wear_fragment(wear)["wear"]}
    if model_path is not None:
        data["model"] = named(os.fspath(model_path), here)
    elif isinstance(data.get("model"), str):
        data["model"] = named(data["model"])
    if cylinders:
        section = data.get("cylinders")
        section = dict(section) if isinstance(section, dict) else {}
        if cylinder_models:
            section["models"] = [named(os.fspath(m), here) for m in cylinder_models]
        elif isinstance(section.get("models"), list):
            section["models"] = [named(m) for m in section["models"]]
        section["detectors"] = [_cylinder_entry(r, c) for r, c in cylinders]
        if cross:
            section["cross_detectors"] = [None if r is None else _cylinder_entry(r, c) for r, c in cross]
        data["cylinders"] = section
        header = _cylinder_headers([r for r, _ in cylinders], rate_per_100h, sources)
        header += _cylinder_headers([r for r, _ in cross], rate_per_100h, sources, "cross-cylinder detector")
        header.append(
            f"# copy of {src.resolve()} with cylinders.detectors (one calibrated detector per cylinder) written"
            " (comments of the original not kept)"
        )
        return _config_text(header, data)
    detector = detector_section(data, src)  # a detector file's keys in place of its name: the copy stands alone
    detector = dict(detector) if isinstance(detector, dict) else {}
    detector["threshold"] = _rounded(result.calibration.threshold)
    detector["baseline_s"] = result.current.baseline_s
    detector["baseline_delay_s"] = result.current.baseline_delay_s
    detector["baseline_freeze"] = result.current.baseline_freeze
    for key in ("nominal_threshold", "nominal_mean", "nominal_spread", "start_fit_mean", "start_fit_spread"):
        detector[key] = _settings_yaml(result.current)[key]
    detector["calibrated_for"] = calibrated_for
    data["detector"] = detector
    header = _header(result, rate_per_100h, sources)
    header.append(
        f"# copy of {src.resolve()} with detector.threshold and baseline settings replaced"
        " (comments of the original not kept)"
    )
    return _config_text(header, data)


def _config_text(header: list[str], data: dict[str, Any]) -> str:
    """The header comment lines and the config's YAML; a ``virtual`` bus commented: set the engine's."""
    lines = yaml.safe_dump(data, sort_keys=False, default_flow_style=None).splitlines()
    bus = data.get("bus")
    if isinstance(bus, dict) and bus.get("interface") == "virtual":
        at = next(i for i, line in enumerate(lines) if line.startswith("bus:"))
        lines.insert(
            at,
            "# bus: 'virtual' connects only the buses of one process (tests, replays): set the engine's bus"
            " before 'ecu-monitor run' (e.g. interface: socketcan, channel: can0)",
        )
    return "\n".join([*header, *lines]) + "\n"


def cylinder_config(config: ServiceConfig, number: int, model: str | None = None) -> ServiceConfig:
    """``config`` monitoring cylinder ``number`` (1-based) alone, as a single-channel engine: its CHT
    input mapped as ``cht_c``, its model (``model``, else its ``cylinders.models`` entry, else
    ``model``), its detector (:meth:`ServiceConfig.cylinder_detector`); the other cylinders' inputs,
    the per-cylinder health frames and the spread alarm dropped. What ``calibrate`` replays per cylinder
    with the flight's ``cht<number>_c`` as its CHT."""
    name = config.cylinder_inputs[number - 1]
    inputs = tuple(
        dataclasses.replace(spec, name=CHT_INPUT) if spec.name == name else spec
        for spec in config.inputs
        if spec.name == name or not (spec.name == CHT_INPUT or CYLINDER_INPUT.match(spec.name))
    )
    if model is None:
        model = config.cylinder_models[number - 1] if config.cylinder_models else config.model
    return config.replace(
        inputs=inputs,
        model=model,
        cylinder_models=(),
        cylinder_detectors=(),
        cylinder_calibrated_for=(),
        cross_detectors=(),
        cross_calibrated_for=(),
        detector=config.cylinder_detector(number),
        health=tuple(h for h in config.health if h.message not in CYLINDER_HEALTH_MESSAGES),
        spread_limit_c=None,
    )


def _cylinder_entry(result: CalibrationResult, calibrated_for: str) -> dict[str, Any]:
    """One ``cylinders.detectors`` entry: the settings it was calibrated with and its model's fingerprint."""
    settings = dataclasses.replace(result.current, threshold=_rounded(result.calibration.threshold))
    return {**_settings_yaml(settings), "calibrated_for": calibrated_for}


def _settings_yaml(settings: DetectorSettings) -> dict[str, Any]:
    """The detector settings as YAML values (the reference's per-region tuples as lists)."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(settings).items()}


def _cylinder_headers(
    results: Sequence[CalibrationResult | None], rate_per_100h: float, sources: Sequence[str], what: str = ""
) -> list[str]:
    lines: list[str] = []
    for number, result in enumerate(results, start=1):
        lines.append(f"# cylinder {number}{', ' + what if what else ''}:")
        if result is None:
            lines.append("#   off: a nominal flight held out raised an alarm (leave-one-flight-out check)")
            continue
        lines += [f"#  {line[1:]}" for line in _header(result, rate_per_100h, sources)]
    return lines


def cylinders_fragment_yaml(
    results: Sequence[CalibrationResult],
    rate_per_100h: float,
    sources: Sequence[str],
    calibrated_for: Sequence[str],
    cross: Sequence[CalibrationResult | None] = (),
) -> str:
    """A ``cylinders: detectors:`` YAML fragment, one detector per cylinder in cylinder order (each with
    every setting it was calibrated with and ``calibrated_for``, its model's :func:`model_fingerprint`),
    to put into the service config's ``cylinders:`` section beside ``models``; comments per cylinder.
    ``cross``: the cross-cylinder detectors' results, written as ``cross_detectors`` the same way (None:
    written null, no cross-cylinder detector on that cylinder)."""
    lines = _cylinder_headers(results, rate_per_100h, sources)
    lines += _cylinder_headers(cross, rate_per_100h, sources, "cross-cylinder detector")
    entries = [_cylinder_entry(r, c) for r, c in zip(results, calibrated_for, strict=True)]
    section: dict[str, Any] = {"detectors": entries}
    if cross:
        section["cross_detectors"] = [
            None if r is None else _cylinder_entry(r, c) for r, c in zip(cross, calibrated_for, strict=True)
        ]
    body = yaml.safe_dump({"cylinders": section}, sort_keys=False, default_flow_style=None)
    return "\n".join(lines) + "\n" + body


def _rounded(value: float) -> float:
    """The threshold as written: 4 significant decimals up (never below the calibrated value)."""
    return math.ceil(value * 1e4) / 1e4
