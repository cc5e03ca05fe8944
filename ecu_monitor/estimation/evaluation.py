"""Evaluation of detection, isolation, the CBEKF-AU reset and thermal headroom on simulated flights.

The virtual ECU (:func:`virtual_bus.plant.fly`) flies random missions
(:func:`virtual_bus.missions.random_mission`); the monitor runs the nominal model (the paper's Table A1
by default). Three sets of flights, disjoint in seeds:

* calibration: nominal flights (>= ``hours``) on which the CUSUM threshold is set
  (:func:`~ecu_monitor.estimation.detection.calibrate_threshold`);
* scoring: other nominal flights (>= ``hours``) on which false alarms per 100 flight hours are counted;
* degraded: step degradations of gamma_Q, gamma_D or both at a random time, several severities,
  missions and seeds: detection delay, isolation accuracy 300 s after onset, estimate error.

Every flight carries unmodelled effects drawn by :func:`residual_effects`: the truth plant is never the
monitor's model. Sizes are those left over after the model has been identified on this engine (the
paper's validated model has mean error < 2-3 %, peak < 10 %): the open-loop error of the nominal
model on these flights is measured and reported beside the results. :func:`full_size_effects_check`
repeats the false-alarm count with the plant's full-size effects (``virtual_bus.plant.random_effects``)
on an un-refitted model, to show what identification buys.

Work is spread over ``workers`` processes (2 by default; short bursts).
"""

from __future__ import annotations

import math
import multiprocessing
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.estimation.detection import (
    DetectorSettings,
    ThresholdCalibration,
    block_means,
    calibrate_threshold,
    count_alarms,
    cusum_path,
)
from ecu_monitor.estimation.ekf import EstimatorSettings
from ecu_monitor.estimation.headroom import thermal_headroom
from ecu_monitor.estimation.isolation import IsolationSettings, run_isolation
from ecu_monitor.estimation.runner import run_estimator
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.model import (
    AirspeedCooling,
    DensityCooling,
    Effects,
    InputSeries,
    MixtureCooling,
    SensorLag,
    ThermalParams,
    coefficients,
    paper_table_a1,
)
from ecu_monitor.model.compiled import simulate_compiled

__all__ = [
    "RESET_MODES_COMPARED",
    "SYMPTOMS",
    "Campaign",
    "EvaluationConfig",
    "FlightCase",
    "FlightResult",
    "HeadroomCheck",
    "headroom_check",
    "plan_cases",
    "residual_effects",
    "run_campaign",
    "simulate_case",
]

#: Symptoms compared for detection: the CBEKF's model deviation (the paper's) and the isolation
#: filter's model deviation f(T, gammas) - f(T, 1, 1). Both degC/s.
SYMPTOMS = ("cbekf", "iso")
#: CBEKF-AU re-initialisations compared.
RESET_MODES_COMPARED = ("midpoint", "boundary")
#: Seconds after onset at which isolation is scored.
ISOLATION_AFTER_S = (300.0, 600.0)


def residual_effects(seed: int) -> Effects:
    """Unmodelled effects of residual size (each on with probability 0.75), deterministic for seed.

    airspeed_cooling gain 0.002-0.008 /(m/s) (floor 0.5); density_cooling exponent 0.05-0.2;
    sensor_lag 1-4 s; mixture_cooling fraction 0.02-0.06 from onset 0.6-0.8. These are a quarter to a
    fifth of the truth plant's full-size ranges (virtual_bus.plant.random_effects): what a model
    identified on this engine (PSO with altitude exponents, heat map and heat-path delay free) leaves
    unexplained.
    """
    rng = np.random.default_rng(np.random.SeedSequence([seed, 7919]))
    draws = rng.uniform(size=8)
    return Effects(
        airspeed_cooling=AirspeedCooling(gain_per_mps=0.002 + 0.006 * draws[1], floor=0.5) if draws[0] < 0.75 else None,
        density_cooling=DensityCooling(exponent=0.05 + 0.15 * draws[3]) if draws[2] < 0.75 else None,
        sensor_lag=SensorLag(time_constant_s=1.0 + 3.0 * draws[5]) if draws[4] < 0.75 else None,
        mixture_cooling=MixtureCooling(fraction=0.02 + 0.04 * draws[7], onset=0.6 + 0.2 * rng.uniform())
        if draws[6] < 0.75
        else None,
    )


