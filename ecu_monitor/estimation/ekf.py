"""EKF, CBEKF and CBEKF-AU on the 0D CHT model: a pure core and thin stateful shells.

State: x = CHT (degC), scalar. The Pade state w of the heat-path delay depends only on the inputs, so
it is propagated alongside, deterministically, as in the paper. Every step of dt_s seconds:

predict (paper Eq. 25)::

    x(k+1|k) = f(x(k|k), u_k) + Delta_k          f = one RK4 step of the model (ecu_monitor.model.rk4_step)
    P(k+1|k) = F_k^2 P(k|k) + Q                   F_k = d f / d x, by complex step (exact to rounding)

update (Eq. 26-28), scalar, with the sigmoid staircase sensor h of :mod:`.quantiser`::

    H = h'(x(k+1|k)),  S = H^2 P + R,  K = P H / S,  x += K (z - h(x)),  P = (1 - K H)^2 P + K^2 R

(Joseph form: equal to (1 - K H) P for this K, but it stays positive under rounding, as filterpy's.)

Model deviation Delta_k (our reading of Eq. 25, docs/estimators.md): the deviation of the measured
CHT trajectory from the nominal model run from the measured state, low-pass filtered::

    d_k     = z_k - f(z_(k-1), u_(k-1))                            (one-step deviation, degC/step)
    Delta_k = Delta_(k-1) + (dt / tau_Delta) (d_k - Delta_(k-1))   (first-order filter, tau_Delta s)

With z quantised, one d_k is useless (zero, or +-1 degC when the reading changes level), but the sum
of d over a window telescopes to (z_end - z_start) minus the model's own increments, so the filtered
value converges to the change of the state derivative that the degradation causes (per step;
``deviation`` = Delta_k / dt in degC/s). Steps without a measurement carry the reference f(...) on
and the next reading spreads its deviation evenly over the steps since the last one.

The conventional EKF uses Delta_k = 0. CBEKF-AU re-initialises x (and P = R) whenever the reading
changes level: to the new interval's midpoint (the paper) or to the boundary just crossed (ours).

The functions :func:`predict`, :func:`update`, :func:`deviation_update`, :func:`filter_step` and
:func:`filter_steps` are pure and use only scalar arithmetic: numba compiles them into their compiled
callers (``register_jitable``; :mod:`ecu_monitor.model.kernels`): the live filter's :func:`live_steps`
(:class:`ThermalEKF`, ``compiled=True``, the default), the whole-flight runner (:mod:`.runner`) and the
step; ``compiled=False`` runs the same functions as plain Python (the reference in the tests).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numba.extending import register_jitable

from ecu_monitor.errors import ConfigError, EstimationError
from ecu_monitor.estimation.quantiser import level_of, reset_value, sensor_model, sensor_slope
from ecu_monitor.model import (
    Coefficients,
    Drive,
    InputSeries,
    ThermalParams,
    coefficients,
    compute_drive,
    initial_pade_state,
    pack_coefficients,
    rk4_step,
    unpack_coefficients,
)
from ecu_monitor.model.kernels import njit
from ecu_monitor.model.thermal import drive_into

__all__ = [
    "COMPLEX_STEP",
    "RESET_MODES",
    "Correction",
    "Estimate",
    "EstimatorSettings",
    "FilterState",
    "Prediction",
    "ThermalEKF",
    "deviation_update",
    "filter_step",
    "live_steps",
    "predict",
    "scalar_drive",
    "update",
]

#: Imaginary step of the complex-step derivative F = Im f(x + i h) / h (exact to rounding for any h
#: this small: no subtraction, so no cancellation).
COMPLEX_STEP = 1e-30
#: CBEKF-AU re-initialisation modes (EstimatorSettings.reset).
RESET_MODES = ("midpoint", "boundary", "none")

_RESET_CODES = {"none": 0, "midpoint": 1, "boundary": 2}


@dataclass(frozen=True)
class EstimatorSettings:
    """Tuning of the estimators (all variants share it; validated on construction).

    dt_s: fixed filter step, s (the paper's 0.02 s).
    process_var: Q, variance added to the CHT per step, degC^2 (model error of one step).
    measurement_var: R, degC^2: quantisation c^2/12 plus the probe's noise before rounding.
    initial_var: P at initialise(), degC^2.
    sigmoid_a, sigmoid_b: steepness and switching point of the sigmoid sensor model (Eq. 27).
    quantum_c: quantisation step of the CHT reading, degC.
    reset: CBEKF-AU re-initialisation on a level change: "midpoint" (paper), "boundary" (ours) or
        "none" (then CBEKF-AU behaves as CBEKF). EKF and CBEKF ignore it.
    deviation_time_s: time constant tau_Delta of the low-pass filter on the model deviation, s.
    """

    dt_s: float = 0.02
    process_var: float = 1e-4
    measurement_var: float = 1.0 / 12.0 + 0.3**2
    initial_var: float = 1.0
    sigmoid_a: float = 100.0
    sigmoid_b: float = 0.5
    quantum_c: float = 1.0
    reset: str = "boundary"
    deviation_time_s: float = 20.0

    def __post_init__(self) -> None:
        positive = ("dt_s", "process_var", "measurement_var", "initial_var", "sigmoid_a", "quantum_c")
        for name in (*positive, "sigmoid_b", "deviation_time_s"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ConfigError(f"estimator.{name}: expected a finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        for name in positive:
            if getattr(self, name) <= 0.0:
                raise ConfigError(f"estimator.{name}: expected a positive number, got {getattr(self, name)!r}")
        if not 0.0 < self.sigmoid_b < 1.0:
            raise ConfigError(f"estimator.sigmoid_b: expected a value in (0, 1), got {self.sigmoid_b!r}")
        if self.deviation_time_s < self.dt_s:
            raise ConfigError(f"estimator.deviation_time_s: expected at least dt_s ({self.dt_s} s)")
        if self.reset not in RESET_MODES:
            raise ConfigError(f"estimator.reset: expected one of {', '.join(RESET_MODES)}, got {self.reset!r}")


@dataclass(frozen=True)
class Estimate:
    """Output of one filter step.

    time_s: time of the step, s. cht_c: corrected CHT estimate x(k|k), degC. variance_c2: P(k|k),
    degC^2. innovation_c: z - h(x(k|k-1)), degC (nan without a measurement). nis: normalised
    innovation squared innovation^2 / S (nan without a measurement). deviation: model-deviation
    symptom Delta_k / dt, degC/s. deviation_raw_c: Delta_k, degC per step. reset: the estimate was
    re-initialised at this step (CBEKF-AU). measured: a reading was used at this step.
    """

    time_s: float
    cht_c: float
    variance_c2: float
    innovation_c: float
    nis: float
    deviation: float
    deviation_raw_c: float
    reset: bool
    measured: bool


class Prediction(NamedTuple):
    """Result of :func:`predict`."""

    x: float  # prior CHT x(k+1|k), degC
    P: float  # prior variance, degC^2
    F: float  # d x(k+1) / d x(k) of the RK4 step, dimensionless
    pade_w: float  # Pade state after the step, W


class Correction(NamedTuple):
    """Result of :func:`update`."""

    x: float  # posterior CHT, degC
    P: float  # posterior variance, degC^2
    innovation: float  # z - h(x prior), degC
    S: float  # innovation variance H^2 P + R, degC^2
    K: float  # Kalman gain
    H: float  # dh/dx at the prior


class FilterState(NamedTuple):
    """Everything a filter carries from one step to the next (floats only)."""

    x: float  # CHT estimate, degC
    P: float  # its variance, degC^2
    pade_w: float  # Pade state, W
    delta: float  # model deviation Delta, degC per step
    reference: float  # nominal model run on from the last reading, degC
    steps_since: float  # steps since the last reading
    level: float  # quantisation level of the last reading


def scalar_drive(inputs: InputSeries, coeffs: Coefficients) -> Drive:
    """The model's drive for one step, as plain floats (the fast form for the scalar filter)."""
    d = compute_drive(inputs, coeffs)
    return Drive(float(d[0]), float(d[1]), float(d[2]), float(d[3]), float(d[4]))


@register_jitable
def predict(
    x: float,
    P: float,
    drive: Drive,
    coeffs: Coefficients,
    dt: float,
    Q: float,
    delta: float,
    pade_w: float,
    gamma_q: float = 1.0,
    gamma_d: float = 1.0,
) -> Prediction:
    """Prediction step (Eq. 25): one RK4 step of the model from x plus delta; F by complex step."""
    step: Any = rk4_step
    x_next, w_next = step(complex(x, COMPLEX_STEP), pade_w, drive, coeffs, dt, gamma_q, gamma_d)
    F = x_next.imag / COMPLEX_STEP
    return Prediction(x_next.real + delta, F * F * P + Q, F, float(w_next))


@register_jitable
def update(x: float, P: float, z: float, R: float, a: float, b: float, c: float = 1.0) -> Correction:
    """Scalar EKF correction (Eq. 26) with the sigmoid sensor model; Joseph-form variance."""
    H = sensor_slope(x, a, b, c)
    innovation = z - sensor_model(x, a, b, c)
    S = H * H * P + R
    K = P * H / S
    one_minus = 1.0 - K * H
    return Correction(x + K * innovation, one_minus * one_minus * P + K * K * R, innovation, S, K, H)


@register_jitable
def deviation_update(
    delta: float, reference_prior: float, z: float, steps_since: float, dt: float, tau: float
) -> float:
    """New model deviation Delta after a reading z (degC per step).

    reference_prior is the nominal model run from the previous reading up to now, steps_since the
    number of steps it covers; the deviation z - reference_prior is spread evenly over those steps,
    each passed through the first-order filter of time constant tau (s).
    """
    sample = (z - reference_prior) / steps_since
    keep = (1.0 - dt / tau) ** steps_since
    return sample + keep * (delta - sample)


@register_jitable
def filter_step(
    state: FilterState,
    drive: Drive,
    z: float,
    measured: bool,
    coeffs: Coefficients,
    dt: float,
    Q: float,
    R: float,
    a: float,
    b: float,
    c: float,
    tau: float,
    use_deviation: bool,
    reset_code: int,
) -> tuple[FilterState, float, float, bool]:
    """One fixed step of EKF / CBEKF / CBEKF-AU: predict with the previous drive, then correct.

    reset_code: 0 none, 1 midpoint, 2 boundary. Returns (new state, innovation, nis, reset); the
    innovation and nis are nan when not measured.
    """
    applied = state.delta if use_deviation else 0.0
    prior = predict(state.x, state.P, drive, coeffs, dt, Q, applied, state.pade_w)
    delta = state.delta
    reference = state.reference
    steps_since = state.steps_since + 1.0
    level = state.level
    if use_deviation:
        reference_step: Any = rk4_step
        reference = float(reference_step(state.reference, state.pade_w, drive, coeffs, dt)[0])
    if not measured:
        new_state = FilterState(prior.x, prior.P, prior.pade_w, delta, reference, steps_since, level)
        return new_state, math.nan, math.nan, False
    if use_deviation:
        delta = deviation_update(delta, reference, z, steps_since, dt, tau)
    new_level = level_of(z, c)
    corrected = update(prior.x, prior.P, z, R, a, b, c)
    nis = corrected.innovation * corrected.innovation / corrected.S
    x = corrected.x
    P = corrected.P
    did_reset = reset_code != 0 and new_level != level
    if did_reset:
        x = reset_value(new_level, level, c, reset_code == 2)
        P = R
    new_state = FilterState(x, P, prior.pade_w, delta, z, 0.0, new_level)
    return new_state, corrected.innovation, nis, did_reset


@register_jitable
def filter_steps(
    state: FilterState,
    drive: Drive,
    z: float,
    measured: bool,
    coeffs: Coefficients,
    dt: float,
    Q: float,
    R: float,
    a: float,
    b: float,
    c: float,
    tau: float,
    use_deviation: bool,
    reset_code: int,
    steps: int,
) -> tuple[FilterState, float, float, bool]:
    """``steps`` fixed steps of :func:`filter_step` with the drive held, the reading on the last one."""
    innovation = math.nan
    nis = math.nan
    did_reset = False
    for k in range(steps):
        state, innovation, nis, did_reset = filter_step(
            state, drive, z, measured and k == steps - 1, coeffs, dt, Q, R, a, b, c, tau, use_deviation, reset_code
        )
    return state, innovation, nis, did_reset


@njit(nogil=False)
def live_steps(
    state: Any,
    drive: Any,
    next_drive: Any,
    out: Any,
    z: float,
    measured: bool,
    coeff_scalars: Any,
    heat_values_w: Any,
    x_breakpoints: Any,
    y_breakpoints: Any,
    dt: float,
    Q: float,
    R: float,
    a: float,
    b: float,
    c: float,
    tau: float,
    use_deviation: bool,
    reset_code: int,
    steps: int,
) -> None:
    """One live filter call in one compiled call: :func:`filter_steps` on the state held in ``state``
    (the FilterState fields, float64[7], updated in place) with the drive held in ``drive`` (the Drive
    fields, float64[5]); then ``next_drive`` (the drive of this call's inputs, the model's ``drive_at``,
    computed once by the caller for every filter it steps) replaces it for the next call. ``out`` gets
    (innovation, nis, reset as 0/1). The model's coefficients come packed
    (``ecu_monitor.model.pack_coefficients``: four arrays, cheap for numba's dispatcher to type)."""
    coeffs = unpack_coefficients(coeff_scalars, heat_values_w, x_breakpoints, y_breakpoints)
    held = FilterState(state[0], state[1], state[2], state[3], state[4], state[5], state[6])
    new, innovation, nis, did_reset = filter_steps(
        held, Drive(drive[0], drive[1], drive[2], drive[3], drive[4]), z, measured, coeffs, dt, Q, R, a, b, c, tau,
        use_deviation, reset_code, steps,
    )  # fmt: skip
    state[0] = new.x
    state[1] = new.P
    state[2] = new.pade_w
    state[3] = new.delta
    state[4] = new.reference
    state[5] = new.steps_since
    state[6] = new.level
    drive[:] = next_drive
    out[0] = innovation
    out[1] = nis
    out[2] = 1.0 if did_reset else 0.0


class ThermalEKF:
    """Stateful shell over :func:`filter_step`: EKF, CBEKF or CBEKF-AU on a given model.

    The model (``params``) is read once, never changed. Call :meth:`initialise` once, then
    :meth:`estimate` every ``settings.dt_s`` (a longer interval is covered by whole prediction
    steps, the reading applied on the last one). Inputs are held from one call to the next (zero-order
    hold, as in :func:`ecu_monitor.model.simulate`): the step ending at t uses the inputs given at the
    previous call.
    """

    def __init__(
        self,
        params: ThermalParams,
        settings: EstimatorSettings,
        *,
        name: str,
        use_deviation: bool,
        reset: str = "none",
        compiled: bool = True,
    ) -> None:
        if reset not in RESET_MODES:
            raise ConfigError(f"estimator reset: expected one of {', '.join(RESET_MODES)}, got {reset!r}")
        self.name = name
        self.params = params
        self.settings = settings
        self.use_deviation = use_deviation
        self.reset_mode = reset
        self._coeffs = coefficients(params)
        self.compiled = compiled
        self._packed_coeffs = pack_coefficients(self._coeffs)
        self._state: FilterState | None = None
        self._drive: Drive | None = None
        self._time_s = 0.0
        # compiled live path: state and drive held in preallocated arrays between calls (no allocation)
        self._state_vec = np.zeros(len(FilterState._fields))
        self._drive_vec = np.zeros(len(Drive._fields))
        self._next_drive = np.zeros(len(Drive._fields))
        self._inputs = np.zeros(len(InputSeries._fields))
        self._out = np.zeros(3)

    @property
    def state(self) -> FilterState:
        """The filter's current state (raises EstimationError before initialise())."""
        if self._state is None:
            raise EstimationError(f"{self.name}: estimate() called before initialise()")
        if self.compiled:
            return FilterState(*self._state_vec.tolist())
        return self._state

    @property
    def held_drive(self) -> Drive | None:
        """The model's drive at the inputs of the latest initialise() or estimate() (held for the next
        call; floats, equal bit for bit to ``compute_drive`` of those inputs); None before initialise()."""
        if self._drive is None:
            return None
        if self.compiled:
            return Drive(*self._drive_vec.tolist())
        return self._drive

    def initialise(self, t_s: float, u: InputSeries, z_cht_c: float) -> None:
        """Start at time t_s from a first reading: x = z, P = initial_var, Pade state in steady state."""
        if not math.isfinite(z_cht_c):
            raise EstimationError(f"{self.name}: initial CHT reading must be finite, got {z_cht_c!r}")
        drive = scalar_drive(u, self._coeffs)
        c = self.settings.quantum_c
        self._drive = drive
        self._time_s = float(t_s)
        self._state = FilterState(
            float(z_cht_c),
            self.settings.initial_var,
            float(initial_pade_state(drive)),
            0.0,
            float(z_cht_c),
            0.0,
            float(level_of(z_cht_c, c)),
        )
        self._state_vec[:] = self._state
        self._drive_vec[:] = drive

    def estimate(self, t_s: float, u: InputSeries, z_cht_c: float | None) -> Estimate:
        """Advance to t_s (one fixed step, or several if t_s is later) and correct with z (None: no reading)."""
        if self._state is None:
            raise EstimationError(f"{self.name}: estimate() called before initialise()")
        s = self.settings
        steps = round((t_s - self._time_s) / s.dt_s)
        if steps < 1:
            raise EstimationError(
                f"{self.name}: time must advance by at least one step of {s.dt_s} s (from {self._time_s} to {t_s})"
            )
        measured = z_cht_c is not None and math.isfinite(z_cht_c)
        z = float(z_cht_c) if measured and z_cht_c is not None else math.nan
        if self.compiled:
            return self._estimate_compiled(float(t_s), u, z, measured, steps)
        drive = self._drive
        if drive is None:  # set together with the state
            raise EstimationError(f"{self.name}: estimate() called before initialise()")
        state, innovation, nis, did_reset = filter_steps(
            self._state,
            drive,
            z,
            measured,
            self._coeffs,
            s.dt_s,
            s.process_var,
            s.measurement_var,
            s.sigmoid_a,
            s.sigmoid_b,
            s.quantum_c,
            s.deviation_time_s,
            self.use_deviation,
            _RESET_CODES[self.reset_mode],
            steps,
        )
        self._state = state
        self._drive = scalar_drive(u, self._coeffs)
        self._time_s = float(t_s)
        return Estimate(
            time_s=float(t_s),
            cht_c=state.x,
            variance_c2=state.P,
            innovation_c=innovation,
            nis=nis,
            deviation=state.delta / s.dt_s if self.use_deviation else 0.0,
            deviation_raw_c=state.delta if self.use_deviation else 0.0,
            reset=did_reset,
            measured=measured,
        )

    def _estimate_compiled(self, t_s: float, u: InputSeries, z: float, measured: bool, steps: int) -> Estimate:
        """:meth:`estimate` as one compiled call (:func:`live_steps`): no Python model code, no allocation
        besides the returned Estimate."""
        s = self.settings
        state = self._state_vec
        out = self._out
        self._inputs[:] = u
        drive_into(self._next_drive, self._inputs, *self._packed_coeffs)
        live_steps(
            state, self._drive_vec, self._next_drive, out, z, measured, *self._packed_coeffs, s.dt_s, s.process_var,
            s.measurement_var, s.sigmoid_a, s.sigmoid_b, s.quantum_c, s.deviation_time_s, self.use_deviation,
            _RESET_CODES[self.reset_mode], steps,
        )  # fmt: skip
        self._time_s = t_s
        delta = float(state[3])
        return Estimate(
            time_s=t_s,
            cht_c=float(state[0]),
            variance_c2=float(state[1]),
            innovation_c=float(out[0]),
            nis=float(out[1]),
            deviation=delta / s.dt_s if self.use_deviation else 0.0,
            deviation_raw_c=delta if self.use_deviation else 0.0,
            reset=bool(out[2]),
            measured=measured,
        )
