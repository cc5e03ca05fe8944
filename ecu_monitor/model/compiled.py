"""Compiled (numba) twin of :func:`ecu_monitor.model.thermal.simulate` for long flights and swarms.

Same equations as thermal.py (tested equal to it): RK4 on (T, w) with inputs held over each step, the
probe lag applied exactly after each step. The loop runs time outer, particles inner over contiguous
per-particle arrays, so numba vectorises it (about a few ns per particle-step here). Used by PSO
identification (a whole swarm per call), the gap diagnosis (many refits) and long replays.

Failures are reported, never hidden: a particle whose trajectory leaves the finite range is flagged
in the returned ``failed`` mask and its trajectory is NaN from then on.
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray

from ecu_monitor.model.atmosphere import (
    KELVIN_OFFSET,
    SEA_LEVEL_PRESSURE_PA,
    SEA_LEVEL_TEMPERATURE_K,
    air_density_kg_m3,
    isa_pressure_pa,
)
from ecu_monitor.model.thermal import Coefficients, InputSeries

__all__ = ["CompiledRun", "simulate_compiled"]

# Column order of the per-particle coefficient matrix handed to the kernel.
_COLUMNS = (
    "c_w",
    "r_ce",
    "radiative_conductance",
    "tau_w",
    "a",
    "b",
    "airspeed_gain_per_mps",
    "airspeed_reference_mps",
    "airspeed_floor",
    "density_exponent",
    "density_reference_kg_m3",
    "sensor_lag_s",
    "mixture_fraction",
    "mixture_onset",
)


class CompiledRun(NamedTuple):
    """Result of :func:`simulate_compiled`: sampled trajectories and a failure mask."""

    cht_c: NDArray[np.float64]  # (N_rec,) or (N_rec, P): true head temperature, degC
    probe_c: NDArray[np.float64]  # same shape: what the (possibly lagging) probe reads, degC
    failed: NDArray[np.bool_]  # () or (P,): trajectory became non-finite


@numba.njit(cache=True, fastmath=False, nogil=True)
def _kernel(
    heat_x: NDArray[np.float64],
    heat_y: NDArray[np.float64],
    log_pressure_ratio: NDArray[np.float64],
    log_temperature_ratio: NDArray[np.float64],
    oat_c: NDArray[np.float64],
    airspeed: NDArray[np.float64],
    log_density: NDArray[np.float64],
    load: NDArray[np.float64],
    gamma_q: NDArray[np.float64],
    gamma_d: NDArray[np.float64],
    changed: NDArray[np.bool_],
    xb: NDArray[np.float64],
    yb: NDArray[np.float64],
    theta: NDArray[np.float64],
    heat: NDArray[np.float64],
    rad_offset: float,
    dt: float,
    t0: NDArray[np.float64],
    record_every: int,
    out_cht: NDArray[np.float64],
    out_probe: NDArray[np.float64],
) -> None:
    n_steps = heat_x.shape[0]
    n_particles = theta.shape[1]
    c_w = theta[0]
    r_ce = theta[1]
    rad = theta[2]
    tau = theta[3]
    a_exp = theta[4]
    b_exp = theta[5]
    k_air = theta[6]
    v_ref = theta[7]
    floor = theta[8]
    n_rho = theta[9]
    log_rho_ref = np.log(theta[10])
    lag = theta[11]
    mix_f = theta[12]
    mix_on = theta[13]
    lag_alpha = np.empty(n_particles)
    for p in range(n_particles):
        lag_alpha[p] = 1.0 if lag[p] <= 0.0 else -np.expm1(-dt / lag[p])
    inv_c = 1.0 / c_w
    kw = 2.0 / tau
    temp = t0.copy()
    pade = np.empty(n_particles)
    probe = t0.copy()
    q0 = np.empty(n_particles)
    gain_heat = np.empty(n_particles)
    cond = np.empty(n_particles)
    nx = xb.shape[0]
    ny = yb.shape[0]
    for k in range(n_steps):
        if not changed[k]:
            _rk4_particles(temp, pade, probe, q0, gain_heat, cond, rad, inv_c, kw, lag_alpha, oat_c[k],
                           rad_offset, gamma_d[k], dt, k, record_every, out_cht, out_probe)  # fmt: skip
            continue
        # shared cell of the heat map for this step
        x = min(max(heat_x[k], xb[0]), xb[nx - 1])
        y = min(max(heat_y[k], yb[0]), yb[ny - 1])
        i = 0
        while i < nx - 2 and x >= xb[i + 1]:
            i += 1
        j = 0
        while j < ny - 2 and y >= yb[j + 1]:
            j += 1
        fx = (x - xb[i]) / (xb[i + 1] - xb[i])
        fy = (y - yb[j]) / (yb[j + 1] - yb[j])
        w00 = (1.0 - fx) * (1.0 - fy)
        w01 = (1.0 - fx) * fy
        w10 = fx * (1.0 - fy)
        w11 = fx * fy
        e_c = oat_c[k]
        for p in range(n_particles):
            q0[p] = (
                w00 * heat[p, i, j] + w01 * heat[p, i, j + 1] + w10 * heat[p, i + 1, j] + w11 * heat[p, i + 1, j + 1]
            )
            g_alt = np.exp(a_exp[p] * log_pressure_ratio[k] + b_exp[p] * log_temperature_ratio[k])
            onset = mix_on[p]
            enrich = min(max((load[k] - onset) / (1.0 - onset), 0.0), 1.0)
            gain_heat[p] = gamma_q[k] * (1.0 - mix_f[p] * enrich) * g_alt
            g_air = max(floor[p], 1.0 + k_air[p] * (airspeed[k] - v_ref[p]))
            g_rho = np.exp(n_rho[p] * (log_density[k] - log_rho_ref[p]))
            cond[p] = g_air * g_rho / r_ce[p]
            if k == 0:
                pade[p] = 2.0 * q0[p]
        _rk4_particles(temp, pade, probe, q0, gain_heat, cond, rad, inv_c, kw, lag_alpha, e_c,
                       rad_offset, gamma_d[k], dt, k, record_every, out_cht, out_probe)  # fmt: skip


@numba.njit(cache=True, fastmath=True, nogil=True)
def _rk4_particles(temp, pade, probe, q0, gain_heat, cond, rad, inv_c, kw, lag_alpha, e_c,
                   rad_offset, gamma_d, dt, k, record_every, out_cht, out_probe):  # fmt: skip
    """One RK4 step of every particle with the drive held (the hot loop; numba vectorises it)."""
    e_k = e_c + rad_offset
    e4 = e_k * e_k * e_k * e_k
    inv_gd = 1.0 / gamma_d
    record = k % record_every == 0
    row = k // record_every
    if record:
        out_cht[row, :] = temp
        out_probe[row, :] = probe
    for p in range(temp.shape[0]):
        tq = temp[p]
        wq = pade[p]
        u = q0[p]
        gh = gain_heat[p]
        gc = cond[p]
        rp = rad[p]
        # stage 1
        tk = tq + rad_offset
        d1t = (gh * (wq - u) - inv_gd * (gc * (tq - e_c) + rp * (tk * tk * tk * tk - e4))) * inv_c[p]
        d1w = kw[p] * (2.0 * u - wq)
        # stage 2
        t2 = tq + 0.5 * dt * d1t
        w2 = wq + 0.5 * dt * d1w
        tk = t2 + rad_offset
        d2t = (gh * (w2 - u) - inv_gd * (gc * (t2 - e_c) + rp * (tk * tk * tk * tk - e4))) * inv_c[p]
        d2w = kw[p] * (2.0 * u - w2)
        # stage 3
        t3 = tq + 0.5 * dt * d2t
        w3 = wq + 0.5 * dt * d2w
        tk = t3 + rad_offset
        d3t = (gh * (w3 - u) - inv_gd * (gc * (t3 - e_c) + rp * (tk * tk * tk * tk - e4))) * inv_c[p]
        d3w = kw[p] * (2.0 * u - w3)
        # stage 4
        t4 = tq + dt * d3t
        w4 = wq + dt * d3w
        tk = t4 + rad_offset
        d4t = (gh * (w4 - u) - inv_gd * (gc * (t4 - e_c) + rp * (tk * tk * tk * tk - e4))) * inv_c[p]
        d4w = kw[p] * (2.0 * u - w4)
        tn = tq + dt / 6.0 * (d1t + 2.0 * d2t + 2.0 * d3t + d4t)
        temp[p] = tn
        pade[p] = wq + dt / 6.0 * (d1w + 2.0 * d2w + 2.0 * d3w + d4w)
        probe[p] = probe[p] + lag_alpha[p] * (tn - probe[p])


def simulate_compiled(
    inputs: InputSeries,
    coeffs: Coefficients,
    dt_s: float,
    initial_cht_c: float | NDArray[np.float64],
    gamma_q: float | NDArray[np.float64] = 1.0,
    gamma_d: float | NDArray[np.float64] = 1.0,
    record_every: int = 1,
) -> CompiledRun:
    """Open-loop run over inputs sampled every dt_s (arrays of length N), like ``thermal.simulate``.

    coeffs may be one parameter set or a swarm (``stack_coefficients``); the output is (N_rec,) or
    (N_rec, P) with N_rec = ceil(N / record_every): sample r is the state after r*record_every steps.
    """
    n = int(np.size(inputs.heat_x))
    if n < 1:
        raise ValueError("simulate_compiled: empty input series")
    hx, hy, alt, air, oat = (np.ascontiguousarray(np.asarray(v, dtype=float).reshape(n)) for v in inputs)
    pressure = np.asarray(isa_pressure_pa(alt), dtype=float)
    log_pr = np.log(pressure / SEA_LEVEL_PRESSURE_PA)
    log_tr = np.log(SEA_LEVEL_TEMPERATURE_K / (oat + KELVIN_OFFSET))
    log_rho = np.log(np.asarray(air_density_kg_m3(pressure, oat), dtype=float))
    xb = np.ascontiguousarray(coeffs.x_breakpoints, dtype=float)
    yb = np.ascontiguousarray(coeffs.y_breakpoints, dtype=float)
    load = np.clip((hx - xb[0]) / (xb[-1] - xb[0]), 0.0, 1.0)
    swarm = np.ndim(coeffs.c_w) > 0
    n_particles = int(np.size(coeffs.c_w)) if swarm else 1
    theta = np.empty((len(_COLUMNS), n_particles))
    for row, name in enumerate(_COLUMNS):
        theta[row] = np.broadcast_to(np.asarray(getattr(coeffs, name), dtype=float), (n_particles,))
    heat = np.ascontiguousarray(
        np.broadcast_to(np.asarray(coeffs.heat_values_w, dtype=float), (n_particles, xb.size, yb.size))
    )
    t0 = np.ascontiguousarray(np.broadcast_to(np.asarray(initial_cht_c, dtype=float), (n_particles,)))
    g_q = np.ascontiguousarray(np.broadcast_to(np.asarray(gamma_q, dtype=float), (n,)))
    g_d = np.ascontiguousarray(np.broadcast_to(np.asarray(gamma_d, dtype=float), (n,)))
    drive_inputs = np.stack([hx, hy, log_pr, log_tr, oat, air, g_q])
    changed = np.ones(n, dtype=np.bool_)
    changed[1:] = np.any(drive_inputs[:, 1:] != drive_inputs[:, :-1], axis=0)
    n_rec = (n + record_every - 1) // record_every
    out_cht = np.empty((n_rec, n_particles))
    out_probe = np.empty((n_rec, n_particles))
    with np.errstate(all="ignore"):
        _kernel(
            hx, hy, log_pr, log_tr, oat, np.maximum(air, 0.0), log_rho, load, g_q, g_d, changed, xb, yb,
            np.ascontiguousarray(theta), heat, float(coeffs.radiation_offset_c), float(dt_s), t0,
            int(record_every), out_cht, out_probe,
        )  # fmt: skip
    bad = ~np.isfinite(out_probe) | (np.abs(out_probe) > 5000.0)
    failed: NDArray[np.bool_] = np.asarray(bad.any(axis=0))
    if failed.any():
        first_bad = np.where(bad.any(axis=0), bad.argmax(axis=0), n_rec)
        rows = np.arange(n_rec)[:, None]
        mask = rows >= first_bad[None, :]
        out_cht[mask] = np.nan
        out_probe[mask] = np.nan
    if not swarm:
        return CompiledRun(out_cht[:, 0], out_probe[:, 0], np.asarray(failed[0]))
    return CompiledRun(out_cht, out_probe, failed)
