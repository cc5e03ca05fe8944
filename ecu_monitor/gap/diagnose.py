"""The gap diagnosis end to end: baseline, where, which effect, how far, the improved model.

1. Baseline: the nominal model open loop on the train and test flights (RMS, peak).
2. Where: the test residual by segment, operating region, correlations, lag signature, spectrum and
   the whiteness of the filtered innovations (the service's CBEKF-AU on the nominal model).
3. Which: the control (the nominal model with R_Ce and the heat scale re-tuned on the train flight)
   and every library candidate refitted on the train flight only, each scored on the test flight;
   a candidate counts when its held-out gain over the control is significant and material
   (:mod:`ecu_monitor.gap.significance`). The best counting candidate is kept; when it leaves a
   structured residual (test RMS above ``pair_threshold_c``), pairs with it are tried greedily and a
   pair counts only if it beats the single effect by the same test.
4. Verdict: the winning effect(s) and the held-out shrink vs the baseline, or ``None``
   ("unexplained") when no candidate counts; then no candidate is named.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ecu_monitor.errors import ParameterError
from ecu_monitor.estimation import run_estimator
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.gap.library import DEFAULT_CANDIDATE_IDS, Candidate, candidate, flight_references
from ecu_monitor.gap.localise import (
    LagSignature,
    SegmentShare,
    Spectrum,
    correlations,
    heat_map_coverage,
    lag_signature,
    ljung_box,
    region_breakdown,
    residual_spectrum,
    segment_breakdown,
)
from ecu_monitor.gap.refit import (
    FitResult,
    PreparedFlight,
    RefitSettings,
    prepare_flight,
    refit,
    reidentify,
    simulate_probe,
)
from ecu_monitor.gap.segments import SEGMENT_NAMES, Segmentation, SegmentSettings, segment_flight
from ecu_monitor.gap.significance import ImprovementTest, SignificanceSettings, improvement_test
from ecu_monitor.identify import PsoSettings
from ecu_monitor.model import ThermalParams

__all__ = ["EffectScore", "GapDiagnosis", "GapSettings", "diagnose"]

Progress = Callable[[str], None]


@dataclass(frozen=True)
class GapSettings:
    """Settings of the diagnosis: candidates tried, refit, significance, segmentation, pairs.

    refit_mode "local" (default) refits the candidate's parameters and two nominal factors from the
    nominal model (:func:`ecu_monitor.gap.refit.refit`); "reidentify" re-identifies the whole nominal
    model jointly with them (:func:`ecu_monitor.gap.refit.reidentify`, PSO with ``pso``), the choice
    when the nominal model was identified on the train flight itself.

    Pairs are tried when the best single effect leaves a test RMS above ``pair_threshold_c`` (degC);
    a pair must beat the single effect by ``pair_min_shrink_pct`` (a higher bar than a single effect
    against the control: the second effect of a pair is fitted to what the first one leaves, small
    structured remainders such as a slightly wrong nominal altitude exponent included)."""

    candidates: tuple[str, ...] = DEFAULT_CANDIDATE_IDS
    refit: RefitSettings = field(default_factory=RefitSettings)
    significance: SignificanceSettings = field(default_factory=SignificanceSettings)
    segments: SegmentSettings = field(default_factory=SegmentSettings)
    try_pairs: bool = True
    pair_threshold_c: float = 1.0
    pair_min_shrink_pct: float = 30.0
    whiteness_estimator: str | None = "cbekf-au"
    refit_mode: str = "local"
    pso: PsoSettings = field(default_factory=PsoSettings)

    def __post_init__(self) -> None:
        for cid in self.candidates:
            candidate(cid)  # raises ParameterError if unknown
        if not self.candidates:
            raise ParameterError("gap: at least one candidate effect is needed")
        if self.refit_mode not in ("local", "reidentify"):
            raise ParameterError(f"gap refit mode: expected 'local' or 'reidentify', got {self.refit_mode!r}")


@dataclass(frozen=True)
class EffectScore:
    """A refitted candidate (or the control) scored on the test flight."""

    fit: FitResult
    test_residual: np.ndarray  # measured - model on the test flight, degC
    test_rms_c: float
    test_peak_c: float
    shrink_pct: float  # held-out RMS shrink vs the baseline (nominal model), %
    versus: ImprovementTest | None  # against the control (singles) or the single effect (pairs)
    role: str  # "control", "single" or "pair"

    @property
    def label(self) -> str:
        """Candidate ids joined with '+' ('control' for the effect-free refit)."""
        return self.fit.label

    @property
    def counts(self) -> bool:
        """Significant and material against its reference."""
        return self.versus is not None and self.versus.counts


@dataclass(frozen=True)
class GapDiagnosis:
    """Everything the report needs (arrays on the test flight's samples)."""

    nominal: ThermalParams
    train: PreparedFlight
    test: PreparedFlight
    baseline_train_residual: np.ndarray
    baseline_test_residual: np.ndarray
    baseline_test_model_c: np.ndarray
    model_rate_c_per_s: np.ndarray
    segmentation: Segmentation
    where: list[SegmentShare]
    regions: dict[str, list[dict[str, float]]]
    correlation: dict[str, float]
    lag: LagSignature
    spectrum: Spectrum
    whiteness: dict[str, Any]
    coverage: dict[str, float]
    control: EffectScore
    effects: list[EffectScore]  # every single and pair tried, sorted by test RMS
    winner: EffectScore | None
    winner_segment: str  # segment with the largest held-out gain of the winner over the control (where[0] if null)
    segment_gain: dict[str, float]  # share of the winner's squared-error reduction (vs the control) by segment
    model: ThermalParams  # the winner's model, or the nominal model when unexplained
    settings: GapSettings
    references: dict[str, float]

    @property
    def verdict_ids(self) -> tuple[str, ...]:
        """The winning candidate ids (empty: unexplained)."""
        return self.winner.fit.ids if self.winner is not None else ()


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.asarray(x, dtype=float) ** 2)))


