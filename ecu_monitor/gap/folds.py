"""One nominal model per held-out flight: by its own swarm, or warm-started from the identification on
every flight.

A leave-one-out without ``--model`` needs, for each flight k, a nominal model that has not seen flight
k. ``gap --leave-one-out`` gives each fold its own swarm on the other flights (:func:`swarm_nominals`,
the swarms at once on every core); the model on every flight, which no held-out figure uses (model.yaml,
the train baseline), is the first fold's re-identified on all of them by the joint least squares. The
inner leave-one-out of ``gap --choose-on-train`` warm-starts the folds instead (:func:`fold_nominals`):
the swarm runs once, on every flight, and each fold's nominal model is that fit re-identified on the
fold's own flights by the joint least squares the candidate refits use
(:data:`ecu_monitor.gap.diagnosis.JOINT_REFIT`: the warm start polished over the whole search space).

What the warm start knows of flight k is taken out first: the heat-map breakpoints the fold's flights
do not visit (under ``MIN_VISIT_S`` of bilinear weight) would keep values fitted to flight k alone, so
they copy their nearest visited breakpoint before the polish. The polish is local: what it keeps of
the start beyond that is the basin it converges in: on the real N550ND flights that kept part of
flight k (its held-out baseline moved towards it, docs/results/gap_real.md), so this serves a choice
among candidates, not a held-out figure to report.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ecu_monitor.flightlog import FlightLog
from ecu_monitor.gap.diagnosis import JOINT_REFIT
from ecu_monitor.identify import identify
from ecu_monitor.identify.heat_grid import visited_weight_s
from ecu_monitor.identify.parallel import run_tasks
from ecu_monitor.identify.pso import PsoSettings
from ecu_monitor.identify.search_settings import MIN_VISIT_S
from ecu_monitor.model import ThermalParams

__all__ = ["fold_nominals", "forget_unvisited", "swarm_nominals"]


def forget_unvisited(params: ThermalParams, logs: Sequence[FlightLog]) -> ThermalParams:
    """``params`` with every heat-map breakpoint ``logs`` do not visit (< ``MIN_VISIT_S`` s of bilinear
    weight) set to the value of the nearest visited one (grid distance): nothing is left that only
    another flight could have fitted."""
    heat_map = params.heat_map
    visited = visited_weight_s(logs, heat_map) >= MIN_VISIT_S
    if visited.all() or not visited.any():
        return params
    values = heat_map.values_array().copy()
    kept = np.argwhere(visited)
    for i, j in np.argwhere(~visited):
        nearest = kept[int(np.argmin((kept[:, 0] - i) ** 2 + (kept[:, 1] - j) ** 2))]
        values[i, j] = values[nearest[0], nearest[1]]
    return params.replace(heat_map=heat_map.with_values(values))


@dataclass(frozen=True)
class _FoldWork:
    """What every fold task reads (a forked worker inherits it)."""

    logs: tuple[FlightLog, ...]
    start: ThermalParams
    pso: PsoSettings


def _fold_task(work: _FoldWork, k: int) -> ThermalParams:
    others = [log for i, log in enumerate(work.logs) if i != k]
    start = forget_unvisited(work.start, others)
    return identify(others, base=start, heat_axes=start.heat_axes, settings=work.pso).params


def fold_nominals(
    logs: Sequence[FlightLog],
    identified: ThermalParams,
    pso: PsoSettings,
    progress: Callable[[str], None] | None = None,
) -> list[ThermalParams]:
    """For each flight k, ``identified`` (the fit on every flight) re-identified on the others with
    ``pso`` (the module doc; the folds on every core)."""
    work = _FoldWork(tuple(logs), identified, pso)
    return run_tasks(_fold_task, work, range(len(logs)), "fold nominal models (warm-started)", progress)


@dataclass(frozen=True)
class _SwarmWork:
    """What every swarm task reads (a forked worker inherits it)."""

    logs: tuple[FlightLog, ...]
    heat_axes: tuple[str, str]
    pso: PsoSettings


def _swarm_task(work: _SwarmWork, k: int) -> ThermalParams:
    """The nominal model identified (PSO and polish, from the paper's model) on every flight but ``k``."""
    flights = [log for i, log in enumerate(work.logs) if i != k]
    return identify(flights, heat_axes=work.heat_axes, settings=work.pso).params


def swarm_nominals(
    logs: Sequence[FlightLog],
    heat_axes: tuple[str, str],
    pso: PsoSettings,
    progress: Callable[[str], None] | None = None,
) -> tuple[list[ThermalParams], ThermalParams]:
    """For each flight k the nominal model identified by its own swarm on the others (nothing of flight k
    in it; all the swarms at once on every core), and the model on every flight: the first fold's
    re-identified on all of them by the joint least squares (:data:`JOINT_REFIT`: a polish, not a swarm; it
    serves model.yaml and the train baseline, never a held-out figure)."""
    work = _SwarmWork(tuple(logs), heat_axes, pso)
    folds = run_tasks(_swarm_task, work, range(len(logs)), "nominal models (one swarm per fold)", progress)
    joint = replace(JOINT_REFIT, dt_s=pso.dt_s, seed=pso.seed)
    every = identify(list(logs), base=folds[0], heat_axes=heat_axes, settings=joint).params
    return folds, every
