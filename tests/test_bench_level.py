"""The level-symptom screen of benchmarks/bench_detect_real.py (``--level``): r and rho from a replay's
open-loop reference, and what the overlay adds to them."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from ecu_monitor.estimation.detection import overlay_degradation
from ecu_monitor.service.health_rows import ReferenceFeed


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_detect_real.py"
    spec = importlib.util.spec_from_file_location("bench_detect_real", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


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
