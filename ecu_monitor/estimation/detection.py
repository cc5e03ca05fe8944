"""Degradation detection with a stated false-alarm rate: a one-sided CUSUM on the model-deviation symptom.

Both degradations heat the head (gamma_Q > 1 puts more heat in, gamma_D > 1 takes less out), so the
test is one-sided on heat-up. The symptom s(t) (degC/s, the change of the state derivative the
estimator attributes to the degradation) is first averaged over blocks of ``block_s`` seconds (this
filters the 50 Hz symptom and its quantisation spikes), then::

    S_n = max(0, S_(n-1) + (mean_n - b_(n-1) - k) * block_s)     (statistic in degC for a degC/s symptom)

b is the symptom's nominal baseline: 0 (``baseline_s`` = 0, the plain test), or an exponential moving
average, time constant ``baseline_s``, of the block means older than ``baseline_delay_s`` (a delay
line: a step stays fully visible to the test for that long before the baseline starts to follow it).
The baseline absorbs the slowly varying offset that the residual model error puts on the symptom at
each operating point; the test then looks for a *change* of the symptom, which is what a degradation
onset is. The price: a degradation that creeps in more slowly than ``baseline_s`` is absorbed too,
and one present from engine start is part of the baseline (the plain test, or the gamma estimates
over flights, must catch those). With ``baseline_freeze`` the baseline stops learning while S > 0
(a change is suspected): a rise keeps its full size in the test however long it lasts, instead of
being absorbed after a few baseline time constants; the baseline learns again once S is back at 0.
On a real engine, whose model error moves with the flight phase, this lets a short baseline follow
the phases and still see a degradation of the size k = 0.1 (docs/results/detection_real.md).
With ``scale_s`` on (the self-normalised test, off by default) each block's excess is weighed by
``scale_floor / max(scale_floor, spread)``, spread the running mean absolute deviation of the block
means from the baseline (time constant ``scale_s``; it does not learn while S > 0): h is then in units of
the flight's own nominal spread wherever that exceeds the floor. Measured on a real engine, it does not
help there (the flights whose nominal statistic peaks highest are not the ones with the larger spread;
docs/results/detection_real.md), so ``ecu-monitor calibrate`` does not choose it.

k (``reference``) is the drift allowance: about half the symptom of the smallest degradation to
detect; h (``threshold``) is set from nominal flights by :func:`calibrate_threshold` for a target
false-alarm rate. The state is SUSPECT once S >= suspect_fraction * h and DEGRADED once S >= h; the
DEGRADED state latches (the first alarm time is kept) until the detector is reset. Nothing
accumulates during the first ``warmup_s`` seconds (engine start: the model's transient from a cold
start is not a degradation).

Calibration (docs/detection_isolation.md): the CUSUM is run without alarms over N nominal flight
hours; the maximum of the statistic in each whole hour is an extreme value, so a Gumbel law is fitted
to the hourly maxima (method of moments); the threshold with a rate r of false alarms per 100 flight
hours is the Gumbel quantile at 1 - r/100, and never below the empirical bound (``margin`` times the
largest statistic seen, part-hours at the end of flights included, when the calibration set is
shorter than 100/r hours).
:func:`count_alarms` scores it on a separate set of nominal flights.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import ConfigError, ParameterError
from ecu_monitor.estimation.regions import REGION_COUNT, REGION_NAMES, REGION_START

__all__ = [
    "NOMINAL_SPREAD_Z",
    "START_FIT_NAMES",
    "UNTESTED_REGIONS",
    "DetectorSettings",
    "ThresholdCalibration",
    "block_means",
    "calibrate_threshold",
    "count_alarms",
    "cusum_blocks",
    "cusum_path",
    "hourly_maxima",
    "overlay_degradation",
    "scale_blocks",
]

_EULER_GAMMA = 0.5772156649015329
#: The reference test's level in a region sits this many spreads (across nominal flights) above its mean.
NOMINAL_SPREAD_Z = 2.0
#: Regions the reference test does not test (its level there is nan), though calibrate learns their mean and
#: spread: the start (the head's warm-up from cold), whose symptom follows the start's initial conditions (head
#: and outside temperature, the filters' first state) more than the engine: on nominal virtual flights its
#: flight means were the most spread and heavy-tailed, and it raised every false DEGRADED while tested
#: (docs/results/detection.md, "The reference without the start region").
UNTESTED_REGIONS: tuple[int, ...] = (REGION_START,)
#: The start fits of the isolation of a fault present from engine start (pipeline/step.py, docs/detection_isolation.md
#: section 4), each a gamma - 1 fitted to the open-loop residual: the cold start's heat factor, the settle's loss
#: factor, the flight's product; calibrate learns their mean and spread over nominal flights.
START_FIT_NAMES: tuple[str, ...] = ("cold_heat", "settle_loss", "flight_product")


@dataclass(frozen=True)
class DetectorSettings:
    """CUSUM settings (validated).

    threshold: h, alarm level of the statistic (symptom unit x s; degC for a degC/s symptom).
    reference: k, drift allowance subtracted from each block mean (symptom unit).
    warmup_s: hold-off after the first sample during which nothing accumulates, s.
    suspect_fraction: SUSPECT from suspect_fraction * threshold, in (0, 1).
    block_s: averaging block of the symptom before the test, s.
    baseline_s: time constant of the adaptive baseline subtracted from the symptom, s (0 = none).
    baseline_delay_s: age of the newest block mean the baseline may use, s (0 = up to the previous block).
    baseline_freeze: the baseline holds while the statistic is above 0 (a change suspected).
    scale_s: time constant of the online spread of the symptom about its baseline, s (0 = off: every
        block's excess counts in full).
    scale_floor: the spread at and below which a block's excess counts in full, symptom unit (> 0 when
        scale_s is on); above it the excess is weighed by scale_floor / spread.
    nominal_threshold: h of the second test, against the engine's own reference (0 = no reference): a
        plain CUSUM (no warm-up, no baseline, the same k and blocks) of the symptom minus its nominal level
        in the sample's operating region (:mod:`.regions`), from engine start wherever the reference has a
        level (``ecu-monitor calibrate`` learns none for the start region); calibrate learns it with the two
        below.
    nominal_mean: per region (REGION_NAMES order) the mean of the symptom over nominal flights, symptom
        unit (nan: no nominal data in that region, not tested there).
    nominal_spread: per region the spread across flights of each flight's mean there (standard deviation),
        symptom unit. The level tested against is mean + NOMINAL_SPREAD_Z x spread.
    start_fit_mean, start_fit_spread: the start fits (START_FIT_NAMES order) over nominal flights: their mean and
        standard deviation across flights (empty: not learned; the isolation of a fault present from engine
        start then leaves it to the isolation filter).

    The defaults are the variant kept by ``ecu-monitor evaluate`` for the CBEKF's model deviation on the
    paper's Table A1 model (docs/results/detection.md: h calibrated on 53 nominal flight hours for 1
    false alarm per 100 h); a monitor running another model must recalibrate h on its own nominal
    flights (:func:`calibrate_threshold`).
    """

    threshold: float = 7.77
    reference: float = 0.05
    warmup_s: float = 600.0
    suspect_fraction: float = 0.5
    block_s: float = 1.0
    baseline_s: float = 120.0
    baseline_delay_s: float = 60.0
    baseline_freeze: bool = False
    scale_s: float = 0.0
    scale_floor: float = 0.0
    nominal_threshold: float = 0.0
    nominal_mean: tuple[float, ...] = ()
    nominal_spread: tuple[float, ...] = ()
    start_fit_mean: tuple[float, ...] = ()
    start_fit_spread: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        self._check_nominal()
        if not isinstance(self.baseline_freeze, bool):
            raise ConfigError(f"detector.baseline_freeze: expected true or false, got {self.baseline_freeze!r}")
        names = (
            "threshold",
            "reference",
            "warmup_s",
            "suspect_fraction",
            "block_s",
            "baseline_s",
            "baseline_delay_s",
            "scale_s",
            "scale_floor",
        )
        for name in names:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ConfigError(f"detector.{name}: expected a finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        if self.threshold <= 0.0 or self.block_s <= 0.0 or self.warmup_s < 0.0 or self.baseline_s < 0.0:
            raise ConfigError("detector: threshold and block_s must be > 0, warmup_s and baseline_s >= 0")
        if 0.0 < self.baseline_s < self.block_s:
            raise ConfigError("detector.baseline_s: expected 0 (off) or at least block_s")
        if not 0.0 <= self.baseline_delay_s <= 3600.0:
            raise ConfigError(f"detector.baseline_delay_s: expected 0-3600 s, got {self.baseline_delay_s!r}")
        if not 0.0 < self.suspect_fraction < 1.0:
            raise ConfigError(f"detector.suspect_fraction: expected a value in (0, 1), got {self.suspect_fraction!r}")
        if self.scale_s < 0.0 or 0.0 < self.scale_s < self.block_s or self.scale_floor < 0.0:
            raise ConfigError("detector.scale_s: expected 0 (off) or at least block_s; scale_floor >= 0")
        if self.scale_s > 0.0 and self.scale_floor <= 0.0:
            raise ConfigError("detector.scale_floor: expected > 0 with scale_s on (ecu-monitor calibrate learns it)")

    def _check_nominal(self) -> None:
        for name in ("nominal_mean", "nominal_spread", "start_fit_mean", "start_fit_spread"):
            values = getattr(self, name)
            if not isinstance(values, list | tuple) or any(
                isinstance(v, bool) or not isinstance(v, int | float) for v in values
            ):
                raise ConfigError(f"detector.{name}: expected a list of numbers, got {values!r}")
            object.__setattr__(self, name, tuple(float(v) for v in values))
        value = self.nominal_threshold
        if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 0.0 or math.isinf(value):
            raise ConfigError(f"detector.nominal_threshold: expected a number >= 0 (0: off), got {value!r}")
        if self.nominal_threshold > 0.0:
            if len(self.nominal_mean) != REGION_COUNT or len(self.nominal_spread) != REGION_COUNT:
                raise ConfigError(
                    f"detector.nominal_mean, nominal_spread: expected {REGION_COUNT} values each (regions"
                    f" {', '.join(REGION_NAMES)}) with nominal_threshold on"
                )
            if any(not (s >= 0.0) and not math.isnan(s) for s in self.nominal_spread):
                raise ConfigError("detector.nominal_spread: expected values >= 0 (nan: no data)")
        lengths = {len(self.start_fit_mean), len(self.start_fit_spread)}
        if lengths not in ({0}, {len(START_FIT_NAMES)}):
            names = ", ".join(START_FIT_NAMES)
            raise ConfigError(f"detector.start_fit_mean, start_fit_spread: expected a value each for {names}, or none")
        if any(not (s >= 0.0) and not math.isnan(s) for s in self.start_fit_spread):
            raise ConfigError("detector.start_fit_spread: expected values >= 0 (nan: no data)")

    @property
    def reference_on(self) -> bool:
        """The test against the engine's reference runs (calibrated)."""
        return self.nominal_threshold > 0.0

    def nominal_levels(self) -> tuple[float, ...]:
        """The level of the symptom per region the reference test measures against: mean + NOMINAL_SPREAD_Z x
        spread (nan where the reference has no data, and in the UNTESTED_REGIONS)."""
        return tuple(
            math.nan if r in UNTESTED_REGIONS else m + NOMINAL_SPREAD_Z * s
            for r, (m, s) in enumerate(zip(self.nominal_mean, self.nominal_spread, strict=True))
        )

    def nominal_settings(self) -> DetectorSettings:
        """The reference test as a plain CUSUM of the symptom minus its level: these blocks, k and suspect
        fraction, h = nominal_threshold (1e300 while not calibrated), no warm-up, no baseline."""
        return DetectorSettings(
            threshold=self.nominal_threshold if self.reference_on else 1e300,
            reference=self.reference,
            warmup_s=0.0,
            suspect_fraction=self.suspect_fraction,
            block_s=self.block_s,
            baseline_s=0.0,
            baseline_delay_s=0.0,
        )

    @property
    def delay_blocks(self) -> int:
        """The baseline delay in blocks."""
        return round(self.baseline_delay_s / self.block_s)


