"""Particle-swarm optimisation over the unit cube, the whole swarm evaluated in one call.

The paper's update, ``v = w v + c1 r1 (p_best - x) + c2 r2 (g_best - x)``, with the well-known
improvements as options (each measured in docs/results/identification.md):

- constriction (Clerc & Kennedy 2002): ``v = chi (v + c1 r1 (p - x) + c2 r2 (g - x))`` with
  ``chi = 2 / |2 - phi - sqrt(phi^2 - 4 phi)|``, ``phi = c1 + c2 > 4``; otherwise the inertia weight
  falls linearly from ``inertia[0]`` to ``inertia[1]`` over the run (Shi & Eberhart);
- velocity clamping to a fraction of the (unit) range per iteration;
- restarts: when the global best has not improved by ``stagnation_tolerance`` (relative) for
  ``stagnation_iterations`` iterations, every particle but the global best is scattered afresh
  (at most ``max_restarts`` times).

Positions leaving the cube are put back on the bound and that velocity component is zeroed. A
non-finite cost (a failed particle) never becomes a personal or global best; the caller counts it.
Everything random comes from one ``numpy.random.Generator`` seeded by ``seed``: same seed, same run.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import ParameterError
from ecu_monitor.identify.problem import IDENTIFICATION_DT_S

__all__ = ["PsoRun", "PsoSettings", "constriction_factor", "minimise"]


@dataclass(frozen=True)
class PsoSettings:
    """PSO settings (dimensionless unless stated).

    The defaults (inertia 0.9 -> 0.4, c1 = c2 = 1.5, velocity clamp 0.25, restarts after 25 stagnant
    iterations) gave the lowest PSO-alone cost of the variants measured in docs/results/identification.md;
    Clerc's constriction (constriction=True, c1 = c2 = 2.05) came close.

    particles, iterations: swarm size and number of swarm evaluations after the initial one.
    inertia: (start, end) inertia weight, linearly interpolated (used when constriction is off).
    cognitive, social: c1, c2 acceleration coefficients.
    constriction: use Clerc's constriction factor (needs c1 + c2 > 4) instead of the inertia weight.
    velocity_clamp: largest velocity per coordinate as a fraction of the range (None = no clamp).
    stagnation_iterations, stagnation_tolerance, max_restarts: restart rule (0 iterations = never).
    seed: random seed (reproducible runs).
    dt_s: integration step of the model inside identification, s (chosen by measured accuracy).
    polish: finish with scipy.optimize.least_squares from the best particle.
    polish_evaluations: largest number of residual evaluations of the polish (each with a Jacobian:
        cheap next to the swarm, and the polish is what converges in 20-30 dimensions).
    """

    particles: int = 48
    iterations: int = 120
    inertia: tuple[float, float] = (0.9, 0.4)
    cognitive: float = 1.5
    social: float = 1.5
    constriction: bool = False
    velocity_clamp: float | None = 0.25
    stagnation_iterations: int = 25
    stagnation_tolerance: float = 1e-4
    max_restarts: int = 2
    seed: int = 0
    dt_s: float = IDENTIFICATION_DT_S
    polish: bool = True
    polish_evaluations: int = 100

    def __post_init__(self) -> None:
        if isinstance(self.particles, bool) or not isinstance(self.particles, int) or self.particles < 2:
            raise ParameterError(f"particles: expected an integer >= 2, got {self.particles!r}")
        if isinstance(self.iterations, bool) or not isinstance(self.iterations, int) or self.iterations < 0:
            raise ParameterError(f"iterations: expected an integer >= 0, got {self.iterations!r}")
        if len(self.inertia) != 2 or not all(0.0 <= w <= 1.2 for w in self.inertia):
            raise ParameterError(f"inertia: expected (start, end) in [0, 1.2], got {self.inertia!r}")
        if not (0.0 <= self.cognitive <= 5.0 and 0.0 <= self.social <= 5.0):
            raise ParameterError("cognitive, social: expected values in [0, 5]")
        if self.constriction and self.cognitive + self.social <= 4.0:
            raise ParameterError("constriction: needs cognitive + social > 4 (e.g. 2.05 each)")
        if self.velocity_clamp is not None and not 0.0 < self.velocity_clamp <= 1.0:
            raise ParameterError(f"velocity_clamp: expected a fraction in (0, 1] or None, got {self.velocity_clamp!r}")
        if self.stagnation_iterations < 0 or self.max_restarts < 0 or self.stagnation_tolerance < 0:
            raise ParameterError("stagnation_iterations, max_restarts, stagnation_tolerance: expected >= 0")
        if not (math.isfinite(self.dt_s) and 0.0 < self.dt_s <= 5.0):
            raise ParameterError(f"dt_s: expected an integration step in (0, 5] s, got {self.dt_s!r}")
        if self.polish_evaluations < 1:
            raise ParameterError("polish_evaluations: expected >= 1")


def constriction_factor(cognitive: float, social: float) -> float:
    """Clerc's constriction factor chi for phi = c1 + c2 > 4 (0.7298 for 2.05 + 2.05)."""
    phi = cognitive + social
    return 2.0 / abs(2.0 - phi - math.sqrt(phi * phi - 4.0 * phi))


