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
from collections.abc import Callable, Sequence
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

__all__ = [
    "JOINT_REFIT",
    "EffectScore",
    "GapDiagnosis",
    "GapSettings",
    "HeldOutFlight",
    "cross_validate",
    "diagnose",
]

#: The re-identification of "reidentify" mode: no swarm iterations, so the best of the initial swarm
#: (the given nominal model with the candidate switched on at its neutral start is one of its
#: particles) is polished by least squares jointly over the whole model and the candidate. On the
#: real flights this gave the same held-out scores as a full PSO run (48 particles x 120 iterations)
#: at a third of the time (docs/results/gap_real.md); pass ``pso=PsoSettings()`` for the full search.
JOINT_REFIT = PsoSettings(particles=4, iterations=0)

Progress = Callable[[str], None]


@dataclass(frozen=True)
class GapSettings:
    """Settings of the diagnosis: candidates tried, refit, significance, segmentation, pairs.

    refit_mode "local" (default) refits the candidate's parameters and two nominal factors from the
    nominal model (:func:`ecu_monitor.gap.refit.refit`); "reidentify" re-identifies the whole nominal
    model jointly with them (:func:`ecu_monitor.gap.refit.reidentify`, with ``pso``: by default
    :data:`JOINT_REFIT`, a joint least-squares refit from the given model), the choice
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
    pso: PsoSettings = field(default_factory=lambda: JOINT_REFIT)

    def __post_init__(self) -> None:
        for cid in self.candidates:
            candidate(cid)  # raises ParameterError if unknown
        if not self.candidates:
            raise ParameterError("gap: at least one candidate effect is needed")
        if self.refit_mode not in ("local", "reidentify"):
            raise ParameterError(f"gap refit mode: expected 'local' or 'reidentify', got {self.refit_mode!r}")


@dataclass(frozen=True)
class EffectScore:
    """A refitted candidate (or the control) scored on the test flight(s): residuals per test flight,
    RMS and peak pooled over all of them."""

    fit: FitResult
    flight_residuals: tuple[np.ndarray, ...]  # measured - model on each test flight, degC
    test_rms_c: float
    test_peak_c: float
    shrink_pct: float  # pooled held-out RMS shrink vs the baseline (nominal model), %
    versus: ImprovementTest | None  # against the control (singles) or the single effect (pairs)
    role: str  # "control", "single" or "pair"
    fold_fits: tuple[FitResult, ...] = ()  # cross-validation: the refit of each fold (fit = the first)

    @property
    def label(self) -> str:
        """Candidate ids joined with '+' ('control' for the effect-free refit)."""
        return self.fit.label

    @property
    def test_residual(self) -> np.ndarray:
        """The residuals of every test flight end to end, degC."""
        return np.concatenate(self.flight_residuals)

    @property
    def flight_rms_c(self) -> tuple[float, ...]:
        """Held-out RMS on each test flight, degC."""
        return tuple(_rms(r) for r in self.flight_residuals)

    @property
    def counts(self) -> bool:
        """Significant and material against its reference."""
        return self.versus is not None and self.versus.counts


@dataclass(frozen=True)
class HeldOutFlight:
    """One held-out flight: the nominal model's open-loop baseline on it and where it departs."""

    flight: PreparedFlight
    baseline_residual: np.ndarray  # measured - nominal model, degC
    baseline_model_c: np.ndarray
    model_rate_c_per_s: np.ndarray
    segmentation: Segmentation
    where: list[SegmentShare]

    @property
    def name(self) -> str:
        """The flight's source (file name)."""
        return self.flight.log.source

    @property
    def baseline_rms_c(self) -> float:
        """RMS of the baseline residual, degC."""
        return _rms(self.baseline_residual)


