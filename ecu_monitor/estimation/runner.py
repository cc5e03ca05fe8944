"""Run an estimator over a whole flight log (replay, results, benchmarks): the fast path.

:func:`run_estimator` puts the log on the filter's fixed step (the model's inputs read by
:func:`ecu_monitor.model.flight_inputs` and interpolated linearly, each CHT reading applied at the
first step at or after its time stamp, no reading in between), computes the model's drive for every
step at once (:func:`ecu_monitor.model.compiled.compute_drive_compiled`, equal bit for bit to the
live filter's per-step drive), and runs the scalar filter loop compiled with numba.

One source of truth: the compiled loop is :func:`trace_loop` below calling
:func:`ecu_monitor.estimation.ekf.filter_steps` (its ``filter_step`` over substeps), which calls the
model's own ``rk4_step``; numba compiles those very functions into the loop (no equation is written
twice; :mod:`ecu_monitor.model.kernels`). ``trace_loop.py_func`` runs it as plain Python (the reference
in the tests). Estimators that are not a :class:`ThermalEKF` (the isolation filter) run step by step
through their ``estimate()``, itself compiled.

numba is loaded on the live path too: :class:`ThermalEKF` and the isolation filter step through the
same compiled functions (the daemon compiles or loads them from the disk cache before it opens the
bus, ``Pipeline.warm_up``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import FlightLogError
from ecu_monitor.estimation.ekf import (
    _RESET_CODES,
    EstimatorSettings,
    FilterState,
    ThermalEKF,
    filter_steps,
)
from ecu_monitor.estimation.quantiser import level_of
from ecu_monitor.estimation.registry import make_estimator
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.model import Coefficients, Drive, InputSeries, ThermalParams, coefficients, scalar_coefficients
from ecu_monitor.model.compiled import compute_drive_compiled
from ecu_monitor.model.inputs import AMBIENT_COLUMNS, flight_inputs, input_columns
from ecu_monitor.model.kernels import njit, python_reference

__all__ = [
    "INPUT_COLUMNS",
    "CallTrace",
    "EstimateTrace",
    "FixedStepFlight",
    "fixed_step_flight",
    "run_estimator",
    "run_estimator_on_calls",
    "run_estimator_on_steps",
    "sample_indices",
    "trace_loop",
]

#: Flight columns the model needs besides the heat map's two axes (and the mixture index's, if any).
INPUT_COLUMNS = AMBIENT_COLUMNS


@dataclass(frozen=True)
class EstimateTrace:
    """An estimator's output over a flight, one value per fixed step (arrays of length N).

    time_s: s. cht_meas_c: last CHT reading held, degC. cht_est_c: estimate, degC. deviation: model
    deviation Delta/dt, degC/s. variance: P, degC^2. innovation: z - h(prior), degC (nan where no
    reading). nis: normalised innovation squared (nan where no reading). reset: CBEKF-AU re-initialised
    at this step. measured: a reading was applied at this step.
    """

    estimator: str
    time_s: NDArray[np.float64]
    cht_meas_c: NDArray[np.float64]
    cht_est_c: NDArray[np.float64]
    deviation: NDArray[np.float64]
    variance: NDArray[np.float64]
    innovation: NDArray[np.float64]
    nis: NDArray[np.float64]
    reset: NDArray[np.bool_]
    measured: NDArray[np.bool_]

    def __len__(self) -> int:
        return int(self.time_s.size)

    def take(self, index: NDArray[np.intp]) -> EstimateTrace:
        """The trace at the given step indices (e.g. decimated to the log's sample times)."""
        return EstimateTrace(
            self.estimator,
            *(np.asarray(getattr(self, name))[index] for name in _ARRAY_FIELDS),
        )


_ARRAY_FIELDS = (
    "time_s",
    "cht_meas_c",
    "cht_est_c",
    "deviation",
    "variance",
    "innovation",
    "nis",
    "reset",
    "measured",
)


@dataclass(frozen=True)
class FixedStepFlight:
    """A flight put on the filter's fixed step: inputs per step, readings where they fall.

    time_s: step times, s. inputs: model inputs per step (arrays). z_c: reading applied at each step,
    degC (nan: none). measured: a reading falls on this step. sample_step: for each log sample, the
    step its reading was applied at.
    """

    time_s: NDArray[np.float64]
    inputs: InputSeries
    z_c: NDArray[np.float64]
    measured: NDArray[np.bool_]
    sample_step: NDArray[np.intp]


def sample_indices(sample_times_s: NDArray[np.float64], t0_s: float, dt_s: float, n_steps: int) -> NDArray[np.intp]:
    """Index of the first fixed step at or after each sample time (clipped to the grid)."""
    steps = np.ceil((np.asarray(sample_times_s, dtype=float) - t0_s) / dt_s - 1e-9).astype(np.intp)
    return np.clip(steps, 0, n_steps - 1)


def fixed_step_flight(log: FlightLog, params: ThermalParams, dt_s: float) -> FixedStepFlight:
    """Resample a flight log onto the fixed step (raises FlightLogError naming a missing column)."""
    missing = [name for name in (*input_columns(params), "cht_c") if not log.has(name)]
    if missing:
        raise FlightLogError(
            f"{log.source}: missing column(s) {', '.join(missing)} needed by the model"
            f" (columns: {', '.join(log.names)})"
        )
    at_samples = flight_inputs(log, params)
    t = log.time_s
    n = math.floor((t[-1] - t[0]) / dt_s + 1e-9) + 1
    if n < 2:
        raise FlightLogError(f"{log.source}: the log spans {t[-1] - t[0]:g} s, shorter than one step of {dt_s} s")
    grid = t[0] + dt_s * np.arange(n, dtype=np.float64)
    inputs = InputSeries(*(np.interp(grid, t, values) for values in at_samples))
    readings = np.asarray(log["cht_c"], dtype=float)
    steps = sample_indices(t, float(t[0]), dt_s, n)
    z = np.full(n, np.nan)
    valid = np.isfinite(readings)
    z[steps[valid]] = readings[valid]  # a later sample on the same step wins
    measured = np.isfinite(z)
    if not measured[0]:
        raise FlightLogError(f"{log.source}: column 'cht_c' has no reading at the first sample")
    return FixedStepFlight(grid, inputs, z, measured, steps)


@njit()
def trace_loop(
    q_sl0_w: NDArray[np.float64],
    altitude_gain: NDArray[np.float64],
    ambient_c: NDArray[np.float64],
    conductance_w_per_c: NDArray[np.float64],
    heat_gain: NDArray[np.float64],
    z_c: NDArray[np.float64],
    measured: NDArray[np.bool_],
    substeps: NDArray[np.int64],
    coeffs: Coefficients,
    initial_var: float,
    dt: float,
    Q: float,
    R: float,
    a: float,
    b: float,
    c: float,
    tau: float,
    use_deviation: bool,
    reset_code: int,
    out_x: NDArray[np.float64],
    out_P: NDArray[np.float64],
    out_delta: NDArray[np.float64],
    out_innovation: NDArray[np.float64],
    out_nis: NDArray[np.float64],
    out_reset: NDArray[np.bool_],
) -> None:
    """The filter over a flight, recorded at each call: call k >= 1 makes ``substeps[k]`` fixed steps with
    the drive of call k-1, the reading z_c[k] on the last (:func:`ecu_monitor.estimation.ekf.filter_steps`,
    the live filter's own loop). On the fixed-step grid every ``substeps[k]`` is 1; the replay's calls hold
    their inputs between calls.

    Call 0 initialises from z_c[0] (x = z, P = initial_var, Pade state in steady state), exactly as
    :meth:`ThermalEKF.initialise`. Its ``.py_func`` is the plain-Python reference.
    """
    z0 = z_c[0]
    state = FilterState(z0, initial_var, 2.0 * q_sl0_w[0], 0.0, z0, 0.0, level_of(z0, c))
    out_x[0] = z0
    out_P[0] = initial_var
    out_delta[0] = 0.0
    out_innovation[0] = math.nan
    out_nis[0] = math.nan
    out_reset[0] = False
    for k in range(1, z_c.shape[0]):
        drive = Drive(
            q_sl0_w[k - 1], altitude_gain[k - 1], ambient_c[k - 1], conductance_w_per_c[k - 1], heat_gain[k - 1]
        )
        state, innovation, nis, did_reset = filter_steps(
            state, drive, z_c[k], measured[k], coeffs, dt, Q, R, a, b, c, tau, use_deviation, reset_code, substeps[k]
        )
        out_x[k] = state.x
        out_P[k] = state.P
        out_delta[k] = state.delta if use_deviation else 0.0
        out_innovation[k] = innovation
        out_nis[k] = nis
        out_reset[k] = did_reset


def _run_compiled(
    flight: FixedStepFlight, params: ThermalParams, settings: EstimatorSettings, estimator: ThermalEKF, compiled: bool
) -> EstimateTrace:
    coeffs = scalar_coefficients(coefficients(params))
    drive = compute_drive_compiled(flight.inputs, coeffs)
    n = flight.time_s.size
    arrays = [np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=np.float64), (n,))) for v in drive]
    out_x, out_P, out_delta, out_innovation, out_nis = (np.empty(n) for _ in range(5))
    out_reset = np.zeros(n, dtype=np.bool_)
    loop: Callable[..., None] = trace_loop if compiled else python_reference(trace_loop)
    s = settings
    loop(
        *arrays,
        flight.z_c,
        flight.measured,
        np.ones(n, dtype=np.int64),
        coeffs,
        s.initial_var,
        s.dt_s,
        s.process_var,
        s.measurement_var,
        s.sigmoid_a,
        s.sigmoid_b,
        s.quantum_c,
        s.deviation_time_s,
        estimator.use_deviation,
        _RESET_CODES[estimator.reset_mode],
        out_x,
        out_P,
        out_delta,
        out_innovation,
        out_nis,
        out_reset,
    )
    return EstimateTrace(
        estimator.name,
        flight.time_s,
        _held(flight.z_c),
        out_x,
        out_delta / s.dt_s,
        out_P,
        out_innovation,
        out_nis,
        out_reset,
        flight.measured.copy(),
    )


