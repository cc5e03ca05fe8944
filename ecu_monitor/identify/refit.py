"""Refit of a candidate effect (or the effect-free control) on the train flight, warm-started from the
nominal model, and its open-loop score on any flight.

The fit is a bounded nonlinear least squares (``scipy.optimize.least_squares``, trust-region
reflective) of measured minus simulated CHT over the train flight, on the candidate's free
parameters plus the re-tuned nominal factors of :data:`ecu_monitor.identify.library.RETUNED_NOMINAL`.
The Jacobian is a forward difference evaluated as one swarm call of the compiled simulator (the
base point and every perturbed point are particles of the same run).

Uncertainty: ``cov = s^2 (J^T J)^-1`` with ``s^2`` the residual variance, inflated by ``N / N_eff``
where ``N_eff = N (1 - rho1) / (1 + rho1)`` and rho1 the lag-1 autocorrelation of the residual: the
open-loop residual is far from white, and the textbook formula would otherwise understate the
spread several-fold.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import least_squares

from ecu_monitor.errors import FlightLogError, ParameterError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.identify.fit import identify, one_blas_thread
from ecu_monitor.identify.flights import FlightGrid
from ecu_monitor.identify.flights import prepare_flight as prepare_grid
from ecu_monitor.identify.library import (
    RETUNED_BOUNDS,
    RETUNED_NOMINAL,
    Candidate,
    FreeParameter,
    candidate_index,
    effects_for,
)
from ecu_monitor.identify.problem import DEFAULT_FREE, IDENTIFICATION_DT_S, default_space
from ecu_monitor.identify.pso import PsoSettings
from ecu_monitor.model import MixtureIndex, ThermalParams, coefficients, simulate, stack_coefficients
from ecu_monitor.model.compiled import simulate_compiled

__all__ = [
    "FitResult",
    "PreparedFlight",
    "RefitSettings",
    "prepare_flight",
    "refit",
    "reidentify",
    "simulate_probe",
]


@dataclass(frozen=True)
class RefitSettings:
    """dt_s: integration step (s, the identification's by default); max_evaluations: least-squares budget;
    engine: "compiled" (numba swarm) or "numpy" (the plain model loop, the benchmark's baseline)."""

    dt_s: float = IDENTIFICATION_DT_S
    max_evaluations: int = 60
    engine: str = "compiled"

    def __post_init__(self) -> None:
        if not (isinstance(self.dt_s, int | float) and 0.01 <= self.dt_s <= 5.0):
            raise ParameterError(f"refit.dt_s: expected a step in [0.01, 5] s, got {self.dt_s!r}")
        if not (isinstance(self.max_evaluations, int) and self.max_evaluations >= 1):
            raise ParameterError(f"refit.max_evaluations: expected a positive integer, got {self.max_evaluations!r}")
        if self.engine not in ("compiled", "numpy"):
            raise ParameterError(f"refit.engine: expected 'compiled' or 'numpy', got {self.engine!r}")


class PreparedFlight(NamedTuple):
    """A flight ready for repeated simulation: the log, its uniform simulation grid (shared with the
    identification, :func:`ecu_monitor.identify.prepare_flight`), the measured CHT at the log's samples
    and the median sample spacing (s)."""

    log: FlightLog
    grid: FlightGrid
    cht_c: np.ndarray
    dt_s: float


def prepare_flight(
    log: FlightLog, heat_axes: tuple[str, str], dt_s: float, mixture: MixtureIndex | None = None
) -> PreparedFlight:
    """Put ``log`` on a uniform integration step ``dt_s`` with the index of ``mixture`` (by default the
    mixture_index candidate's, :func:`candidate_index`, when the log gives one); FlightLogError if a column is
    missing."""
    if len(log) < 10:
        raise FlightLogError(f"{log.source}: too short for a gap diagnosis ({len(log)} samples)")
    if mixture is None:
        mixture = candidate_index([log])
    grid = prepare_grid(log, heat_axes, dt_s, record_period_s=max(dt_s, 1.0), mixture=mixture)
    spacing = float(np.median(np.diff(log.time_s)))
    return PreparedFlight(log, grid, np.asarray(grid.measured_c, dtype=float), spacing)


def simulate_probe(params: Sequence[ThermalParams], flight: PreparedFlight, engine: str = "compiled") -> np.ndarray:
    """Open-loop probe CHT (degC) of each parameter set at the log's samples: (N, P); NaN where a run failed."""
    grid = flight.grid
    if engine == "numpy":
        columns = []
        for p in params:
            _, probe = simulate(grid.inputs, coefficients(p), grid.dt_s, grid.initial_c)
            columns.append(np.asarray(probe)[:: grid.record_every])
        recorded = np.column_stack(columns)
    else:
        run = simulate_compiled(
            grid.inputs, stack_coefficients(list(params)), grid.dt_s, grid.initial_c, record_every=grid.record_every
        )
        recorded = np.asarray(run.probe_c).reshape(-1, len(params))
    return np.asarray(grid.sample(recorded)).reshape(flight.cht_c.size, len(params))


@dataclass(frozen=True)
class FitResult:
    """A refitted model: the candidates switched on, fitted values and 1-sigma uncertainties."""

    ids: tuple[str, ...]
    params: ThermalParams
    values: dict[str, dict[str, float]]  # candidate id -> free parameter -> value
    std: dict[str, dict[str, float]]  # same keys: 1-sigma uncertainty (inf if not identifiable)
    nominal_factors: dict[str, float]  # r_ce_factor, heat_factor
    train_rms_c: float
    evaluations: int
    failed_evaluations: int
    converged: bool
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def label(self) -> str:
        """The candidate ids joined with '+', or 'control' for the effect-free refit."""
        return "+".join(self.ids) if self.ids else "control"


def _flights(train: PreparedFlight | Sequence[PreparedFlight]) -> tuple[PreparedFlight, ...]:
    """One prepared flight or several, as a tuple."""
    flights = (train,) if isinstance(train, PreparedFlight) else tuple(train)
    if not flights:
        raise ParameterError("refit: at least one train flight is needed")
    return flights


class _Problem:
    """Maps the parameter vector to models and residuals over all train flights (concatenated);
    counts evaluations and failures."""

    def __init__(
        self,
        nominal: ThermalParams,
        entries: Sequence[Candidate],
        references: Mapping[str, float],
        flights: Sequence[PreparedFlight],
        engine: str,
    ) -> None:
        self.nominal = nominal
        self.entries = tuple(entries)
        self.references = references
        self.flights = tuple(flights)
        self.measured = np.concatenate([f.cht_c for f in self.flights])
        self.engine = engine
        self.names = [(e.id, p.name) for e in self.entries for p in e.free]
        mixture = nominal.effects.mixture_index or candidate_index([f.log for f in self.flights])
        self.mixture_source = mixture.source if mixture is not None else "egt_c"
        bounds = [self._bounds(e, p) for e in self.entries for p in e.free]
        self.low = np.array([low for low, _ in bounds] + [RETUNED_BOUNDS[0]] * 2)
        self.high = np.array([high for _, high in bounds] + [RETUNED_BOUNDS[1]] * 2)
        starts = [self._start(e, p) for e in self.entries for p in e.free]
        self.start = np.array([*starts, 0.0, 0.0])
        self.steps = 1e-3 * (self.high - self.low)
        self.evaluations = 0
        self.failed = 0
        self.heat_values = nominal.heat_map.values_array()

    def _bounds(self, entry: Candidate, free: FreeParameter) -> tuple[float, float]:
        """The library's bounds, but a mixture index's gain reaches as far as its index allows
        (:meth:`MixtureIndex.gain_reach`; the library's are the EGT's)."""
        if entry.effect == "mixture_index" and free.name == "gain":
            reach = MixtureIndex.gain_reach(self.mixture_source)
            return -reach, reach
        return free.low, free.high

    def _start(self, entry: Candidate, free: FreeParameter) -> float:
        """Warm start: the nominal model's own value when it has one (a nominal field, or an effect the
        nominal model already has on), else the library's start value."""
        if entry.effect == "nominal":
            value = float(getattr(self.nominal, free.name))
        else:
            current = getattr(self.nominal.effects, entry.effect)
            value = float(getattr(current, free.name)) if current is not None else free.start
        return float(np.clip(value, *self._bounds(entry, free)))

    def starts(self) -> list[np.ndarray]:
        """The warm start, then one start per alternative value of each parameter with restarts."""
        out = [self.start]
        k = 0
        for e in self.entries:
            for p in e.free:
                for value in p.restarts:
                    if not np.isclose(value, self.start[k]):
                        alternative = self.start.copy()
                        alternative[k] = value
                        out.append(alternative)
                k += 1
        return out

    def values(self, x: np.ndarray) -> dict[str, dict[str, float]]:
        out: dict[str, dict[str, float]] = {e.id: {} for e in self.entries}
        for (cid, name), value in zip(self.names, x[: len(self.names)], strict=True):
            out[cid][name] = float(value)
        return out

    def params(self, x: np.ndarray) -> ThermalParams:
        r_log, h_log = float(x[-2]), float(x[-1])
        values = self.values(x)
        effects = effects_for(self.nominal.effects, self.entries, values, self.references)
        nominal_fields = {k: v for e in self.entries if e.effect == "nominal" for k, v in e.fixed}
        nominal_fields.update({k: v for e in self.entries if e.effect == "nominal" for k, v in values[e.id].items()})
        return self.nominal.replace(
            **nominal_fields,
            r_ce=self.nominal.r_ce * math.exp(r_log),
            heat_map=self.nominal.heat_map.with_values(self.heat_values * math.exp(h_log)),
            effects=effects,
        )

    def residuals(self, points: Sequence[np.ndarray]) -> np.ndarray:
        """Measured minus simulated CHT for each point, all train flights end to end: (N, len(points));
        failures count and get 1e3."""
        params = [self.params(x) for x in points]
        probe = np.concatenate([simulate_probe(params, flight, self.engine) for flight in self.flights], axis=0)
        self.evaluations += len(points)
        bad = ~np.all(np.isfinite(probe), axis=0)
        self.failed += int(bad.sum())
        residual = self.measured[:, None] - probe
        residual[:, bad] = 1e3
        return residual

    def fun(self, x: np.ndarray) -> np.ndarray:
        return self.residuals([x])[:, 0]

    def jac(self, x: np.ndarray) -> np.ndarray:
        points = [x]
        signs = []
        for i in range(x.size):
            step = self.steps[i] if x[i] + self.steps[i] <= self.high[i] else -self.steps[i]
            shifted = x.copy()
            shifted[i] += step
            points.append(shifted)
            signs.append(step)
        residual = self.residuals(points)
        return (residual[:, 1:] - residual[:, :1]) / np.asarray(signs)[None, :]


def _uncertainty(jac: np.ndarray, residual: np.ndarray, n_params: int) -> np.ndarray:
    n = residual.size
    s2 = float(residual @ residual) / max(n - n_params, 1)
    centred = residual - residual.mean()
    denom = float(centred @ centred)
    rho = float(centred[1:] @ centred[:-1]) / denom if denom > 0 else 0.0
    rho = min(max(rho, 0.0), 0.999)
    inflation = (1.0 + rho) / (1.0 - rho)
    jtj = jac.T @ jac
    try:
        cov = np.linalg.pinv(jtj) * s2 * inflation
    except np.linalg.LinAlgError:
        return np.full(jac.shape[1], np.inf)
    diag = np.diag(cov)
    return np.sqrt(np.where(diag >= 0, diag, np.inf))


def identifiable_std(std: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """``std`` with inf where a parameter is not identifiable: a sigma that is not finite, zero to
    round-off (below 1e-9 of its bound width: a flat or pinned direction of the Jacobian) or wider
    than the whole bound interval (the data do not constrain it)."""
    std = np.asarray(std, dtype=float)
    width = np.asarray(high, dtype=float) - np.asarray(low, dtype=float)
    bad = ~np.isfinite(std) | (std <= 1e-9 * width) | (std > width)
    return np.where(bad, np.inf, std)


def refit(
    nominal: ThermalParams,
    train: PreparedFlight | Sequence[PreparedFlight],
    entries: Sequence[Candidate],
    references: Mapping[str, float],
    settings: RefitSettings | None = None,
) -> FitResult:
    """Refit ``entries`` (empty: the control) plus the re-tuned nominal factors on the train flight(s)
    (several: one fit over all of them, residuals end to end)."""
    settings = settings or RefitSettings()
    problem = _Problem(nominal, entries, references, _flights(train), settings.engine)
    result = None
    for start in problem.starts():
        with one_blas_thread():
            attempt = least_squares(
                problem.fun,
                start,
                jac=problem.jac,
                bounds=(problem.low, problem.high),
                method="trf",
                x_scale="jac",
                max_nfev=settings.max_evaluations,
                xtol=1e-6,
                ftol=1e-8,
            )
        if result is None or attempt.cost < result.cost:
            result = attempt
    if result is None:  # starts() always yields the warm start
        raise ParameterError("refit: no start point")
    x = np.asarray(result.x, dtype=float)
    residual = np.asarray(result.fun, dtype=float)
    std = identifiable_std(
        _uncertainty(np.asarray(result.jac, dtype=float), residual, x.size), problem.low, problem.high
    )
    values = problem.values(x)
    stds: dict[str, dict[str, float]] = {e.id: {} for e in problem.entries}
    for (cid, name), sigma in zip(problem.names, std[: len(problem.names)], strict=True):
        stds[cid][name] = float(sigma)
    return FitResult(
        ids=tuple(e.id for e in problem.entries),
        params=problem.params(x),
        values=values,
        std=stds,
        nominal_factors={
            "r_ce_factor": math.exp(float(x[-2])),
            "heat_factor": math.exp(float(x[-1])),
            "r_ce_factor_std": math.exp(float(x[-2])) * float(std[-2]),
            "heat_factor_std": math.exp(float(x[-1])) * float(std[-1]),
        },
        train_rms_c=float(np.sqrt(np.mean(residual**2))),
        evaluations=problem.evaluations,
        failed_evaluations=problem.failed,
        converged=bool(result.success),
        extra={"retuned": list(RETUNED_NOMINAL)},
    )


def reidentify(
    nominal: ThermalParams,
    train: PreparedFlight | Sequence[PreparedFlight],
    entries: Sequence[Candidate],
    references: Mapping[str, float],
    settings: RefitSettings | None = None,
    pso: PsoSettings | None = None,
) -> FitResult:
    """Re-identify the whole nominal model (PSO, :func:`ecu_monitor.identify.identify`: C_w, R_Ce, tau_w,
    the visited heat map) jointly with the candidates' free parameters on the train flight, then
    polish and estimate the uncertainty with :func:`refit` from there.

    This is the refit to use when the nominal model was itself identified on the train flight: its
    heat map has then absorbed whatever part of an effect the operating point can mimic (a hot ground
    run becomes "more heat at low fuel flow"), and only a joint fit can give it back to the effect.
    The control is the same identification with no candidate (same PSO seed). An effect ``nominal``
    already has on starts at its values there (a pair re-identified from its first effect's fit).
    """
    settings = settings or RefitSettings()
    pso = pso or PsoSettings()
    flights = _flights(train)
    # an effect the given model already has on keeps its fitted values (a warm start, as in refit)
    effect_entries = [e for e in entries if e.effect != "nominal" and getattr(nominal.effects, e.effect) is None]
    start = {e.id: {p.name: p.start for p in e.free} for e in effect_entries}
    base = nominal.replace(effects=effects_for(nominal.effects, effect_entries, start, references))
    free = list(DEFAULT_FREE)
    for e in entries:
        for p in e.free:
            free.append(p.name if e.effect == "nominal" else f"effects.{e.effect}.{p.name}")
    fixed = {k: v for e in entries if e.effect == "nominal" for k, v in e.fixed}
    base = base.replace(**fixed) if fixed else base
    logs = [f.log for f in flights]
    space = default_space(logs, base=base, heat_axes=nominal.heat_axes, free=free)
    identified = identify(logs, space=space, settings=pso).params
    fit = refit(identified, flights, entries, references, settings)
    return dataclasses.replace(
        fit,
        extra={**fit.extra, "refit": "reidentify", "pso_particles": pso.particles, "pso_iterations": pso.iterations},
    )
