"""Compiled (numba) twin of :func:`ecu_monitor.model.thermal.simulate` for long flights and swarms.

The kernel below is only a loop: time outer, particles inner over contiguous per-particle arrays (so
numba vectorises the RK4 across particles). Every equation it runs (the drive with its effects, the
heat balance, RK4, the probe lag) is a compiled twin of :mod:`ecu_monitor.model.equations`
(:func:`ecu_monitor.model.kernels.compiled_equations`), so it equals :func:`thermal.simulate` to
round-off (tested). Used by PSO identification (a whole swarm per call), the gap diagnosis (many
refits) and long replays.

Failures are reported, never hidden: a particle whose trajectory leaves the finite range is flagged
in the returned ``failed`` mask and its trajectory is NaN from then on.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.model import equations as _eq
from ecu_monitor.model.equations import C_W, PARAMETER_FIELDS, RADIATIVE, SENSOR_LAG, TAU_W, Coefficients
from ecu_monitor.model.kernels import SWARM_FASTMATH, compiled_equations, fingerprint, jit
from ecu_monitor.model.thermal import Drive, InputSeries

__all__ = ["CompiledRun", "compute_drive_compiled", "drive_kernel", "simulate_compiled", "simulate_held"]


class CompiledRun(NamedTuple):
    """Result of :func:`simulate_compiled`: sampled trajectories and a failure mask."""

    cht_c: NDArray[np.float64]  # (N_rec,) or (N_rec, P): true head temperature, degC
    probe_c: NDArray[np.float64]  # same shape: what the (possibly lagging) probe reads, degC
    failed: NDArray[np.bool_]  # () or (P,): trajectory became non-finite


def _heat_cell(x: float, y: float, xb: NDArray[np.float64], yb: NDArray[np.float64]) -> tuple[int, int, float, float]:
    """The heat-map cell of the point (x, y), clamped to the breakpoints ``xb``, ``yb``: its lower corner
    (i, j) and the fractions (fx, fy) in [0, 1] across it, for :func:`equations.blend`. Inlined into every
    kernel that reads the heat map (numba ``inline="always"``), so each does the same arithmetic."""
    nx = xb.shape[0]
    ny = yb.shape[0]
    x = min(max(x, xb[0]), xb[nx - 1])
    y = min(max(y, yb[0]), yb[ny - 1])
    i = 0
    while i < nx - 2 and x >= xb[i + 1]:
        i += 1
    j = 0
    while j < ny - 2 and y >= yb[j + 1]:
        j += 1
    return i, j, (x - xb[i]) / (xb[i + 1] - xb[i]), (y - yb[j]) / (yb[j + 1] - yb[j])


def _swarm_kernel(
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
                            log_temperature_ratio[k], log_density[k], airspeed[k], load[k], mixture[k],
                            theta)  # fmt: skip
        if k % record_every == 0:
            row = k // record_every
            out_cht[row, :] = temp
            out_probe[row, :] = probe
        particles_step(temp, pade, probe, q0, gain, cond, c_w, tau, rad, fraction, ambient[k], offset, gamma_q[k],
                       gamma_d[k], dt)  # fmt: skip


def _held_kernel(
    heat_x: NDArray[np.float64],
    heat_y: NDArray[np.float64],
    log_pressure_ratio: NDArray[np.float64],
    log_temperature_ratio: NDArray[np.float64],
    log_density: NDArray[np.float64],
    airspeed: NDArray[np.float64],
    load: NDArray[np.float64],
    mixture: NDArray[np.float64],
    ambient: NDArray[np.float64],
    steps: NDArray[np.int64],
    xb: NDArray[np.float64],
    yb: NDArray[np.float64],
    theta: NDArray[np.float64],
    heat: NDArray[np.float64],
    offset: float,
    gamma_q: float,
    gamma_d: float,
    dt: float,
    t0: NDArray[np.float64],
    out_cht: NDArray[np.float64],
    out_first_bad: NDArray[np.int64],
) -> None:
    """:func:`_swarm_kernel` with the inputs held over ``steps[c]`` steps from each call c, recorded at
    the calls only (out_cht[c]: particle 0 when call c is reached): the same arithmetic without an input
    array per step. Written as the swarm kernel is (the particle loop, the gammas as arguments) so that
    the compiler folds and contracts the same way: equal to it bit for bit (tested; a constant gamma of
    1 or a drive outside the particle loop changed the last bit). out_first_bad[0]: the first step whose
    probe value is not finite or beyond 5000 degC (-1: none), the failure test of
    :func:`simulate_compiled` at every step."""
    c_w, tau, rad, fraction, temp, probe, pade, q0, gain, cond = particles_start(theta, t0, dt)
    k = 0
    for c in range(steps.shape[0]):
        i, j, fx, fy = heat_cell(heat_x[c], heat_y[c], xb, yb)
        particles_drive(q0, gain, cond, pade, c == 0, heat, i, j, fx, fy, log_pressure_ratio[c],
                        log_temperature_ratio[c], log_density[c], airspeed[c], load[c], mixture[c], theta)  # fmt: skip
        out_cht[c] = temp[0]
        for _ in range(steps[c]):
            if out_first_bad[0] < 0 and not abs(probe[0]) <= 5000.0:
                out_first_bad[0] = k
            particles_step(temp, pade, probe, q0, gain, cond, c_w, tau, rad, fraction, ambient[c], offset, gamma_q,
                           gamma_d, dt)  # fmt: skip
            k += 1


def _particles_start(theta: NDArray[np.float64], t0: NDArray[np.float64], dt: float) -> tuple[Any, ...]:
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


def _particles_drive(
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
    mixture: float,
    theta: NDArray[np.float64],
) -> None:
    """Each particle's drive at one operating point, in place: q0 (W) blended in the heat-map cell
    (i, j, fx, fy), gain = g(z) x heat factor, cond (W/degC); on the ``first`` step the Pade state too."""
    for p in range(theta.shape[0]):
        q0[p] = blend(heat[p, i, j], heat[p, i, j + 1], heat[p, i + 1, j], heat[p, i + 1, j + 1], fx, fy)
        altitude_gain, heat_factor, conductance = drive(
            log_pressure_ratio, log_temperature_ratio, log_density, airspeed, load, mixture, theta[p]
        )
        gain[p] = altitude_gain * heat_factor
        cond[p] = conductance
        if first:
            pade[p] = 2.0 * q0[p]


def _particles_step(
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


def _drive_kernel(
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
    xb = coeffs.x_breakpoints
    yb = coeffs.y_breakpoints
    v = coeffs.heat_values_w
    nx = xb.shape[0]
    for k in range(heat_x.shape[0]):
        i, j, fx, fy = heat_cell(heat_x[k], heat_y[k], xb, yb)
        out[0, k] = blend(v[i, j], v[i, j + 1], v[i + 1, j], v[i + 1, j + 1], fx, fy)
        lpr, ltr, lrho, air, load = conditions(heat_x[k], altitude_m[k], airspeed_mps[k], oat_c[k], xb[0], xb[nx - 1])
        out[1, k], out[2, k], out[3, k] = drive(lpr, ltr, lrho, air, load, mixture[k], coeffs)


# Names the kernels call; _kernel(), _held() and _drive() bind them to the compiled equations.
heat_cell: Any = None
blend: Any = None
drive: Any = None
rk4: Any = None
lag_fraction: Any = None
probe_step: Any = None
conditions: Any = None
particles_step: Any = None
particles_start: Any = None
particles_drive: Any = None


def _swarm_callees(tag: str) -> dict[str, Any]:
    """The names the swarm and held kernels call, bound to the equations' numba twins compiled with
    :data:`SWARM_FASTMATH` (one set for both, so both do the same arithmetic)."""
    eq = compiled_equations(SWARM_FASTMATH)
    fast = set(SWARM_FASTMATH)
    return {
        "particles_step": jit(_particles_step, tag, fastmath=fast, rk4=eq.rk4, probe_step=eq.probe_step),
        "heat_cell": jit(_heat_cell, f"{tag}_swarm", fastmath=fast, inline="always"),
        "particles_drive": jit(_particles_drive, tag, fastmath=fast, inline="always", blend=eq.blend, drive=eq.drive),
        "particles_start": jit(_particles_start, tag, fastmath=fast, inline="always", lag_fraction=eq.lag_fraction),
        "blend": eq.blend,
        "drive": eq.drive,
        "rk4": eq.rk4,
        "lag_fraction": eq.lag_fraction,
        "probe_step": eq.probe_step,
    }


@functools.cache
def _kernel() -> Callable[..., None]:
    """The swarm kernel compiled with the equations' numba twins (cached on disk)."""
    tag = fingerprint([__file__])
    return jit(_swarm_kernel, tag, fastmath=set(SWARM_FASTMATH), **_swarm_callees(tag))


