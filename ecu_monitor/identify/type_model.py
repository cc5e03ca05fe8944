"""A type model over the flights of several airframes of one engine type, and its adaptation to an airframe.

``identify --type`` fits one model over flights of several airframes (:func:`fit_type`): the shared
parameters are identified on every flight (PSO and polish, the terms as ``--effects`` names them), then
refined jointly with each airframe's own terms (a least-squares polish from that fit). An airframe's
own terms (:data:`AIRFRAME_TERMS`) are

- ``heat_scale``: the heat into its head relative to the type's heat map (baffles, probe depth, a
  leaner engine): every heat-map value times the scale;
- ``probe_lag``: its CHT probe's time constant, s (another probe or mounting).

Each airframe keeps a term only where its own data say it is needed: its terms are fitted on the first
half of each of its flights (the shared parameters fixed) and scored on the second halves, and a term
is kept when it lowers that held-out RMS by at least :data:`~ecu_monitor.identify.select.MIN_GAIN`.
Each term carries a prior centred on "no difference from the type" (:data:`HEAT_SCALE_SIGMA`,
:data:`PROBE_LAG_SIGMA_S`), which also keeps the common level of all airframes in the shared heat map.

``identify --base TYPE.yaml FLIGHT`` (:func:`adapt`) fits only one new airframe's terms on its flight
(or its first minutes), the type's shared parameters fixed: a few small least-squares fits.

A CHT offset (the same degrees at every operating point) is not among the terms: the model, and so the
estimator, replay and run, has no output offset; the heat scale is the term that moves an airframe's
head temperature at its operating points.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import ParameterError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.identify.fit import IdentificationResult, polish
from ecu_monitor.identify.flights import ErrorStats, flight_errors, prepare_flight, run_grid
from ecu_monitor.identify.problem import DEFAULT_FREE, ParameterSpace
from ecu_monitor.identify.pso import PsoSettings
from ecu_monitor.identify.search_settings import PRIOR_SCALE_C
from ecu_monitor.identify.select import MIN_GAIN, identify_flights
from ecu_monitor.model import AirframeTerms, Coefficients, SensorLag, ThermalParams, coefficients
from ecu_monitor.model.equations import PARAMETER_FIELDS
from ecu_monitor.model.params import HEAT_SCALE_RANGE

__all__ = [
    "AIRFRAME_TERMS",
    "HEAT_SCALE_SIGMA",
    "MIN_PART_S",
    "PROBE_LAG_SIGMA_S",
    "Adaptation",
    "AirframeFit",
    "TypeFit",
    "adapt",
    "airframe_model",
    "choose_terms",
    "describe_terms",
    "first_minutes",
    "fit_type",
]

#: The terms an airframe may have of its own (module doc).
AIRFRAME_TERMS: tuple[str, ...] = ("heat_scale", "probe_lag")
#: Prior width of an airframe's heat scale, in its logarithm (a 10 % hotter head costs 1 sigma).
HEAT_SCALE_SIGMA = math.log(1.10)
#: Prior width of an airframe's probe lag about the type's, s.
PROBE_LAG_SIGMA_S = 15.0
#: Search range of an airframe's probe lag, s (the sensor_lag effect's own search range).
PROBE_LAG_RANGE_S: tuple[float, float] = SensorLag.PARAMETERS["time_constant_s"].search
#: Shortest half of a flight that chooses an airframe's terms (fit on one half, score the other), s.
MIN_PART_S = 300.0
#: The type model's probe lag where it has none of its own (the prior's centre), s.
_NO_LAG_S = 0.0


# --------------------------------------------------------------------------------------------------
# The joint space: the type's shared coordinates (optional) and each airframe's terms
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TypeSpace:
    """Search coordinates of a type fit: ``shared``'s coordinates (None: the shared model is fixed), then
    for each of ``airframes`` airframes its ``terms`` (heat scale searched in its logarithm, probe lag in s).
    The same interface as :class:`ParameterSpace` where the polish reads it."""

    shared: ParameterSpace | None
    airframes: int
    terms: tuple[str, ...]
    lag_prior_s: float

    @property
    def shared_dimension(self) -> int:
        return 0 if self.shared is None else self.shared.dimension

    @property
    def dimension(self) -> int:
        return self.shared_dimension + self.airframes * len(self.terms)

    def _bounds(self, term: str) -> tuple[float, float]:
        if term == "heat_scale":
            return math.log(HEAT_SCALE_RANGE[0]), math.log(HEAT_SCALE_RANGE[1])
        return PROBE_LAG_RANGE_S

    def from_unit(self, unit: NDArray[np.float64]) -> NDArray[np.float64]:
        """Coordinates (P, D): shared ones as the shared space gives them, then heat scale and lag values."""
        u = np.atleast_2d(np.asarray(unit, dtype=float))
        out = np.empty_like(u)
        d = self.shared_dimension
        if self.shared is not None:
            out[:, :d] = self.shared.from_unit(u[:, :d])
        for k, term in enumerate(self.terms * self.airframes):
            lo, hi = self._bounds(term)
            value = lo + u[:, d + k] * (hi - lo)
            out[:, d + k] = np.exp(value) if term == "heat_scale" else value
        return out

    def to_unit(self, vectors: NDArray[np.float64]) -> NDArray[np.float64]:
        """Inverse of :meth:`from_unit` (clipped to the unit cube)."""
        v = np.atleast_2d(np.asarray(vectors, dtype=float))
        out = np.empty_like(v)
        d = self.shared_dimension
        if self.shared is not None:
            out[:, :d] = self.shared.to_unit(v[:, :d])
        for k, term in enumerate(self.terms * self.airframes):
            lo, hi = self._bounds(term)
            value = np.log(v[:, d + k]) if term == "heat_scale" else v[:, d + k]
            out[:, d + k] = (value - lo) / (hi - lo)
        return np.clip(out, 0.0, 1.0)

    def neutral(self) -> NDArray[np.float64]:
        """The airframe coordinates of "no difference from the type" (A * len(terms),)."""
        one = [1.0 if term == "heat_scale" else self.lag_prior_s for term in self.terms]
        return np.asarray(one * self.airframes, dtype=float)

    def split(
        self, vectors: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(shared coordinates (P, d), heat scales (P, A), probe lags (P, A); NaN where a term is not searched)."""
        v = np.atleast_2d(np.asarray(vectors, dtype=float))
        d = self.shared_dimension
        own = v[:, d:].reshape(v.shape[0], self.airframes, len(self.terms))
        p = v.shape[0]
        scale = (
            own[:, :, self.terms.index("heat_scale")] if "heat_scale" in self.terms else np.ones((p, self.airframes))
        )
        lag = (
            own[:, :, self.terms.index("probe_lag")]
            if "probe_lag" in self.terms
            else np.full((p, self.airframes), np.nan)
        )
        return v[:, :d], scale, lag

    def prior_residual_matrix(self, vectors: NDArray[np.float64]) -> NDArray[np.float64]:
        """The shared space's prior terms, then each airframe term's distance from the type (degC)."""
        shared, scale, lag = self.split(vectors)
        parts = [] if self.shared is None else [self.shared.prior_residual_matrix(shared)]
        if "heat_scale" in self.terms:
            parts.append(PRIOR_SCALE_C * np.log(scale) / HEAT_SCALE_SIGMA)
        if "probe_lag" in self.terms:
            parts.append(PRIOR_SCALE_C * (lag - self.lag_prior_s) / PROBE_LAG_SIGMA_S)
        return np.concatenate(parts, axis=1) if parts else np.zeros((scale.shape[0], 0))