@dataclass(frozen=True)
class EvaluationConfig:
    """What :func:`run_campaign` simulates.

    hours: nominal flight hours in each of the calibration and the scoring set (>= 50 for the
    report). seed: base seed (sets are disjoint: seed*100000 + 10000/20000/30000 + i).
    severities: gamma values of the degraded flights; combined_severities: values used for both
    gammas at once. degraded_seeds: missions per (kind, severity). target_per_100h: false-alarm rate
    the threshold is calibrated for. workers: processes. full_size: also score nominal flights with
    the plant's full-size effects (hours of those).
    """

    hours: float = 50.0
    seed: int = 0
    severities: tuple[float, ...] = (1.05, 1.1, 1.2, 1.3, 1.5)
    combined_severities: tuple[float, ...] = (1.05, 1.1, 1.2)
    degraded_seeds: int = 4
    target_per_100h: float = 1.0
    workers: int = 2
    full_size_hours: float = 10.0
    detector: DetectorSettings = field(default_factory=lambda: DetectorSettings(reference=0.04, block_s=1.0))
    isolation: IsolationSettings = field(default_factory=IsolationSettings)
    estimator: EstimatorSettings = field(default_factory=EstimatorSettings)


@dataclass(frozen=True)
class FlightCase:
    """One simulated flight: role (calibration, scoring, degraded, full_size), mission seed, planned
    mission duration (s), kind (nominal, gamma_q, gamma_d, combined), severity, onset time (s)."""

    role: str
    seed: int
    duration_s: float
    kind: str = "nominal"
    severity: float = 1.0
    onset_s: float = math.inf

    @property
    def gamma_q(self) -> float:
        return self.severity if self.kind in ("gamma_q", "combined") else 1.0

    @property
    def gamma_d(self) -> float:
        return self.severity if self.kind in ("gamma_d", "combined") else 1.0


class FlightResult(NamedTuple):
    """What one flight leaves for the report (1 s samples and a few figures)."""

    case: FlightCase
    hours: float
    time_s: NDArray[np.float64]  # 1 s block ends
    symptoms: dict[str, NDArray[np.float64]]  # symptom name -> 1 s block means, degC/s
    gamma_q: NDArray[np.float64]  # isolation filter, 1 s means
    gamma_d: NDArray[np.float64]
    cht_rms_c: dict[str, float]  # estimator -> RMS of (estimate - true CHT), degC (after onset if degraded)
    model_error_mean_pct: float  # open-loop nominal model vs truth: mean |error| / (T - OAT), %
    model_error_peak_c: float  # largest |open-loop error|, degC
    model_error_mean_c: float


def plan_cases(config: EvaluationConfig) -> list[FlightCase]:
    """Flights of the campaign (deterministic for config.seed)."""
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 4242]))
    base = config.seed * 100_000
    cases: list[FlightCase] = []
    for role, offset, hours in (
        ("calibration", 10_000, config.hours),
        ("scoring", 20_000, config.hours),
        ("full_size", 40_000, config.full_size_hours),
    ):
        total = 0.0
        i = 0
        while total < hours * 3600.0:
            duration = float(rng.uniform(3600.0, 3.0 * 3600.0))
            cases.append(FlightCase(role, base + offset + i, duration))
            total += duration
            i += 1
    i = 0
    plan = [(kind, s) for kind in ("gamma_q", "gamma_d") for s in config.severities]
    plan += [("combined", s) for s in config.combined_severities]
    for kind, severity in plan:
        for _ in range(config.degraded_seeds):
            onset = float(rng.uniform(600.0, 3000.0))
            cases.append(FlightCase("degraded", base + 30_000 + i, 5400.0, kind, severity, onset))
            i += 1
    return cases


