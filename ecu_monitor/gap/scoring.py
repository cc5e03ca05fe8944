"""Scoring refitted candidates on the held-out flights: residuals per fold, the significance test
against a reference, whether a pair's second effect acts, where the gain lies, the whiteness of the
nominal model's innovations."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ecu_monitor.estimation import run_estimator
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.gap.diagnosis import EffectScore, GapSettings, HeldOutFlight, rms_of, shrink_percent
from ecu_monitor.gap.localise import (
    ljung_box,
)
from ecu_monitor.gap.segments import SEGMENT_NAMES
from ecu_monitor.gap.significance import SignificanceSettings, improvement_test
from ecu_monitor.identify.library import candidate
from ecu_monitor.identify.parallel import run_tasks
from ecu_monitor.identify.refit import (
    FitResult,
    PreparedFlight,
    simulate_probe,
)
from ecu_monitor.model import ThermalParams


@dataclass(frozen=True)
class RefitFold:
    """One refit set-up: the nominal model, the flights the candidates are refitted on, their
    reference conditions, and the indices (into the diagnosis's test flights) it is scored on."""

    nominal: ThermalParams
    trains: tuple[PreparedFlight, ...]
    references: dict[str, float]
    tests: tuple[int, ...]


def score_fits(
    fits: Sequence[FitResult],
    folds: Sequence[RefitFold],
    tests: tuple[HeldOutFlight, ...],
    baseline_rms: float,
    engine: str,
    role: str,
    reference: EffectScore | None,
    n_tests: float,
    significance: SignificanceSettings,
) -> EffectScore:
    """Each fold's fit simulated on that fold's test flights; residuals in the order of ``tests``
    (``n_tests``: the test is at level alpha / n_tests)."""
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
    rms = rms_of(pooled)
    versus = None
    if reference is not None:
        versus = improvement_test(reference.flight_residuals, residuals, tests[0].flight.dt_s, n_tests, significance)
    return EffectScore(
        fit=fits[0],
        flight_residuals=tuple(residuals),
        test_rms_c=rms,
        test_peak_c=float(np.max(np.abs(pooled))),
        shrink_pct=shrink_percent(baseline_rms, rms),
        versus=versus,
        role=role,
        fold_fits=tuple(fits) if len(fits) > 1 else (),
    )


def _innovations(work: tuple[ThermalParams, tuple[FlightLog, ...], str], k: int) -> np.ndarray:
    """The estimator's innovations on flight ``k``, one per CHT reading (degC)."""
    nominal, logs, estimator = work
    innovation = np.asarray(run_estimator(logs[k], nominal, estimator).innovation, dtype=float)
    return innovation[np.isfinite(innovation)]


def innovation_whiteness(nominal: ThermalParams, logs: Sequence[FlightLog], estimator: str | None) -> dict[str, Any]:
    """Ljung-Box whiteness of ``estimator``'s innovations on ``logs`` with ``nominal`` (the flights on every core)."""
    if estimator is None:
        return {"estimator": None}
    parts = run_tasks(_innovations, (nominal, tuple(logs), estimator), range(len(logs)), "innovations")
    innovation = np.concatenate(parts)
    result: dict[str, Any] = {"estimator": estimator, **ljung_box(innovation, lags=20)}
    result["innovation_rms_c"] = float(np.sqrt(np.mean(innovation**2))) if innovation.size else 0.0
    return result


def second_effect_acts(
    pair: EffectScore,
    folds: Sequence[RefitFold],
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


def segment_gain_shares(reference: np.ndarray, improved: np.ndarray, labels: np.ndarray) -> dict[str, float]:
    gain = reference**2 - improved**2
    total = float(np.sum(np.clip(gain, 0.0, None))) or 1.0
    out = {}
    for index, name in enumerate(SEGMENT_NAMES):
        mask = labels == index
        if np.any(mask):
            out[name] = float(np.sum(gain[mask])) / total
    return out
