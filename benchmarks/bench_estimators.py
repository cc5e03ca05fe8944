"""Steps per second of the CHT estimators against filterpy's ExtendedKalmanFilter, measured in one run.

    .venv/bin/python benchmarks/bench_estimators.py [--steps 20000] [--flight-hours 1]

Every variant does the same work per 0.02 s step: one RK4 prediction of the thermal model with its
Jacobian, one scalar update with the sigmoid sensor model (the baseline, filterpy, gets the model's
rk4_step as its state transition, our complex-step F, and the sigmoid h and dh/dx).

* filterpy EKF: ``ExtendedKalmanFilter.predict()`` + ``update()`` with the drive precomputed.
* core, Python: :func:`ecu_monitor.estimation.filter_step` on floats with the drive precomputed.
* class, Python: ``ThermalEKF.estimate(t, u, z)`` as the live service calls it (includes the model's
  drive from the raw inputs, numpy-based, each step).
* runner, numba: :func:`ecu_monitor.estimation.run_estimator` over a whole flight (log resampled onto
  the step, drive for every step at once, compiled loop; compile time excluded, reported apart).

Prints a table with steps/s, us/step and the ratio to filterpy.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from ecu_monitor.estimation import EstimatorSettings, make_estimator, run_estimator
from ecu_monitor.estimation.ekf import FilterState, filter_step, predict, scalar_drive
from ecu_monitor.estimation.quantiser import sensor_model, sensor_slope
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


def _flight(hours: float, seed: int = 0) -> FlightLog:
    """A flight with throttle and altitude changes, readings at 10 Hz quantised to 1 degC (noise 0.3)."""
    n = round(hours * 3600.0 / DT) + 1
    t = DT * np.arange(n)
    throttle = 55.0 + 15.0 * np.sign(np.sin(2 * np.pi * t / 600.0))
    altitude = 1000.0 + 800.0 * np.sin(2 * np.pi * t / 3000.0)
    inputs: Any = InputSeries(throttle, 6000.0 + 20.0 * throttle, altitude, np.full(n, 23.0), 10.0 - 0.0065 * altitude)
    coeffs = coefficients(paper_table_a1())
    first = inputs.at(0)
    truth = simulate_compiled(inputs, coeffs, DT, steady_state_cht(compute_drive(first, coeffs), coeffs)).cht_c
    rng = np.random.default_rng(seed)
    keep = slice(None, None, 5)
    readings = np.round(truth[keep] + 0.3 * rng.standard_normal(truth[keep].size))
    columns = dict(zip(("throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c"), inputs, strict=True))
    return FlightLog({"time_s": t[keep], **{k: v[keep] for k, v in columns.items()}, "cht_c": readings})


class _ModelEKF(ExtendedKalmanFilter):
    """filterpy's EKF with the thermal model's RK4 step as its state transition."""

    def __init__(self, coeffs: Any, drive: Drive) -> None:
        super().__init__(dim_x=1, dim_z=1)
        self.coeffs = coeffs
        self.drive = drive
        self.pade_w: Any = float(initial_pade_state(drive))

    def predict_x(self, u: Any = 0) -> None:
        state: Any = self.x  # type: ignore[has-type]  # filterpy is untyped
        x_next, self.pade_w = rk4_step(float(state[0, 0]), self.pade_w, self.drive, self.coeffs, DT)
        self.x = np.array([[x_next]])


def _bench_filterpy(drives: list[Drive], z: np.ndarray, settings: EstimatorSettings, coeffs: Any) -> float:
    ekf = _ModelEKF(coeffs, drives[0])
    ekf.x = np.array([[float(z[0])]])
    ekf.P = np.array([[settings.initial_var]])
    ekf.Q = np.array([[settings.process_var]])
    ekf.R = np.array([[settings.measurement_var]])
    a, b, c = settings.sigmoid_a, settings.sigmoid_b, settings.quantum_c

    def jacobian(s: np.ndarray) -> np.ndarray:
        return np.array([[sensor_slope(float(s[0, 0]), a, b, c)]])

    def measure(s: np.ndarray) -> np.ndarray:
        return np.array([[sensor_model(float(s[0, 0]), a, b, c)]])

    started = time.perf_counter()
    for k in range(1, len(drives)):
        ekf.drive = drives[k - 1]
        ekf.F = np.array([[predict(float(ekf.x[0, 0]), 0.0, ekf.drive, coeffs, DT, 0.0, 0.0, ekf.pade_w).F]])
        ekf.predict()
        ekf.update(np.array([[z[k]]]), jacobian, measure)
    return time.perf_counter() - started


def _bench_core(
    drives: list[Drive], z: np.ndarray, settings: EstimatorSettings, coeffs: Any, use_deviation: bool
) -> float:
    s = settings
    state = FilterState(float(z[0]), s.initial_var, float(initial_pade_state(drives[0])), 0.0, float(z[0]), 0.0, 0.0)
    started = time.perf_counter()
    for k in range(1, len(drives)):
        state = filter_step(
            state,
            drives[k - 1],
            float(z[k]),
            True,
            coeffs,
            DT,
            s.process_var,
            s.measurement_var,
            s.sigmoid_a,
            s.sigmoid_b,
            s.quantum_c,
            s.deviation_time_s,
            use_deviation,
            2,
        )[0]
    return time.perf_counter() - started


def _bench_class(inputs: list[InputSeries], z: np.ndarray, settings: EstimatorSettings, name: str) -> float:
    est = make_estimator(name, paper_table_a1(), settings)
    est.initialise(0.0, inputs[0], float(z[0]))
    started = time.perf_counter()
    for k in range(1, len(inputs)):
        est.estimate(k * DT, inputs[k], float(z[k]))
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=20000, help="steps for the per-step variants")
    parser.add_argument("--flight-hours", type=float, default=1.0, help="flight length for the numba runner")
    args = parser.parse_args()
    settings = EstimatorSettings()
    params = paper_table_a1()
    coeffs = coefficients(params)
    log = _flight(args.flight_hours)
    short = log.resample(DT).select(0.0, (args.steps - 1) * DT + 1e-9)
    columns = [short[c] for c in ("throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c")]
    inputs = [InputSeries(*(float(col[k]) for col in columns)) for k in range(len(short))]
    drives = [scalar_drive(u, coeffs) for u in inputs]
    z = np.round(short["cht_c"])
    steps = len(short) - 1

    rows: list[tuple[str, float]] = []
    rows.append(("filterpy ExtendedKalmanFilter (baseline)", _bench_filterpy(drives, z, settings, coeffs) / steps))
    rows.append(("core filter_step, Python floats, EKF", _bench_core(drives, z, settings, coeffs, False) / steps))
    rows.append(("core filter_step, Python floats, CBEKF-AU", _bench_core(drives, z, settings, coeffs, True) / steps))
    rows.append(
        ("ThermalEKF.estimate (live, incl. drive), CBEKF-AU", _bench_class(inputs, z, settings, "cbekf-au") / steps)
    )

    started = time.perf_counter()
    run_estimator(log.select(0.0, 10.0), params, "cbekf-au", settings)  # compile or load the numba cache
    first_call = time.perf_counter() - started
    n_flight = round(log.duration_s / DT)
    for name in ("ekf", "cbekf-au"):
        best = np.inf
        for _ in range(3):
            started = time.perf_counter()
            run_estimator(log, params, name, settings)
            best = min(best, time.perf_counter() - started)
        rows.append(
            (f"run_estimator numba, {name}, {args.flight_hours:g} h flight (incl. resampling)", best / n_flight)
        )

    base = rows[0][1]
    print(f"{'variant':<72} {'steps/s':>12} {'us/step':>9} {'x filterpy':>11}")
    for label, per_step in rows:
        print(f"{label:<72} {1.0 / per_step:>12,.0f} {per_step * 1e6:>9.3f} {base / per_step:>11.1f}")
    print(
        f"numba first call (compile or cache load): {first_call:.2f} s; per-step runs: {steps} steps;"
        f" runner: {n_flight} steps, best of 3"
    )


if __name__ == "__main__":
    main()
