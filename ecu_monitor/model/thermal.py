"""The 0D single-zone CHT model as pure functions of (state, inputs, coefficients).

    C_w dT/dt = gamma_Q * h_mix * g(z) * Q_SL  -  (1/gamma_D) * [ G (T - T_e) + (T^4 - T_e^4)/(alpha R_e) ]
    w' = (2/tau_w) (2 Q_SL0 - w),   Q_SL = w - Q_SL0          (first-order Pade delay, notes.md)
    g(z) = (p(z)/p_SL)^a (T_SL/T_e)^b                        (ISA pressure, measured OAT)
    G = (1/R_Ce) * airspeed gain * density gain                (both 1 in the paper's model)

States (declared once):
    T  cylinder-head temperature, degC
    w  internal state of the Pade delay, W (steady state: w = 2 Q_SL0)
    T_probe  probe temperature, degC (only with the sensor_lag effect; otherwise the probe reads T)
Inputs (flight columns): the two heat-map axes (default throttle_pct, rpm), altitude_m,
    airspeed_mps, oat_c.

Everything here is plain arithmetic on floats or numpy arrays, so the same functions run for one
parameter set (floats: the live estimator), for a swarm (arrays of shape (P,): PSO) and over a whole
flight at once (arrays of shape (N,): diagnostics). Inputs are held constant over a step (zero-order
hold); the step is RK4.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.model.atmosphere import (
    ISA_PRESSURE_EXPONENT,
    KELVIN_OFFSET,
    LAPSE_RATE_K_PER_M,
    SEA_LEVEL_DENSITY_KG_M3,
    SEA_LEVEL_PRESSURE_PA,
    SEA_LEVEL_TEMPERATURE_K,
    air_density_kg_m3,
    isa_pressure_pa,
)
from ecu_monitor.model.heatmap import bilinear
from ecu_monitor.model.params import ThermalParams

#: A float for one parameter set, or an array for a swarm / a whole flight.
Real = float | NDArray[np.float64]

__all__ = [
    "STATE_NAMES",
    "Coefficients",
    "Drive",
    "InputSeries",
    "Real",
    "coefficients",
    "compute_drive",
    "derivatives",
    "initial_pade_state",
    "rk4_step",
    "sensor_step",
    "simulate",
    "stack_coefficients",
    "steady_state_cht",
]

STATE_NAMES = ("cht_c", "pade_w", "probe_c")


class Coefficients(NamedTuple):
    """Numeric form of ThermalParams for the kernels: each field a float or an array (P,) for a swarm.

    heat_values_w has shape (n, m) or (P, n, m); breakpoints are shared by all particles.
    Effects that are off take their neutral value (gain 0, exponent 0, lag 0, fraction 0).
    """

    c_w: Real  # J/degC
    r_ce: Real  # degC/W
    radiative_conductance: Real  # 1/(alpha R_e), W/deg^4
    radiation_offset_c: float  # 273.15 when T^4 is in Kelvin, 0 for the paper's preset
    tau_w: Real  # s
    a: Real
    b: Real
    heat_values_w: np.ndarray  # (n, m) or (P, n, m), W
    x_breakpoints: np.ndarray
    y_breakpoints: np.ndarray
    airspeed_gain_per_mps: Real  # 1/(m/s)
    airspeed_reference_mps: Real
    airspeed_floor: Real
    density_exponent: Real
    density_reference_kg_m3: Real
    sensor_lag_s: Real  # s, 0 = no lag
    mixture_fraction: Real
    mixture_onset: Real


class Drive(NamedTuple):
    """Exogenous quantities of one step (or of every step of a flight), held over the step."""

    q_sl0_w: Real  # sea-level heat map value Q_SL0, W
    altitude_gain: Real  # g(z), dimensionless
    ambient_c: Real  # T_e, degC
    conductance_w_per_c: Real  # G = gains / R_Ce, W/degC
    heat_gain: Real  # mixture-cooling multiplier on the heat, dimensionless


class InputSeries(NamedTuple):
    """Model inputs over time (arrays of length N, or floats for one step)."""

    heat_x: Real  # first heat-map axis (e.g. throttle_pct)
    heat_y: Real  # second heat-map axis (e.g. rpm)
    altitude_m: Real
    airspeed_mps: Real
    oat_c: Real


def coefficients(params: ThermalParams) -> Coefficients:
    """Kernel coefficients of one parameter set."""
    fx = params.effects
    air, dens, lag, mix = fx.airspeed_cooling, fx.density_cooling, fx.sensor_lag, fx.mixture_cooling
    return Coefficients(
        c_w=params.c_w,
        r_ce=params.r_ce,
        radiative_conductance=1.0 / params.alpha_r_e,
        radiation_offset_c=KELVIN_OFFSET if params.radiation_in_kelvin else 0.0,
        tau_w=params.tau_w,
        a=params.a,
        b=params.b,
        heat_values_w=params.heat_map.values_array(),
        x_breakpoints=np.asarray(params.heat_map.x_breakpoints, dtype=float),
        y_breakpoints=np.asarray(params.heat_map.y_breakpoints, dtype=float),
        airspeed_gain_per_mps=air.gain_per_mps if air else 0.0,
        airspeed_reference_mps=air.reference_mps if air else 23.0,
        airspeed_floor=air.floor if air else 1.0,
        density_exponent=dens.exponent if dens else 0.0,
        density_reference_kg_m3=dens.reference_kg_m3 if dens else SEA_LEVEL_DENSITY_KG_M3,
        sensor_lag_s=lag.time_constant_s if lag else 0.0,
        mixture_fraction=mix.fraction if mix else 0.0,
        mixture_onset=mix.onset if mix else 0.7,
    )


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
    """Drive quantities from the inputs: heat map, altitude scaling and the effects' gains.

    One step of one parameter set (all floats) takes a plain-float path (~10x cheaper than numpy on
    scalars: the live filter calls this every 20 ms); anything else is broadcast with numpy.
    """
    if _is_scalar_case(inputs, coeffs):
        return _compute_drive_scalar(inputs, coeffs)
    q_sl0 = bilinear(coeffs.heat_values_w, coeffs.x_breakpoints, coeffs.y_breakpoints, inputs.heat_x, inputs.heat_y)
    oat_c = np.asarray(inputs.oat_c, dtype=float)
    pressure = np.asarray(isa_pressure_pa(inputs.altitude_m))
    oat_k = oat_c + KELVIN_OFFSET
    altitude_gain = (pressure / SEA_LEVEL_PRESSURE_PA) ** coeffs.a * (SEA_LEVEL_TEMPERATURE_K / oat_k) ** coeffs.b
    airspeed = np.maximum(np.asarray(inputs.airspeed_mps, dtype=float), 0.0)
    airspeed_gain = np.maximum(
        coeffs.airspeed_floor,
        1.0 + coeffs.airspeed_gain_per_mps * (airspeed - coeffs.airspeed_reference_mps),
    )
    density = air_density_kg_m3(pressure, oat_c)
    density_gain = (density / coeffs.density_reference_kg_m3) ** coeffs.density_exponent
    span = coeffs.x_breakpoints[-1] - coeffs.x_breakpoints[0]
    load = np.clip((np.asarray(inputs.heat_x, dtype=float) - coeffs.x_breakpoints[0]) / span, 0.0, 1.0)
    onset = np.asarray(coeffs.mixture_onset, dtype=float)
    enrichment = np.clip((load - onset) / (1.0 - onset), 0.0, 1.0)
    heat_gain = 1.0 - coeffs.mixture_fraction * enrichment
    return Drive(
        q_sl0_w=q_sl0,
        altitude_gain=altitude_gain,
        ambient_c=oat_c,
        conductance_w_per_c=airspeed_gain * density_gain / coeffs.r_ce,
        heat_gain=heat_gain,
    )


_SCALAR_TYPES = (float, int, np.floating, np.integer)


def _is_scalar_case(inputs: InputSeries, coeffs: Coefficients) -> bool:
    return (
        all(isinstance(v, _SCALAR_TYPES) for v in inputs)
        and isinstance(coeffs.c_w, _SCALAR_TYPES)
        and isinstance(coeffs.a, _SCALAR_TYPES)
        and np.ndim(coeffs.heat_values_w) == 2
    )


def _cell_scalar(breakpoints: NDArray[np.float64], q: float) -> tuple[int, float]:
    low, high = float(breakpoints[0]), float(breakpoints[-1])
    q = low if q < low else high if q > high else q
    index = min(max(bisect.bisect_right(breakpoints, q) - 1, 0), len(breakpoints) - 2)
    x0, x1 = float(breakpoints[index]), float(breakpoints[index + 1])
    return index, (q - x0) / (x1 - x0)


def _compute_drive_scalar(inputs: InputSeries, coeffs: Coefficients) -> Drive:
    """compute_drive for floats with the math module (same formulas; tested equal)."""
    heat_x, heat_y, altitude_m, airspeed_mps, oat_c = (float(v) for v in inputs)
    c: Any = coeffs
    i, fx = _cell_scalar(c.x_breakpoints, heat_x)
    j, fy = _cell_scalar(c.y_breakpoints, heat_y)
    v = c.heat_values_w
    q_sl0 = (1 - fx) * ((1 - fy) * v[i, j] + fy * v[i, j + 1]) + fx * ((1 - fy) * v[i + 1, j] + fy * v[i + 1, j + 1])
    ratio = max(1.0 - LAPSE_RATE_K_PER_M * altitude_m / SEA_LEVEL_TEMPERATURE_K, 1e-6)
    pressure_ratio = ratio**ISA_PRESSURE_EXPONENT
    oat_k = oat_c + KELVIN_OFFSET
    altitude_gain = pressure_ratio**c.a * (SEA_LEVEL_TEMPERATURE_K / oat_k) ** c.b
    airspeed_gain = max(
        c.airspeed_floor, 1.0 + c.airspeed_gain_per_mps * (max(airspeed_mps, 0.0) - c.airspeed_reference_mps)
    )
    density_gain = 1.0
    if c.density_exponent != 0.0:
        density = float(air_density_kg_m3(SEA_LEVEL_PRESSURE_PA * pressure_ratio, oat_c))
        density_gain = (density / c.density_reference_kg_m3) ** c.density_exponent
    x_low, x_high = float(c.x_breakpoints[0]), float(c.x_breakpoints[-1])
    load = min(max((heat_x - x_low) / (x_high - x_low), 0.0), 1.0)
    enrichment = min(max((load - c.mixture_onset) / (1.0 - c.mixture_onset), 0.0), 1.0)
    return Drive(
        q_sl0_w=float(q_sl0),
        altitude_gain=float(altitude_gain),
        ambient_c=oat_c,
        conductance_w_per_c=float(airspeed_gain * density_gain / c.r_ce),
        heat_gain=float(1.0 - c.mixture_fraction * enrichment),
    )


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
    q_sl = pade_w - drive.q_sl0_w
    heat_in = gamma_q * drive.heat_gain * drive.altitude_gain * q_sl
    t_k = cht_c + coeffs.radiation_offset_c
    e_k = drive.ambient_c + coeffs.radiation_offset_c
    dissipated = drive.conductance_w_per_c * (cht_c - drive.ambient_c) + coeffs.radiative_conductance * (
        t_k * t_k * t_k * t_k - e_k * e_k * e_k * e_k
    )
    d_cht = (heat_in - dissipated / gamma_d) / coeffs.c_w
    d_pade = (2.0 / coeffs.tau_w) * (2.0 * drive.q_sl0_w - pade_w)
    return d_cht, d_pade


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
    k1t, k1w = derivatives(cht_c, pade_w, drive, coeffs, gamma_q, gamma_d)
    h = 0.5 * dt_s
    k2t, k2w = derivatives(cht_c + h * k1t, pade_w + h * k1w, drive, coeffs, gamma_q, gamma_d)
    k3t, k3w = derivatives(cht_c + h * k2t, pade_w + h * k2w, drive, coeffs, gamma_q, gamma_d)
    k4t, k4w = derivatives(cht_c + dt_s * k3t, pade_w + dt_s * k3w, drive, coeffs, gamma_q, gamma_d)
    sixth = dt_s / 6.0
    return (
        cht_c + sixth * (k1t + 2.0 * k2t + 2.0 * k3t + k4t),
        pade_w + sixth * (k1w + 2.0 * k2w + 2.0 * k3w + k4w),
    )


def sensor_step(probe_c: Real, cht_c: Real, coeffs: Coefficients, dt_s: float) -> Real:
    """Probe temperature after dt_s (exact first-order lag towards cht_c); no lag -> cht_c."""
    lag = np.asarray(coeffs.sensor_lag_s, dtype=float)
    alpha = np.where(lag > 0.0, -np.expm1(-dt_s / np.maximum(lag, 1e-12)), 1.0)
    result = probe_c + alpha * (np.asarray(cht_c) - probe_c)
    return float(result) if np.ndim(result) == 0 else result


def steady_state_cht(
    drive: Drive, coeffs: Coefficients, gamma_q: float = 1.0, gamma_d: float = 1.0, iterations: int = 60
) -> Real:
    """CHT (degC) where heat in equals heat out for a held drive (Newton on the balance).

    Starts from the convective-only solution (an upper bound: the balance is convex, so Newton falls
    monotonically) and stops once every step is below 1e-9 degC, at most ``iterations`` steps.
    """
    heat = gamma_q * gamma_d * np.asarray(drive.heat_gain) * drive.altitude_gain * drive.q_sl0_w
    g_conv = np.asarray(drive.conductance_w_per_c, dtype=float)
    off = coeffs.radiation_offset_c
    e_k = np.asarray(drive.ambient_c) + off
    temp = np.asarray(drive.ambient_c) + heat / g_conv  # convective-only solution, an upper bound
    for _ in range(iterations):
        t_k = temp + off
        residual = g_conv * (temp - drive.ambient_c) + coeffs.radiative_conductance * (t_k**4 - e_k**4) - heat
        slope = g_conv + 4.0 * coeffs.radiative_conductance * t_k**3
        change = residual / slope
        temp = temp - change
        if not np.any(np.abs(change) > 1e-9):
            break
    return float(temp) if np.ndim(temp) == 0 else temp


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
    series = InputSeries(*(np.asarray(v, dtype=float).reshape(n) for v in inputs))
    swarm = np.ndim(coeffs.c_w) > 0
    per_time = coeffs
    if swarm:  # per-particle fields (P,) -> (P, 1) so the drive broadcasts to (P, N)
        columns: dict[str, Any] = {
            name: np.asarray(getattr(coeffs, name), dtype=float)[:, None]
            for name in Coefficients._fields
            if name not in ("radiation_offset_c", "heat_values_w", "x_breakpoints", "y_breakpoints")
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
