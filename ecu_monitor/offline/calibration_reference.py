"""The engine's own reference, learned by ``ecu-monitor calibrate`` from nominal flights: what the detector's
symptom looks like in each operating region (:mod:`ecu_monitor.estimation.regions`) on a healthy engine, and
the threshold of the test that measures each flight against it from engine start (from the end of the start
region: the test leaves the :data:`~ecu_monitor.estimation.detection.UNTESTED_REGIONS` out, though their mean
and spread are learned and printed).

Per flight and region, the mean of the symptom the service fed its detector (degC/s for the CBEKF's
deviation); per region, the mean of these flight means (``nominal_mean``) and their standard deviation
across flights (``nominal_spread``). The test's level in a region is mean + NOMINAL_SPREAD_Z x spread
(:meth:`DetectorSettings.nominal_levels`); the test is a plain CUSUM of the symptom minus that level
(:meth:`DetectorSettings.nominal_settings`), the very detector the step runs.

With it, the start fits' mean and spread across the flights (:func:`flight_start_fits`): what a fault present
from engine start is isolated against (pipeline/step.py, ``start_fault_call``).

Its threshold is calibrated honestly for flights the reference never saw: each flight in turn is measured
against the reference learned on the others (leave one flight out), and the hourly maxima of these
statistics set h for the asked false-alarm rate (:func:`~ecu_monitor.estimation.detection.calibrate_threshold`,
as for the adaptive test). Needs :data:`MIN_REFERENCE_FLIGHTS` flights (a spread from two others at least).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import ConfigError, ParameterError
from ecu_monitor.estimation.detection import (
    START_FIT_NAMES,
    DetectorSettings,
    ThresholdCalibration,
    calibrate_threshold,
    cusum_path,
)
from ecu_monitor.estimation.regions import REGION_COUNT
from ecu_monitor.offline.calibration_replays import UNBOUNDED_THRESHOLD, FlightFeeds

__all__ = [
    "MIN_REFERENCE_FLIGHTS",
    "MIN_REGION_S",
    "ReferenceCalibration",
    "calibrate_reference",
    "flight_region_means",
    "flight_start_fits",
    "reference_paths",
    "with_reference",
]

#: Flights the reference needs: each one left out leaves two to take a spread from.
MIN_REFERENCE_FLIGHTS = 3
#: A flight's mean in a region counts when the symptom was fed there at least this long, s.
MIN_REGION_S = 60.0


def flight_region_means(flight: FlightFeeds) -> NDArray[np.float64]:
    """The mean of the flight's fed symptom in each region (nan: fed there less than MIN_REGION_S)."""
    sums = np.zeros(REGION_COUNT)
    counts = np.zeros(REGION_COUNT)
    seconds = np.zeros(REGION_COUNT)
    for (time_s, symptom), regions in zip(flight.feed, flight.regions, strict=True):
        if time_s.size < 2:
            continue
        step = float(np.median(np.diff(time_s)))
        fed = np.isfinite(symptom) & (regions >= 0)
        sums += np.bincount(regions[fed], weights=symptom[fed], minlength=REGION_COUNT)
        n = np.bincount(regions[fed], minlength=REGION_COUNT)
        counts += n
        seconds += n * step
    with np.errstate(invalid="ignore", divide="ignore"):
        means = sums / counts
    means[seconds < MIN_REGION_S] = math.nan
    return means


def flight_start_fits(flight: FlightFeeds) -> NDArray[np.float64]:
    """The flight's start fits (START_FIT_NAMES order) at the end of its first clock segment whose fits are all
    known (nan: none; the fits start afresh with each segment, as the engine's start)."""
    for fits in flight.start_fits:
        if np.all(np.isfinite(fits)):
            return np.asarray(fits, dtype=float)
    return np.full(len(START_FIT_NAMES), math.nan)


