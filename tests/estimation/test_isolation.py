"""Isolation filter (cbekf-iso): equations against the model, live shell against the compiled run,
and the separation of gamma_Q from gamma_D on a short varied flight."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ecu_monitor.errors import ConfigError, EstimationError
from ecu_monitor.estimation import ESTIMATORS, make_estimator
from ecu_monitor.estimation.isolation import (
    ESTIMATOR_NAME,
    IsolationFilter,
    IsolationSettings,
    run_isolation,
)
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.model import InputSeries, coefficients, paper_table_a1
from ecu_monitor.model.compiled import simulate_compiled

DT = 0.02
RECORD = 5  # log every 0.1 s


def _varied_flight(duration_s: float, gamma_q: float, gamma_d: float, onset_s: float, seed: int) -> FlightLog:
    """A short flight with throttle steps, a sine throttle variation and an altitude change, simulated
    by the model itself (no unmodelled effect) and read by a noisy 1 degC sensor."""
    params = paper_table_a1()
    t = np.arange(0.0, duration_s, DT)
    throttle = np.where(t < 120.0, 30.0, np.where(t < 500.0, 90.0, 55.0 + 15.0 * np.sin(2 * np.pi * t / 240.0)))
    throttle = np.where((t > 900.0) & (t < 1000.0), 100.0, throttle)
    airspeed = np.where(t < 120.0, 0.0, 22.0)
    altitude = np.clip((t - 120.0) * 2.5, 0.0, 900.0) + np.clip((t - 1100.0) * 2.0, 0.0, 400.0)
    oat = 15.0 - 6.5 * altitude / 1000.0
    rpm = np.clip(1800.0 + 7000.0 * (throttle / 100.0) ** 0.8 + 10.0 * airspeed, 1500.0, 9200.0)
    gq = np.where(t >= onset_s, gamma_q, 1.0)
    gd = np.where(t >= onset_s, gamma_d, 1.0)
    run = simulate_compiled(InputSeries(throttle, rpm, altitude, airspeed, oat), coefficients(params), DT, 20.0, gq, gd)
    rng = np.random.default_rng(seed)
    keep = slice(0, None, RECORD)
    measured = np.round(run.cht_c[keep] + 0.3 * rng.standard_normal(t[keep].size))
    return FlightLog(
        {
            "time_s": t[keep],
            "throttle_pct": throttle[keep],
            "rpm": rpm[keep],
            "altitude_m": altitude[keep],
            "airspeed_mps": airspeed[keep],
            "oat_c": oat[keep],
            "cht_c": measured,
            "cht_true_c": run.cht_c[keep],
        }
    )


def test_prediction_equals_the_model_when_readings_are_ignored() -> None:
    log = _varied_flight(600.0, 1.0, 1.0, math.inf, 1)
    params = paper_table_a1()
    settings = IsolationSettings(measurement_var=1e12, gamma_q_process_var=1e-12, gamma_d_process_var=1e-12)
    trace = run_isolation(log, params, settings, cht_column="cht_true_c")
    # the model on the same held-per-sample inputs
    hold = np.repeat(np.arange(len(log)), RECORD)
    inputs = InputSeries(*(log[c][hold] for c in ("throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c")))
    run = simulate_compiled(inputs, coefficients(params), DT, float(log["cht_true_c"][0]))
    assert np.max(np.abs(trace.cht_c - run.cht_c[::RECORD])) < 1e-6
    assert np.max(np.abs(trace.gamma_q - 1.0)) < 1e-6 and np.max(np.abs(trace.gamma_d - 1.0)) < 1e-6
    assert np.max(np.abs(trace.deviation)) < 1e-6


def test_live_filter_equals_the_compiled_run() -> None:
    log = _varied_flight(200.0, 1.2, 1.0, 50.0, 2)
    params = paper_table_a1()
    trace = run_isolation(log, params)
    live = make_estimator(ESTIMATOR_NAME, params)
    assert isinstance(live, IsolationFilter)
    cols = ("throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c")
    t = log.time_s

    def u(k: int) -> InputSeries:
        return InputSeries(*(float(log[c][k]) for c in cols))

    live.initialise(float(t[0]), u(0), float(log["cht_c"][0]))
    for k in range(1, len(log)):
        est = live.estimate(float(t[k]), u(k), float(log["cht_c"][k]))
    assert est.cht_c == pytest.approx(trace.cht_c[-1], abs=1e-9)
    assert live.gamma_q == pytest.approx(trace.gamma_q[-1], abs=1e-12)
    assert live.gamma_d == pytest.approx(trace.gamma_d[-1], abs=1e-12)
    assert est.deviation == pytest.approx(trace.deviation[-1], abs=1e-12)
    assert est.measured and math.isfinite(est.nis)
    assert live.gamma_covariance.shape == (2, 2)


@pytest.mark.parametrize(
    ("gamma_q", "gamma_d"),
    [(1.2, 1.0), (1.0, 1.2)],
)
def test_separates_gamma_q_from_gamma_d_on_a_varied_flight(gamma_q: float, gamma_d: float) -> None:
    log = _varied_flight(1500.0, gamma_q, gamma_d, 300.0, 3)
    trace = run_isolation(log, paper_table_a1())
    end = trace.time_s >= 1400.0
    gq = float(np.mean(trace.gamma_q[end]))
    gd = float(np.mean(trace.gamma_d[end]))
    assert gq == pytest.approx(gamma_q, abs=0.05)
    assert gd == pytest.approx(gamma_d, abs=0.05)
    # and the split is right, not only the product
    assert (gq - gd) * (gamma_q - gamma_d) > 0.0
    assert abs(gq - gd) > 0.1
    before = trace.time_s < 300.0
    assert np.max(np.abs(trace.gamma_q[before] - 1.0)) < 0.03


def test_registry_settings_and_errors() -> None:
    assert ESTIMATOR_NAME in ESTIMATORS
    with pytest.raises(ConfigError):
        IsolationSettings(gamma_min=1.5)
    with pytest.raises(ConfigError):
        IsolationSettings(measurement_var=0.0)
    live = IsolationFilter(paper_table_a1())
    with pytest.raises(EstimationError):
        live.estimate(1.0, InputSeries(50.0, 6000.0, 0.0, 23.0, 15.0), 100.0)
