"""Estimators: filterpy cross-check, complex-step Jacobian, sigmoid sensor, CBEKF vs EKF, numba runner."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import ExtendedKalmanFilter

from ecu_monitor.errors import ConfigError, EstimationError, FlightLogError
from ecu_monitor.estimation import (
    ESTIMATORS,
    EstimatorSettings,
    ThermalEKF,
    deviation_update,
    make_estimator,
    predict,
    register_estimator,
    run_estimator,
    sensor_model,
    sensor_slope,
)
from ecu_monitor.estimation.ekf import scalar_drive
from ecu_monitor.estimation.quantiser import quantise, reset_value
from ecu_monitor.estimation.runner import run_estimator_on_calls, run_estimator_on_steps
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.model import (
    Drive,
    InputSeries,
    coefficients,
    compute_drive,
    initial_pade_state,
    paper_table_a1,
    rk4_step,
    steady_state_cht,
)
from ecu_monitor.model.compiled import simulate_compiled

DT = 0.02
PARAMS = paper_table_a1()
COEFFS = coefficients(PARAMS)
CRUISE = InputSeries(60.0, 6500.0, 500.0, 23.0, 12.0)


def _flight(
    duration_s: float,
    gamma_q: float = 1.0,
    inject_s: float = 150.0,
    *,
    noise_c: float = 0.3,
    seed: int = 0,
    record_every: int = 1,
    vary: bool = False,
) -> tuple[FlightLog, np.ndarray]:
    """A cruise flight on the fixed step (optionally with throttle steps), truth from the model, readings
    quantised to 1 degC after Gaussian noise; returns (log sampled every record_every steps, truth)."""
    n = round(duration_s / DT) + 1
    t = DT * np.arange(n)
    one = np.ones(n)
    throttle = 60.0 + (10.0 * np.sign(np.sin(2 * np.pi * t / 240.0)) if vary else 0.0)
    inputs = InputSeries(throttle * one, 6500.0 * one, 500.0 * one, 23.0 * one, 12.0 * one)
    start = steady_state_cht(compute_drive(CRUISE, COEFFS), COEFFS)
    gammas = np.where(t >= inject_s, gamma_q, 1.0)
    truth = simulate_compiled(inputs, COEFFS, DT, start, gammas).cht_c
    rng = np.random.default_rng(seed)
    readings = np.floor(truth + noise_c * rng.standard_normal(n) + 0.5)
    keep = slice(None, None, record_every)
    columns = {
        "time_s": t[keep],
        "throttle_pct": inputs.heat_x[keep],
        "rpm": inputs.heat_y[keep],
        "altitude_m": inputs.altitude_m[keep],
        "airspeed_mps": inputs.airspeed_mps[keep],
        "oat_c": inputs.oat_c[keep],
        "cht_c": readings[keep],
    }
    return FlightLog(columns, source="synthetic"), truth


# --- sensor model --------------------------------------------------------------------------------


def _round_half_up(x: float) -> float:
    return math.floor(x + 0.5)


@pytest.mark.parametrize("x", [120.0, 120.1, 120.3, 120.42, 120.58, 120.7, 120.95, -3.2, -3.8])
def test_sigmoid_sensor_is_the_round_function_away_from_half_steps(x):
    assert sensor_model(x, 100.0, 0.5, 1.0) == pytest.approx(_round_half_up(x), abs=2e-3)
    assert quantise(x, 1.0) == _round_half_up(x)


def test_sigmoid_sensor_is_continuous_and_passes_half_steps_at_midlevel():
    a, b = 100.0, 0.5
    assert sensor_model(120.5, a, b, 1.0) == pytest.approx(120.5, abs=1e-12)
    assert sensor_model(121.0 - 1e-12, a, b, 1.0) == pytest.approx(sensor_model(121.0, a, b, 1.0), abs=1e-9)
    assert sensor_slope(120.5, a, b, 1.0) == pytest.approx(a / 4.0)
    assert sensor_slope(120.0, a, b, 1.0) < 1e-18
    # a coarser quantum: step of 0.5 degC
    assert sensor_model(10.3, a, b, 0.5) == pytest.approx(10.5, abs=1e-4)


@pytest.mark.parametrize("x", [120.45, 120.48, 120.5, 120.53, 120.6, 99.52, 100.3])
def test_sigmoid_slope_matches_central_difference(x):
    h = 1e-6
    numeric = (sensor_model(x + h, 100.0, 0.5, 1.0) - sensor_model(x - h, 100.0, 0.5, 1.0)) / (2 * h)
    assert sensor_slope(x, 100.0, 0.5, 1.0) == pytest.approx(numeric, rel=1e-5, abs=1e-8)


def test_reset_value_midpoint_and_boundary():
    assert reset_value(121.0, 120.0, 1.0, boundary=False) == 121.0
    assert reset_value(121.0, 120.0, 1.0, boundary=True) == 120.5
    assert reset_value(119.0, 120.0, 1.0, boundary=True) == 119.5


# --- prediction Jacobian -------------------------------------------------------------------------


@pytest.mark.parametrize("cht", [40.0, 118.0, 160.0])
@pytest.mark.parametrize("kelvin", [False, True])
def test_complex_step_jacobian_matches_finite_difference(cht, kelvin):
    params = PARAMS.replace(radiation_in_kelvin=True, alpha_r_e=4.4e8) if kelvin else PARAMS
    coeffs = coefficients(params)
    drive = scalar_drive(InputSeries(85.0, 7200.0, 1000.0, 20.0, 8.0), coeffs)
    w = float(initial_pade_state(drive)) * 0.9  # off steady state: exercises the Pade term too
    pred = predict(cht, 2.0, drive, coeffs, DT, 1e-4, 0.0, w)
    h = 1e-4
    plus = rk4_step(cht + h, w, drive, coeffs, DT)[0]
    minus = rk4_step(cht - h, w, drive, coeffs, DT)[0]
    jacobian, variance = pred.F, pred.P
    assert jacobian == pytest.approx((plus - minus) / (2 * h), rel=1e-9)
    assert pred.x == pytest.approx(rk4_step(cht, w, drive, coeffs, DT)[0], abs=1e-12)
    assert variance == pytest.approx(jacobian**2 * 2.0 + 1e-4, rel=1e-14)
    assert 0.99 < jacobian < 1.0  # a cooling head: the step contracts errors


# --- cross-check against filterpy ----------------------------------------------------------------


class _ModelEKF(ExtendedKalmanFilter):
    """filterpy's EKF with the thermal model's RK4 step as the state transition (Pade state alongside)."""

    def __init__(self, drive: Drive, pade_w: float) -> None:
        super().__init__(dim_x=1, dim_z=1)
        self.drive = drive
        self.pade_w = pade_w

    def predict_x(self, u=0):
        x_next, self.pade_w = rk4_step(float(self.x[0, 0]), self.pade_w, self.drive, COEFFS, DT)
        self.x = np.array([[x_next]])


def test_ekf_matches_filterpy_step_for_step():
    settings = EstimatorSettings(process_var=1e-3)
    log, _ = _flight(120.0, gamma_q=1.2, inject_s=10.0, vary=True)
    ekf = make_estimator("ekf", PARAMS, settings)
    columns = [log[name] for name in ("throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c")]
    z = log["cht_c"]

    def inputs(k: int) -> InputSeries:
        return InputSeries(*(float(c[k]) for c in columns))

    ekf.initialise(0.0, inputs(0), float(z[0]))
    drive = scalar_drive(inputs(0), COEFFS)
    ref = _ModelEKF(drive, float(initial_pade_state(drive)))
    ref.x = np.array([[float(z[0])]])
    ref.P = np.array([[settings.initial_var]])
    ref.Q = np.array([[settings.process_var]])
    ref.R = np.array([[settings.measurement_var]])
    args = (settings.sigmoid_a, settings.sigmoid_b, settings.quantum_c)
    max_dx = max_dp = 0.0
    crossings = 0
    for k in range(1, len(log)):
        # our F (complex step, tested against a finite difference above); filterpy does the rest
        ref.F = np.array([[predict(float(ref.x[0, 0]), 0.0, ref.drive, COEFFS, DT, 0.0, 0.0, ref.pade_w).F]])
        ref.predict()
        ref.update(
            np.array([[z[k]]]),
            lambda s: np.array([[sensor_slope(float(s[0, 0]), *args)]]),
            lambda s: np.array([[sensor_model(float(s[0, 0]), *args)]]),
        )
        ref.drive = scalar_drive(inputs(k), COEFFS)
        est = ekf.estimate(k * DT, inputs(k), float(z[k]))
        max_dx = max(max_dx, abs(est.cht_c - float(ref.x[0, 0])))
        max_dp = max(max_dp, abs(est.variance_c2 - float(ref.P[0, 0])))
        crossings += abs(est.innovation_c) > 0.4
    assert crossings > 20  # the run exercised the sensor model's steep part, not just flat levels
    assert max_dx < 1e-9
    assert max_dp < 1e-9


# --- the paper's Section 3.2 claims, measured ----------------------------------------------------


@pytest.fixture(scope="module")
def degraded_runs():
    log, truth = _flight(600.0, gamma_q=1.1, inject_s=150.0)
    runs = {}
    for name, reset in (("ekf", "none"), ("cbekf", "none"), ("cbekf-au", "boundary"), ("cbekf-au-mid", "midpoint")):
        runs[name] = run_estimator(log, PARAMS, name.removesuffix("-mid"), EstimatorSettings(reset=reset))
    return log, truth, runs


def _settle_time(time_s, error, after_s, threshold_c=0.5, window_s=10.0):
    """Seconds after ``after_s`` until the window-mean |error| stays below the threshold."""
    n = round(window_s / DT)
    mean_abs = np.convolve(np.abs(error), np.ones(n) / n, mode="full")[: error.size]  # trailing window
    late = (time_s >= after_s) & (mean_abs > threshold_c)
    idx = np.nonzero(late)[0]
    return 0.0 if idx.size == 0 else float(time_s[idx[-1]] - after_s)


def test_cbekf_removes_the_steady_error_the_ekf_keeps(degraded_runs):
    _, truth, runs = degraded_runs
    tail = runs["ekf"].time_s >= 450.0
    ekf_error = np.mean(runs["ekf"].cht_est_c[tail] - truth[tail])
    cbekf_error = np.mean(runs["cbekf"].cht_est_c[tail] - truth[tail])
    # measured: EKF about -6.1 degC (-5 % of 124 degC), CBEKF about 0.0 degC
    assert ekf_error < -4.0
    assert abs(cbekf_error) < 0.3


def test_cbekf_au_converges_faster_than_cbekf(degraded_runs):
    _, truth, runs = degraded_runs
    t = runs["cbekf"].time_s
    cbekf = _settle_time(t, runs["cbekf"].cht_est_c - truth, 150.0)
    au = _settle_time(t, runs["cbekf-au"].cht_est_c - truth, 150.0)
    au_mid = _settle_time(t, runs["cbekf-au-mid"].cht_est_c - truth, 150.0)
    # measured: CBEKF about 67 s, CBEKF-AU 0 s (boundary and midpoint)
    assert cbekf > 15.0
    assert au < 0.5 * cbekf
    assert au_mid < 0.5 * cbekf
    assert runs["cbekf-au"].reset.sum() > 10
    assert not runs["cbekf"].reset.any()


def test_deviation_measures_the_degradation_rate(degraded_runs):
    runs = degraded_runs[2]
    t = runs["cbekf"].time_s
    deviation = runs["cbekf"].deviation
    before = np.mean(deviation[(t > 30.0) & (t < 150.0)])
    after = np.mean(deviation[t > 300.0])
    # expected: the extra heat (gamma_Q - 1) Q_in / C_w at the degraded steady state
    drive = compute_drive(CRUISE, COEFFS)
    expected = 0.1 * float(drive.altitude_gain * drive.q_sl0_w) / COEFFS.c_w
    assert abs(before) < 0.02
    assert after == pytest.approx(expected, rel=0.05)  # measured: 0.1632 vs 0.1631 degC/s
    assert np.all(runs["ekf"].deviation == 0.0)


# --- numba runner equals the Python class --------------------------------------------------------


@pytest.mark.parametrize("name", ["ekf", "cbekf", "cbekf-au"])
def test_compiled_runner_equals_python_class(name):
    log, _ = _flight(200.0, gamma_q=1.2, inject_s=60.0, record_every=5, vary=True)  # readings at 10 Hz
    settings = EstimatorSettings()
    trace = run_estimator(log, PARAMS, name, settings)
    assert trace.measured.sum() == len(log)
    estimator = make_estimator(name, PARAMS, settings)
    columns = [log[c] for c in ("throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c")]
    times = trace.time_s
    t_log = log.time_s

    def inputs_at(t: float) -> InputSeries:
        return InputSeries(*(float(np.interp(t, t_log, c)) for c in columns))

    estimator.initialise(float(times[0]), inputs_at(times[0]), float(log["cht_c"][0]))
    x = np.empty(times.size)
    dev = np.empty(times.size)
    x[0], dev[0] = trace.cht_est_c[0], 0.0
    for k in range(1, times.size):
        z = float(trace.cht_meas_c[k]) if trace.measured[k] else None
        est = estimator.estimate(float(times[k]), inputs_at(times[k]), z)
        x[k], dev[k] = est.cht_c, est.deviation
    assert np.max(np.abs(x - trace.cht_est_c)) < 1e-9
    assert np.max(np.abs(dev - trace.deviation)) < 1e-9


def test_python_and_compiled_trace_loops_agree():
    log, _ = _flight(60.0, gamma_q=1.3, inject_s=10.0, vary=True)
    fast = run_estimator(log, PARAMS, "cbekf-au")
    slow = run_estimator(log, PARAMS, "cbekf-au", compiled=False)
    assert np.max(np.abs(fast.cht_est_c - slow.cht_est_c)) < 1e-9
    assert np.array_equal(fast.reset, slow.reset)
    assert np.nanmax(np.abs(fast.nis - slow.nis)) < 1e-9


@pytest.mark.parametrize("name", ["ekf", "cbekf", "cbekf-au", "cbekf-iso"])
def test_estimator_on_calls_equals_the_steps_with_inputs_held(name):
    """The replay's call-level runner makes the very filter steps of the per-step runner: inputs held
    between irregular calls, readings only at some calls, equal bit for bit at every call."""
    log, _ = _flight(120.0, gamma_q=1.25, inject_s=40.0, vary=True)
    n = len(log)
    rng = np.random.default_rng(3)
    calls = np.concatenate(([0], np.sort(rng.choice(np.arange(1, n), size=n // 5, replace=False))))
    which = np.repeat(np.arange(calls.size), np.diff(calls, append=n))
    names = ("throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c")
    columns = [np.asarray(log[c])[calls] for c in names]
    z = np.where(rng.random(calls.size) < 0.7, np.asarray(log["cht_c"])[calls], np.nan)
    z[0] = log["cht_c"][0]
    per_step_z = np.full(n, np.nan)
    per_step_z[calls] = z
    settings = EstimatorSettings()
    steps = run_estimator_on_steps(log.time_s, InputSeries(*(v[which] for v in columns)), per_step_z, PARAMS, name,
                                   settings)  # fmt: skip
    on_calls = run_estimator_on_calls(log.time_s, calls, InputSeries(*columns), z, PARAMS, name, settings)
    assert np.array_equal(on_calls.cht_est_c, steps.cht_est_c[calls])
    assert np.array_equal(on_calls.deviation, steps.deviation[calls])


# --- contract and errors -------------------------------------------------------------------------


def test_registry_and_unknown_names():
    assert {"ekf", "cbekf", "cbekf-au"} <= set(ESTIMATORS)
    with pytest.raises(ConfigError, match="cbekf-au"):
        make_estimator("kalman", PARAMS)
    est = make_estimator("cbekf-au", PARAMS, EstimatorSettings(reset="midpoint"))
    assert isinstance(est, ThermalEKF) and est.reset_mode == "midpoint" and est.name == "cbekf-au"

    def factory(params, settings):
        return ThermalEKF(params, settings, name="custom", use_deviation=True, reset="boundary")

    register_estimator("custom-test", factory)
    try:
        assert make_estimator("custom-test", PARAMS).name == "custom"
    finally:
        del ESTIMATORS["custom-test"]


@pytest.mark.parametrize(
    "changes",
    [{"dt_s": 0.0}, {"process_var": -1.0}, {"reset": "always"}, {"sigmoid_b": 1.5}, {"measurement_var": math.nan}],
)
def test_settings_are_validated(changes):
    with pytest.raises(ConfigError):
        EstimatorSettings(**changes)


def test_estimate_needs_initialise_and_advancing_time():
    est = make_estimator("cbekf", PARAMS)
    with pytest.raises(EstimationError):
        est.estimate(0.02, CRUISE, 118.0)
    est.initialise(0.0, CRUISE, 118.0)
    with pytest.raises(EstimationError):
        est.estimate(0.0, CRUISE, 118.0)
    quiet = est.estimate(0.02, CRUISE, None)
    assert not quiet.measured and math.isnan(quiet.innovation_c) and math.isnan(quiet.nis)
    later = est.estimate(0.1, CRUISE, 118.0)  # four steps at once, the reading on the last
    assert later.measured and later.time_s == pytest.approx(0.1)


def test_run_estimator_names_a_missing_column():
    log, _ = _flight(5.0)
    columns = {k: log[k] for k in log.names if k != "oat_c"}
    with pytest.raises(FlightLogError, match="oat_c"):
        run_estimator(FlightLog(columns, source="x.csv"), PARAMS, "ekf")


def test_drive_of_estimator_equals_model_drive():
    d = scalar_drive(CRUISE, COEFFS)
    ref = compute_drive(CRUISE, COEFFS)
    assert isinstance(d, Drive)
    assert all(isinstance(v, float) for v in d)
    assert np.allclose(d, [float(v) for v in ref], rtol=0, atol=0)


# --- properties ----------------------------------------------------------------------------------


def test_sensor_model_is_monotonic_and_within_half_a_step():
    from hypothesis import given, settings
    from hypothesis import strategies as st

    @settings(max_examples=300, deadline=None)
    @given(st.floats(-50.0, 400.0), st.floats(1e-6, 0.2), st.sampled_from([0.5, 1.0, 2.0]))
    def check(x, step, c):
        assert sensor_model(x + step, 100.0, 0.5, c) >= sensor_model(x, 100.0, 0.5, c) - 1e-9
        assert abs(sensor_model(x, 100.0, 0.5, c) - x) <= 0.5 * c + 1e-9
        assert sensor_slope(x, 100.0, 0.5, c) >= 0.0

    check()


def test_deviation_is_exact_for_an_ideal_sensor():
    """Readings equal to the truth (no quantisation, no noise): Delta converges to the exact one-step
    model deviation of the degraded plant, f_degraded(x) - f_nominal(x)."""
    drive = scalar_drive(CRUISE, COEFFS)
    w = float(initial_pade_state(drive))
    truth = 118.0
    delta = 0.0
    settings = EstimatorSettings()
    for _ in range(round(200.0 / DT)):  # 10 tau_Delta
        nxt = rk4_step(truth, w, drive, COEFFS, DT, 1.3)[0]
        reference = rk4_step(truth, w, drive, COEFFS, DT)[0]
        delta = deviation_update(delta, reference, nxt, 1.0, DT, settings.deviation_time_s)
        truth = nxt
    expected = rk4_step(truth, w, drive, COEFFS, DT, 1.3)[0] - rk4_step(truth, w, drive, COEFFS, DT)[0]
    assert delta == pytest.approx(expected, rel=1e-3)
    # spreading a gap of n steps gives the same filter output as n single steps of equal deviation
    one_by_one = 0.0
    for _ in range(5):
        one_by_one = deviation_update(one_by_one, 0.0, 0.01, 1.0, DT, 20.0)
    assert deviation_update(0.0, 0.0, 0.05, 5.0, DT, 20.0) == pytest.approx(one_by_one, rel=1e-12)


def test_live_filter_compiled_equals_python():
    """ThermalEKF's compiled hot loop (numba twin of filter_steps) gives the Python result."""
    from ecu_monitor.estimation import EstimatorSettings, ThermalEKF
    from ecu_monitor.model import InputSeries, paper_table_a1

    params = paper_table_a1()
    settings = EstimatorSettings()
    filters = [
        ThermalEKF(params, settings, name="cbekf-au", use_deviation=True, reset="boundary", compiled=flag)
        for flag in (True, False)
    ]
    u = InputSeries(60.0, 6500.0, 800.0, 23.0, 12.0)
    for f in filters:
        f.initialise(0.0, u, 100.0)
    for k in range(1, 400):
        z = float(round(100.0 + 0.03 * k))
        t = 0.1 * k  # five 20 ms steps per call, the reading on the last
        fast, slow = (f.estimate(t, u, z if k % 2 else None) for f in filters)
        assert fast.cht_c == pytest.approx(slow.cht_c, abs=1e-9)
        assert fast.deviation == pytest.approx(slow.deviation, abs=1e-12)
        assert fast.reset == slow.reset


