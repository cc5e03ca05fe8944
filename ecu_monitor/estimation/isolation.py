"""Isolation of the degradation: an augmented-state EKF that estimates gamma_Q and gamma_D online.

The paper leaves isolation as future work. Here the CBEKF's single state grows to three::

    x = [T, gamma_Q, gamma_D]        T = CHT (degC); the gammas are random walks (dimensionless)
    C_w dT/dt = gamma_Q * H * (w - Q_SL0)  -  D(T) / gamma_D        (the model of ecu_monitor.model)
    D(T) = G (T - T_e) + (T^4 - T_e^4) / (alpha R_e)                   (heat dissipated, W)

with H = heat gain x altitude gain and w the Pade state, propagated alongside from the inputs only.
Every dt_s (0.02 s): RK4 prediction of T with the gammas held, a first-order (I + A dt) transition
Jacobian with A = d f / d x::

    dT'/dT  = -D'(T) / (gamma_D C_w)      dT'/dgamma_Q = H (w - Q_SL0) / C_w      dT'/dgamma_D = D(T) / (gamma_D^2 C_w)

P <- F P F^T + diag(q_T, q_Q, q_D) dt, and on each reading a linear update with h(x) = T, R = the
quantisation variance c^2/12 plus the probe's noise, inflated because the quantisation error is
correlated in time (``measurement_var``). The sigmoid staircase of the scalar filters is *not* used:
its slope is zero except at the level edges, which starves the gammas of information; the sensor's
dither noise makes the rounded reading unbiased on average, which the linear update exploits.
Gammas are clipped to [gamma_min, gamma_max] after each update; gamma_min = 1 by default, the
paper's definition (a degradation only adds heat or removes dissipation). This projection matters on
real data: the residual model error otherwise drives the split apart (gamma_Q < 1 with gamma_D > 1 at
an unchanged product); measured on eight degraded flights, it halves that drift before onset and cuts
the 90th percentile of the isolation error from 0.16 to 0.10 (docs/detection_isolation.md).

Observability (docs/detection_isolation.md): in a steady state only the product gamma_Q gamma_D is
seen (D(T) = gamma_Q gamma_D H Q). gamma_D also stretches the thermal time constant (C_w gamma_D /
D'(T)); the two separate only through transients: climbs, throttle and altitude changes.

The estimator is ``cbekf-iso`` in the registry's table (:mod:`.registry`). Its :class:`Estimate`
``deviation`` is the model deviation the gamma estimates explain, f(T, gamma_Q, gamma_D) - f(T, 1, 1)
in degC/s: the same symptom (change of the state derivative caused by the degradation) as the CBEKF's Delta_k / dt.

:func:`run_isolation` runs a whole flight through the same step function. The step calls the model's
own ``derivatives`` and ``rk4`` (:mod:`ecu_monitor.model.equations`); the Jacobian entries are their
complex-step derivatives (exact to rounding, no hand-derived formula). Both the live filter and the
flight runner run the step compiled with numba (compiled on first use, cached on disk).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numba.extending import register_jitable
from numpy.typing import NDArray

from ecu_monitor.errors import ConfigError, EstimationError
from ecu_monitor.estimation.ekf import Estimate, scalar_drive
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.model import (
    Coefficients,
    Drive,
    InputSeries,
    ThermalParams,
    coefficients,
    pack_coefficients,
    scalar_coefficients,
)
from ecu_monitor.model.compiled import compute_drive_compiled
from ecu_monitor.model.equations import derivatives, rk4
from ecu_monitor.model.inputs import flight_inputs
from ecu_monitor.model.kernels import njit
from ecu_monitor.model.thermal import drive_into

__all__ = [
    "ESTIMATOR_NAME",
    "IsolationFilter",
    "IsolationSettings",
    "IsolationTrace",
    "flight_drive",
    "make_isolation_filter",
    "run_isolation",
]

#: Name of the isolation filter in the estimator registry.
ESTIMATOR_NAME = "cbekf-iso"

# Layout of the filter's state vector (one float64 array, so numba and Python share the step).
_T, _GQ, _GD, _W = 0, 1, 2, 3
_P = 4  # 3 x 3 covariance, row-major, indices 4..12
_STATE_SIZE = 13
# Layout of the settings vector handed to the compiled step.
_S_DT, _S_QT, _S_QQ, _S_QD, _S_R, _S_GMIN, _S_GMAX = range(7)


@dataclass(frozen=True)
class IsolationSettings:
    """Tuning of the isolation filter (validated on construction).

    dt_s: filter step, s. cht_process_var: q_T, spectral density of the CHT process noise, degC^2/s
    (the model error the filter tolerates). gamma_q_process_var, gamma_d_process_var: q_Q, q_D,
    spectral densities of the gammas' random walks, 1/s (how fast they may move). measurement_var:
    R of one reading, degC^2. initial_cht_var: P_TT at start, degC^2. initial_gamma_var: P of each
    gamma at start. gamma_min, gamma_max: bounds the gamma estimates are clipped to.
    """

    dt_s: float = 0.02
    cht_process_var: float = 2e-3
    gamma_q_process_var: float = 2e-6
    gamma_d_process_var: float = 2e-6
    measurement_var: float = 2.0
    initial_cht_var: float = 1.0
    initial_gamma_var: float = 1e-4
    gamma_min: float = 1.0
    gamma_max: float = 3.0

    def __post_init__(self) -> None:
        names = (
            "dt_s",
            "cht_process_var",
            "gamma_q_process_var",
            "gamma_d_process_var",
            "measurement_var",
            "initial_cht_var",
            "initial_gamma_var",
            "gamma_min",
            "gamma_max",
        )
        for name in names:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
                raise ConfigError(f"isolation.{name}: expected a positive number, got {value!r}")
            object.__setattr__(self, name, float(value))
        if not self.gamma_min <= 1.0 < self.gamma_max:
            raise ConfigError("isolation.gamma_min/gamma_max: expected gamma_min <= 1 < gamma_max")

    def vector(self) -> NDArray[np.float64]:
        """The settings in the order the compiled step reads them."""
        return np.array(
            [
                self.dt_s,
                self.cht_process_var,
                self.gamma_q_process_var,
                self.gamma_d_process_var,
                self.measurement_var,
                self.gamma_min,
                self.gamma_max,
            ]
        )


# --------------------------------------------------------------------------------------------------
# The core: one step on a state vector (shared by the live filter and the flight runner), compiled
# with the model's own equations (ecu_monitor.model.equations: derivatives, rk4)
# --------------------------------------------------------------------------------------------------

#: Imaginary step of the complex-step derivatives of the Jacobian (exact to rounding).
_COMPLEX_STEP = 1e-30


@register_jitable
def _predict(s: NDArray[np.float64], q0: float, hg: float, g: float, te: float, model: NDArray[np.float64],
             cfg: NDArray[np.float64]) -> None:  # fmt: skip
    """One prediction step of dt (RK4 on T and w, gammas held) and the covariance propagation.

    model: (C_w, tau_w, 1/(alpha R_e), radiation offset). The Jacobian A = d(dT/dt)/d(T, gamma_Q,
    gamma_D) at the start of the step is the complex-step derivative of the model's own derivatives.
    """
    dt = cfg[_S_DT]
    t = s[_T]
    gq = s[_GQ]
    gd = s[_GD]
    w = s[_W]
    c_w, tau, rad, off = model[0], model[1], model[2], model[3]
    h = _COMPLEX_STEP
    a_tt = derivatives(complex(t, h), w, q0, hg, te, g, c_w, tau, rad, off, gq, gd)[0].imag / h
    a_tq = derivatives(t, w, q0, hg, te, g, c_w, tau, rad, off, complex(gq, h), gd)[0].imag / h
    a_td = derivatives(t, w, q0, hg, te, g, c_w, tau, rad, off, gq, complex(gd, h))[0].imag / h
    s[_T], s[_W] = rk4(t, w, q0, hg, te, g, c_w, tau, rad, off, gq, gd, dt)
    # P <- F P F^T + Qc dt with F = [[1 + a_tt dt, a_tq dt, a_td dt], [0, 1, 0], [0, 0, 1]]
    f0 = 1.0 + a_tt * dt
    f1 = a_tq * dt
    f2 = a_td * dt
    p00, p01, p02 = s[_P], s[_P + 1], s[_P + 2]
    p11, p12, p22 = s[_P + 4], s[_P + 5], s[_P + 8]
    r0 = f0 * p00 + f1 * p01 + f2 * p02  # row 0 of F P
    r1 = f0 * p01 + f1 * p11 + f2 * p12
    r2 = f0 * p02 + f1 * p12 + f2 * p22
    n00 = r0 * f0 + r1 * f1 + r2 * f2 + cfg[_S_QT] * dt
    s[_P] = n00
    s[_P + 1] = r1
    s[_P + 2] = r2
    s[_P + 3] = r1
    s[_P + 6] = r2
    s[_P + 4] = p11 + cfg[_S_QQ] * dt
    s[_P + 8] = p22 + cfg[_S_QD] * dt


@register_jitable
def _correct(s: NDArray[np.float64], z: float, cfg: NDArray[np.float64]) -> tuple[float, float]:
    """Linear update with h(x) = T (Joseph form); returns (innovation degC, NIS)."""
    r = cfg[_S_R]
    innovation = z - s[_T]
    p = s[_P : _P + 9].copy()
    s_var = p[0] + r
    k0 = p[0] / s_var
    k1 = p[3] / s_var
    k2 = p[6] / s_var
    s[_T] += k0 * innovation
    s[_GQ] += k1 * innovation
    s[_GD] += k2 * innovation
    # Joseph form: (I - K H) P (I - K H)^T + K R K^T, H = [1, 0, 0]
    k = (k0, k1, k2)
    for i in range(3):
        for j in range(3):
            value = p[3 * i + j] - k[i] * p[j] - k[j] * p[3 * i] + k[i] * k[j] * p[0] + k[i] * k[j] * r
            s[_P + 3 * i + j] = value
    lo = cfg[_S_GMIN]
    hi = cfg[_S_GMAX]
    s[_GQ] = min(max(s[_GQ], lo), hi)
    s[_GD] = min(max(s[_GD], lo), hi)
    return innovation, innovation * innovation / s_var


@register_jitable
def _deviation(s: NDArray[np.float64], q0: float, hg: float, g: float, te: float,
               model: NDArray[np.float64]) -> float:  # fmt: skip
    """f(T, gamma_Q, gamma_D) - f(T, 1, 1): the state-derivative change the gammas explain, degC/s."""
    t = s[_T]
    w = s[_W]
    c_w, tau, rad, off = model[0], model[1], model[2], model[3]
    with_gammas = derivatives(t, w, q0, hg, te, g, c_w, tau, rad, off, s[_GQ], s[_GD])[0]
    return with_gammas - derivatives(t, w, q0, hg, te, g, c_w, tau, rad, off, 1.0, 1.0)[0]


@njit()
def _run(
    q0: NDArray[np.float64],
    hg: NDArray[np.float64],
    g: NDArray[np.float64],
    te: NDArray[np.float64],
    z: NDArray[np.float64],
    substeps: NDArray[np.int64],
    model: NDArray[np.float64],
    cfg: NDArray[np.float64],
    s: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """Whole flight: for sample k >= 1, substeps[k] predictions with sample k-1's drive, then the
    update with z[k] (skipped when nan). out[k] = T, gamma_Q, gamma_D, P_TT, P_QQ, P_DD, P_QD,
    innovation, NIS, deviation."""
    n = q0.shape[0]
    out[0, 0] = s[_T]
    out[0, 1] = s[_GQ]
    out[0, 2] = s[_GD]
    out[0, 3] = s[_P]
    out[0, 4] = s[_P + 4]
    out[0, 5] = s[_P + 8]
    out[0, 6] = s[_P + 5]
    out[0, 7] = np.nan
    out[0, 8] = np.nan
    out[0, 9] = _deviation(s, q0[0], hg[0], g[0], te[0], model)
    for k in range(1, n):
        for _ in range(substeps[k]):
            _predict(s, q0[k - 1], hg[k - 1], g[k - 1], te[k - 1], model, cfg)
        innovation = np.nan
        nis = np.nan
        if not np.isnan(z[k]):
            innovation, nis = _correct(s, z[k], cfg)
        out[k, 0] = s[_T]
        out[k, 1] = s[_GQ]
        out[k, 2] = s[_GD]
        out[k, 3] = s[_P]
        out[k, 4] = s[_P + 4]
        out[k, 5] = s[_P + 8]
        out[k, 6] = s[_P + 5]
        out[k, 7] = innovation
        out[k, 8] = nis
        out[k, 9] = _deviation(s, q0[k - 1], hg[k - 1], g[k - 1], te[k - 1], model)


@njit(nogil=False)
def live_steps(
    s: NDArray[np.float64],
    drive: NDArray[np.float64],
    next_drive: NDArray[np.float64],
    out: NDArray[np.float64],
    z: float,
    measured: bool,
    steps: int,
    model: NDArray[np.float64],
    cfg: NDArray[np.float64],
) -> None:
    """One live call in one compiled call: ``steps`` predictions with the held drive (``drive``, the
    Drive fields), the update with z when measured, the deviation; then ``next_drive`` (the drive of this
    call's inputs, the model's ``drive_at``, computed once by the caller) is held for the next call.
    out = (innovation, NIS, deviation)."""
    q0 = drive[0]
    hg = drive[4] * drive[1]
    g = drive[3]
    te = drive[2]
    for _ in range(steps):
        _predict(s, q0, hg, g, te, model, cfg)
    innovation = np.nan
    nis = np.nan
    if measured:
        innovation, nis = _correct(s, z, cfg)
    out[0] = innovation
    out[1] = nis
    out[2] = _deviation(s, q0, hg, g, te, model)
    drive[:] = next_drive


def _initial_state(cht_c: float, pade_w: float, settings: IsolationSettings) -> NDArray[np.float64]:
    s = np.zeros(_STATE_SIZE)
    s[_T] = cht_c
    s[_GQ] = 1.0
    s[_GD] = 1.0
    s[_W] = pade_w
    s[_P] = settings.initial_cht_var
    s[_P + 4] = settings.initial_gamma_var
    s[_P + 8] = settings.initial_gamma_var
    return s


def model_vector(coeffs: Coefficients) -> NDArray[np.float64]:
    """(C_w, tau_w, 1/(alpha R_e), radiation offset) of a single parameter set, as the core reads them."""
    return np.array(
        [float(coeffs.c_w), float(coeffs.tau_w), float(coeffs.radiative_conductance), float(coeffs.radiation_offset_c)]
    )


# --------------------------------------------------------------------------------------------------
# Live filter (CHTEstimator protocol)
# --------------------------------------------------------------------------------------------------


class IsolationFilter:
    """Stateful shell of the isolation EKF with the estimators' ``initialise`` / ``estimate`` API.

    Inputs are held from one call to the next (the step ending at t uses the inputs given at the
    previous call), as in :class:`ecu_monitor.estimation.ekf.ThermalEKF`. The current gamma estimates
    and their covariance are in :attr:`gamma_q`, :attr:`gamma_d`, :attr:`gamma_covariance`.
    """

    name = ESTIMATOR_NAME

    def __init__(self, params: ThermalParams, settings: IsolationSettings | None = None) -> None:
        self.params = params
        self.settings = settings or IsolationSettings()
        self._coeffs = coefficients(params)
        self._model = model_vector(self._coeffs)
        self._cfg = self.settings.vector()
        self._state: NDArray[np.float64] | None = None
        self._drive: Drive | None = None
        self._time_s = 0.0
        # the live call's drive, scratch and outputs, preallocated (estimate() allocates no array)
        self._drive_vec = np.zeros(len(Drive._fields))
        self._next_drive = np.zeros(len(Drive._fields))
        self._inputs = np.zeros(len(InputSeries._fields))
        self._packed_coeffs = pack_coefficients(self._coeffs)
        self._out = np.zeros(3)

    def _require(self) -> tuple[NDArray[np.float64], Drive]:
        if self._state is None or self._drive is None:
            raise EstimationError(f"{self.name}: estimate() called before initialise()")
        return self._state, self._drive

    @property
    def gamma_q(self) -> float:
        """Current estimate of gamma_Q (heat-in factor)."""
        return float(self._require()[0][_GQ])

    @property
    def gamma_d(self) -> float:
        """Current estimate of gamma_D (dissipation factor)."""
        return float(self._require()[0][_GD])

    @property
    def cht_c(self) -> float:
        """Current CHT estimate, degC."""
        return float(self._require()[0][_T])

    @property
    def pade_w(self) -> float:
        """Current Pade state w of the heat-path delay, W."""
        return float(self._require()[0][_W])

    @property
    def gamma_covariance(self) -> NDArray[np.float64]:
        """2 x 2 covariance of (gamma_Q, gamma_D)."""
        p = self._require()[0][_P : _P + 9].reshape(3, 3)
        return p[1:, 1:].copy()

    def initialise(self, t_s: float, u: InputSeries, z_cht_c: float) -> None:
        """Start at t_s from the first reading: T = z, gammas = 1, Pade state in steady state."""
        if not math.isfinite(z_cht_c):
            raise EstimationError(f"{self.name}: initial CHT reading must be finite, got {z_cht_c!r}")
        drive = scalar_drive(u, self._coeffs)
        self._state = _initial_state(float(z_cht_c), 2.0 * float(drive.q_sl0_w), self.settings)
        self._drive = drive
        self._drive_vec[:] = drive
        self._time_s = float(t_s)

    def estimate(self, t_s: float, u: InputSeries, z_cht_c: float | None) -> Estimate:
        """Advance to t_s by whole steps with the held inputs, then correct with z (None: no reading)."""
        s, _ = self._require()  # the drive held for this call is in self._drive_vec
        steps = round((t_s - self._time_s) / self.settings.dt_s)
        if steps < 1:
            raise EstimationError(
                f"{self.name}: time must advance by at least one step of {self.settings.dt_s} s"
                f" (from {self._time_s} to {t_s})"
            )
        measured = z_cht_c is not None and math.isfinite(z_cht_c)
        z = float(z_cht_c) if measured and z_cht_c is not None else math.nan
        out = self._out
        self._inputs[:] = u
        drive_into(self._next_drive, self._inputs, *self._packed_coeffs)
        live_steps(s, self._drive_vec, self._next_drive, out, z, measured, steps, self._model, self._cfg)
        innovation, nis, deviation = float(out[0]), float(out[1]), float(out[2])
        self._time_s = float(t_s)
        return Estimate(
            time_s=float(t_s),
            cht_c=float(s[_T]),
            variance_c2=float(s[_P]),
            innovation_c=float(innovation),
            nis=float(nis),
            deviation=deviation,
            deviation_raw_c=deviation * self.settings.dt_s,
            reset=False,
            measured=measured,
        )


def make_isolation_filter(params: ThermalParams, settings: Any = None) -> IsolationFilter:
    """Factory for the estimator registry: ``settings`` may be IsolationSettings, or the shared
    EstimatorSettings (only its dt_s is used) or None for the defaults."""
    if isinstance(settings, IsolationSettings):
        return IsolationFilter(params, settings)
    if settings is not None and hasattr(settings, "dt_s"):
        return IsolationFilter(params, IsolationSettings(dt_s=float(settings.dt_s)))
    return IsolationFilter(params)


# --------------------------------------------------------------------------------------------------
# Whole flights (compiled)
# --------------------------------------------------------------------------------------------------


class IsolationTrace(NamedTuple):
    """Output of :func:`run_isolation`, one value per log sample (arrays of length N)."""

    time_s: NDArray[np.float64]
    cht_c: NDArray[np.float64]  # CHT estimate, degC
    gamma_q: NDArray[np.float64]
    gamma_d: NDArray[np.float64]
    cht_var_c2: NDArray[np.float64]
    gamma_q_var: NDArray[np.float64]
    gamma_d_var: NDArray[np.float64]
    gamma_qd_cov: NDArray[np.float64]
    innovation_c: NDArray[np.float64]  # nan where no reading
    nis: NDArray[np.float64]
    deviation: NDArray[np.float64]  # f(T, gammas) - f(T, 1, 1), degC/s


def flight_drive(log: FlightLog, params: ThermalParams) -> dict[str, NDArray[np.float64]]:
    """The model's drive at every sample of a flight log: Drive field name -> array of length N."""
    drive = compute_drive_compiled(flight_inputs(log, params), scalar_coefficients(coefficients(params)))
    n = len(log)
    return {
        name: np.ascontiguousarray(np.broadcast_to(np.asarray(value, dtype=float), (n,)))
        for name, value in drive._asdict().items()
    }


