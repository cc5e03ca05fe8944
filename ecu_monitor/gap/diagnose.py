"""The gap diagnosis end to end: baseline, where, which effect, how far, the improved model.

1. Baseline: the nominal model open loop on the train and test flights (RMS, peak).
2. Where: the test residual by segment, operating region, correlations, lag signature, spectrum and
   the whiteness of the filtered innovations (the service's CBEKF-AU on the nominal model).
3. Which: the control (the nominal model with R_Ce and the heat scale re-tuned on the train flight)
   and every library candidate refitted on the train flight only, each scored on the test flight;
   a candidate counts when its held-out gain over the control is significant and material
   (:mod:`ecu_monitor.gap.significance`). The best counting candidate is kept; when it leaves a
   structured residual (test RMS above ``pair_threshold_c``), pairs with it are tried greedily (in
   "reidentify" mode each re-identified from that effect's own joint fit on the same flights, with a
   longer polish: :data:`ecu_monitor.gap.diagnosis.PAIR_POLISH_FACTOR`) and a
   pair counts only if it beats the single effect by the same test and also shrinks the single's
   TRAIN RMS materially (a second effect must explain the flights it was fitted on, not only some
   accident of the held-out ones). When no single effect counts but
   the best one's gain is material (large, not significant: it holds on some test flights and fails
   on others), pairs with it are tried too, each tested against the control (alpha spread over the
   singles and the pairs): two effects that each hold where the other fails count only together.
4. Verdict: the winning effect(s) and the held-out shrink vs the baseline, or ``None``
   ("unexplained") when no candidate counts; then no candidate is named.

When asked (``GapSettings.choose_on_train_from``, ``gap --choose-on-train``) step 3 is a leave-one-flight-out
over the train flights alone (:func:`cross_validate`); its verdict (or its lead) is refitted on every
train flight and scored on the test flights with the control: the choice never depends on the test
flights, which only measure it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ecu_monitor.errors import ParameterError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.gap.diagnosis import (
    JOINT_REFIT,
    PAIR_POLISH_FACTOR,
    SCREEN_POLISH_EVALUATIONS,
    EffectScore,
    GapDiagnosis,
    GapSettings,
    HeldOutFlight,
    rms_of,
    shrink_percent,
)
from ecu_monitor.gap.folds import fold_nominals
from ecu_monitor.gap.localise import (
    correlations,
    heat_map_coverage,
    lag_signature,
    region_breakdown,
    residual_spectrum,
    segment_breakdown,
)
from ecu_monitor.gap.scoring import RefitFold, innovation_whiteness, score_fits, second_effect_acts, segment_gain_shares
from ecu_monitor.gap.segments import Segmentation, segment_flight
from ecu_monitor.identify.library import candidate, flight_references
from ecu_monitor.identify.parallel import run_tasks
from ecu_monitor.identify.refit import (
    FitResult,
    PreparedFlight,
    prepare_flight,
    refit,
    reidentify,
    simulate_probe,
)
from ecu_monitor.model import ThermalParams

__all__ = [
    "JOINT_REFIT",
    "EffectScore",
    "GapDiagnosis",
    "GapSettings",
    "HeldOutFlight",
    "cross_validate",
    "diagnose",
    "train_led_shares",
    "train_shrink_pct",
]

Progress = Callable[[str], None]


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
    flight = prepare_flight(log, nominal.heat_axes, settings.refit.dt_s, nominal.effects.mixture_index)
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
    chosen_by = None
    if 0 < settings.choose_on_train_from <= len(train_logs):
        say = progress or (lambda message: None)
        say(f"choosing the verdict by leave-one-flight-out over the {len(train_logs)} train flights (not the test)")
        if settings.refit_mode == "reidentify":  # the nominal model was identified on these flights
            nominals = fold_nominals(train_logs, nominal, settings.pso, progress)
        else:
            nominals = [nominal] * len(train_logs)
        inner = dataclasses.replace(settings, whiteness_estimator=None)  # only its verdict is used
        chosen_by = cross_validate(nominals, train_logs, nominal, inner, progress)
    mixture = nominal.effects.mixture_index  # the index the model reads (None: the candidate's)
    trains = tuple(prepare_flight(log, nominal.heat_axes, settings.refit.dt_s, mixture) for log in train_logs)
    fold = RefitFold(nominal, trains, _references(train_logs, settings), tuple(range(len(test_logs))))
    return _diagnose([fold], trains, test_logs, [nominal] * len(test_logs), nominal, settings, progress, chosen_by)


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
    resampled). The winner is then refitted on all the flights from ``final_nominal`` for model.yaml.

    First the screen (``settings.screen_min_shrink_pct``, :class:`GapSettings`): every candidate fitted once on
    all the flights from ``final_nominal``; the folds refit only those that shrink its control's train RMS by
    the screen's bar."""
    settings = settings or GapSettings()
    logs = _as_logs(logs, "train")
    if len(logs) < 2 or len(nominals) != len(logs):
        raise ParameterError("gap leave-one-out: at least two flights, and one nominal model per flight")
    dt = settings.refit.dt_s
    mixture = final_nominal.effects.mixture_index
    prepared = tuple(prepare_flight(log, final_nominal.heat_axes, dt, mixture) for log in logs)
    folds = []
    for k, nominal in enumerate(nominals):
        others = tuple(f for i, f in enumerate(prepared) if i != k)
        references = _references([log for i, log in enumerate(logs) if i != k], settings)
        folds.append(RefitFold(nominal, others, references, (k,)))
    screen = (
        _screen(prepared, logs, final_nominal, settings, progress) if settings.screen_min_shrink_pct is not None else {}
    )
    return _diagnose(folds, prepared, logs, list(nominals), final_nominal, settings, progress, None, screen)