@functools.cache
def _held() -> Callable[..., None]:
    """:func:`_held_kernel` compiled as :func:`_kernel` (the same equations and flags; cached on disk)."""
    tag = fingerprint([__file__])
    return jit(_held_kernel, tag, fastmath=set(SWARM_FASTMATH), **_swarm_callees(tag))


@functools.cache
def _drive() -> Callable[..., None]:
    """The drive kernel compiled with the exact (IEEE) equations: equal bit for bit to the scalar path."""
    eq = compiled_equations(False)
    tag = fingerprint([__file__])
    cell = jit(_heat_cell, f"{tag}_exact", inline="always")
    return jit(_drive_kernel, tag, heat_cell=cell, blend=eq.blend, conditions=eq.conditions, drive=eq.drive)


def drive_kernel() -> Callable[..., None]:
    """The compiled drive kernel ``(heat_x, heat_y, altitude_m, airspeed_mps, oat_c, mixture, coeffs, out)``
    (arrays of length N; out (4, N): q_sl0, g(z), heat factor, G), for compiled callers such as the
    live filter step."""
    return _drive()


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
    kernel: Any = _drive()
    kernel(hx, hy, alt, air, oat, mix, coeffs, out)
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
    kernel: Any = _kernel()
    with np.errstate(all="ignore"):
        kernel(
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


def simulate_held(
    inputs: InputSeries, steps: NDArray[np.int64], coeffs: Coefficients, dt_s: float, initial_cht_c: float
) -> NDArray[np.float64]:
    """:func:`simulate_compiled` of one parameter set over inputs held between calls, taken at the calls.

    ``inputs``: one value per call (arrays of length C); ``steps[c]``: the steps of dt_s call c's inputs
    hold for. Equal bit for bit to ``simulate_compiled`` over the per-step inputs (each call's repeated
    ``steps[c]`` times) taken at the steps the calls fall on (its failure mask included: NaN from the
    first step whose probe value is not finite or beyond 5000 degC), without the per-step arrays
    (the replay's open-loop reference: 16 h, 2.9 M steps, 0.29 M calls)."""
    count = int(np.size(steps))
    if count < 1:
        raise ValueError("simulate_held: no calls")
    hx, hy, alt, air, oat, mix = (
        np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=float), (count,))) for v in inputs
    )
    xb = np.ascontiguousarray(coeffs.x_breakpoints, dtype=float)
    yb = np.ascontiguousarray(coeffs.y_breakpoints, dtype=float)
    conditions = [np.ascontiguousarray(v) for v in _eq.conditions(hx, alt, air, oat, float(xb[0]), float(xb[-1]))]
    theta = np.empty((1, len(PARAMETER_FIELDS)))
    for column, name in enumerate(PARAMETER_FIELDS):
        theta[0, column] = float(getattr(coeffs, name))
    heat = np.ascontiguousarray(np.asarray(coeffs.heat_values_w, dtype=float)[None, :, :])
    held = np.ascontiguousarray(steps, dtype=np.int64)
    out_cht = np.empty(count)
    first_bad = np.full(1, -1, dtype=np.int64)
    kernel: Any = _held()
    with np.errstate(all="ignore"):
        kernel(hx, hy, *conditions, mix, oat, held, xb, yb, theta, heat, float(coeffs.radiation_offset_c), 1.0, 1.0,
               float(dt_s), np.array([float(initial_cht_c)]), out_cht, first_bad)  # fmt: skip
    if first_bad[0] >= 0:
        at = np.cumsum(held) - held  # the step each call falls on
        out_cht[at >= first_bad[0]] = np.nan
    return out_cht
