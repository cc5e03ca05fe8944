"""Calibrating the cross-cylinder detectors on a user's nominal flights (``ecu-monitor calibrate`` on a
config with ``cylinders.cross_detector``).

Each flight is replayed once with every cylinder (the service's batch path, its own models and the
config's cross-cylinder settings); what each cylinder's cross-cylinder detector was fed
(:attr:`ReplayResult.cross_feeds`: its symptom minus the median of the other cylinders',
pipeline/step.py cross_step) is run through the CUSUM without alarms, and each cylinder's threshold is
set from its own statistics by the single-channel procedure (:func:`calibrate_flights`: the Gumbel
quantile of the hourly maxima, never below 1.1 x the largest value seen when the flights hold fewer
hours than one expected alarm). The baseline settings are the config's.

:func:`leave_one_out` is the check that goes with it: each flight in turn held out, h calibrated on
the others, the held-out flight's alarms counted (each crossing one false alarm). A cylinder whose
check counts an alarm keeps no cross-cylinder detector (:func:`calibrate_cross` gives None for it):
its cross symptom has excursions on some flights that the others do not show (on N550ND: a cylinder
whose model fits worst, at the take-off and initial climb; docs/results/cylinders.md), so a threshold
from these flights would not hold on the next one. Its own-symptom detector keeps watching it.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ecu_monitor.config import ServiceConfig
from ecu_monitor.errors import FlightLogError, ParameterError
from ecu_monitor.model import ThermalParams
from ecu_monitor.offline.calibration import MIN_WHOLE_HOURS, CalibrationResult, calibrate_flights
from ecu_monitor.offline.calibration_replays import FlightFeeds
from ecu_monitor.offline.replay import replay_file

__all__ = ["HeldOut", "calibrate_cross", "cross_feeds", "leave_one_out"]


def cross_feeds(
    paths: Sequence[str | os.PathLike[str]], config: ServiceConfig, params: Sequence[ThermalParams]
) -> list[list[FlightFeeds]]:
    """Per cylinder, per flight: what its cross-cylinder detector is fed on that flight (one replay of
    each flight with every cylinder). ParameterError when the config has no cross-cylinder detector."""
    if not config.cross_detectors:
        raise ParameterError(f"{config.source}: cylinders.cross_detector is not set: nothing to calibrate")
    out: list[list[FlightFeeds]] = [[] for _ in config.cylinder_inputs]
    for path in paths:
        result = replay_file(path, config, params, keep_feeds=True)
        time_s = result.columns["time_s"]
        if time_s.size == 0 or not result.cross_feeds:
            raise FlightLogError(f"{path}: the service's estimator never started on this log (no usable CHT, inputs)")
        for cylinder, feed in zip(out, result.cross_feeds, strict=True):
            cylinder.append(FlightFeeds(Path(path).name, feed, float(time_s[0]), float(time_s[-1]), float("nan"), ()))
    return out


def calibrate_cross(
    feeds: Sequence[Sequence[FlightFeeds]],
    config: ServiceConfig,
    rate_per_100h: float,
    checks: Sequence[HeldOut] | None = None,
) -> list[CalibrationResult | None]:
    """Each cylinder's cross-cylinder threshold from its feeds (:func:`cross_feeds`), with the config's
    cross-cylinder settings otherwise; None for a cylinder that has none in the config or whose
    leave-one-flight-out check (``checks``, from :func:`leave_one_out`; computed when None) counts an alarm."""
    if checks is None:
        checks = leave_one_out(feeds, config, rate_per_100h)
    results: list[CalibrationResult | None] = []
    for number, (flights, check) in enumerate(zip(feeds, checks, strict=True), start=1):
        settings = config.cross_detector(number)
        if settings is None or sum(check.false_alarms) > 0:
            results.append(None)
            continue
        results.append(calibrate_flights([f.statistic_for(settings) for f in flights], rate_per_100h, settings))
    return results


@dataclass(frozen=True)
class HeldOut:
    """One cylinder's leave-one-flight-out check: per flight, the h calibrated without it and the false
    alarms it raised (nan h: the other flights hold too few whole hours)."""

    cylinder: int
    flights: tuple[str, ...]
    thresholds: tuple[float, ...]
    false_alarms: tuple[int, ...]


def leave_one_out(feeds: Sequence[Sequence[FlightFeeds]], config: ServiceConfig, rate_per_100h: float) -> list[HeldOut]:
    """Each flight in turn held out: h calibrated on the others (per cylinder), alarms on the held-out
    flight with that h (a cylinder without a cross-cylinder detector: nothing checked)."""
    out = []
    for number, flights in enumerate(feeds, start=1):
        settings = config.cross_detector(number)
        if settings is None:
            out.append(HeldOut(number, tuple(f.name for f in flights), (), ()))
            continue
        thresholds: list[float] = []
        alarms: list[int] = []
        for i, held in enumerate(flights):
            others = [f.statistic_for(settings) for j, f in enumerate(flights) if j != i]
            if sum(f.whole_hours(settings.block_s) for f in others) < MIN_WHOLE_HOURS:
                thresholds.append(float("nan"))
                alarms.append(0)
                continue
            h = calibrate_flights(others, rate_per_100h, settings).calibration.threshold
            thresholds.append(h)
            alarms.append(int(held.statistic_for(dataclasses.replace(settings, threshold=h)).alarm_times_s.size))
        out.append(HeldOut(number, tuple(f.name for f in flights), tuple(thresholds), tuple(alarms)))
    return out