def _held(z: NDArray[np.float64]) -> NDArray[np.float64]:
    """Last finite value carried forward (z[0] is finite)."""
    index = np.where(np.isfinite(z), np.arange(z.size), 0)
    np.maximum.accumulate(index, out=index)
    return z[index]


def _run_stepwise(flight: FixedStepFlight, estimator: Any, name: str) -> EstimateTrace:
    n = flight.time_s.size
    out = {key: np.full(n, np.nan) for key in ("x", "P", "dev", "inn", "nis")}
    reset = np.zeros(n, dtype=np.bool_)
    columns = [np.broadcast_to(np.asarray(v, dtype=float), (n,)) for v in flight.inputs]  # a float: every step

    def inputs_at(k: int) -> InputSeries:
        return InputSeries(*(float(col[k]) for col in columns))

    estimator.initialise(float(flight.time_s[0]), inputs_at(0), float(flight.z_c[0]))
    out["x"][0] = flight.z_c[0]
    out["dev"][0] = 0.0
    for k in range(1, n):
        z = float(flight.z_c[k]) if flight.measured[k] else None
        est = estimator.estimate(float(flight.time_s[k]), inputs_at(k), z)
        out["x"][k], out["P"][k], out["dev"][k] = est.cht_c, est.variance_c2, est.deviation
        out["inn"][k], out["nis"][k], reset[k] = est.innovation_c, est.nis, est.reset
    return EstimateTrace(
        name,
        flight.time_s,
        _held(flight.z_c),
        out["x"],
        out["dev"],
        out["P"],
        out["inn"],
        out["nis"],
        reset,
        flight.measured.copy(),
    )