def _fly(case: FlightCase, params: ThermalParams) -> FlightLog:
    from virtual_bus.missions import random_mission
    from virtual_bus.plant import Degradation, fly, random_effects

    effects = random_effects(case.seed) if case.role == "full_size" else residual_effects(case.seed)
    degradation = []
    if case.gamma_q != 1.0:
        degradation.append(Degradation("gamma_q", case.gamma_q, case.onset_s))
    if case.gamma_d != 1.0:
        degradation.append(Degradation("gamma_d", case.gamma_d, case.onset_s))
    max_duration = case.onset_s + 900.0 if case.kind != "nominal" else None
    return fly(
        random_mission(case.seed, case.duration_s),
        params,
        effects=effects,
        degradation=degradation,
        seed=case.seed,
        max_duration_s=max_duration,
    )


def _model_error(log: FlightLog, params: ThermalParams) -> tuple[float, float, float]:
    """Open-loop nominal model vs the truth CHT: (mean |err| % of the rise over OAT, peak degC, mean degC)."""
    x_axis, y_axis = params.heat_axes
    inputs = InputSeries(log[x_axis], log[y_axis], log["altitude_m"], log["airspeed_mps"], log["oat_c"])
    dt = float(np.median(np.diff(log.time_s)))
    run = simulate_compiled(inputs, coefficients(params), dt, float(log["cht_true_c"][0]))
    err = np.abs(run.cht_c - log["cht_true_c"])
    rise = np.maximum(log["cht_true_c"] - log["oat_c"], 10.0)
    return float(100.0 * np.mean(err / rise)), float(np.max(err)), float(np.mean(err))


def simulate_case(case: FlightCase, params: ThermalParams, config: EvaluationConfig) -> FlightResult:
    """Fly one case and run every estimator over it; keep 1 s symptoms and summary figures."""
    log = _fly(case, params)
    one_second = DetectorSettings(threshold=1.0, reference=0.0, warmup_s=0.0, block_s=1.0)
    t = log.time_s
    truth_t = t
    truth_cht = log["cht_true_c"]
    scored = truth_t >= (case.onset_s if math.isfinite(case.onset_s) else -math.inf)
    symptoms: dict[str, NDArray[np.float64]] = {}
    rms: dict[str, float] = {}
    cbekf = run_estimator(log, params, "cbekf", config.estimator)
    ends, symptoms["cbekf"] = block_means(cbekf.time_s, cbekf.deviation, one_second)
    for mode in RESET_MODES_COMPARED:
        settings = EstimatorSettings(**{**_settings_dict(config.estimator), "reset": mode})
        trace = run_estimator(log, params, "cbekf-au", settings)
        est = np.interp(truth_t, trace.time_s, trace.cht_est_c)
        rms[f"cbekf-au/{mode}"] = float(np.sqrt(np.mean((est - truth_cht)[scored] ** 2)))
    est = np.interp(truth_t, cbekf.time_s, cbekf.cht_est_c)
    rms["cbekf"] = float(np.sqrt(np.mean((est - truth_cht)[scored] ** 2)))
    iso = run_isolation(log, params, config.isolation)
    rms["cbekf-iso"] = float(np.sqrt(np.mean((iso.cht_c - truth_cht)[scored] ** 2)))
    _, symptoms["iso"] = block_means(iso.time_s, iso.deviation, one_second)
    _, gq = block_means(iso.time_s, iso.gamma_q, one_second)
    _, gd = block_means(iso.time_s, iso.gamma_d, one_second)
    n = min(ends.size, gq.size, symptoms["iso"].size, symptoms["cbekf"].size)
    symptoms = {k: v[:n] for k, v in symptoms.items()}
    err_pct, err_peak, err_mean = _model_error(log, params)
    return FlightResult(
        case, log.duration_s / 3600.0, ends[:n], symptoms, gq[:n], gd[:n], rms, err_pct, err_peak, err_mean
    )


def _settings_dict(settings: EstimatorSettings) -> dict[str, Any]:
    from dataclasses import asdict

    return asdict(settings)


def _simulate_star(args: tuple[FlightCase, ThermalParams, EvaluationConfig]) -> FlightResult:
    return simulate_case(*args)


