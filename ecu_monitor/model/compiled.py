"""Compiled (numba) twin of :func:`ecu_monitor.model.thermal.simulate` for long flights and swarms.

The kernel below is only a loop: time outer, particles inner over contiguous per-particle arrays (so
numba vectorises the RK4 across particles). Every equation it runs (the drive with its effects, the
heat balance, RK4, the probe lag) is a compiled twin of :mod:`ecu_monitor.model.equations`
(``register_jitable``, inlined with the kernel's fast-math flags), so it equals :func:`thermal.simulate` to
round-off (tested). Used by PSO identification (a whole swarm per call), the gap diagnosis (many
refits) and long replays.

Failures are reported, never hidden: a particle whose trajectory leaves the finite range is flagged
in the returned ``failed`` mask and its trajectory is NaN from then on.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numba.extending import register_jitable
from numpy.typing import NDArray

from ecu_monitor.model import equations as _eq
from ecu_monitor.model.equations import (
    C_W,
    PARAMETER_FIELDS,
    RADIATIVE,
    SENSOR_LAG,
    TAU_W,
    Coefficients,
    blend,
    drive,
    lag_fraction,
    probe_step,
    rk4,
)
from ecu_monitor.model.heatmap import heat_cell
from ecu_monitor.model.kernels import SWARM_FASTMATH, njit
from ecu_monitor.model.thermal import Drive, InputSeries, drive_at

__all__ = ["CompiledRun", "compute_drive_compiled", "drive_kernel", "simulate_compiled"]


class CompiledRun(NamedTuple):
    """Result of :func:`simulate_compiled`: sampled trajectories and a failure mask."""

    cht_c: NDArray[np.float64]  # (N_rec,) or (N_rec, P): true head temperature, degC
    probe_c: NDArray[np.float64]  # same shape: what the (possibly lagging) probe reads, degC
    failed: NDArray[np.bool_]  # () or (P,): trajectory became non-finite


@njit(fastmath=SWARM_FASTMATH)
def swarm_kernel(
    heat_x: NDArray[np.float64],
    heat_y: NDArray[np.float64],
    log_pressure_ratio: NDArray[np.float64],
    log_temperature_ratio: NDArray[np.float64],
    log_density: NDArray[np.float64],
    airspeed: NDArray[np.float64],
    load: NDArray[np.float64],
    mixture: NDArray[np.float64],
    ambient: NDArray[np.float64],
    gamma_q: NDArray[np.float64],
    gamma_d: NDArray[np.float64],
    changed: NDArray[np.bool_],
    xb: NDArray[np.float64],
    yb: NDArray[np.float64],
    theta: NDArray[np.float64],
    heat: NDArray[np.float64],
    offset: float,
    dt: float,
    t0: NDArray[np.float64],
    record_every: int,
    out_cht: NDArray[np.float64],
    out_probe: NDArray[np.float64],
) -> None:
    """Every particle over every step: the drive where an input changed, then RK4 and the probe lag.

    theta: (P, len(PARAMETER_FIELDS)) coefficients, one contiguous row per particle; heat (P, n, m).
    Row r of out_* is the state after r * record_every steps.
    """
    n_steps = heat_x.shape[0]
    c_w, tau, rad, fraction, temp, probe, pade, q0, gain, cond = particles_start(theta, t0, dt)
    for k in range(n_steps):
        if changed[k]:
            # the heat-map cell shared by every particle at this step
            i, j, fx, fy = heat_cell(heat_x[k], heat_y[k], xb, yb)
            particles_drive(q0, gain, cond, pade, k == 0, heat, i, j, fx, fy, log_pressure_ratio[k],
                            log_temperature_ratio[k], log_density[k], airspeed[k], load[k], heat_y[k], mixture[k],
                            theta)  # fmt: skip
        if k % record_every == 0:
            row = k // record_every
            out_cht[row, :] = temp
            out_probe[row, :] = probe
        particles_step(temp, pade, probe, q0, gain, cond, c_w, tau, rad, fraction, ambient[k], offset, gamma_q[k],
                       gamma_d[k], dt)  # fmt: skip


@register_jitable(inline="always")
def particles_start(theta: NDArray[np.float64], t0: NDArray[np.float64], dt: float) -> tuple[Any, ...]:
    """The per-particle arrays the swarm and held kernels step: the constants C_w, tau_w, the radiative
    coefficient and the probe's lag fraction over ``dt`` (s) from ``theta``; the head and probe
    temperatures from ``t0`` (degC); the Pade state, q0, gain and conductance, filled by the first drive."""
    n_particles = theta.shape[0]
    fraction = np.empty(n_particles)
    for p in range(n_particles):
        fraction[p] = lag_fraction(theta[p, SENSOR_LAG], dt)
    return (
        theta[:, C_W].copy(),
        theta[:, TAU_W].copy(),
        theta[:, RADIATIVE].copy(),
        fraction,
        t0.copy(),
        t0.copy(),
        np.empty(n_particles),
        np.empty(n_particles),
        np.empty(n_particles),
        np.empty(n_particles),
    )


@register_jitable(inline="always")
def particles_drive(
    q0: NDArray[np.float64],
    gain: NDArray[np.float64],
    cond: NDArray[np.float64],
    pade: NDArray[np.float64],
    first: bool,
    heat: NDArray[np.float64],
    i: int,
    j: int,
    fx: float,
    fy: float,
    log_pressure_ratio: float,
    log_temperature_ratio: float,
    log_density: float,
    airspeed: float,
    load: float,
    engine_speed: float,
    mixture: float,
    theta: NDArray[np.float64],
) -> None:
    """Each particle's drive at one operating point, in place: q0 (W) blended in the heat-map cell
    (i, j, fx, fy), gain = g(z) x heat factor, cond (W/degC); on the ``first`` step the Pade state too."""
    for p in range(theta.shape[0]):
        q0[p] = blend(heat[p, i, j], heat[p, i, j + 1], heat[p, i + 1, j], heat[p, i + 1, j + 1], fx, fy)
        altitude_gain, heat_factor, conductance = drive(
            log_pressure_ratio, log_temperature_ratio, log_density, airspeed, load, engine_speed, mixture, theta[p]
        )
        gain[p] = altitude_gain * heat_factor
        cond[p] = conductance
        if first:
            pade[p] = 2.0 * q0[p]


@njit(fastmath=SWARM_FASTMATH)
def particles_step(
    temp: NDArray[np.float64],
    pade: NDArray[np.float64],
    probe: NDArray[np.float64],
    q0: NDArray[np.float64],
    gain: NDArray[np.float64],
    cond: NDArray[np.float64],
    c_w: NDArray[np.float64],
    tau: NDArray[np.float64],
    rad: NDArray[np.float64],
    fraction: NDArray[np.float64],
    ambient: float,
    offset: float,
    gamma_q: float,
    gamma_d: float,
    dt: float,
) -> None:
    """One RK4 step and probe-lag step of every particle with the drive held (the hot loop)."""
    for p in range(temp.shape[0]):
        t, w = rk4(temp[p], pade[p], q0[p], gain[p], ambient, cond[p], c_w[p], tau[p], rad[p], offset, gamma_q,
                   gamma_d, dt)  # fmt: skip
        temp[p] = t
        pade[p] = w
        probe[p] = probe_step(probe[p], t, fraction[p])


@njit()
def drive_kernel(
    heat_x: NDArray[np.float64],
    heat_y: NDArray[np.float64],
    altitude_m: NDArray[np.float64],
    airspeed_mps: NDArray[np.float64],
    oat_c: NDArray[np.float64],
    mixture: NDArray[np.float64],
    coeffs: Any,
    out: NDArray[np.float64],
) -> None:
    """The drive of one parameter set at every step (rows of out: q_sl0, g(z), heat factor, G)."""
    for k in range(heat_x.shape[0]):
        u = (heat_x[k], heat_y[k], altitude_m[k], airspeed_mps[k], oat_c[k], mixture[k])
        q_sl0, altitude_gain, _, conductance, heat_gain = drive_at(u, coeffs)
        out[0, k] = q_sl0
        out[1, k] = altitude_gain
        out[2, k] = heat_gain
        out[3, k] = conductance


def compute_drive_compiled(inputs: InputSeries, coeffs: Coefficients) -> Drive:
    """:func:`ecu_monitor.model.compute_drive` of one parameter set over N steps, compiled.

    Each step equals the scalar path of ``compute_drive`` bit for bit (same equations, same math
    library), so a filter run over a whole flight matches the live filter stepping through it.
    ``coeffs`` must hold floats (``ecu_monitor.estimation.ekf.scalar_coefficients``).
    """
    n = int(np.size(inputs.heat_x))
    hx, hy, alt, air, oat, mix = (
        np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=float), (n,))) for v in inputs
    )
    out = np.empty((4, n))
    drive_kernel(hx, hy, alt, air, oat, mix, coeffs, out)
    return Drive(out[0], out[1], oat, out[3], out[2])


def _same(values: NDArray[np.float64]) -> NDArray[np.bool_]:
    """values[k] == values[k-1] for k >= 1, NaN equal to NaN."""
    a, b = values[1:], values[:-1]
    return (a == b) | (np.isnan(a) & np.isnan(b))


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
    hx, hy, alt, air, oat, mix = (
        np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=float), (n,))) for v in inputs
    )
    xb = np.ascontiguousarray(coeffs.x_breakpoints, dtype=float)
    yb = np.ascontiguousarray(coeffs.y_breakpoints, dtype=float)
    conditions = [np.ascontiguousarray(v) for v in _eq.conditions(hx, alt, air, oat, float(xb[0]), float(xb[-1]))]
    swarm = np.ndim(coeffs.c_w) > 0
    n_particles = int(np.size(coeffs.c_w)) if swarm else 1
    theta = np.empty((n_particles, len(PARAMETER_FIELDS)))
    for column, name in enumerate(PARAMETER_FIELDS):
        theta[:, column] = np.broadcast_to(np.asarray(getattr(coeffs, name), dtype=float), (n_particles,))
    heat = np.ascontiguousarray(
        np.broadcast_to(np.asarray(coeffs.heat_values_w, dtype=float), (n_particles, xb.size, yb.size))
    )
    t0 = np.ascontiguousarray(np.broadcast_to(np.asarray(initial_cht_c, dtype=float), (n_particles,)))
    g_q = np.ascontiguousarray(np.broadcast_to(np.asarray(gamma_q, dtype=float), (n,)))
    g_d = np.ascontiguousarray(np.broadcast_to(np.asarray(gamma_d, dtype=float), (n,)))
    changed = np.ones(n, dtype=np.bool_)
    for values in (hx, hy, alt, air, oat, mix):
        changed[1:] &= _same(values)
    changed[1:] = ~changed[1:]
    n_rec = (n + record_every - 1) // record_every
    out_cht = np.empty((n_rec, n_particles))
    out_probe = np.empty((n_rec, n_particles))
    with np.errstate(all="ignore"):
        swarm_kernel(
            hx, hy, *conditions, mix, oat, g_q, g_d, changed, xb, yb, theta, heat, float(coeffs.radiation_offset_c),
            float(dt_s), t0, int(record_every), out_cht, out_probe,
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