@dataclass(frozen=True)
class GapDiagnosis:
    """Everything the report needs. Pooled quantities are over every test flight end to end;
    ``tests`` holds each test flight's own baseline and segments."""

    nominal: ThermalParams
    trains: tuple[PreparedFlight, ...]
    tests: tuple[HeldOutFlight, ...]
    baseline_train_residual: np.ndarray  # every train flight end to end
    baseline_test_residual: np.ndarray  # every test flight end to end
    where: list[SegmentShare]  # pooled over the test flights
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
    folds: int = 1  # > 1: leave-one-flight-out (each test flight scored by refits on the others)

    @property
    def train(self) -> PreparedFlight:
        """The first train flight."""
        return self.trains[0]

    @property
    def test(self) -> PreparedFlight:
        """The first test flight."""
        return self.tests[0].flight

    @property
    def verdict_ids(self) -> tuple[str, ...]:
        """The winning candidate ids (empty: unexplained)."""
        return self.winner.fit.ids if self.winner is not None else ()

    def flight_detail(self, score: EffectScore | None = None) -> list[dict[str, Any]]:
        """Per test flight: baseline, control and ``score`` (default the winner) RMS, their shrink,
        and by segment the RMS before/after and whether the effect holds there (its RMS below the
        control's)."""
        score = score if score is not None else self.winner
        rows = []
        for k, test in enumerate(self.tests):
            base = test.baseline_residual
            control = self.control.flight_residuals[k]
            row: dict[str, Any] = {
                "flight": test.name,
                "duration_s": float(test.flight.log.duration_s),
                "samples": int(base.size),
                "baseline_rms_c": _rms(base),
                "baseline_peak_c": float(np.max(np.abs(base))),
                "control_rms_c": _rms(control),
                "where": [w.to_dict() for w in test.where],
            }
            if score is not None:
                after = score.flight_residuals[k]
                row["test_rms_c"] = _rms(after)
                row["test_peak_c"] = float(np.max(np.abs(after)))
                row["shrink_pct"] = _shrink(_rms(base), _rms(after))
                row["shrink_vs_control_pct"] = _shrink(_rms(control), _rms(after))
                segments = {}
                for index, name in enumerate(SEGMENT_NAMES):
                    mask = test.segmentation.labels == index
                    if not np.any(mask):
                        continue
                    b, c, a = _rms(base[mask]), _rms(control[mask]), _rms(after[mask])
                    segments[name] = {
                        "duration_s": float(mask.sum()) * test.flight.dt_s,
                        "baseline_rms_c": b,
                        "control_rms_c": c,
                        "rms_c": a,
                        "shrink_pct": _shrink(b, a),
                        "shrink_vs_control_pct": _shrink(c, a),
                        "holds": bool(a < c and a < b),
                    }
                row["segments"] = segments
            rows.append(row)
        return rows


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.asarray(x, dtype=float) ** 2)))


def _shrink(before: float, after: float) -> float:
    return 100.0 * (1.0 - after / before) if before > 0 else 0.0


@dataclass(frozen=True)
class _Fold:
    """One refit set-up: the nominal model, the flights the candidates are refitted on, their
    reference conditions, and the indices (into the diagnosis's test flights) it is scored on."""

    nominal: ThermalParams
    trains: tuple[PreparedFlight, ...]
    references: dict[str, float]
    tests: tuple[int, ...]


def _score(
    fits: Sequence[FitResult],
    folds: Sequence[_Fold],
    tests: tuple[HeldOutFlight, ...],
    baseline_rms: float,
    engine: str,
    role: str,
    reference: EffectScore | None,
    n_tests: int,
    significance: SignificanceSettings,
) -> EffectScore:
    """Each fold's fit simulated on that fold's test flights; residuals in the order of ``tests``."""
    by_flight: dict[int, np.ndarray] = {}
    for fit, fold in zip(fits, folds, strict=True):
        for k in fold.tests:
            model = simulate_probe([fit.params], tests[k].flight, engine)[:, 0]
            residual = tests[k].flight.cht_c - model
            if not np.all(np.isfinite(residual)):  # a diverged run scores 1000 degC where it failed: it never counts
                residual = np.where(np.isfinite(residual), residual, 1e3)
            by_flight[k] = residual
    residuals = [by_flight[k] for k in range(len(tests))]
    pooled = np.concatenate(residuals)
    rms = _rms(pooled)
    versus = None
    if reference is not None:
        versus = improvement_test(reference.flight_residuals, residuals, tests[0].flight.dt_s, n_tests, significance)
    return EffectScore(
        fit=fits[0],
        flight_residuals=tuple(residuals),
        test_rms_c=rms,
        test_peak_c=float(np.max(np.abs(pooled))),
        shrink_pct=_shrink(baseline_rms, rms),
        versus=versus,
        role=role,
        fold_fits=tuple(fits) if len(fits) > 1 else (),
    )