def _mean_spread(means: NDArray[np.float64]) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Per region (columns of flights x regions): the mean over the flights that have it, and the standard
    deviation across them (nan with fewer than two)."""
    mean, spread = [], []
    for column in means.T:
        seen = column[np.isfinite(column)]
        mean.append(float(seen.mean()) if seen.size >= 2 else math.nan)
        spread.append(float(seen.std(ddof=1)) if seen.size >= 2 else math.nan)
    return tuple(mean), tuple(spread)


def with_reference(
    settings: DetectorSettings,
    mean: Sequence[float],
    spread: Sequence[float],
    threshold: float,
    start_fit_mean: Sequence[float] = (),
    start_fit_spread: Sequence[float] = (),
) -> DetectorSettings:
    """``settings`` with the reference (per-region mean and spread, the reference test's h, the start fits' mean
    and spread)."""
    return dataclasses.replace(
        settings,
        nominal_mean=tuple(mean),
        nominal_spread=tuple(spread),
        nominal_threshold=float(threshold),
        start_fit_mean=tuple(start_fit_mean),
        start_fit_spread=tuple(start_fit_spread),
    )


def reference_paths(
    flight: FlightFeeds, levels: Sequence[float], settings: DetectorSettings
) -> tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...]:
    """The reference test's statistic without alarms over a flight measured against ``levels`` (per region):
    per clock segment, (block end times s, statistic)."""
    test = dataclasses.replace(settings.nominal_settings(), threshold=UNBOUNDED_THRESHOLD)
    table = np.asarray(levels, dtype=float)
    out = []
    for (time_s, symptom), regions in zip(flight.feed, flight.regions, strict=True):
        level = np.where(regions >= 0, table[np.clip(regions, 0, REGION_COUNT - 1)], math.nan)
        ends, stat, _ = cusum_path(time_s, symptom - level, test)
        out.append((ends, stat))
    return tuple(out)


@dataclass(frozen=True)
class ReferenceCalibration:
    """The reference and its test: per flight (in the order given) its region means; the reference's mean
    and spread per region; the test's threshold calibration; the largest held-out statistic per flight; per
    flight its start fits, and their mean and spread (empty: fewer than two flights with them)."""

    flights: tuple[str, ...]
    flight_means: NDArray[np.float64]
    mean: tuple[float, ...]
    spread: tuple[float, ...]
    calibration: ThresholdCalibration
    held_out_max: tuple[float, ...]
    flight_fits: NDArray[np.float64]
    fit_mean: tuple[float, ...]
    fit_spread: tuple[float, ...]

    def settings(self, settings: DetectorSettings) -> DetectorSettings:
        """``settings`` carrying this reference (h rounded up to 4 decimals, as written)."""
        h = math.ceil(self.calibration.threshold * 1e4) / 1e4
        return with_reference(settings, self.mean, self.spread, h, self.fit_mean, self.fit_spread)


def calibrate_reference(
    flights: Sequence[FlightFeeds], settings: DetectorSettings, rate_per_100h: float
) -> ReferenceCalibration:
    """The reference from ``flights`` (nominal, replayed by :func:`flight_feeds`) and its test's threshold for
    ``rate_per_100h`` false alarms per 100 flight hours, each flight measured against the reference of the
    others. ParameterError (one line) with fewer than MIN_REFERENCE_FLIGHTS flights or too few hours."""
    if len(flights) < MIN_REFERENCE_FLIGHTS:
        raise ParameterError(
            f"{len(flights)} flight(s) given: the engine's reference needs {MIN_REFERENCE_FLIGHTS} nominal flights"
        )
    means = np.array([flight_region_means(f) for f in flights])
    paths: list[NDArray[np.float64]] = []
    held_out_max = []
    for i, flight in enumerate(flights):
        mean, spread = _mean_spread(np.delete(means, i, axis=0))
        levels = with_reference(settings, mean, spread, 1.0).nominal_levels()
        own = [stat for _, stat in reference_paths(flight, levels, settings)]
        paths += own
        held_out_max.append(max((float(s.max()) for s in own if s.size), default=0.0))
    try:
        calibration = calibrate_threshold(paths, rate_per_100h, sample_period_s=settings.block_s)
    except ConfigError as exc:  # too few whole hours, said as the reference's
        raise ParameterError(f"the engine's reference: {exc}") from None
    mean, spread = _mean_spread(means)
    fits = np.array([flight_start_fits(f) for f in flights])
    fit_mean, fit_spread = _mean_spread(fits)
    if not all(math.isfinite(s) for s in fit_spread):
        fit_mean, fit_spread = (), ()
    return ReferenceCalibration(tuple(f.name for f in flights), means, mean, spread, calibration, tuple(held_out_max),
                                fits, fit_mean, fit_spread)  # fmt: skip