class TypeObjective:
    """Residuals of a type fit: every flight simulated with its airframe's terms (``groups[f]``: the
    airframe of flight f). The shared model is ``space.shared``'s coordinates, or ``shared`` fixed."""

    def __init__(
        self,
        flights: Sequence[FlightLog],
        groups: Sequence[int],
        space: TypeSpace,
        shared: ThermalParams,
        dt_s: float,
    ):
        self.space = space
        self.shared = shared
        self.groups = list(groups)
        mixture = shared.effects.mixture_index
        self.grids = [prepare_flight(log, shared.heat_axes, dt_s, 1.0, mixture) for log in flights]
        self.samples = int(sum(g.measured_c.size for g in self.grids))
        self.evaluations = 0

    def _shared_coefficients(self, shared_vectors: NDArray[np.float64], p: int) -> Coefficients:
        if self.space.shared is not None:
            return self.space.shared.coefficient_arrays(shared_vectors)
        one = coefficients(self.shared)
        fields = {name: np.full(p, float(getattr(one, name))) for name in PARAMETER_FIELDS}
        heat = np.broadcast_to(np.asarray(one.heat_values_w, dtype=float), (p, *np.shape(one.heat_values_w)))
        return one._replace(heat_values_w=heat, **fields)

    def residuals(self, unit: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """Simulated minus measured CHT (P, samples of all flights) and the failure mask (P,)."""
        unit = np.atleast_2d(unit)
        shared, scale, lag = self.space.split(self.space.from_unit(unit))
        base = self._shared_coefficients(shared, unit.shape[0])
        heat = np.asarray(base.heat_values_w, dtype=float)
        parts = []
        failed = np.zeros(unit.shape[0], dtype=bool)
        for grid, group in zip(self.grids, self.groups, strict=True):
            own_lag = lag[:, group]
            coeffs = base._replace(
                heat_values_w=np.ascontiguousarray(heat * scale[:, group, None, None]),
                sensor_lag_s=np.where(np.isfinite(own_lag), own_lag, base.sensor_lag_s),
            )
            probe, bad = run_grid(grid, coeffs)
            parts.append(probe.T - grid.measured_c[None, :])
            failed |= np.asarray(bad, dtype=bool)
        residual = np.concatenate(parts, axis=1)
        failed |= ~np.all(np.isfinite(residual), axis=1)
        self.evaluations += unit.shape[0]
        return residual, failed


# --------------------------------------------------------------------------------------------------
# Models of one airframe
# --------------------------------------------------------------------------------------------------


def airframe_model(type_params: ThermalParams, terms: AirframeTerms) -> ThermalParams:
    """The model of one airframe: the type's shared parameters with the airframe's terms applied (heat
    map times its heat scale, its probe lag), recording the airframe and no engine type."""
    params = type_params.replace(engine_type="", airframes=(terms,))
    if terms.heat_scale is not None:
        params = params.replace(heat_map=params.heat_map.with_values(params.heat_map.values_array() * terms.heat_scale))
    if terms.probe_lag_s is not None:
        params = params.replace(
            effects=params.effects.replace("sensor_lag", SensorLag(time_constant_s=terms.probe_lag_s))
        )
    return params


def _type_lag_s(params: ThermalParams) -> float:
    lag = params.effects.sensor_lag
    return _NO_LAG_S if lag is None else float(lag.time_constant_s)


def _terms_of(airframe: str, terms: Sequence[str], scale: float, lag: float) -> AirframeTerms:
    return AirframeTerms(
        airframe,
        heat_scale=float(scale) if "heat_scale" in terms else None,
        probe_lag_s=float(lag) if "probe_lag" in terms else None,
    )


def _fit_airframe(
    shared: ThermalParams, flights: Sequence[FlightLog], terms: Sequence[str], settings: PsoSettings
) -> tuple[float, float]:
    """One airframe's heat scale and probe lag fitted on ``flights`` with the shared model fixed (the terms
    not in ``terms`` stay the type's: scale 1, the type's lag)."""
    type_lag = _type_lag_s(shared)
    if not terms:
        return 1.0, type_lag
    space = TypeSpace(None, 1, tuple(terms), type_lag)
    objective = TypeObjective(flights, [0] * len(flights), space, shared, settings.dt_s)
    start = space.to_unit(space.neutral()[None, :])[0]
    best, _cost = polish(objective, start, settings.polish_evaluations)
    _, scale, lag = space.split(space.from_unit(best[None, :]))
    return float(scale[0, 0]), float(lag[0, 0]) if "probe_lag" in terms else type_lag


def _centred(shared: ThermalParams, scales: NDArray[np.float64], lags: NDArray[np.float64]) -> ThermalParams:
    """The shared model as the type's typical airframe: its heat map times the airframes' geometric-mean
    heat scale, its probe lag their median lag (when they were fitted)."""
    factor = float(np.exp(np.mean(np.log(scales))))
    shared = shared.replace(heat_map=shared.heat_map.with_values(shared.heat_map.values_array() * factor))
    if np.all(np.isfinite(lags)):
        lag = SensorLag(time_constant_s=float(np.median(lags)))
        shared = shared.replace(effects=shared.effects.replace("sensor_lag", lag))
    return shared


def _halves(log: FlightLog) -> tuple[FlightLog, FlightLog] | None:
    t = np.asarray(log.time_s, dtype=float)
    middle = t[0] + 0.5 * (t[-1] - t[0])
    if middle - t[0] < MIN_PART_S:
        return None
    return log.select(t[0], middle), log.select(float(t[t > middle][0]), t[-1])


def _pooled_rms(params: ThermalParams, flights: Sequence[FlightLog], dt_s: float) -> float:
    stats = [flight_errors(params, log, dt_s) for log in flights]
    n = [len(log) for log in flights]
    return float(math.sqrt(sum(s.rms_c**2 * k for s, k in zip(stats, n, strict=True)) / sum(n)))


def choose_terms(
    shared: ThermalParams,
    flights: Sequence[FlightLog],
    candidates: Sequence[str],
    settings: PsoSettings,
    min_gain: float = MIN_GAIN,
) -> tuple[tuple[str, ...], dict[tuple[str, ...], float]]:
    """The airframe terms among ``candidates`` its flights show are needed: each subset fitted on the first
    halves and scored (pooled RMS, degC) on the second halves; the fewest terms within ``min_gain`` of the
    best. Returns (the terms, the held-out RMS of each subset). Flights too short to halve
    (:data:`MIN_PART_S`) leave every candidate on, their priors keeping them near the type."""
    parts = [h for h in (_halves(log) for log in flights) if h is not None]
    if not parts:
        return tuple(candidates), {}
    first, second = [a for a, _ in parts], [b for _, b in parts]
    scores: dict[tuple[str, ...], float] = {}
    for size in range(len(candidates) + 1):
        for subset in itertools.combinations(candidates, size):
            scale, lag = _fit_airframe(shared, first, subset, settings)
            model = airframe_model(shared, _terms_of("-", subset, scale, lag))
            scores[subset] = _pooled_rms(model, second, settings.dt_s)
    best = min(scores.values())
    chosen = min((s for s, v in scores.items() if v <= best * (1.0 + min_gain)), key=lambda s: (len(s), scores[s]))
    return chosen, scores


# --------------------------------------------------------------------------------------------------
# identify --type and identify --base TYPE.yaml
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class AirframeFit:
    """One airframe of a type fit or an adaptation.

    terms: its own terms (only the kept ones are set); held_out: held-out RMS (degC) of each subset of
    terms tried (second halves; empty when the flights were too short to halve); errors: the airframe's
    model on each of its flights (the data it was fitted on); as_type: the type model as is on them.
    """

    terms: AirframeTerms
    held_out: dict[tuple[str, ...], float]
    errors: tuple[ErrorStats, ...]
    as_type: tuple[ErrorStats, ...]


@dataclass(frozen=True)
class TypeFit:
    """Outcome of :func:`fit_type`: the type model (``params``, its airframes' terms inside), the shared
    identification (stage one), each airframe's fit, the joint polish's cost (degC, None when it did not
    improve), and the wall time, s."""

    params: ThermalParams
    shared: IdentificationResult
    airframes: dict[str, AirframeFit]
    joint_cost: float | None
    elapsed_s: float


def fit_type(
    flights: Sequence[FlightLog],
    airframes: Sequence[str],
    *,
    engine_type: str,
    base: ThermalParams,
    heat_axes: tuple[str, str],
    grid: tuple[int, int] | None,
    settings: PsoSettings,
    terms: dict[str, bool] | str | None = None,
    free: Sequence[str] = DEFAULT_FREE,
    candidates: Sequence[str] = AIRFRAME_TERMS,
    progress: Callable[[str], None] | None = None,
    pso_progress: Callable[[int, float, float], None] | None = None,
) -> TypeFit:
    """The type model of ``flights`` (``airframes[f]``: the airframe of flight f; two or more airframes):
    the shared identification, the joint polish with every airframe's terms, then each airframe's terms
    chosen by held-out error and refitted on its flights (module doc)."""
    names = sorted(set(airframes))
    if len(names) < 2:
        raise ParameterError(f"a type model needs flights of two airframes or more, got {', '.join(names) or 'none'}")
    if len(airframes) != len(flights):
        raise ParameterError("fit_type: one airframe per flight")
    say = progress or (lambda _line: None)
    started = time.perf_counter()
    say(f"type {engine_type}: {len(flights)} flights of {len(names)} airframes; shared identification")
    stage, _cv, _selection = identify_flights(
        flights, base=base, heat_axes=heat_axes, grid=grid, settings=settings, terms=terms, free=free, lofo=False,
        progress=progress, pso_progress=pso_progress,
    )  # fmt: skip
    shared = stage.params
    groups = [names.index(a) for a in airframes]
    joint = TypeSpace(stage.space, len(names), tuple(candidates), _type_lag_s(shared))
    joint_cost = None
    if candidates and settings.polish:
        say(f"joint polish: the shared parameters with {', '.join(candidates)} of each airframe")
        objective = TypeObjective(flights, groups, joint, shared, settings.dt_s)
        start = joint.to_unit(np.concatenate([stage.best_vector, joint.neutral()])[None, :])[0]
        best, cost = polish(objective, start, settings.polish_evaluations)
        if cost < stage.best_cost:
            vector = joint.from_unit(best[None, :])
            _, scales, lags = joint.split(vector)
            shared = _centred(stage.space.to_params(vector[0, : joint.shared_dimension]), scales[0], lags[0])
            joint_cost = cost
    fits: dict[str, AirframeFit] = {}
    for name in names:
        own = [log for log, a in zip(flights, airframes, strict=True) if a == name]
        chosen, held_out = choose_terms(shared, own, candidates, settings)
        scale, lag = _fit_airframe(shared, own, chosen, settings)
        kept = _terms_of(name, chosen, scale, lag)
        model = airframe_model(shared, kept)
        fits[name] = AirframeFit(
            kept,
            held_out,
            tuple(flight_errors(model, log) for log in own),
            tuple(flight_errors(shared, log) for log in own),
        )
        say(f"airframe {name}: {describe_terms(kept)}")
    params = shared.replace(engine_type=engine_type, airframes=tuple(fits[n].terms for n in names))
    return TypeFit(params, stage, fits, joint_cost, time.perf_counter() - started)


@dataclass(frozen=True)
class Adaptation:
    """Outcome of :func:`adapt`: the airframe's model, its fit and the wall time, s."""

    params: ThermalParams
    fit: AirframeFit
    elapsed_s: float


def adapt(type_params: ThermalParams, flights: Sequence[FlightLog], airframe: str, settings: PsoSettings) -> Adaptation:
    """A new airframe's model from a type model and its flights: only its own terms are fitted (the type's
    shared parameters fixed), chosen among those the type's airframes needed (all of them when none did)
    by held-out error on the halves of its flights."""
    if not type_params.engine_type:
        raise ParameterError("--base: not a type model (made by identify --type): it has no engine type")
    started = time.perf_counter()
    shared = type_params.replace(engine_type="", airframes=())
    needed = [t for t in AIRFRAME_TERMS if any(_has(a, t) for a in type_params.airframes)]
    candidates = tuple(needed) or AIRFRAME_TERMS
    chosen, held_out = choose_terms(shared, flights, candidates, settings)
    scale, lag = _fit_airframe(shared, flights, chosen, settings)
    terms = _terms_of(airframe, chosen, scale, lag)
    params = airframe_model(shared, terms).replace(engine_type="")
    fit = AirframeFit(
        terms,
        held_out,
        tuple(flight_errors(params, log) for log in flights),
        tuple(flight_errors(shared, log) for log in flights),
    )
    return Adaptation(params, fit, time.perf_counter() - started)


def _has(terms: AirframeTerms, term: str) -> bool:
    return (terms.heat_scale if term == "heat_scale" else terms.probe_lag_s) is not None


def describe_terms(terms: AirframeTerms) -> str:
    """One airframe's own terms in words ("heat scale 1.042, probe lag 21.0 s" or "no terms of its own")."""
    kept = []
    if terms.heat_scale is not None:
        kept.append(f"heat scale {terms.heat_scale:.3f}")
    if terms.probe_lag_s is not None:
        kept.append(f"probe lag {terms.probe_lag_s:.1f} s")
    return ", ".join(kept) or "no terms of its own (the type as is)"


def first_minutes(log: FlightLog, minutes: float) -> FlightLog:
    """The first ``minutes`` of a flight (from its first sample)."""
    if not (math.isfinite(minutes) and minutes > 0.0):
        raise ParameterError(f"--first-minutes: expected a positive number of minutes, got {minutes!r}")
    t0 = float(log.time_s[0])
    return log.select(t0, t0 + 60.0 * minutes)