def _whiteness(nominal: ThermalParams, logs: Sequence[FlightLog], estimator: str | None) -> dict[str, Any]:
    if estimator is None:
        return {"estimator": None}
    parts = []
    for log in logs:
        innovation = np.asarray(run_estimator(log, nominal, estimator).innovation, dtype=float)
        parts.append(innovation[np.isfinite(innovation)])  # one per CHT reading
    innovation = np.concatenate(parts)
    result: dict[str, Any] = {"estimator": estimator, **ljung_box(innovation, lags=20)}
    result["innovation_rms_c"] = float(np.sqrt(np.mean(innovation**2))) if innovation.size else 0.0
    return result


def _second_acts(
    pair: EffectScore,
    folds: Sequence[_Fold],
    tests: Sequence[HeldOutFlight],
    engine: str,
    settings: GapSettings,
) -> bool:
    """True when the pair's second effect changes its test prediction by at least min_rms_drop_c RMS
    (switched off with every other fitted value kept; pooled over the test flights): a pair whose gain
    comes from a better fit of the first effect's own parameters does not name a second effect."""
    entry = candidate(pair.fit.ids[1])
    parts = []
    for fit, fold in zip(pair.fold_fits or (pair.fit,), folds, strict=True):
        params = fit.params
        if entry.effect == "nominal":
            names = [p.name for p in entry.free] + [name for name, _ in entry.fixed]
            without = params.replace(**{name: getattr(fold.nominal, name) for name in names})
        else:
            without = params.replace(effects=params.effects.replace(entry.effect, None))
        parts += [simulate_probe([params, without], tests[k].flight, engine) for k in fold.tests]
    both = np.concatenate(parts, axis=0)
    change = float(np.sqrt(np.mean((both[:, 0] - both[:, 1]) ** 2)))
    return change >= settings.significance.min_rms_drop_c


def _segment_gain(reference: np.ndarray, improved: np.ndarray, labels: np.ndarray) -> dict[str, float]:
    gain = reference**2 - improved**2
    total = float(np.sum(np.clip(gain, 0.0, None))) or 1.0
    out = {}
    for index, name in enumerate(SEGMENT_NAMES):
        mask = labels == index
        if np.any(mask):
            out[name] = float(np.sum(gain[mask])) / total
    return out


def _end_to_end(logs: Sequence[FlightLog], columns: Sequence[str]) -> FlightLog:
    """The flights one after the other in one log (each shifted to start 1 s after the previous
    one ends), with the ``columns`` they all carry: for pooled breakdowns, never for simulation."""
    if len(logs) == 1:
        return logs[0]
    shared = [c for c in columns if all(log.has(c) for log in logs)]
    times, offset = [], 0.0
    for log in logs:
        t = log.time_s - log.time_s[0] + offset
        times.append(t)
        offset = float(t[-1]) + 1.0
    data = {"time_s": np.concatenate(times)}
    data.update({c: np.concatenate([np.asarray(log[c]) for log in logs]) for c in shared if c != "time_s"})
    return FlightLog(data, source=" + ".join(log.source for log in logs))


def _as_logs(flights: FlightLog | Sequence[FlightLog], side: str) -> tuple[FlightLog, ...]:
    logs = (flights,) if isinstance(flights, FlightLog) else tuple(flights)
    if not logs:
        raise ParameterError(f"gap: at least one {side} flight is needed")
    return logs


