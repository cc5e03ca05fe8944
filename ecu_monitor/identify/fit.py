"""identify(): PSO over the parameter space, then an optional least-squares polish.

The cost (RMS of simulated probe minus measured CHT over every training flight, initial state from
each flight's first sample) is evaluated for the whole swarm in one compiled simulation per flight.

Three first-order lags in series (the heat path's delay tau_w, the head's time constant C_w R_Ce and
the probe lag) are hard to tell apart from a CHT record, and one search can end in a wrong basin with
one of them at a bound (measured on the four N550ND flights: head 0.5 s, probe 60 s, 6-8 degC on its own
flights, where another seed finds 105 s, 24 s and 1.7-1.9 degC). When a time scale ends at a bound,
:func:`identify` searches once more from another seed and keeps the lower cost.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

from ecu_monitor.errors import ParameterError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.identify.objective import SwarmObjective
from ecu_monitor.identify.problem import (
    DEFAULT_FREE,
    ErrorStats,
    ParameterSpace,
    default_space,
    flight_errors,
)
from ecu_monitor.identify.pso import PsoRun, PsoSettings, minimise
from ecu_monitor.identify.search_settings import BOUND_TOLERANCE
from ecu_monitor.model import ThermalParams

__all__ = ["IdentificationResult", "identify", "one_blas_thread", "polish"]

#: Finite-difference step of the polish's Jacobian, in unit-cube coordinates.
_FD_STEP = 1e-4


@dataclass(frozen=True)
class IdentificationResult:
    """Outcome of :func:`identify`.

    params: the identified model.
    cost_history: best cost (RMS error, degC, plus any prior penalty) after the initial swarm and after
        each PSO iteration; the polish's final cost is ``polish_cost``.
    failed_particles: particle simulations whose trajectory was not finite (excluded, counted).
    evaluations: particle simulations over all training flights (PSO + polish).
    train_errors: errors of the identified model on each training flight (reference step 0.02 s).
    elapsed_s: wall time of the identification, s.
    space: the parameter space searched; best_vector: the identified coordinates.
    best_cost: final cost (after the polish if any); restarts: PSO restarts made.
    at_bounds: coordinates that ended within 1 % of a bound (readable lines; empty = none).
    """

    params: ThermalParams
    cost_history: tuple[float, ...]
    failed_particles: int
    evaluations: int
    train_errors: list[ErrorStats]
    elapsed_s: float
    space: ParameterSpace
    best_vector: NDArray[np.float64]
    best_cost: float
    pso_cost: float
    polish_cost: float | None
    restarts: int
    at_bounds: tuple[str, ...] = ()


def one_blas_thread() -> threadpool_limits:
    """A context in which BLAS and LAPACK (numpy's and scipy's OpenBLAS) run on one thread, for least squares:
    its SVD of the tall Jacobian (every sample x the free parameters) took several times the CPU and the wall
    time on two threads as on one, alone or beside the other fits (docs/results/gap_real.md); the fits use
    the cores as processes (:mod:`ecu_monitor.identify.parallel`)."""
    return threadpool_limits(limits=1)


def polish(
    objective: SwarmObjective, start_unit: NDArray[np.float64], max_evaluations: int
) -> tuple[NDArray[np.float64], float]:
    """scipy least_squares (trust-region reflective, bounds = the unit cube) from ``start_unit``.

    Residuals are the per-sample errors / sqrt(N) plus the prior terms, so their sum of squares is the
    PSO cost squared. The Jacobian is by forward differences, all D columns simulated in one swarm call.
    Returns (best point, its cost).
    """
    space = objective.space
    n = objective.samples

    def residuals_of(unit: NDArray[np.float64]) -> NDArray[np.float64]:
        res, failed = objective.residuals(unit)
        prior = space.prior_residual_matrix(space.from_unit(np.atleast_2d(unit)))
        out = np.concatenate([res / np.sqrt(n), prior], axis=1)
        out[failed] = np.nan
        return out

    def fun(u: NDArray[np.float64]) -> NDArray[np.float64]:
        return residuals_of(u[None, :])[0]

    def jac(u: NDArray[np.float64]) -> NDArray[np.float64]:
        d = u.size
        step = np.where(u + _FD_STEP <= 1.0, _FD_STEP, -_FD_STEP)
        points = np.repeat(u[None, :], d + 1, axis=0)
        points[1:][np.arange(d), np.arange(d)] += step
        values = residuals_of(points)
        jacobian = (values[1:] - values[0]) / step[:, None]
        return np.nan_to_num(jacobian.T, nan=0.0, posinf=0.0, neginf=0.0)

    start = np.clip(start_unit, 0.0, 1.0)
    start_res = fun(start)
    start_cost = float(np.sqrt(np.sum(start_res**2)))
    if not np.all(np.isfinite(start_res)):
        return start, start_cost
    with one_blas_thread():
        solution = least_squares(fun, start, jac=jac, bounds=(0.0, 1.0), method="trf", max_nfev=max_evaluations)
    cost = float(np.sqrt(2.0 * solution.cost))
    if not np.isfinite(cost) or cost >= start_cost:
        return start, start_cost
    return np.asarray(solution.x), cost


#: Coordinates whose bound, when hit, sends identification to a second search (:func:`identify`).
TIME_SCALES: tuple[str, ...] = ("time_constant_s", "tau_w", "effects.sensor_lag.time_constant_s")


def _time_scale_at_bound(space: ParameterSpace, unit: NDArray[np.float64]) -> bool:
    """Whether the head's time constant, the heat-path delay or the probe lag ended within 1 % of a
    bound (a probe lag of 0, no lag, is a legitimate answer and does not count)."""
    for k, name in enumerate(space.names):
        if name in TIME_SCALES and (unit[k] >= 1.0 - BOUND_TOLERANCE or (
            unit[k] <= BOUND_TOLERANCE and name != "effects.sensor_lag.time_constant_s")):  # fmt: skip
            return True
    return False


def _search(
    objective: SwarmObjective,
    space: ParameterSpace,
    settings: PsoSettings,
    initial: NDArray[np.float64],
    progress: Callable[[int, float, float], None] | None,
) -> tuple[PsoRun, NDArray[np.float64], float, float | None]:
    """PSO from ``initial`` plus the least-squares polish: (PSO run, best point, its cost, polish cost)."""
    run = minimise(objective.costs, space.dimension, settings, initial=initial, progress=progress)
    best_unit, best_cost = run.best_unit, run.best_cost
    polish_cost: float | None = None
    if settings.polish and np.isfinite(best_cost):
        best_unit, best_cost = polish(objective, best_unit, settings.polish_evaluations)
        polish_cost = best_cost
    return run, best_unit, float(best_cost), polish_cost


def identify(
    flights: Sequence[FlightLog],
    *,
    base: ThermalParams | None = None,
    heat_axes: tuple[str, str] = ("throttle_pct", "rpm"),
    space: ParameterSpace | None = None,
    settings: PsoSettings | None = None,
    progress: Callable[[int, float, float], None] | None = None,
    free: Sequence[str] = DEFAULT_FREE,
    grid: tuple[int, int] | None = None,
) -> IdentificationResult:
    """Identify the thermal model on one or more flights (see the module doc).

    base: starting/fixed values (default: the paper's Table A1); space: the search space (default:
    :func:`default_space` of the flights, the base and heat_axes); settings: default PsoSettings().
    The base model's coordinates are placed as one particle of the initial swarm. free and grid
    (see :func:`default_space`) apply only when no space is given.
    """
    if not flights:
        raise ParameterError("identification needs at least one flight")
    settings = PsoSettings() if settings is None else settings
    started = time.perf_counter()
    if space is None:
        axes = (heat_axes[0], heat_axes[1])
        space = default_space(flights, base=base, heat_axes=axes, grid=grid, free=free)
    objective = SwarmObjective(flights, space, settings.dt_s)
    initial = space.to_unit(space.from_params(space.base))[None, :]
    run, best_unit, best_cost, polish_cost = _search(objective, space, settings, initial, progress)
    if _time_scale_at_bound(space, best_unit):
        # a time scale at its bound is the mark of a wrong basin (three lags in series: heat path,
        # head, probe); search once more from another seed and keep the lower cost
        retry = _search(objective, space, replace(settings, seed=settings.seed + 1), initial, progress)
        if retry[2] < best_cost:
            run, best_unit, best_cost, polish_cost = retry
        if settings.polish:
            # and the start (the base, its effects at their start rules) polished: both swarms can settle in a
            # broad basin a physical start does not lie in (a propeller wash at the cruise speed that switches
            # the airspeed term off, docs/results/identification.md)
            start_unit, start_cost = polish(objective, initial[0], settings.polish_evaluations)
            if start_cost < best_cost:
                best_unit, best_cost, polish_cost = start_unit, start_cost, start_cost
    if not np.isfinite(best_cost):
        raise ParameterError(
            f"identification failed: every one of {objective.evaluations} particle simulations diverged;"
            " check the flight's units and the bounds"
        )
    vector = space.from_unit(best_unit)
    params = space.to_params(vector)
    train = [flight_errors(params, log) for log in flights]
    return IdentificationResult(
        params=params,
        cost_history=run.history,
        failed_particles=objective.failed,
        evaluations=objective.evaluations,
        train_errors=train,
        elapsed_s=time.perf_counter() - started,
        space=space,
        best_vector=vector,
        best_cost=float(best_cost),
        pso_cost=float(run.best_cost),
        polish_cost=polish_cost,
        restarts=run.restarts,
        at_bounds=tuple(space.at_bounds(vector)),
    )
