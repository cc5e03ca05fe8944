"""The offline screens of benchmarks/bench_detect_real.py: the heat soak (``--soak``: the first-order lag and the
fit) and the level symptom (``--level``: r and rho from a replay's open-loop reference, what the overlay adds)."""

from __future__ import annotations

import importlib.util
import math
from types import ModuleType

import numpy as np
import pytest

from ecu_monitor.estimation.detection import overlay_degradation
from ecu_monitor.pipeline.outputs import ReferenceFeed
from tests.helpers import REPO


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    path = REPO / "benchmarks" / "bench_detect_real.py"
    spec = importlib.util.spec_from_file_location("bench_detect_real", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_lag_of_a_step_is_the_exponential_at_irregular_times(bench: ModuleType) -> None:
    t = np.concatenate(([0.0], 1.0 + np.cumsum(np.linspace(0.5, 3.0, 400))))
    q = np.ones(t.size)
    q[0] = 0.0  # the step is seen from the second sample on (held between samples)
    y = bench.first_order_lag(t, q, 300.0)
    assert y[0] == 0.0
    assert np.allclose(y[1:], 1.0 - np.exp(-(t[1:] - t[1]) / 300.0), rtol=0.0, atol=1e-12)


def test_lag_fills_gaps_and_starts_at_rest(bench: ModuleType) -> None:
    t = np.arange(0.0, 100.0)
    q = np.full(t.size, 2.0)
    q[[0, 10, 11]] = np.nan
    assert np.allclose(bench.first_order_lag(t, q, 50.0), 2.0)
    assert np.isnan(bench.first_order_lag(t, np.full(t.size, np.nan), 50.0)).all()


def _flight(bench: ModuleType, rng: np.random.Generator, offset: float, taus: list[float], b: float, tau: float):
    """Times (10 Hz), a symptom offset + b (lag(q, tau) - q) (+ gaps) and the regressors for ``taus``."""
    t_log = np.arange(0.0, 5400.0)
    q = np.repeat(rng.uniform(0.3, 1.6, 18), 300)  # a power step every 5 min
    t = np.arange(0.0, 5399.0, 0.1)
    regressors = {k: np.interp(t, t_log, bench.first_order_lag(t_log, q, k) - q) for k in taus}
    x = offset + b * regressors[tau]
    x[(t > 1000.0) & (t < 1100.0)] = np.nan  # the detector not fed (supervisor not NOMINAL)
    return t, x, regressors


def test_fit_finds_the_coefficient_and_time_constant_of_each_flight_s_offset_apart(bench: ModuleType) -> None:
    rng = np.random.default_rng(3)
    taus = [300.0, 600.0, 1200.0, 1800.0]
    flights = [_flight(bench, rng, offset, taus, -0.04, 600.0) for offset in (0.02, -0.05, 0.1)]
    fit = bench.fit_soak(flights)
    assert set(fit) == set(taus)
    best = min(fit, key=lambda k: fit[k][1])
    assert best == 600.0
    b, rss, rss0 = fit[600.0]
    assert b == pytest.approx(-0.04, rel=1e-9)
    assert rss == pytest.approx(0.0, abs=1e-12 * rss0) and rss0 > 0.0
    assert all(fit[k][1] > 1e-3 * rss0 for k in taus if k != 600.0)


def test_fit_of_a_symptom_without_the_term_gives_no_coefficient(bench: ModuleType) -> None:
    rng = np.random.default_rng(4)
    taus = [600.0]
    flights = [_flight(bench, rng, 0.03, taus, 0.0, 600.0) for _ in range(2)]
    b, rss, rss0 = bench.fit_soak(flights)[600.0]
    assert b == 0.0 or math.isclose(b, 0.0, abs_tol=1e-12)
    assert rss == pytest.approx(rss0)


def _reference(cht: np.ndarray, model: np.ndarray, oat: np.ndarray) -> ReferenceFeed:
    return ReferenceFeed(np.arange(cht.size, dtype=float), cht, model, oat)


def test_residual_and_relative_residual(bench: ModuleType) -> None:
    model = np.array([100.0, 150.0, 200.0, 30.0, np.nan])
    oat = np.array([20.0, 10.0, 0.0, 25.0, np.nan])
    cht = model + np.array([4.0, -7.0, 10.0, 1.0, np.nan])
    t, r = bench.level_symptom(_reference(cht, model, oat), relative=False)
    assert np.array_equal(t, np.arange(5.0))
    assert np.allclose(r[:4], [4.0, -7.0, 10.0, 1.0]) and math.isnan(r[4])
    _, rho = bench.level_symptom(_reference(cht, model, oat), relative=True)
    # the rise above OAT is floored at RHO_FLOOR_C (the fourth sample's 5 degC: a cold engine)
    expected = [4.0 / 80.0, -7.0 / 140.0, 10.0 / 200.0, 1.0 / bench.RHO_FLOOR_C]
    assert np.allclose(rho[:4], expected) and math.isnan(rho[4])


def test_overlay_adds_about_its_gain_to_rho_at_every_power(bench: ModuleType) -> None:
    """CHT + k (CHT - OAT) f(t) moves rho by k f(t) (CHT - OAT) / (model - OAT): k f(t) where the model is right,
    at a low rise as at a high one; r moves by k (CHT - OAT) f(t)."""
    t = np.arange(0.0, 1800.0, 1.0)
    oat = np.full(t.size, 15.0)
    model = 15.0 + np.where(t < 900.0, 160.0, 70.0)  # cruise, then a power-off descent
    cht = model + 2.0 * np.sin(t / 97.0)  # a model error of a few degC
    gain, onset = 0.1, 600.0
    overlaid = overlay_degradation(t, cht, oat, onset, gain, 240.0)
    _, rho = bench.level_symptom(_reference(cht, model, oat), relative=True)
    _, rho_k = bench.level_symptom(_reference(overlaid, model, oat), relative=True)
    _, r = bench.level_symptom(_reference(cht, model, oat), relative=False)
    _, r_k = bench.level_symptom(_reference(overlaid, model, oat), relative=False)
    shape = np.where(t >= onset, 1.0 - np.exp(-(t - onset) / 240.0), 0.0)
    assert np.allclose(rho_k - rho, gain * shape, rtol=0.0, atol=gain * 2.0 / 70.0)
    assert np.allclose(r_k - r, gain * (cht - oat) * shape, rtol=1e-9, atol=1e-9)
    # the allowance is half the k = 0.1 overlay's rho 300 s after the onset
    assert pytest.approx(0.5 * gain * (1.0 - math.exp(-300.0 / 240.0))) == bench.RHO_ALLOWANCE


def test_level_feeds_replace_every_replays_symptom_by_its_own_reference(bench: ModuleType) -> None:
    """Training flights (FlightFeeds, their overlays) and the held-out runs each get the level symptom of their own
    reference, times their fold's scale; the derivative feeds are not used."""
    from ecu_monitor.offline.calibration_replays import FlightFeeds, OverlayRun

    t = np.arange(0.0, 5.0)
    oat = np.full(5, 10.0)

    def reference(offset: float) -> tuple[ReferenceFeed, ...]:
        return (ReferenceFeed(t, np.full(5, 110.0 + offset), np.full(5, 110.0), oat),)

    derivative = ((t, np.full(5, 99.0)),)
    training = FlightFeeds("a.csv", derivative, 0.0, 4.0, 0.0, (OverlayRun(2.0, 0.1, derivative, reference(3.0)),),
                           reference(1.0))  # fmt: skip
    feeds = {(0, 0): [(math.nan, 0.0, 0.0, derivative), (2.0, 0.2, 0.0, derivative)], (0, 1): training,
             (1, 1): [(math.nan, 0.0, 0.0, derivative)], (1, 0): training}  # fmt: skip
    references = {0: [reference(2.0), reference(4.0)], 1: [reference(5.0)]}
    levelled = bench._level_feeds(feeds, references, 2, relative=True, scales=[1.0, 10.0])
    assert [float(run[3][0][1][0]) for run in levelled[(0, 0)]] == pytest.approx([0.02, 0.04])
    assert [run[:3] for run in levelled[(0, 0)]] == [run[:3] for run in feeds[(0, 0)]]
    assert float(levelled[(0, 1)].feed[0][1][0]) == pytest.approx(0.01)
    assert float(levelled[(0, 1)].overlays[0].feed[0][1][0]) == pytest.approx(0.03)
    assert float(levelled[(1, 0)].feed[0][1][0]) == pytest.approx(0.1)  # fold 1: scale 10
    assert float(levelled[(1, 1)][0][3][0][1][0]) == pytest.approx(0.5)
    assert levelled[(0, 1)].overlays[0].onset_s == 2.0 and levelled[(0, 1)].name == "a.csv"