def _held_out(nominal: ThermalParams, log: FlightLog, settings: GapSettings) -> HeldOutFlight:
    flight = prepare_flight(log, nominal.heat_axes, settings.refit.dt_s)
    model = simulate_probe([nominal], flight, settings.refit.engine)[:, 0]
    residual = flight.cht_c - model
    segmentation = segment_flight(log, settings.segments)
    return HeldOutFlight(
        flight=flight,
        baseline_residual=residual,
        baseline_model_c=model,
        model_rate_c_per_s=np.gradient(model, log.time_s),
        segmentation=segmentation,
        where=segment_breakdown(residual, segmentation, flight.dt_s),
    )


def diagnose(
    nominal: ThermalParams,
    train_logs: FlightLog | Sequence[FlightLog],
    test_logs: FlightLog | Sequence[FlightLog],
    settings: GapSettings | None = None,
    progress: Progress | None = None,
) -> GapDiagnosis:
    """Run the whole diagnosis of ``nominal``: every candidate refitted on all the train flights
    together, scored on every test flight (one flight or a sequence on each side)."""
    settings = settings or GapSettings()
    train_logs = _as_logs(train_logs, "train")
    test_logs = _as_logs(test_logs, "test")
    trains = tuple(prepare_flight(log, nominal.heat_axes, settings.refit.dt_s) for log in train_logs)
    fold = _Fold(nominal, trains, _references(train_logs, settings), tuple(range(len(test_logs))))
    return _diagnose([fold], trains, test_logs, [nominal] * len(test_logs), nominal, settings, progress)


def cross_validate(
    nominals: Sequence[ThermalParams],
    logs: Sequence[FlightLog],
    final_nominal: ThermalParams,
    settings: GapSettings | None = None,
    progress: Progress | None = None,
) -> GapDiagnosis:
    """Leave-one-flight-out diagnosis: for each flight k, every candidate refitted on the other
    flights from ``nominals[k]`` (a nominal model that has not seen flight k) and scored on flight k;
    the scores and the significance test pooled over all the held-out flights (flights and blocks
    resampled). The winner is then refitted on all the flights from ``final_nominal`` for model.yaml."""
    settings = settings or GapSettings()
    logs = _as_logs(logs, "train")
    if len(logs) < 2 or len(nominals) != len(logs):
        raise ParameterError("gap leave-one-out: at least two flights, and one nominal model per flight")
    dt = settings.refit.dt_s
    prepared = tuple(prepare_flight(log, final_nominal.heat_axes, dt) for log in logs)
    folds = []
    for k, nominal in enumerate(nominals):
        others = tuple(f for i, f in enumerate(prepared) if i != k)
        references = _references([log for i, log in enumerate(logs) if i != k], settings)
        folds.append(_Fold(nominal, others, references, (k,)))
    return _diagnose(folds, prepared, logs, list(nominals), final_nominal, settings, progress)


def _references(logs: Sequence[FlightLog], settings: GapSettings) -> dict[str, float]:
    pooled = _end_to_end(logs, ("airspeed_mps", "altitude_m", "oat_c"))
    return flight_references(pooled, settings.segments.ground_airspeed_mps)