def _score(
    fit: FitResult,
    test: PreparedFlight,
    baseline_rms: float,
    engine: str,
    role: str,
    reference: np.ndarray | None,
    n_tests: int,
    significance: SignificanceSettings,
) -> EffectScore:
    model = simulate_probe([fit.params], test, engine)[:, 0]
    residual = test.cht_c - model
    if not np.all(np.isfinite(residual)):  # a diverged run scores 1000 degC where it failed: it never counts
        residual = np.where(np.isfinite(residual), residual, 1e3)
    rms = _rms(residual)
    versus = None
    if reference is not None:
        versus = improvement_test(reference, residual, test.dt_s, n_tests, significance)
    return EffectScore(
        fit=fit,
        test_residual=residual,
        test_rms_c=rms,
        test_peak_c=float(np.max(np.abs(residual))),
        shrink_pct=100.0 * (1.0 - rms / baseline_rms) if baseline_rms > 0 else 0.0,
        versus=versus,
        role=role,
    )


def _whiteness(nominal: ThermalParams, test_log: FlightLog, estimator: str | None) -> dict[str, Any]:
    if estimator is None:
        return {"estimator": None}
    trace = run_estimator(test_log, nominal, estimator)
    innovation = np.asarray(trace.innovation, dtype=float)
    innovation = innovation[np.isfinite(innovation)]  # one per CHT reading
    result: dict[str, Any] = {"estimator": estimator, **ljung_box(innovation, lags=20)}
    result["innovation_rms_c"] = float(np.sqrt(np.mean(innovation**2))) if innovation.size else 0.0
    return result


def _second_acts(
    pair: EffectScore, nominal: ThermalParams, test: PreparedFlight, engine: str, settings: GapSettings
) -> bool:
    """True when the pair's second effect changes its test prediction by at least min_rms_drop_c RMS
    (switched off with every other fitted value kept): a pair whose gain comes from a better fit of
    the first effect's own parameters does not name a second effect."""
    entry = candidate(pair.fit.ids[1])
    params = pair.fit.params
    if entry.effect == "nominal":
        without = params.replace(**{p.name: getattr(nominal, p.name) for p in entry.free})
    else:
        without = params.replace(effects=params.effects.replace(entry.effect, None))
    both = simulate_probe([params, without], test, engine)
    change = float(np.sqrt(np.mean((both[:, 0] - both[:, 1]) ** 2)))
    return change >= settings.significance.min_rms_drop_c


def _segment_gain(reference: np.ndarray, improved: np.ndarray, segmentation: Segmentation) -> dict[str, float]:
    gain = reference**2 - improved**2
    total = float(np.sum(np.clip(gain, 0.0, None))) or 1.0
    out = {}
    for index, name in enumerate(SEGMENT_NAMES):
        mask = segmentation.labels == index
        if np.any(mask):
            out[name] = float(np.sum(gain[mask])) / total
    return out