# --------------------------------------------------------------------------------------------------
# Whole flights (vectorised / compiled), calibration and scoring
# --------------------------------------------------------------------------------------------------


def block_means(
    time_s: NDArray[np.float64], symptom: NDArray[np.float64], settings: DetectorSettings
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(block end times s, block means) of a symptom over a flight, after the warm-up: the blocks
     live step's detector forms (pipeline/step.py ``detector_step``: samples in [start + warmup + i*block_s,
    ... + block_s); empty blocks nan)."""
    t = np.asarray(time_s, dtype=float)
    x = np.asarray(symptom, dtype=float)
    begin = t[0] + settings.warmup_s
    keep = (t >= begin) & np.isfinite(x)
    n_blocks = math.floor((t[-1] - begin) / settings.block_s + 1e-9) if t[-1] > begin else 0
    if n_blocks < 1:
        return np.empty(0), np.empty(0)
    index = np.floor((t[keep] - begin) / settings.block_s + 1e-9).astype(np.int64)
    inside = index < n_blocks
    sums = np.bincount(index[inside], weights=x[keep][inside], minlength=n_blocks)
    counts = np.bincount(index[inside], minlength=n_blocks)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    ends = begin + settings.block_s * (np.arange(n_blocks) + 1.0)
    return ends, means


@numba.njit(cache=True)
def _cusum_step(statistic: float, baseline: float, scale: float, learned: float, mean: float, lagged: float,
                k: float, block_s: float, baseline_s: float, steady: bool, freeze: bool, scale_s: float,
                floor: float) -> tuple[float, float, float, float]:  # fmt: skip
    """One CUSUM update: (new statistic, new baseline, new scale, blocks the scale has learned). mean:
    this block's mean (nan = empty block); lagged: the block mean leaving the delay line now, which
    enters the baseline after the test (nan = none); baseline nan = not started yet (the statistic
    stays 0 until it has a value). steady False: the statistic is held (a transient of the inputs),
    the baseline still learns. freeze: a started baseline does not learn while the (new) statistic is
    above 0. scale_s > 0: the excess is weighed by floor / max(floor, scale), scale the running mean
    absolute deviation of the lagged block means from the baseline (time constant scale_s, a plain mean
    over its first scale_s; nan before its first block), which never learns while the statistic is
    above 0."""
    if baseline_s <= 0.0:
        baseline = 0.0
    weight = 1.0
    if scale_s > 0.0 and not math.isnan(scale) and scale > floor:
        weight = floor / scale
    if steady and not math.isnan(mean) and not math.isnan(baseline):
        statistic = max(0.0, statistic + (mean - baseline - k) * block_s * weight)
    if math.isnan(lagged):
        return statistic, baseline, scale, learned
    if math.isnan(baseline):
        return statistic, lagged, scale, learned
    if statistic > 0.0 and (freeze or scale_s > 0.0):
        if freeze or baseline_s <= 0.0:
            return statistic, baseline, scale, learned
        return statistic, baseline + (block_s / baseline_s) * (lagged - baseline), scale, learned
    if scale_s > 0.0:
        deviation = abs(lagged - baseline)
        learned += 1.0
        if math.isnan(scale):
            scale = deviation
        else:
            scale += max(block_s / scale_s, 1.0 / learned) * (deviation - scale)
    if baseline_s <= 0.0:
        return statistic, baseline, scale, learned
    return statistic, baseline + (block_s / baseline_s) * (lagged - baseline), scale, learned


@numba.njit(cache=True)
def _cusum(means: NDArray[np.float64], steady: NDArray[np.bool_], k: float, h: float, block_s: float,
           baseline_s: float, delay: int, restart: bool, freeze: bool, scale_s: float,
           floor: float) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:  # fmt: skip
    stat = np.empty(means.shape[0])
    scales = np.empty(means.shape[0])
    alarms = np.empty(means.shape[0], dtype=np.int64)
    n_alarms = 0
    s = 0.0
    baseline = np.nan
    scale = np.nan
    learned = 0.0
    for i in range(means.shape[0]):
        lagged = means[i - delay] if i >= delay else np.nan
        s, baseline, scale, learned = _cusum_step(
            s, baseline, scale, learned, means[i], lagged, k, block_s, baseline_s, steady[i], freeze, scale_s, floor
        )
        stat[i] = s
        scales[i] = scale
        if s >= h:
            alarms[n_alarms] = i
            n_alarms += 1
            if restart:
                s = 0.0
            else:
                h = np.inf
    return stat, alarms[:n_alarms], scales


def cusum_path(
    time_s: NDArray[np.float64],
    symptom: NDArray[np.float64],
    settings: DetectorSettings,
    *,
    restart: bool = False,
    steady: NDArray[np.bool_] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The CUSUM over a whole flight: (block end times s, statistic after each block, alarm times s).

    restart=False: the statistic is never reset (as the latched live detector; one alarm at most).
    restart=True: after each alarm the statistic restarts from 0 (to count false alarms over long
    nominal flights: each crossing is one false alarm). steady: per-sample flag (same length as
    time_s, e.g. from :func:`steady_mask`); a block with any unsteady sample holds the statistic.
    """
    ends, means = block_means(time_s, symptom, settings)
    if ends.size == 0:
        return ends, means, np.empty(0)
    block_steady = None
    if steady is not None:
        _, fraction = block_means(time_s, np.asarray(steady, dtype=float), settings)
        block_steady = ~(fraction < 1.0)  # nan (no sample) counts as steady: nothing to hold
    stat, alarm_index = cusum_blocks(means, settings, restart=restart, steady=block_steady)
    return ends, stat, ends[alarm_index]


