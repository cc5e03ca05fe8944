"""What the gap diagnosis takes and gives: :class:`GapSettings`, and the results it hands the report
(:class:`GapDiagnosis`, with an :class:`EffectScore` per candidate tried and a :class:`HeldOutFlight` per
test flight)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ecu_monitor.errors import ParameterError
from ecu_monitor.gap.localise import (
    LagSignature,
    SegmentShare,
    Spectrum,
)
from ecu_monitor.gap.segments import SEGMENT_NAMES, Segmentation, SegmentSettings
from ecu_monitor.gap.significance import ImprovementTest, SignificanceSettings
from ecu_monitor.identify import PsoSettings
from ecu_monitor.identify.library import DEFAULT_CANDIDATE_IDS, candidate
from ecu_monitor.identify.refit import (
    FitResult,
    PreparedFlight,
    RefitSettings,
)
from ecu_monitor.model import ThermalParams

#: The re-identification of "reidentify" mode: no swarm iterations, so the best of the initial swarm
#: (the given nominal model with the candidate switched on at its neutral start is one of its
#: particles) is polished by least squares jointly over the whole model and the candidate. On the
#: real flights this gave the same held-out scores as a full PSO run (48 particles x 120 iterations)
#: at a third of the time (docs/results/gap_real.md); pass ``pso=PsoSettings()`` for the full search.
JOINT_REFIT = PsoSettings(particles=4, iterations=0)
#: The polish budget of a pair's joint re-identification, as a multiple of a single's
#: (``GapSettings.pso.polish_evaluations``). A pair starts at its first effect's fit (model.yaml's: at the
#: nominal model), the optimum of another form: a second effect can change what the whole heat map means
#: (``no_altitude_factor`` takes the altitude out of the heat), and the joint least squares converges slowly
#: from there; a pair polished less than a single stopped well above its train optimum on the real flights,
#: where `identify` fitting the same form reached it (docs/results/gap_real.md).
PAIR_POLISH_FACTOR = 3
#: The polish budget of the leave-one-out's screen (each candidate fitted once on every flight, from the
#: nominal model on every flight): its train RMS only decides which candidates the folds refit.
SCREEN_POLISH_EVALUATIONS = 30


@dataclass(frozen=True)
class GapSettings:
    """Settings of the diagnosis: candidates tried, refit, significance, segmentation, pairs.

    refit_mode "local" (default) refits the candidate's parameters and two nominal factors from the
    nominal model (:func:`ecu_monitor.identify.refit.refit`); "reidentify" re-identifies the whole nominal
    model jointly with them (:func:`ecu_monitor.identify.refit.reidentify`, with ``pso``: by default
    :data:`JOINT_REFIT`, a joint least-squares refit from the given model), the choice
    when the nominal model was identified on the train flight itself.

    Pairs are tried when the best single effect leaves a test RMS above ``pair_threshold_c`` (degC);
    a pair must beat the single effect (or, when no single counts, the control) by
    ``pair_min_shrink_pct`` (a higher bar than a single effect
    against the control: the second effect of a pair is fitted to what the first one leaves, small
    structured remainders such as a slightly wrong nominal altitude exponent included), and must also
    shrink its reference's TRAIN RMS by ``significance.min_shrink_pct``: a second effect has to explain
    the flights it was fitted on, not only an accident of the held-out ones.

    With ``choose_on_train_from`` > 0 (``gap --choose-on-train``: 3) and at least that many train flights,
    the verdict is chosen by a leave-one-flight-out diagnosis over the train flights alone, then refitted
    on all of them and scored on the test flights: the choice never depends on the test flights, which
    only measure it. Off by default: on the four N550ND folds it did not carry better than the choice on the
    test flights (docs/results/gap_real.md) and costs a leave-one-out.

    A leave-one-out first screens the candidates (``screen_min_shrink_pct``, None: no screen): each is fitted
    once on every flight (the polish capped at :data:`SCREEN_POLISH_EVALUATIONS`), and only those that shrink
    that fit's control train RMS by at least this percentage are refitted in every fold. The screen sees
    every flight, so it buys no power: the family-wise alpha stays spread over every candidate."""

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
    choose_on_train_from: int = 0
    screen_min_shrink_pct: float | None = 10.0

    def __post_init__(self) -> None:
        for cid in self.candidates:
            candidate(cid)  # raises ParameterError if unknown
        if not self.candidates:
            raise ParameterError("gap: at least one candidate effect is needed")
        if not (isinstance(self.choose_on_train_from, int) and self.choose_on_train_from >= 0):
            raise ParameterError(
                f"gap choose_on_train_from: expected a number of flights >= 0, got {self.choose_on_train_from!r}"
            )
        if self.screen_min_shrink_pct is not None and not (
            isinstance(self.screen_min_shrink_pct, int | float) and 0.0 <= self.screen_min_shrink_pct < 100.0
        ):
            raise ParameterError(
                "gap screen_min_shrink_pct: expected a percentage in [0, 100) or None,"
                f" got {self.screen_min_shrink_pct!r}"
            )
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
    versus: ImprovementTest | None  # against the control (singles, pair_vs_control) or the single effect (pair)
    role: str  # "control", "single", "pair" (vs the counting single) or "pair_vs_control" (no single counts)
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
        return tuple(rms_of(r) for r in self.flight_residuals)

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
        return rms_of(self.baseline_residual)


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
    chosen_by: GapDiagnosis | None = None  # the leave-one-flight-out over the train flights that chose the verdict
    # leave-one-out: each candidate's train RMS shrink (%) vs the control, both fitted once on every flight
    screen: dict[str, float] = field(default_factory=dict)

    @property
    def screened_out(self) -> tuple[str, ...]:
        """The candidates the leave-one-out's screen kept out of the folds (under the screen's bar)."""
        bar = self.settings.screen_min_shrink_pct
        return tuple(cid for cid, pct in self.screen.items() if bar is not None and pct < bar)

    @property
    def train(self) -> PreparedFlight:
        """The first train flight."""
        return self.trains[0]

    @property
    def test(self) -> PreparedFlight:
        """The first test flight."""
        return self.tests[0].flight

    @property
    def lead(self) -> EffectScore | None:
        """With no winner: the candidate with the lowest held-out RMS when it is below both the control's
        and the baseline's (a gain the test could not confirm: too few flights, or not significant across
        them); None when there is a winner or no candidate shrinks the held-out error."""
        if self.winner is not None or not self.effects:
            return None
        best = min(self.effects, key=lambda s: s.test_rms_c)
        below = min(self.control.test_rms_c, rms_of(self.baseline_test_residual))
        return best if best.test_rms_c < below else None

    def lead_sentence(self) -> str | None:
        """The lead (:attr:`lead`) in one line: what it does on the held-out flights and why it is not named."""
        lead = self.lead
        if lead is None:
            return None
        flights = "the test flight" if len(self.tests) == 1 else f"the {len(self.tests)} test flights"
        found = (
            f"{lead.label}: held-out {-lead.shrink_pct:+.0f} % on {flights} ({lead.test_rms_c:.2f} degC,"
            f" control {self.control.test_rms_c:.2f})"
        )
        inner = self.chosen_by.lead if self.chosen_by is not None else None
        if self.chosen_by is not None:
            over = f"{inner.label} {-inner.shrink_pct:+.0f} % over them, {self._why(inner)}" if inner else "no lead"
            return f"{found}, not chosen by the leave-one-out over the {len(self.trains)} train flights ({over})"
        advice = "add flights" if self.folds > 1 else "add flights or run --leave-one-out"
        return f"{found}, not confirmed across flights ({self._why(lead)}): {advice}"

    def _why(self, score: EffectScore) -> str:
        """Why ``score`` does not count: its p-value and materiality against the control."""
        versus = score.versus
        reasons = []
        if versus is not None and not versus.significant:
            reasons.append(f"p = {versus.p_value:.2f} against the control, needs <= {versus.level:.3f}")
        if versus is not None and not versus.material:
            bar = self.settings.significance
            reasons.append(
                f"{versus.shrink_pct:.0f} % below the control, material from {bar.min_shrink_pct:.0f} %"
                f" and {bar.min_rms_drop_c:g} degC"
            )
        return "; ".join(reasons) or "not tested"

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
                "baseline_rms_c": rms_of(base),
                "baseline_peak_c": float(np.max(np.abs(base))),
                "control_rms_c": rms_of(control),
                "where": [w.to_dict() for w in test.where],
            }
            if score is not None:
                after = score.flight_residuals[k]
                row["test_rms_c"] = rms_of(after)
                row["test_peak_c"] = float(np.max(np.abs(after)))
                row["shrink_pct"] = shrink_percent(rms_of(base), rms_of(after))
                row["shrink_vs_control_pct"] = shrink_percent(rms_of(control), rms_of(after))
                segments = {}
                for index, name in enumerate(SEGMENT_NAMES):
                    mask = test.segmentation.labels == index
                    if not np.any(mask):
                        continue
                    b, c, a = rms_of(base[mask]), rms_of(control[mask]), rms_of(after[mask])
                    segments[name] = {
                        "duration_s": float(mask.sum()) * test.flight.dt_s,
                        "baseline_rms_c": b,
                        "control_rms_c": c,
                        "rms_c": a,
                        "shrink_pct": shrink_percent(b, a),
                        "shrink_vs_control_pct": shrink_percent(c, a),
                        "holds": bool(a < c and a < b),
                    }
                row["segments"] = segments
            rows.append(row)
        return rows


def rms_of(x: np.ndarray) -> float:
    """Root mean square of ``x`` (same unit, degC for residuals)."""
    return float(np.sqrt(np.mean(np.asarray(x, dtype=float) ** 2)))


def shrink_percent(before: float, after: float) -> float:
    """How much ``after`` is below ``before``, % of ``before`` (0 when ``before`` is 0)."""
    return 100.0 * (1.0 - after / before) if before > 0 else 0.0
