"""Calibrating the detector's threshold on a user's own nominal flights (``ecu-monitor calibrate``).

Each flight goes through the replay's batch path (:func:`~ecu_monitor.service.replay.replay_file`:
the same decoding, supervision, estimator, symptom, warm-up and baseline as the service), and the
detector's input (:attr:`ReplayResult.detector_feed`) is run through
:func:`~ecu_monitor.estimation.detection.cusum_path` with no alarm (threshold 1e300, as
``ecu-monitor evaluate`` calibrates). :func:`~ecu_monitor.estimation.detection.calibrate_threshold`
then fits the hourly maxima of these paths for the asked false-alarm rate.

Helpers write the result as a ``detector:`` YAML fragment, or as a full copy of the service config
with the threshold replaced (relative paths made absolute, so the copy loads from anywhere).
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

from ecu_monitor.errors import ConfigError, FlightLogError, ParameterError
from ecu_monitor.estimation.detection import DetectorSettings, ThresholdCalibration, calibrate_threshold, cusum_path
from ecu_monitor.model import ThermalParams
from ecu_monitor.service.config import MODEL_PRESETS, ServiceConfig
from ecu_monitor.service.replay import ReplayResult, replay_file
from ecu_monitor.shipped import resolve_file, shipped_file

__all__ = [
    "MIN_WHOLE_HOURS",
    "UNBOUNDED_THRESHOLD",
    "CalibrationResult",
    "FlightStatistic",
    "calibrate_flights",
    "calibration_method",
    "config_copy_yaml",
    "detector_fragment_yaml",
    "flight_statistic",
    "statistic_paths",
]

#: calibrate_threshold needs at least this many whole hours of statistic.
MIN_WHOLE_HOURS = 2
#: The threshold of the "no alarm" CUSUM run for calibration (as research.evaluation.score).
UNBOUNDED_THRESHOLD = 1e300


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
    result = replay_file(path, config, params)
    time_s = result.columns["time_s"]
    if time_s.size == 0 or not result.detector_feed:
        raise FlightLogError(f"{path}: the service's estimator never started on this log (no usable CHT and inputs)")
    alarms = [cusum_path(t, x, config.detector, restart=True)[2] for t, x in result.detector_feed]
    return FlightStatistic(
        name=Path(path).name,
        hours=float(time_s[-1] - time_s[0]) / 3600.0,
        paths=statistic_paths(result, config.detector),
        start_s=float(time_s[0]),
        alarm_times_s=np.concatenate(alarms) if alarms else np.empty(0),
    )


def calibrate_flights(
    flights: Sequence[FlightStatistic], rate_per_100h: float, settings: DetectorSettings
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
    return CalibrationResult(calibration, calibration_method(calibration), tuple(flights), settings)


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
    data["detector"] = detector
    header = _header(result, rate_per_100h, sources)
    header.append(f"# copy of {src.resolve()} with detector.threshold replaced (comments of the original not kept)")
    return "\n".join(header) + "\n" + yaml.safe_dump(data, sort_keys=False, default_flow_style=None)


def _rounded(value: float) -> float:
    """The threshold as written: 4 significant decimals up (never below the calibrated value)."""
    return math.ceil(value * 1e4) / 1e4