def run_campaign(
    config: EvaluationConfig,
    params: ThermalParams | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[FlightResult]:
    """Simulate every planned flight (in ``config.workers`` processes) and return their results."""
    params = params or paper_table_a1()
    cases = plan_cases(config)
    jobs = [(case, params, config) for case in cases]
    results: list[FlightResult] = []
    if config.workers <= 1:
        for i, job in enumerate(jobs):
            results.append(_simulate_star(job))
            if progress:
                progress(i + 1, len(jobs))
        return results
    with multiprocessing.get_context("fork").Pool(config.workers) as pool:
        for i, result in enumerate(pool.imap(_simulate_star, jobs, chunksize=1)):
            results.append(result)
            if progress:
                progress(i + 1, len(jobs))
    return results


# --------------------------------------------------------------------------------------------------
# Scoring
# --------------------------------------------------------------------------------------------------


class DelayRow(NamedTuple):
    """Detection of one degraded flight: delay (s, inf = not within 900 s), early (alarm before onset)."""

    case: FlightCase
    delay_s: float
    early: bool


@dataclass
class Campaign:
    """Scored campaign: thresholds, false alarms, delays, isolation and reset figures per symptom."""

    config: EvaluationConfig
    results: list[FlightResult]
    calibration: dict[str, ThresholdCalibration] = field(default_factory=dict)
    false_alarms: dict[str, tuple[int, float]] = field(default_factory=dict)
    full_size_alarms: dict[str, tuple[int, float]] = field(default_factory=dict)
    delays: dict[str, list[DelayRow]] = field(default_factory=dict)

    def role(self, name: str) -> list[FlightResult]:
        return [r for r in self.results if r.case.role == name]

    def detector(self, symptom: str) -> DetectorSettings:
        """The detector settings with the calibrated threshold of ``symptom``."""
        base = self.config.detector
        return DetectorSettings(
            threshold=self.calibration[symptom].threshold,
            reference=base.reference,
            warmup_s=base.warmup_s,
            suspect_fraction=base.suspect_fraction,
            block_s=base.block_s,
        )


def score(config: EvaluationConfig, results: list[FlightResult]) -> Campaign:
    """Calibrate on the calibration set, count false alarms on the scoring set, measure delays."""
    campaign = Campaign(config, results)
    base = config.detector
    for symptom in SYMPTOMS:
        free = DetectorSettings(threshold=1.0, reference=base.reference, warmup_s=base.warmup_s, block_s=base.block_s)
        paths = []
        for r in campaign.role("calibration"):
            _, stat, _ = cusum_path(r.time_s, r.symptoms[symptom], _no_alarm(free))
            paths.append(stat)
        campaign.calibration[symptom] = calibrate_threshold(paths, config.target_per_100h, sample_period_s=base.block_s)
        detector = campaign.detector(symptom)
        campaign.false_alarms[symptom] = count_alarms(
            [(r.time_s, r.symptoms[symptom]) for r in campaign.role("scoring")], detector
        )
        campaign.full_size_alarms[symptom] = count_alarms(
            [(r.time_s, r.symptoms[symptom]) for r in campaign.role("full_size")], detector
        )
        rows = []
        for r in campaign.role("degraded"):
            _, _, alarms = cusum_path(r.time_s, r.symptoms[symptom], detector)
            if alarms.size == 0:
                rows.append(DelayRow(r.case, math.inf, False))
            elif alarms[0] < r.case.onset_s:
                rows.append(DelayRow(r.case, math.nan, True))
            else:
                rows.append(DelayRow(r.case, float(alarms[0] - r.case.onset_s), False))
        campaign.delays[symptom] = rows
    return campaign


def _no_alarm(settings: DetectorSettings) -> DetectorSettings:
    return DetectorSettings(
        threshold=1e300, reference=settings.reference, warmup_s=settings.warmup_s, block_s=settings.block_s
    )


def isolation_errors(result: FlightResult, after_s: float) -> tuple[float, float]:
    """(gamma_Q estimate - truth, gamma_D estimate - truth) ``after_s`` seconds after onset (nan if
    the flight ended before)."""
    when = result.case.onset_s + after_s
    if not result.time_s.size or when > result.time_s[-1]:
        return math.nan, math.nan
    k = int(np.searchsorted(result.time_s, when))
    k = min(k, result.time_s.size - 1)
    return float(result.gamma_q[k] - result.case.gamma_q), float(result.gamma_d[k] - result.case.gamma_d)


# --------------------------------------------------------------------------------------------------
# Headroom against the truth plant
# --------------------------------------------------------------------------------------------------


class HeadroomCheck(NamedTuple):
    """One headroom prediction: severity of gamma_Q, residual-effects seed, time of the prediction
    (s), predicted time to limit with the filter's gammas and with the true gammas (s), actual (s)."""

    severity: float
    seed: int
    at_s: float
    predicted_s: float
    predicted_true_gamma_s: float
    actual_s: float


def _full_throttle_mission(seed: int) -> Any:
    from virtual_bus.missions import Atmosphere, Climb, Cruise, GroundRun, Landing, Mission, Takeoff

    rng = np.random.default_rng(seed)
    return Mission(
        name=f"full-throttle-{seed}",
        segments=(
            GroundRun(duration_s=120.0, throttle_pct=30.0),
            Takeoff(),
            Climb(target_altitude_m=float(rng.uniform(200.0, 600.0)), throttle_pct=60.0, airspeed_mps=22.0),
            Cruise(duration_s=900.0, throttle_pct=50.0, airspeed_mps=23.0),
            Cruise(duration_s=3000.0, throttle_pct=float(rng.uniform(85.0, 100.0)), airspeed_mps=23.0),
            Landing(),
        ),
        atmosphere=Atmosphere(oat_offset_c=float(rng.uniform(-5.0, 15.0))),
    )


def headroom_check(
    params: ThermalParams | None = None,
    severities: Sequence[float] = (1.0, 1.1, 1.2),
    seeds: Sequence[int] = (1, 2, 3),
    isolation: IsolationSettings | None = None,
) -> list[HeadroomCheck]:
    """Predict the time to the CHT limit during a held high-power leg and compare with the truth plant.

    Mission: ground run, take-off, a climb to 200-600 m, 900 s cruise at 50 %, then 3000 s at 85-100 %
    throttle (held; OAT offset -5..+15 degC) with gamma_Q = severity from the start of the flight
    and residual unmodelled effects. Predictions every 60 s of the high-power leg until the limit,
    from the isolation filter's state (CHT, Pade state, gamma estimates) and the inputs at that time.
    """
    from virtual_bus.plant import Degradation, fly

    params = params or paper_table_a1()
    isolation = isolation or IsolationSettings()
    coeffs = coefficients(params)
    limit = params.cht_limit_c
    checks: list[HeadroomCheck] = []
    for severity in severities:
        for seed in seeds:
            degradation = [Degradation("gamma_q", severity, 0.0)] if severity != 1.0 else []
            log = fly(_full_throttle_mission(seed), params, effects=residual_effects(seed), degradation=degradation,
                      seed=seed)  # fmt: skip
            t = log.time_s
            truth = log["cht_true_c"]
            iso = run_isolation(log, params, isolation)
            high = np.nonzero(log["throttle_pct"] > 80.0)[0]
            if high.size == 0:
                continue
            start = float(t[high[0]]) + 30.0
            over = np.nonzero(truth >= limit)[0]
            crossing = float(t[over[0]]) if over.size else math.inf
            at = start
            x_axis, y_axis = params.heat_axes
            while at < min(crossing, start + 2400.0):
                k = int(np.searchsorted(t, at))
                u = InputSeries(*(float(log[c][k]) for c in (x_axis, y_axis, "altitude_m", "airspeed_mps", "oat_c")))
                est = thermal_headroom(float(iso.cht_c[k]), None, u, params, gamma_q=float(iso.gamma_q[k]),
                                       gamma_d=float(iso.gamma_d[k]), coeffs=coeffs)  # fmt: skip
                true_gamma = thermal_headroom(float(iso.cht_c[k]), None, u, params, gamma_q=severity, coeffs=coeffs)
                actual = crossing - float(t[k]) if math.isfinite(crossing) else math.inf
                checks.append(HeadroomCheck(severity, seed, float(t[k]), est.time_to_limit_s,
                                            true_gamma.time_to_limit_s, actual))  # fmt: skip
                at += 60.0
    return checks