def _screen(
    prepared: tuple[PreparedFlight, ...],
    logs: Sequence[FlightLog],
    nominal: ThermalParams,
    settings: GapSettings,
    progress: Progress | None,
) -> dict[str, float]:
    """Each candidate's train RMS shrink (%) against the control, both fitted once on every flight from
    ``nominal`` (the polish capped at :data:`SCREEN_POLISH_EVALUATIONS`; every core)."""
    say = progress or (lambda message: None)
    bar = settings.screen_min_shrink_pct
    say(
        f"screen: every candidate fitted once on all {len(logs)} flights; the folds refit those that shrink"
        f" the control's train RMS by {bar:g} % or more"
    )
    polish = min(settings.pso.polish_evaluations, SCREEN_POLISH_EVALUATIONS)
    capped = dataclasses.replace(settings, pso=dataclasses.replace(settings.pso, polish_evaluations=polish))
    work = _FitWork((RefitFold(nominal, prepared, _references(logs, settings), ()),), capped)
    tasks = [(0, ids, None) for ids in [(), *((cid,) for cid in settings.candidates)]]
    control, *fits = run_tasks(_fit_task, work, tasks, "screen fits", say)
    shrink = {
        cid: shrink_percent(control.train_rms_c, fit.train_rms_c)
        for cid, fit in zip(settings.candidates, fits, strict=True)
    }
    say("screen: " + ", ".join(f"{cid} {pct:.0f} %" for cid, pct in shrink.items()))
    return shrink


def _train_cost(fits: Sequence[FitResult]) -> float:
    """Mean squared train residual over the folds (degC^2): how well a candidate fits the flights it
    was refitted on, never the held-out ones."""
    return float(np.mean([fit.train_rms_c**2 for fit in fits]))


def train_shrink_pct(score: EffectScore, reference: EffectScore) -> float:
    """How much ``score`` shrinks the TRAIN RMS of ``reference`` (%, pooled over the folds): a pair must
    explain the flights its second effect was fitted on, not only the held-out ones."""
    mine = _train_cost(score.fold_fits or (score.fit,))
    theirs = _train_cost(reference.fold_fits or (reference.fit,))
    return 100.0 * (1.0 - math.sqrt(mine / theirs)) if theirs > 0 else 0.0


def train_led_shares(train_costs: Sequence[float]) -> list[float]:
    """Each single candidate's share of the family-wise alpha (weighted Bonferroni, shares sum to 1):
    half to the candidate that fits the TRAIN flights best, the other half spread evenly over the rest.

    The order comes from the train flights only, so it is independent of the held-out flights' noise
    and the family-wise error stays at alpha; the test gains power where it matters (the effect that
    is in the data also fits the train flights best) and loses a little on the others."""
    n = len(train_costs)
    if n == 1:
        return [1.0]
    lead = int(np.argmin(train_costs))
    return [0.5 if k == lead else 0.5 / (n - 1) for k in range(n)]


