"""The across-flight detector: the wear index rule, the reference's spread bound, the CUSUM's h and verdicts."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ecu_monitor.errors import ConfigError
from ecu_monitor.estimation.wear import (
    FlightWear,
    WearReference,
    WearSettings,
    cusum_threshold,
    reference_from_flights,
    wear_ratios,
    wear_verdict,
)


def _run_lengths(h: float, k: float, runs: int, rng: np.random.Generator, limit: int = 20_000) -> np.ndarray:
    """Flights to the first alert of the unit-variance CUSUM on in-control N(0, 1) flights, vectorised over runs."""
    s = np.zeros(runs)
    length = np.full(runs, limit)
    alive = np.ones(runs, dtype=bool)
    for n in range(1, limit + 1):
        s = np.maximum(0.0, s + rng.standard_normal(runs) - k)
        crossed = alive & (s >= h)
        length[crossed] = n
        alive &= ~crossed
        if not alive.any():
            break
    return length


def test_threshold_gives_the_asked_false_alert_rate() -> None:
    """Siegmund's h: the in-control average run length of a simulated CUSUM is the asked one (+-15 %)."""
    rng = np.random.default_rng(26)
    for target in (100.0, 400.0):
        h = cusum_threshold(target, 0.5)
        mean = float(np.mean(_run_lengths(h, 0.5, 3000, rng)))
        assert 0.85 * target <= mean <= 1.15 * target, (target, h, mean)
    assert cusum_threshold(2000.0, 0.5) > cusum_threshold(400.0, 0.5) > cusum_threshold(100.0, 0.5) > 0.0


def test_spread_bound_shrinks_with_flights_and_never_under_the_sample_sd() -> None:
    bounds = [WearReference(0.0, 1.0, n).sd_upper(0.9) for n in (3, 5, 10, 30, 300)]
    assert all(b > 1.0 for b in bounds) and bounds == sorted(bounds, reverse=True)
    assert bounds[-1] < 1.1
    # against the chi-square quantile (df 9, 10 %: 4.168): sqrt(9 / 4.168) = 1.469
    assert WearReference(0.0, 1.0, 10).sd_upper(0.9) == pytest.approx(1.4695, abs=0.01)


def test_wear_ratio_rule_and_accumulator() -> None:
    cht = np.array([150.0, 110.0, 90.0, math.nan, 200.0])
    model = np.array([140.0, 100.0, 50.0, 120.0, 200.0])
    oat = np.array([20.0, 20.0, 20.0, 20.0, 20.0])
    ratios = wear_ratios(cht, model, oat, 40.0)
    assert ratios.tolist() == pytest.approx([10.0 / 120.0, 10.0 / 80.0, 0.0])  # rise 30 < 40 and nan left out
    settings = WearSettings(min_samples=3)
    whole, one_by_one = FlightWear(settings), FlightWear(settings)
    whole.add_many(cht, model, oat)
    for c, m, o in zip(cht, model, oat, strict=True):
        one_by_one.add(c, m, o)
    assert whole.index == pytest.approx(one_by_one.index) == pytest.approx(float(np.mean(ratios)))
    assert whole.spread == pytest.approx(float(np.std(ratios)))
    resumed = FlightWear(settings)
    resumed.restore(whole.n, whole.index, whole.spread)
    resumed.add_many(cht, model, oat)
    assert resumed.index == pytest.approx(whole.index) and resumed.spread == pytest.approx(whole.spread)
    assert FlightWear(WearSettings(min_samples=4)).index is None


def test_verdict_alerts_on_a_drift_and_not_on_nominal_flights() -> None:
    rng = np.random.default_rng(7)
    settings = WearSettings()
    reference = reference_from_flights(list(rng.normal(0.01, 0.005, 10)))
    assert reference is not None and reference.flights == 10
    nominal = list(rng.normal(0.01, 0.005, 100))
    assert not wear_verdict(nominal, settings, reference).alerted
    drift = [x + 0.0035 * n for n, x in enumerate(rng.normal(0.01, 0.005, 30))]
    verdict = wear_verdict(drift, settings, reference)
    assert verdict.alerted and verdict.alert_at is not None and 3 <= verdict.alert_at < 20
    assert verdict.statistic[verdict.alert_at] >= verdict.threshold > (verdict.statistic[verdict.alert_at - 1] or 0)


def test_without_a_reference_the_first_flights_give_it_and_missing_indices_are_skipped() -> None:
    settings = WearSettings(baseline_flights=5)
    flights: list[float | None] = [0.01, None, 0.012, 0.008, 0.011, 0.009] + [0.01 + 0.01 * n for n in range(1, 20)]
    verdict = wear_verdict(flights, settings)
    assert verdict.learned and verdict.reference is not None and verdict.reference.flights == 5
    assert verdict.statistic[:6] == (None,) * 6 and verdict.alerted
    assert not wear_verdict(flights[:5], settings).alerted and wear_verdict(flights[:5], settings).reference is None


def test_settings_are_validated_with_their_key() -> None:
    with pytest.raises(ConfigError, match=r"wear\.false_alert_flights"):
        WearSettings(false_alert_flights=1.0)
    with pytest.raises(ConfigError, match=r"wear\.spread_confidence"):
        WearSettings(spread_confidence=1.0)
    with pytest.raises(ConfigError, match=r"wear\.baseline_flights"):
        WearSettings(baseline_flights=2)
    with pytest.raises(ConfigError, match="wear reference"):
        WearReference(0.0, 0.0, 5)