def cusum_blocks(
    means: NDArray[np.float64],
    settings: DetectorSettings,
    *,
    restart: bool = False,
    steady: NDArray[np.bool_] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The CUSUM over given block means (nan = a block without a sample), compiled: (statistic after
    each block, indices of the blocks that raised an alarm). The statistic the live step's detector
    holds after closing the same blocks; restart and steady (per block) as in :func:`cusum_path`."""
    stat, alarms, _ = _cusum_compiled(means, settings, restart, steady)
    return stat, alarms


def scale_blocks(means: NDArray[np.float64], settings: DetectorSettings) -> NDArray[np.float64]:
    """The detector's online spread (``scale_s`` on) after each of the given block means, symptom unit
    (nan before its first block): what ``ecu-monitor calibrate`` learns ``scale_floor`` from."""
    return _cusum_compiled(means, dataclasses.replace(settings, threshold=1e300), False, None)[2]


def _cusum_compiled(
    means: NDArray[np.float64], settings: DetectorSettings, restart: bool, steady: NDArray[np.bool_] | None
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    m = np.ascontiguousarray(means, dtype=np.float64)
    block_steady = np.ones(m.size, dtype=np.bool_) if steady is None else np.asarray(steady, dtype=np.bool_)
    return _cusum(
        m,
        block_steady,
        settings.reference,
        settings.threshold,
        settings.block_s,
        settings.baseline_s,
        settings.delay_blocks,
        restart,
        settings.baseline_freeze,
        settings.scale_s,
        settings.scale_floor,
    )


def count_alarms(flights: Sequence[tuple[NDArray[Any], ...]], settings: DetectorSettings) -> tuple[int, float]:
    """(false alarms, flight hours) of the detector over nominal flights given as (time_s, symptom)
    or (time_s, symptom, steady)."""
    alarms = 0
    hours = 0.0
    for flight in flights:
        time_s, symptom = flight[0], flight[1]
        steady = np.asarray(flight[2], dtype=np.bool_) if len(flight) > 2 else None
        _, _, alarm_times = cusum_path(time_s, symptom, settings, restart=True, steady=steady)
        alarms += int(alarm_times.size)
        hours += float(time_s[-1] - time_s[0]) / 3600.0
    return alarms, hours


@dataclass(frozen=True)
class ThresholdCalibration:
    """Result of :func:`calibrate_threshold`.

    threshold: the calibrated h. gumbel_threshold: the Gumbel quantile alone. empirical_max: the
    empirical bound (margin x the largest value seen, or the empirical quantile, see
    calibrate_threshold). gumbel_location, gumbel_scale: the fitted law of the hourly maxima.
    hours: number of whole nominal hours used. target_per_100h: the rate asked for.
    """

    threshold: float
    gumbel_threshold: float
    empirical_max: float
    gumbel_location: float
    gumbel_scale: float
    hours: int
    target_per_100h: float


def hourly_maxima(
    statistics: Sequence[NDArray[np.float64]], sample_period_s: float, *, part_hours: bool = False
) -> NDArray[np.float64]:
    """Maximum of each whole hour of each statistic path (paths sampled every sample_period_s);
    ``part_hours``: also the maximum of each path's trailing part-hour."""
    per_hour = round(3600.0 / sample_period_s)
    out: list[float] = []
    for path in statistics:
        values = np.asarray(path, dtype=float)
        whole = values.size // per_hour
        if whole:
            out.extend(values[: whole * per_hour].reshape(whole, per_hour).max(axis=1).tolist())
        if part_hours and values.size > whole * per_hour:
            out.append(float(values[whole * per_hour :].max()))
    return np.asarray(out)


def calibrate_threshold(
    nominal_statistics: Sequence[NDArray[np.float64]],
    target_false_alarms_per_100h: float = 1.0,
    *,
    sample_period_s: float = 1.0,
    margin: float = 1.1,
    minimum: float = 1.0,
) -> ThresholdCalibration:
    """Threshold h giving about ``target_false_alarms_per_100h`` false alarms per 100 flight hours.

    ``nominal_statistics``: CUSUM paths (no alarms, no restart) of nominal flights sampled every
    ``sample_period_s`` (the block length). Each whole hour contributes its maximum; a Gumbel law
    (method of moments: scale = std sqrt(6)/pi, location = mean - 0.5772 scale) is fitted to these
    maxima and h is its quantile at 1 - rate/100 per hour, raised to the empirical bound if that is
    higher (the fit must not undercut what was seen): ``margin`` x the largest value of any path when
    the set holds fewer hours than one expected alarm (100 / rate), else the empirical 1 - rate/100
    quantile of the hourly maxima with each path's trailing part-hour as one more maximum. The
    part-hours count for the empirical bound, not for the Gumbel law of whole-hour maxima: a flight
    ends with descent, landing and taxi, where the nominal statistic often peaks, and a bound that
    dropped them would set h below what the calibration flights themselves reach. ``minimum`` (1 degC
    for a degC/s symptom: 0.1 degC/s of excess for 10 s) keeps h away from 0 when the nominal
    statistic almost never leaves 0 (a gated test): the calibration set then carries no information
    about the tail, and h ~ 0 would alarm on any single block above the allowance.
    """
    if not 0.0 < target_false_alarms_per_100h < 100.0:
        raise ConfigError(
            f"target_false_alarms_per_100h: expected a rate in (0, 100), got {target_false_alarms_per_100h!r}"
        )
    maxima = hourly_maxima(nominal_statistics, sample_period_s)
    if maxima.size < 2:
        raise ConfigError(f"calibrate_threshold: need at least 2 whole nominal flight hours, got {maxima.size}")
    scale = float(np.std(maxima, ddof=1)) * math.sqrt(6.0) / math.pi
    location = float(np.mean(maxima)) - _EULER_GAMMA * scale
    p_hour = target_false_alarms_per_100h / 100.0
    gumbel = location - scale * math.log(-math.log(1.0 - p_hour))
    if p_hour * maxima.size < 1.0:  # fewer hours than one expected alarm: stay above all we saw
        empirical = margin * max(float(np.max(path)) for path in nominal_statistics if len(path))
    else:  # enough hours to see the rate: the empirical quantile of the hourly (and part-hour) maxima
        empirical = float(
            np.quantile(hourly_maxima(nominal_statistics, sample_period_s, part_hours=True), 1.0 - p_hour)
        )
    threshold = max(gumbel, empirical, minimum)
    return ThresholdCalibration(
        threshold=threshold,
        gumbel_threshold=gumbel,
        empirical_max=empirical,
        gumbel_location=location,
        gumbel_scale=scale,
        hours=int(maxima.size),
        target_per_100h=float(target_false_alarms_per_100h),
    )


# --------------------------------------------------------------------------------------------------
# A degradation overlaid on a recorded nominal flight (for testing the detector on real engines)
# --------------------------------------------------------------------------------------------------


def overlay_degradation(
    time_s: NDArray[np.float64],
    cht_c: NDArray[np.float64],
    oat_c: NDArray[np.float64],
    onset_s: float,
    gain: float,
    time_constant_s: float = 240.0,
) -> NDArray[np.float64]:
    """The CHT of a nominal flight with a heat-up degradation overlaid from ``onset_s`` (s, the clock of
    ``time_s``): ``cht + gain (cht - oat)(1 - exp(-(t - onset)/time_constant_s))`` for t >= onset, the
    recorded CHT before. ``gain`` 0.1 and 0.2 give at steady state the rise of (CHT - OAT) that
    gamma_Q = 1.1 and 1.2 give; the first-order approach (time constant about 240 s) is that of the
    head's response. Non-finite readings stay as they are. ParameterError on bad arguments.
    """
    t = np.asarray(time_s, dtype=float)
    cht = np.asarray(cht_c, dtype=float)
    oat = np.asarray(oat_c, dtype=float)
    if t.shape != cht.shape or t.shape != oat.shape or t.ndim != 1:
        raise ParameterError(f"overlay_degradation: time, CHT and OAT must be 1-D of one length, got {t.shape},"
                             f" {cht.shape}, {oat.shape}")  # fmt: skip
    for name, value, low in (
        ("onset_s", onset_s, -math.inf),
        ("gain", gain, 0.0),
        ("time_constant_s", time_constant_s, 0.0),
    ):
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < low:
            raise ParameterError(f"overlay_degradation: {name} must be a finite number >= {low}, got {value!r}")
    if time_constant_s <= 0.0:
        raise ParameterError(f"overlay_degradation: time_constant_s must be > 0, got {time_constant_s!r}")
    elapsed = np.maximum(t - onset_s, 0.0)
    rise = gain * (cht - oat) * -np.expm1(-elapsed / time_constant_s)
    return np.where(t >= onset_s, cht + rise, cht)