def test_live_filter_call_follows_changing_inputs_as_the_python_filter():
    """The compiled live call computes the next call's drive itself (the model's compiled drive kernel):
    with inputs changing at every call (across heat-map cells, altitude, airspeed, OAT), the whole filter
    state, Pade state included, stays the Python filter's, for CBEKF-AU and the open-loop EKF."""
    from ecu_monitor.estimation import EstimatorSettings, ThermalEKF
    from ecu_monitor.model import InputSeries, paper_table_a1

    params = paper_table_a1()
    settings = EstimatorSettings()
    for kind, deviation, reset in (("cbekf-au", True, "boundary"), ("ekf", False, "none")):
        filters = [
            ThermalEKF(params, settings, name=kind, use_deviation=deviation, reset=reset, compiled=flag)
            for flag in (True, False)
        ]
        rng = np.random.default_rng(3)
        for f in filters:
            f.initialise(0.0, InputSeries(40.0, 4000.0, 300.0, 20.0, 10.0), 120.0)
        for k in range(1, 300):
            u = InputSeries(*rng.uniform((-5.0, 1500.0, -200.0, 0.0, -30.0), (105.0, 9500.0, 4000.0, 45.0, 40.0)))
            z = float(round(120.0 + 10.0 * math.sin(0.05 * k))) if kind == "cbekf-au" and k % 3 else None
            fast, slow = (f.estimate(0.1 * k, u, z) for f in filters)
            assert fast.cht_c == pytest.approx(slow.cht_c, abs=1e-9)
            assert fast.deviation == pytest.approx(slow.deviation, abs=1e-12)
            assert fast.reset == slow.reset
            assert filters[0].state == pytest.approx(filters[1].state, abs=1e-9)