@dataclass(frozen=True)
class PsoRun:
    """Outcome of :func:`minimise`.

    best_unit: best point found (unit cube); best_cost: its cost.
    history: best cost after the initial evaluation and after each iteration (length iterations + 1).
    failed: number of particle evaluations with a non-finite cost; evaluations: particle evaluations.
    restarts: number of restarts made.
    """

    best_unit: NDArray[np.float64]
    best_cost: float
    history: tuple[float, ...]
    failed: int
    evaluations: int
    restarts: int


def minimise(
    cost: Callable[[NDArray[np.float64]], NDArray[np.float64]],
    dimension: int,
    settings: PsoSettings,
    initial: NDArray[np.float64] | None = None,
    progress: Callable[[int, float, float], None] | None = None,
) -> PsoRun:
    """Minimise ``cost`` over the unit cube [0, 1]^dimension.

    cost: maps a swarm (P, D) to costs (P,); non-finite = failed particle.
    initial: optional points (K, D) placed as the first particles (e.g. the base model); the rest are
    uniform random. progress(iteration, best_cost, elapsed_s) is called after every iteration.
    """
    if dimension < 1:
        raise ParameterError("PSO: nothing to optimise (dimension 0)")
    rng = np.random.default_rng(settings.seed)
    p, d = settings.particles, dimension
    start = time.perf_counter()
    x = rng.random((p, d))
    if initial is not None:
        seeds = np.clip(np.atleast_2d(np.asarray(initial, dtype=float)), 0.0, 1.0)[:p]
        x[: seeds.shape[0]] = seeds
    clamp = settings.velocity_clamp if settings.velocity_clamp is not None else math.inf
    v = np.clip(rng.uniform(-0.5, 0.5, (p, d)) * min(1.0, clamp), -clamp, clamp)
    chi = constriction_factor(settings.cognitive, settings.social) if settings.constriction else 1.0
    failed = 0
    evaluations = 0

    def evaluate(points: NDArray[np.float64]) -> NDArray[np.float64]:
        nonlocal failed, evaluations
        values = np.asarray(cost(points), dtype=float).reshape(points.shape[0])
        bad = ~np.isfinite(values)
        failed += int(bad.sum())
        evaluations += points.shape[0]
        return np.where(bad, np.inf, values)

    f = evaluate(x)
    p_best, p_cost = x.copy(), f.copy()
    g = int(np.argmin(p_cost))
    g_best, g_cost = p_best[g].copy(), float(p_cost[g])
    history = [g_cost]
    last_improved_cost, stagnant, restarts = g_cost, 0, 0
    for it in range(1, settings.iterations + 1):
        r1 = rng.random((p, d))
        r2 = rng.random((p, d))
        pull = settings.cognitive * r1 * (p_best - x) + settings.social * r2 * (g_best - x)
        if settings.constriction:
            v = chi * (v + pull)
        else:
            frac = (it - 1) / max(1, settings.iterations - 1)
            w = settings.inertia[0] + (settings.inertia[1] - settings.inertia[0]) * frac
            v = w * v + pull
        v = np.clip(v, -clamp, clamp)
        x = x + v
        outside = (x < 0.0) | (x > 1.0)
        x = np.clip(x, 0.0, 1.0)
        v[outside] = 0.0
        f = evaluate(x)
        better = f < p_cost
        p_best[better] = x[better]
        p_cost[better] = f[better]
        g = int(np.argmin(p_cost))
        if p_cost[g] < g_cost:
            g_best, g_cost = p_best[g].copy(), float(p_cost[g])
        history.append(g_cost)
        if g_cost < last_improved_cost * (1.0 - settings.stagnation_tolerance):
            last_improved_cost, stagnant = g_cost, 0
        else:
            stagnant += 1
        if (
            settings.stagnation_iterations
            and stagnant >= settings.stagnation_iterations
            and restarts < settings.max_restarts
            and it < settings.iterations
        ):
            restarts += 1
            stagnant = 0
            x = rng.random((p, d))
            x[0] = g_best
            v = np.clip(rng.uniform(-0.5, 0.5, (p, d)) * min(1.0, clamp), -clamp, clamp)
            p_best, p_cost = x.copy(), np.full(p, np.inf)
            p_best[0], p_cost[0] = g_best, g_cost
        if progress is not None:
            progress(it, g_cost, time.perf_counter() - start)
    return PsoRun(g_best, g_cost, tuple(history), failed, evaluations, restarts)
