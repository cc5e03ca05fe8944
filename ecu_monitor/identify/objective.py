"""The swarm cost of identification: RMS of simulated minus measured CHT over all flights, plus the prior."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.flightlog import FlightLog
from ecu_monitor.identify.flights import FlightGrid, prepare_flight, run_grid

if TYPE_CHECKING:
    from ecu_monitor.identify.problem import ParameterSpace
    from ecu_monitor.model import Coefficients

__all__ = ["SwarmObjective", "pooled_residuals"]


def pooled_residuals(
    grids: Sequence[FlightGrid], coefficients_of: Callable[[int], Coefficients]
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Simulated (probe) minus measured CHT of every flight side by side (P, samples of all flights), flight
    k simulated with ``coefficients_of(k)`` (a swarm of P), and the mask (P,) of particles not finite."""
    parts = []
    failed: NDArray[np.bool_] | None = None
    for k, grid in enumerate(grids):
        probe, bad = run_grid(grid, coefficients_of(k))
        parts.append(probe.T - grid.measured_c[None, :])
        failed = np.asarray(bad, dtype=bool) if failed is None else failed | np.asarray(bad, dtype=bool)
    residual = np.concatenate(parts, axis=1)
    return residual, np.asarray(failed) | ~np.all(np.isfinite(residual), axis=1)


class SwarmObjective:
    """Cost of a whole swarm at once: RMS of simulated (probe) minus measured CHT over all flights.

    ``costs(unit)`` takes points of the unit cube (P, D) and returns the cost of each (P,), with the
    prior penalty added inside the square root; a particle whose trajectory is not finite on any flight
    gets +inf and is counted in ``failed``. ``evaluations`` counts particle simulations (one particle
    over all flights = 1).
    """

    def __init__(self, flights: Sequence[FlightLog], space: ParameterSpace, dt_s: float, record_period_s: float = 1.0):
        self.space = space
        mixture = space.base.effects.mixture_index
        self.grids = [prepare_flight(log, space.base.heat_axes, dt_s, record_period_s, mixture) for log in flights]
        self.samples = int(sum(g.measured_c.size for g in self.grids))
        self.failed = 0
        self.evaluations = 0

    def residuals(self, unit: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """Simulated minus measured CHT (P, samples of all flights) and the failure mask (P,)."""
        unit = np.atleast_2d(unit)
        vectors = self.space.from_unit(unit)
        coeffs = self.space.coefficient_arrays(vectors)
        residual, failed = pooled_residuals(self.grids, lambda _flight: coeffs)
        self.evaluations += unit.shape[0]
        self.failed += int(failed.sum())
        return residual, failed

    def costs(self, unit: NDArray[np.float64]) -> NDArray[np.float64]:
        """Cost of each point (P,): sqrt(mean squared error + prior penalty), +inf for a failed particle."""
        residual, failed = self.residuals(unit)
        with np.errstate(invalid="ignore", over="ignore"):
            mse = np.mean(residual * residual, axis=1)
        cost = np.sqrt(mse + self.space.prior_penalty(self.space.from_unit(np.atleast_2d(unit))))
        cost[failed] = np.inf
        return cost
