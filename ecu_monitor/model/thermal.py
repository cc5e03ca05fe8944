"""The 0D single-zone CHT model as functions of (state, inputs, coefficients): the numpy reference.

    C_w dT/dt = gamma_Q * h_mix * g(z) * Q_SL  -  (1/gamma_D) * [ G (T - T_e) + (T^4 - T_e^4)/(alpha R_e) ]
    w' = (2/tau_w) (2 Q_SL0 - w),   Q_SL = w - Q_SL0          (first-order Pade delay, docs/model.md)
    g(z) = (p(z)/p_SL)^a (T_SL/T_e)^b                        (ISA pressure, measured OAT)
    G = (1/R_Ce) * airspeed factor * density factor          (both 1 in the paper's model)

The equations themselves are written once, in :mod:`ecu_monitor.model.equations`; this module puts
them in the shapes callers use: :func:`coefficients` (ThermalParams -> numbers), :func:`compute_drive`
(inputs -> drive), :func:`rk4_step`, :func:`simulate` (the reference open-loop run).

States (declared once):
    T  cylinder-head temperature, degC
    w  internal state of the Pade delay, W (steady state: w = 2 Q_SL0)
    T_probe  probe temperature, degC (only with the sensor_lag effect; otherwise the probe reads T)
Inputs (:class:`InputSeries`; :func:`ecu_monitor.model.inputs.flight_inputs` reads them from a flight
log): the two heat-map axes (default throttle_pct, rpm), altitude_m, airspeed_mps, oat_c and the
optional mixture index of the mixture_index effect.

The same functions run for one parameter set (floats: one step of the live filter, on the math
module), for a swarm (arrays of shape (P,)) and over a whole flight at once (arrays of shape (N,)).
Inputs are held constant over a step (zero-order hold); the step is RK4.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
from numba.extending import register_jitable
from numpy.typing import NDArray

from ecu_monitor.model import equations as _eq
from ecu_monitor.model.atmosphere import KELVIN_OFFSET
from ecu_monitor.model.effects import EFFECT_COEFFICIENTS
from ecu_monitor.model.equations import Coefficients
from ecu_monitor.model.heatmap import bilinear, heat_cell
from ecu_monitor.model.kernels import njit
from ecu_monitor.model.params import ThermalParams

#: A float for one parameter set, or an array for a swarm / a whole flight.
Real = float | NDArray[np.float64]

__all__ = [
    "EFFECT_COEFFICIENTS",
    "STATE_NAMES",
    "Coefficients",
    "Drive",
    "InputSeries",
    "PackedCoefficients",
    "Real",
    "coefficients",
    "compute_drive",
    "derivatives",
    "drive_at",
    "initial_pade_state",
    "pack_coefficients",
    "rk4_step",
    "scalar_coefficients",
    "sensor_step",
    "simulate",
    "stack_coefficients",
    "steady_state_cht",
    "unpack_coefficients",
]

STATE_NAMES = ("cht_c", "pade_w", "probe_c")


class Drive(NamedTuple):
    """Exogenous quantities of one step (or of every step of a flight), held over the step."""

    q_sl0_w: Real  # sea-level heat map value Q_SL0, W
    altitude_gain: Real  # g(z), dimensionless
    ambient_c: Real  # T_e, degC
    conductance_w_per_c: Real  # G = gains / R_Ce, W/degC
    heat_gain: Real  # mixture-cooling multiplier on the heat, dimensionless


class InputSeries(NamedTuple):
    """Model inputs over time (arrays of length N, or floats for one step).

    mixture_index is the lean/rich index the mixture_index effect reads (EGT degC or fuel per
    revolution mL/rev, as the effect's ``source`` says); NaN (the default) means not logged: the
    effect's factor is then 1. Build these from a flight log with
    :func:`ecu_monitor.model.inputs.flight_inputs`.
    """

    heat_x: Real  # first heat-map axis (e.g. throttle_pct)
    heat_y: Real  # second heat-map axis (e.g. rpm)
    altitude_m: Real  # pressure altitude, m
    airspeed_mps: Real  # calibrated airspeed, m/s
    oat_c: Real  # outside air temperature, degC
    mixture_index: Real = math.nan  # lean/rich index of the mixture_index effect (NaN: not logged)

    def at(self, k: int) -> InputSeries:
        """The inputs of step ``k`` as floats (a field given as one number holds for every step)."""
        return InputSeries(*(float(v) if np.ndim(v) == 0 else float(np.asarray(v)[k]) for v in self))


def coefficients(params: ThermalParams) -> Coefficients:
    """Kernel coefficients of one parameter set (terms switched off and effects off are neutral)."""
    fields: dict[str, Any] = {}
    for key, (name, neutral) in EFFECT_COEFFICIENTS.items():
        effect, parameter = key.split(".")
        value = getattr(params.effects, effect)
        fields[name] = float(getattr(value, parameter)) if value is not None else neutral
    altitude_on = params.term_on("altitude_scaling")
    return Coefficients(
        c_w=params.c_w,
        r_ce=params.r_ce,
        radiative_conductance=1.0 / params.alpha_r_e if params.term_on("radiation") else 0.0,
        tau_w=params.tau_w,
        a=params.a if altitude_on else 0.0,
        b=params.b if altitude_on else 0.0,
        radiation_offset_c=KELVIN_OFFSET if params.radiation_in_kelvin else 0.0,
        heat_values_w=params.heat_map.values_array(),
        x_breakpoints=np.asarray(params.heat_map.x_breakpoints, dtype=float),
        y_breakpoints=np.asarray(params.heat_map.y_breakpoints, dtype=float),
        **fields,
    )


def scalar_coefficients(coeffs: Coefficients) -> Coefficients:
    """Coefficients of one parameter set with every scalar field a Python float and every array
    contiguous float64 (one numba type for every model)."""
    fields: dict[str, Any] = {
        name: float(value) if np.ndim(value) == 0 else np.ascontiguousarray(value, dtype=np.float64)
        for name, value in coeffs._asdict().items()
    }
    return Coefficients(**fields)


class PackedCoefficients(NamedTuple):
    """The coefficients of one parameter set as four contiguous float64 arrays, as the live filters pass
    them to their compiled calls: numba types a namedtuple argument in Python at every call (tens of
    microseconds when the caches are cold, docs/performance.md), four arrays in its C dispatcher.
    :func:`unpack_coefficients` rebuilds the :class:`Coefficients` inside the compiled code."""

    scalars: NDArray[np.float64]  # every field before heat_values_w, in Coefficients order
    heat_values_w: NDArray[np.float64]
    x_breakpoints: NDArray[np.float64]
    y_breakpoints: NDArray[np.float64]


#: Coefficients fields held in PackedCoefficients.scalars (the parameter fields, then radiation_offset_c).
_SCALAR_FIELDS = Coefficients._fields[: Coefficients._fields.index("heat_values_w")]


def pack_coefficients(coeffs: Coefficients) -> PackedCoefficients:
    """The coefficients of one parameter set (floats, not a swarm) as :class:`PackedCoefficients`."""
    scalar = scalar_coefficients(coeffs)
    return PackedCoefficients(
        np.array([getattr(scalar, name) for name in _SCALAR_FIELDS], dtype=np.float64),
        scalar.heat_values_w,
        scalar.x_breakpoints,
        scalar.y_breakpoints,
    )


@register_jitable
def unpack_coefficients(
    scalars: NDArray[np.float64],
    heat_values_w: NDArray[np.float64],
    x_breakpoints: NDArray[np.float64],
    y_breakpoints: NDArray[np.float64],
) -> Coefficients:
    """The :class:`Coefficients` that :func:`pack_coefficients` packed (compiled into the live filters' calls;
    equal to ``scalar_coefficients`` of the original, field for field)."""
    s = scalars
    return Coefficients(
        s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], s[8], s[9], s[10], s[11], s[12], s[13], s[14], s[15],
        s[16], s[17], s[18], s[19], s[20], s[21], heat_values_w, x_breakpoints, y_breakpoints,
    )  # fmt: skip


def stack_coefficients(params: Sequence[ThermalParams]) -> Coefficients:
    """Coefficients of a swarm: each field an array (P,); all must share axes, breakpoints and
    radiation convention."""
    each = [coefficients(p) for p in params]
    first = each[0]
    for c in each[1:]:
        if (
            c.radiation_offset_c != first.radiation_offset_c
            or not np.array_equal(c.x_breakpoints, first.x_breakpoints)
            or not np.array_equal(c.y_breakpoints, first.y_breakpoints)
        ):
            raise ValueError("stack_coefficients: parameter sets differ in breakpoints or radiation units")
    fields = {}
    for name in Coefficients._fields:
        if name in ("radiation_offset_c", "x_breakpoints", "y_breakpoints"):
            fields[name] = getattr(first, name)
        else:
            fields[name] = np.stack([np.asarray(getattr(c, name), dtype=float) for c in each])
    return Coefficients(**fields)


def compute_drive(inputs: InputSeries, coeffs: Coefficients) -> Drive:
    """Drive quantities from the inputs: heat map, altitude scaling and the effects' factors.

    One step of one parameter set (all floats) runs :func:`drive_at` compiled (the math module, as every
    compiled caller); anything else is broadcast with numpy. Same equations either way.
    """
    if _is_scalar_case(inputs, coeffs):
        return _compute_drive_scalar(inputs, coeffs)
    xb = coeffs.x_breakpoints
    q_sl0 = bilinear(coeffs.heat_values_w, xb, coeffs.y_breakpoints, inputs.heat_x, inputs.heat_y)
    oat_c = np.asarray(inputs.oat_c, dtype=float)
    conditions: tuple[Any, Any, Any, Any, Any] = _eq.conditions(
        np.asarray(inputs.heat_x, dtype=float),
        np.asarray(inputs.altitude_m, dtype=float),
        np.asarray(inputs.airspeed_mps, dtype=float),
        oat_c,
        float(xb[0]),
        float(xb[-1]),
    )
    altitude_gain, heat_gain, conductance = _eq.drive(
        *conditions, np.asarray(inputs.heat_y, dtype=float), np.asarray(inputs.mixture_index, dtype=float), coeffs
    )
    return Drive(q_sl0, altitude_gain, oat_c, conductance, heat_gain)


_SCALAR_TYPES = (float, int, np.floating, np.integer)


def _is_scalar_case(inputs: InputSeries, coeffs: Coefficients) -> bool:
    return (
        all(isinstance(v, _SCALAR_TYPES) for v in inputs)
        and isinstance(coeffs.c_w, _SCALAR_TYPES)
        and isinstance(coeffs.a, _SCALAR_TYPES)
        and np.ndim(coeffs.heat_values_w) == 2
    )


@register_jitable
def drive_at(u: Any, coeffs: Any) -> tuple[float, float, float, float, float]:
    """The model's drive at one operating point ``u`` (the six inputs in :class:`InputSeries` order), in
    :class:`Drive` order (q_sl0 W, g(z), ambient degC, conductance W/degC, heat factor): the heat-map
    cell, its blend, the conditions and the effects. The one assembly of the drive; every compiled
    caller (the drive kernel, the filters, the step) uses it."""
    xb = coeffs.x_breakpoints
    v = coeffs.heat_values_w
    i, j, fx, fy = heat_cell(u[0], u[1], xb, coeffs.y_breakpoints)
    q_sl0 = _eq.blend(v[i, j], v[i, j + 1], v[i + 1, j], v[i + 1, j + 1], fx, fy)
    log_p, log_t, log_rho, airspeed, load = _eq.conditions(u[0], u[2], u[3], u[4], xb[0], xb[xb.shape[0] - 1])
    altitude_gain, heat_gain, conductance = _eq.drive(log_p, log_t, log_rho, airspeed, load, u[1], u[5], coeffs)
    return q_sl0, altitude_gain, u[4], conductance, heat_gain


#: :func:`drive_at` compiled (the math module's primitives, as every compiled caller), for one step from Python.
_drive_compiled = njit()(drive_at)


@njit(nogil=False)
def drive_into(
    out: Any, inputs: Any, coeff_scalars: Any, heat_values_w: Any, x_breakpoints: Any, y_breakpoints: Any
) -> None:
    """:func:`drive_at` of the six ``inputs`` (float64[6], InputSeries order) into ``out`` (float64[5], Drive
    order), the coefficients packed (``pack_coefficients``): the held filters' next drive in one cheap compiled
    call from Python (a scalar :func:`compute_drive` boxes every coefficient)."""
    coeffs = unpack_coefficients(coeff_scalars, heat_values_w, x_breakpoints, y_breakpoints)
    u = (inputs[0], inputs[1], inputs[2], inputs[3], inputs[4], inputs[5])
    out[0], out[1], out[2], out[3], out[4] = drive_at(u, coeffs)


def _compute_drive_scalar(inputs: InputSeries, coeffs: Coefficients) -> Drive:
    """compute_drive for floats: :func:`drive_at` compiled, so a Python filter drives its model exactly as
    the compiled ones do."""
    return Drive(*_drive_compiled(tuple(float(v) for v in inputs), scalar_coefficients(coeffs)))


def initial_pade_state(drive: Drive) -> Real:
    """Pade state w in steady state for the given drive (w = 2 Q_SL0), W."""
    return 2.0 * np.asarray(drive.q_sl0_w)


def derivatives(
    cht_c: Real,
    pade_w: Real,
    drive: Drive,
    coeffs: Coefficients,
    gamma_q: Real = 1.0,
    gamma_d: Real = 1.0,
) -> tuple[Real, Real]:
    """(dT/dt in degC/s, dw/dt in W/s) of the model (Eq. 18 with the Pade delay)."""
    return _eq.derivatives(
        cht_c, pade_w, drive.q_sl0_w, drive.heat_gain * drive.altitude_gain, drive.ambient_c,
        drive.conductance_w_per_c, coeffs.c_w, coeffs.tau_w, coeffs.radiative_conductance,
        coeffs.radiation_offset_c, gamma_q, gamma_d,
    )  # fmt: skip


@register_jitable
def rk4_step(
    cht_c: Real,
    pade_w: Real,
    drive: Drive,
    coeffs: Coefficients,
    dt_s: float,
    gamma_q: Real = 1.0,
    gamma_d: Real = 1.0,
) -> tuple[Real, Real]:
    """One RK4 step of (T, w) over dt_s seconds with the drive held constant."""
    return _eq.rk4(
        cht_c, pade_w, drive.q_sl0_w, drive.heat_gain * drive.altitude_gain, drive.ambient_c,
        drive.conductance_w_per_c, coeffs.c_w, coeffs.tau_w, coeffs.radiative_conductance,
        coeffs.radiation_offset_c, gamma_q, gamma_d, dt_s,
    )  # fmt: skip


def sensor_step(probe_c: Real, cht_c: Real, coeffs: Coefficients, dt_s: float) -> Real:
    """Probe temperature after dt_s (exact first-order lag towards cht_c); no lag -> cht_c."""
    fraction = _eq.lag_fraction(np.asarray(coeffs.sensor_lag_s, dtype=float), dt_s)
    result = _eq.probe_step(probe_c, np.asarray(cht_c), fraction)
    return float(result) if np.ndim(result) == 0 else result


def steady_state_cht(
    drive: Drive,
    coeffs: Coefficients,
    gamma_q: float = 1.0,
    gamma_d: float = 1.0,
    iterations: int = 60,
    below: float = -math.inf,
) -> Real:
    """CHT (degC) where heat in equals heat out for a held drive (Newton on the balance).

    Starts from the convective-only solution (an upper bound: the balance is convex, so Newton falls
    monotonically) and stops once every step is below 1e-9 degC, at most ``iterations`` steps, or as soon as
    every iterate is below ``below`` (degC): the steady state is then below it too, and the iterate is
    returned (for a caller that only asks whether the steady state is below ``below``). For one
    operating point (every argument a number) the same iteration runs on Python floats and complex
    numbers (the live headroom: ~10x cheaper than numpy on 0-d arrays).
    """
    if all(isinstance(v, float | int) for v in (*drive, gamma_q, gamma_d)):
        try:
            return _steady_state_scalar(drive, coeffs, float(gamma_q), float(gamma_d), iterations, below)
        except ZeroDivisionError:  # no conductance: numpy's inf and nan below, as for arrays
            pass
    heat = gamma_q * gamma_d * np.asarray(drive.heat_gain) * drive.altitude_gain * drive.q_sl0_w
    g_conv = np.asarray(drive.conductance_w_per_c, dtype=float)
    ambient = np.asarray(drive.ambient_c, dtype=float)
    temp = ambient + heat / g_conv  # convective-only solution, an upper bound
    for _ in range(iterations):
        # the balance's residual and its slope (complex step: exact, and no second formula)
        lost = _eq.dissipation(
            temp + 1j * _COMPLEX_STEP, ambient, g_conv, coeffs.radiative_conductance, coeffs.radiation_offset_c
        )
        change = (lost.real - heat) / (lost.imag / _COMPLEX_STEP)
        temp = temp - change
        if not np.any(np.abs(change) > 1e-9) or (below > -math.inf and np.all(temp < below)):
            break
    return float(temp) if np.ndim(temp) == 0 else temp


_COMPLEX_STEP = 1e-30


def _steady_state_scalar(
    drive: Drive, coeffs: Coefficients, gamma_q: float, gamma_d: float, iterations: int, below: float = -math.inf
) -> float:
    """:func:`steady_state_cht` of one operating point on Python floats (the same operations in the same order)."""
    heat = gamma_q * gamma_d * float(drive.heat_gain) * float(drive.altitude_gain) * float(drive.q_sl0_w)
    g_conv = float(drive.conductance_w_per_c)
    ambient = float(drive.ambient_c)
    radiative = float(coeffs.radiative_conductance)
    offset = float(coeffs.radiation_offset_c)
    dissipation = _eq.dissipation
    temp = ambient + heat / g_conv
    for _ in range(iterations):
        lost = dissipation(complex(temp, _COMPLEX_STEP), ambient, g_conv, radiative, offset)
        change = (lost.real - heat) / (lost.imag / _COMPLEX_STEP)
        temp = temp - change
        if not abs(change) > 1e-9 or temp < below:
            break
    return temp


def simulate(
    inputs: InputSeries,
    coeffs: Coefficients,
    dt_s: float,
    initial_cht_c: Real,
    gamma_q: Real = 1.0,
    gamma_d: Real = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Open-loop run over inputs sampled every dt_s (arrays of length N).

    Returns (cht_c, probe_c), each of shape (N,) or (N, P) for a swarm; sample k is the state after
    k steps, so sample 0 is the initial state. gamma_q/gamma_d may be floats or arrays (N,) (a
    degradation schedule). Plain numpy loop: fine for a few thousand steps or a big swarm; the
    identification uses a compiled kernel with the same equations.
    """
    n = int(np.size(inputs.heat_x))
    series = InputSeries(*(np.broadcast_to(np.asarray(v, dtype=float), (n,)) for v in inputs))
    swarm = np.ndim(coeffs.c_w) > 0
    per_time = coeffs
    if swarm:  # per-particle fields (P,) -> (P, 1) so the drive broadcasts to (P, N)
        columns: dict[str, Any] = {
            name: np.asarray(getattr(coeffs, name), dtype=float)[:, None]
            for name in Coefficients._fields
            if name in _eq.PARAMETER_FIELDS
        }
        per_time = coeffs._replace(**columns)
    drive_all = Drive(*(np.asarray(v, dtype=float) for v in compute_drive(series, per_time)))
    g_q = np.broadcast_to(np.asarray(gamma_q, dtype=float), (n,))
    g_d = np.broadcast_to(np.asarray(gamma_d, dtype=float), (n,))

    def at(k: int) -> Drive:
        return Drive(*(np.asarray(v)[..., k] for v in drive_all))

    first = at(0)
    cht: Any = np.asarray(initial_cht_c, dtype=float) + 0.0 * np.asarray(coeffs.c_w, dtype=float)
    pade: Any = np.asarray(initial_pade_state(first), dtype=float) + 0.0 * cht
    probe = cht.copy()
    out_cht = np.empty((n, *cht.shape))
    out_probe = np.empty((n, *cht.shape))
    out_cht[0] = cht
    out_probe[0] = probe
    for k in range(1, n):
        drive = at(k - 1)
        cht, pade = rk4_step(cht, pade, drive, coeffs, dt_s, g_q[k - 1], g_d[k - 1])
        probe = sensor_step(probe, cht, coeffs, dt_s)
        out_cht[k] = cht
        out_probe[k] = probe
    return out_cht, out_probe