def run_isolation(
    log: FlightLog, params: ThermalParams, settings: IsolationSettings | None = None, *, cht_column: str = "cht_c"
) -> IsolationTrace:
    """Run the isolation filter over a whole flight (compiled): steps of dt_s between samples, the
    inputs of each sample held until the next, each reading applied at its sample time."""
    settings = settings or IsolationSettings()
    time_s = log.time_s
    z = np.ascontiguousarray(log[cht_column], dtype=float)
    if not math.isfinite(z[0]):
        raise EstimationError(f"{log.source}: the first CHT reading must be finite")
    drive = flight_drive(log, params)
    substeps = np.zeros(len(log), dtype=np.int64)
    substeps[1:] = np.maximum(1, np.round(np.diff(time_s) / settings.dt_s)).astype(np.int64)
    state = _initial_state(float(z[0]), 2.0 * float(drive["q_sl0_w"][0]), settings)
    columns = np.empty((10, len(log)))  # written as out[k, i] through its transpose: each column contiguous
    hg = np.ascontiguousarray(drive["heat_gain"] * drive["altitude_gain"])
    _run(
        drive["q_sl0_w"], hg, drive["conductance_w_per_c"], drive["ambient_c"], z, substeps,
        model_vector(coefficients(params)), settings.vector(), state, columns.T,
    )  # fmt: skip
    return IsolationTrace(time_s.copy(), *columns)