def _diagnose(
    folds: Sequence[_Fold],
    trains: tuple[PreparedFlight, ...],
    test_logs: Sequence[FlightLog],
    test_nominals: Sequence[ThermalParams],
    final_nominal: ThermalParams,
    settings: GapSettings,
    progress: Progress | None,
) -> GapDiagnosis:
    say = progress or (lambda message: None)
    engine = settings.refit.engine
    nominal = final_nominal
    axes = nominal.heat_axes
    train_logs = [f.log for f in trains]
    references = _references(train_logs, settings)

    say(f"baseline: nominal model open loop on {len(trains)} train and {len(test_logs)} test flight(s)")
    base_train = np.concatenate([f.cht_c - simulate_probe([nominal], f, engine)[:, 0] for f in trains])
    tests = tuple(_held_out(m, log, settings) for m, log in zip(test_nominals, test_logs, strict=True))
    base_test = np.concatenate([t.baseline_residual for t in tests])
    baseline_rms = _rms(base_test)

    say("where: segments, regions, correlations, spectrum, innovations")
    columns = [c for c in (*axes, "airspeed_mps", "altitude_m", "oat_c") if all(log.has(c) for log in test_logs)]
    columns = list(dict.fromkeys(columns))
    pooled_log = _end_to_end(test_logs, columns)
    labels = np.concatenate([t.segmentation.labels for t in tests])
    rate = np.concatenate([t.model_rate_c_per_s for t in tests])
    dt_s = tests[0].flight.dt_s
    where = segment_breakdown(base_test, Segmentation(labels, ()), dt_s)
    regions = region_breakdown(base_test, pooled_log, columns)
    corr = correlations(base_test, pooled_log, columns, rate)
    lag = lag_signature(base_test, rate)
    spectrum = residual_spectrum(base_test, dt_s)
    whiteness = _whiteness(nominal, test_logs, settings.whiteness_estimator)
    hm = nominal.heat_map
    coverage = heat_map_coverage(
        base_test, _end_to_end(train_logs, axes), _end_to_end(test_logs, axes), axes, hm.x_breakpoints, hm.y_breakpoints
    )

    def fit_one(fold: _Fold, entries: list[Candidate]) -> FitResult:
        if settings.refit_mode == "reidentify":
            return reidentify(fold.nominal, fold.trains, entries, fold.references, settings.refit, settings.pso)
        return refit(fold.nominal, fold.trains, entries, fold.references, settings.refit)

    def fit_candidates(entries: list[Candidate]) -> list[FitResult]:
        return [fit_one(fold, entries) for fold in folds]

    def score(fits: list[FitResult], role: str, reference: EffectScore | None, n: int, test: Any) -> EffectScore:
        return _score(fits, folds, tests, baseline_rms, engine, role, reference, n, test)

    fold_note = f", {len(folds)} folds" if len(folds) > 1 else ""
    say(f"refit: control (nominal with R_Ce and heat scale re-tuned on the train flights{fold_note})")
    control = score(fit_candidates([]), "control", None, 1, settings.significance)
    n_tests = len(settings.candidates)
    singles: list[EffectScore] = []
    for number, cid in enumerate(settings.candidates, start=1):
        say(f"refit: {cid} ({number}/{len(settings.candidates)})")
        singles.append(score(fit_candidates([candidate(cid)]), "single", control, n_tests, settings.significance))
    counting = [s for s in singles if s.counts]
    winner = min(counting, key=lambda s: s.test_rms_c) if counting else None
    pairs: list[EffectScore] = []
    if winner is not None and settings.try_pairs and winner.test_rms_c > settings.pair_threshold_c:
        first = winner.fit.ids[0]
        others = [cid for cid in settings.candidates if cid != first]
        pair_test = dataclasses.replace(settings.significance, min_shrink_pct=settings.pair_min_shrink_pct)
        for cid in others:
            say(f"refit: pair {first}+{cid}")
            fits = fit_candidates([candidate(first), candidate(cid)])
            pairs.append(score(fits, "pair", winner, len(others), pair_test))
        better = [p for p in pairs if p.counts and _second_acts(p, folds, tests, engine, settings)]
        if better:
            winner = min(better, key=lambda s: s.test_rms_c)
    effects = sorted(singles + pairs, key=lambda s: s.test_rms_c)
    if winner is not None:
        gain = _segment_gain(control.test_residual, winner.test_residual, labels)
        winner_segment = max(gain, key=lambda k: gain[k])
        model = winner.fit.params
        if len(folds) > 1:
            say(f"refit: {winner.label} on all {len(trains)} flights (model.yaml)")
            final = _Fold(final_nominal, trains, references, ())
            model = fit_one(final, [candidate(cid) for cid in winner.fit.ids]).params
    else:
        gain = {}
        winner_segment = where[0].segment
        model = nominal
    say("verdict: " + (winner.label if winner is not None else "unexplained"))
    return GapDiagnosis(
        nominal=nominal,
        trains=trains,
        tests=tests,
        baseline_train_residual=base_train,
        baseline_test_residual=base_test,
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
        folds=len(folds),
    )