def _material_lead(singles: Sequence[EffectScore]) -> EffectScore | None:
    """When no single effect counts: the best one whose held-out gain over the control is material but
    not significant (it may hold on some test flights and fail on others, where a second effect is
    missing); None when no single effect is material."""
    material = [s for s in singles if s.versus is not None and s.versus.material]
    return min(material, key=lambda s: s.test_rms_c) if material else None


@dataclass(frozen=True)
class _FitWork:
    """What every refit task reads (a forked worker inherits it): the folds and the settings."""

    folds: tuple[RefitFold, ...]
    settings: GapSettings


def _fit_task(work: _FitWork, task: tuple[int, tuple[str, ...], ThermalParams | None]) -> FitResult:
    """The candidates ``ids`` (none: the control) refitted on fold ``k`` (the settings' refit mode); a
    re-identification starts from ``start`` when given (a fit on the same fold), else the fold's nominal."""
    k, ids, start = task
    fold, settings = work.folds[k], work.settings
    entries = [candidate(cid) for cid in ids]
    if settings.refit_mode == "reidentify":
        pso = settings.pso
        if len(ids) > 1:  # a pair: the longer polish
            pso = dataclasses.replace(pso, polish_evaluations=pso.polish_evaluations * PAIR_POLISH_FACTOR)
        base = fold.nominal if start is None else start
        return reidentify(base, fold.trains, entries, fold.references, settings.refit, pso)
    return refit(fold.nominal, fold.trains, entries, fold.references, settings.refit)


def _references(logs: Sequence[FlightLog], settings: GapSettings) -> dict[str, float]:
    pooled = _end_to_end(logs, ("airspeed_mps", "altitude_m", "oat_c", "rpm", "egt_c", "fuel_flow_lph",
                                "manifold_pressure_kpa"))  # fmt: skip
    return flight_references(pooled, settings.segments.ground_airspeed_mps)


def _diagnose(
    folds: Sequence[RefitFold],
    trains: tuple[PreparedFlight, ...],
    test_logs: Sequence[FlightLog],
    test_nominals: Sequence[ThermalParams],
    final_nominal: ThermalParams,
    settings: GapSettings,
    progress: Progress | None,
    chosen_by: GapDiagnosis | None,
    screen: dict[str, float] | None = None,
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
    baseline_rms = rms_of(base_test)

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
    whiteness = innovation_whiteness(nominal, test_logs, settings.whiteness_estimator)
    hm = nominal.heat_map
    coverage = heat_map_coverage(
        base_test, _end_to_end(train_logs, axes), _end_to_end(test_logs, axes), axes, hm.x_breakpoints, hm.y_breakpoints
    )

    work = _FitWork(tuple(folds), settings)

    def fit_batch(
        label: str, batch: Sequence[tuple[str, ...]], starts: Sequence[FitResult] | None = None
    ) -> list[list[FitResult]]:
        """Every candidate set of ``batch`` refitted on every fold, on every core: one list of fold fits per
        set (``starts``: one fit per fold to start each re-identification from)."""
        n = len(folds)
        tasks = [(k, ids, None if starts is None else starts[k].params) for ids in batch for k in range(n)]
        fits = run_tasks(_fit_task, work, tasks, label, say)
        return [fits[i * n : (i + 1) * n] for i in range(len(batch))]

    def score(fits: list[FitResult], role: str, reference: EffectScore | None, n: float, test: Any) -> EffectScore:
        return score_fits(fits, folds, tests, baseline_rms, engine, role, reference, n, test)

    if chosen_by is not None:
        control, effects, winner = _score_chosen(chosen_by, fit_batch, score, settings)
    else:
        bar = settings.screen_min_shrink_pct
        tried = tuple(c for c in settings.candidates if not (screen and bar is not None and screen[c] < bar))
        control, effects, winner = _search(folds, tests, fit_batch, score, settings, say, tried)
    if winner is not None:
        gain = segment_gain_shares(control.test_residual, winner.test_residual, labels)
        winner_segment = max(gain, key=lambda k: gain[k])
        model = winner.fit.params
        if len(folds) > 1:
            say(f"refit: {winner.label} on all {len(trains)} flights (model.yaml)")
            final = _FitWork((RefitFold(final_nominal, trains, references, ()),), settings)
            model = _fit_task(final, (0, winner.fit.ids, None)).params
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
        chosen_by=chosen_by,
        screen=dict(screen or {}),
    )