def run_estimator(
    log: FlightLog,
    params: ThermalParams,
    name: str,
    settings: EstimatorSettings | None = None,
    *,
    compiled: bool = True,
) -> EstimateTrace:
    """Run estimator ``name`` over a flight log on the fixed step (numba fast path for the built-ins).

    ``compiled=False`` runs the same loop in plain Python (slow; the reference in tests). Estimators
    registered by other layers run through their ``estimate()`` step by step.
    """
    settings = settings if settings is not None else EstimatorSettings()
    estimator = make_estimator(name, params, settings)
    flight = fixed_step_flight(log, params, settings.dt_s)
    if isinstance(estimator, ThermalEKF):
        return _run_compiled(flight, params, settings, estimator, compiled)
    return _run_stepwise(flight, estimator, name)


def run_estimator_on_steps(
    time_s: NDArray[np.float64],
    inputs: InputSeries,
    z_c: NDArray[np.float64],
    params: ThermalParams,
    name: str,
    settings: EstimatorSettings | None = None,
) -> EstimateTrace:
    """:func:`run_estimator` on a flight already on the fixed step: ``time_s`` every ``settings.dt_s``,
    ``inputs`` held per step, ``z_c`` the reading of each step (nan: none; z_c[0] finite). Nothing is
    resampled (the replay's batch path: its steps are the live pipeline's)."""
    settings = settings if settings is not None else EstimatorSettings()
    estimator = make_estimator(name, params, settings)
    z = np.asarray(z_c, dtype=np.float64)
    if not math.isfinite(float(z[0])):
        raise FlightLogError("run_estimator_on_steps: no reading at the first step")
    columns = InputSeries(*(np.ascontiguousarray(v, dtype=np.float64) for v in inputs))
    flight = FixedStepFlight(np.asarray(time_s, dtype=np.float64), columns, z, np.isfinite(z), np.arange(z.size))
    if isinstance(estimator, ThermalEKF):
        return _run_compiled(flight, params, settings, estimator, True)
    return _run_stepwise(flight, estimator, name)