def diagnose(
    nominal: ThermalParams,
    train_log: FlightLog,
    test_log: FlightLog,
    settings: GapSettings | None = None,
    progress: Progress | None = None,
) -> GapDiagnosis:
    """Run the whole diagnosis of ``nominal`` with ``train_log`` for refits and ``test_log`` held out."""
    settings = settings or GapSettings()
    say = progress or (lambda message: None)
    engine = settings.refit.engine
    axes = nominal.heat_axes
    train = prepare_flight(train_log, axes, settings.refit.dt_s)
    test = prepare_flight(test_log, axes, settings.refit.dt_s)
    references = flight_references(train_log, settings.segments.ground_airspeed_mps)

    say("baseline: nominal model open loop on both flights")
    base_train = train.cht_c - simulate_probe([nominal], train, engine)[:, 0]
    base_model = simulate_probe([nominal], test, engine)[:, 0]
    base_test = test.cht_c - base_model
    baseline_rms = _rms(base_test)

    say("where: segments, regions, correlations, spectrum, innovations")
    segmentation = segment_flight(test_log, settings.segments)
    rate = np.gradient(base_model, test_log.time_s)
    columns = [c for c in (*axes, "airspeed_mps", "altitude_m", "oat_c") if test_log.has(c)]
    columns = list(dict.fromkeys(columns))
    where = segment_breakdown(base_test, segmentation, test.dt_s)
    regions = region_breakdown(base_test, test_log, columns)
    corr = correlations(base_test, test_log, columns, rate)
    lag = lag_signature(base_test, rate)
    spectrum = residual_spectrum(base_test, test.dt_s)
    whiteness = _whiteness(nominal, test_log, settings.whiteness_estimator)
    hm = nominal.heat_map
    coverage = heat_map_coverage(base_test, train_log, test_log, axes, hm.x_breakpoints, hm.y_breakpoints)

    def fit_candidates(entries: list[Candidate]) -> FitResult:
        if settings.refit_mode == "reidentify":
            return reidentify(nominal, train, entries, references, settings.refit, settings.pso)
        return refit(nominal, train, entries, references, settings.refit)

    say("refit: control (nominal with R_Ce and heat scale re-tuned on the train flight)")
    control_fit = fit_candidates([])
    control = _score(control_fit, test, baseline_rms, engine, "control", None, 1, settings.significance)
    n_tests = len(settings.candidates)
    singles: list[EffectScore] = []
    for cid in settings.candidates:
        say(f"refit: {cid}")
        fit = fit_candidates([candidate(cid)])
        singles.append(
            _score(fit, test, baseline_rms, engine, "single", control.test_residual, n_tests, settings.significance)
        )
    counting = [s for s in singles if s.counts]
    winner = min(counting, key=lambda s: s.test_rms_c) if counting else None
    pairs: list[EffectScore] = []
    if winner is not None and settings.try_pairs and winner.test_rms_c > settings.pair_threshold_c:
        first = winner.fit.ids[0]
        others = [cid for cid in settings.candidates if cid != first]
        pair_test = dataclasses.replace(settings.significance, min_shrink_pct=settings.pair_min_shrink_pct)
        for cid in others:
            say(f"refit: pair {first}+{cid}")
            fit = fit_candidates([candidate(first), candidate(cid)])
            pairs.append(_score(fit, test, baseline_rms, engine, "pair", winner.test_residual, len(others), pair_test))
        better = [p for p in pairs if p.counts and _second_acts(p, nominal, test, engine, settings)]
        if better:
            winner = min(better, key=lambda s: s.test_rms_c)
    effects = sorted(singles + pairs, key=lambda s: s.test_rms_c)
    if winner is not None:
        gain = _segment_gain(control.test_residual, winner.test_residual, segmentation)
        winner_segment = max(gain, key=lambda k: gain[k])
        model = winner.fit.params
    else:
        gain = {}
        winner_segment = where[0].segment
        model = nominal
    say("verdict: " + (winner.label if winner is not None else "unexplained"))
    return GapDiagnosis(
        nominal=nominal,
        train=train,
        test=test,
        baseline_train_residual=base_train,
        baseline_test_residual=base_test,
        baseline_test_model_c=base_model,
        model_rate_c_per_s=rate,
        segmentation=segmentation,
        where=where,
        regions=regions,
        correlation=corr,
        lag=lag,
        spectrum=spectrum,
        whiteness=whiteness,
        coverage=coverage,
        control=control,
        effects=effects,
        winner=winner,
        winner_segment=winner_segment,
        segment_gain=gain,
        model=model,
        settings=settings,
        references=references,
    )