def _search(
    folds: Sequence[RefitFold],
    tests: tuple[HeldOutFlight, ...],
    fit_batch: Callable[[str, Sequence[tuple[str, ...]]], list[list[FitResult]]],
    score: Callable[..., EffectScore],
    settings: GapSettings,
    say: Progress,
    tried: tuple[str, ...],
) -> tuple[EffectScore, list[EffectScore], EffectScore | None]:
    """The control, every single candidate of ``tried`` (the candidates past the screen, or all) and the
    pairs (module doc, step 3): (control, effects sorted by test RMS, winner or None). The family-wise
    alpha is spread over every candidate of the settings, tried or not."""
    engine = settings.refit.engine
    fold_note = f", {len(folds)} folds" if len(folds) > 1 else ""
    say(
        f"refit: the control (nominal with R_Ce and heat scale re-tuned on the train flights{fold_note}) and"
        f" {', '.join(tried) or 'no candidate'}"
    )
    control_fits, *single_fits = fit_batch("refits", [(), *((cid,) for cid in tried)])
    control = score(control_fits, "control", None, 1, settings.significance)
    n_tests = len(settings.candidates)
    costs = dict(zip(tried, (_train_cost(fits) for fits in single_fits), strict=True))
    shares = dict(
        zip(settings.candidates, train_led_shares([costs.get(c, math.inf) for c in settings.candidates]), strict=True)
    )
    singles = [
        score(fits, "single", control, 1.0 / shares[cid], settings.significance)
        for cid, fits in zip(tried, single_fits, strict=True)
    ]
    counting = [s for s in singles if s.counts]
    winner = min(counting, key=lambda s: s.test_rms_c) if counting else None
    lead = winner if winner is not None else _material_lead(singles)
    pairs: list[EffectScore] = []
    first = lead.fit.ids[0] if lead is not None else ""
    others = [cid for cid in tried if cid != first]
    if lead is not None and others and settings.try_pairs and lead.test_rms_c > settings.pair_threshold_c:
        n_others = len(settings.candidates) - 1  # the family, as for the singles
        pair_test = dataclasses.replace(settings.significance, min_shrink_pct=settings.pair_min_shrink_pct)
        # a counting single: a pair must beat it; none counts: a pair must beat the control, the
        # family-wise alpha then spread over the singles and the pairs
        reference, role, n_pair_tests = (
            (winner, "pair", n_others) if winner is not None else (control, "pair_vs_control", n_tests + n_others)
        )
        say(f"refit: pairs {first}+ {', '.join(others)}")
        # re-identified from the lead's own fit on each fold (the same flights, nothing held out in it):
        # the first effect and the whole model start where the lead's joint fit left them
        starts = (lead.fold_fits or (lead.fit,)) if settings.refit_mode == "reidentify" else None
        pair_fits = fit_batch("pair refits", [(first, cid) for cid in others], starts)
        pairs = [score(fits, role, reference, n_pair_tests, pair_test) for fits in pair_fits]
        train_bar = settings.significance.min_shrink_pct
        better = [
            p
            for p in pairs
            if p.counts
            and second_effect_acts(p, folds, tests, engine, settings)
            and train_shrink_pct(p, reference) >= train_bar
        ]
        if better:
            winner = min(better, key=lambda s: s.test_rms_c)
    return control, sorted(singles + pairs, key=lambda s: s.test_rms_c), winner


def _score_chosen(
    chosen_by: GapDiagnosis,
    fit_batch: Callable[[str, Sequence[tuple[str, ...]]], list[list[FitResult]]],
    score: Callable[..., EffectScore],
    settings: GapSettings,
) -> tuple[EffectScore, list[EffectScore], EffectScore | None]:
    """The verdict chosen by the leave-one-flight-out over the train flights (or, unexplained there, its
    lead), refitted on every train flight and scored on the test flights against the control: (control,
    [it], it when chosen_by named it)."""
    chosen = chosen_by.winner or chosen_by.lead
    batch = [(), chosen.fit.ids] if chosen is not None else [()]
    fits = fit_batch("refits of the control and the chosen effect(s)", batch)
    control = score(fits[0], "control", None, 1, settings.significance)
    if chosen is None:
        return control, [], None
    role = "single" if len(chosen.fit.ids) == 1 else "pair_vs_control"
    mine = score(fits[1], role, control, 1, settings.significance)
    return control, [mine], mine if chosen_by.winner is not None else None