class CallTrace(NamedTuple):
    """The estimate and the model deviation at each filter call (:func:`run_estimator_on_calls`):
    cht_est_c degC, deviation Delta/dt degC/s."""

    cht_est_c: NDArray[np.float64]
    deviation: NDArray[np.float64]


def run_estimator_on_calls(
    time_s: NDArray[np.float64],
    calls: NDArray[np.int64],
    inputs: InputSeries,
    z_c: NDArray[np.float64],
    params: ThermalParams,
    name: str,
    settings: EstimatorSettings | None = None,
) -> CallTrace:
    """:func:`run_estimator_on_steps` with the inputs held between filter calls, recorded at the calls
    only (the replay's batch path). ``time_s``: every step (every ``settings.dt_s``); ``calls``: the
    steps the filter is called on (increasing, calls[0] == 0); ``inputs`` and ``z_c`` per call (the
    inputs used by the steps up to the next call; the reading applied at the call, nan: none; z_c[0]
    finite). Equal to :func:`run_estimator_on_steps` over the steps with those inputs held, taken at
    the calls; the built-in filters compute the model's drive per call instead of per step."""
    settings = settings if settings is not None else EstimatorSettings()
    estimator = make_estimator(name, params, settings)
    z = np.ascontiguousarray(z_c, dtype=np.float64)
    if not math.isfinite(float(z[0])):
        raise FlightLogError("run_estimator_on_calls: no reading at the first call")
    at = np.asarray(calls, dtype=np.int64)
    if not isinstance(estimator, ThermalEKF):  # step by step through estimate(), the inputs held per step
        held = np.repeat(np.arange(at.size), np.diff(at, append=len(time_s)))
        per_step = np.full(len(time_s), np.nan)
        per_step[at] = z
        series = InputSeries(*(np.broadcast_to(np.asarray(v, dtype=np.float64), (at.size,))[held] for v in inputs))
        trace = run_estimator_on_steps(time_s, series, per_step, params, name, settings)
        return CallTrace(trace.cht_est_c[at], trace.deviation[at])
    coeffs = scalar_coefficients(coefficients(params))
    drive = compute_drive_compiled(InputSeries(*(np.ascontiguousarray(v, dtype=np.float64) for v in inputs)), coeffs)
    n = z.size
    arrays = [np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=np.float64), (n,))) for v in drive]
    out_x, out_P, out_delta, out_innovation, out_nis = (np.empty(n) for _ in range(5))
    s = settings
    trace_loop(
        *arrays, z, np.isfinite(z), np.diff(at, prepend=0), coeffs, s.initial_var, s.dt_s, s.process_var,
        s.measurement_var, s.sigmoid_a, s.sigmoid_b, s.quantum_c, s.deviation_time_s, estimator.use_deviation,
        _RESET_CODES[estimator.reset_mode], out_x, out_P, out_delta, out_innovation, out_nis,
        np.zeros(n, dtype=np.bool_),
    )  # fmt: skip
    return CallTrace(out_x, out_delta / s.dt_s)
