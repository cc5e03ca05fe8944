"""A type model over the flights of several airframes of one engine type, and its adaptation to an airframe.

``identify --type`` fits one model over flights of several airframes (:func:`fit_type`): the shared
parameters are identified on every flight (PSO and polish, the terms as ``--effects`` names them), then
refined jointly with each airframe's own terms (a least-squares polish from that fit). An airframe's
own terms (:data:`AIRFRAME_TERMS`) are

- ``heat_scale``: the heat into its head relative to the type's heat map (probe depth, a leaner
  engine): every heat-map value times the scale;
- ``cooling_scale``: its convective cooling relative to the type's (baffles, cowling, cowl flaps):
  the conductance 1/R_Ce times the scale, so the head's time constant and its rise above the air shrink
  together;
- ``probe_lag``: its CHT probe's time constant, s (another probe or mounting).

Each airframe keeps a term only where its own data say it is needed: its terms are fitted on the first
half of each of its flights (the shared parameters fixed) and scored on the second halves, and a term
is kept when it lowers that held-out RMS by at least :data:`~ecu_monitor.identify.select.MIN_GAIN`.
Each term carries a prior centred on "no difference from the type" (:data:`SCALE_SIGMA`,
:data:`PROBE_LAG_SIGMA_S`), which also keeps the common level of all airframes in the shared heat map.

``identify --base TYPE.yaml FLIGHT`` (:func:`adapt`) fits only one new airframe's terms on its flight
(or its first minutes), the type's shared parameters fixed: a few small least-squares fits. Then the
heat-map values its flight visits may move from the type's, each under a prior towards the type's value,
as far as the halves of its flights (each half predicting the other) show that predicts better
(:func:`choose_heat_map_prior`): an airframe's head can differ from the type's at some operating points
and not at others, which no single scale carries. Given several
type models of one type in other forms (another heat map's axes, other effects: ``--or-base``),
:func:`adapt_choosing` adapts each and keeps the first unless another predicts the held-out halves of the
new airframe's flights clearly better (:data:`FORM_MIN_GAIN`): the airframe's own data choose the form, on
the halves that choose its terms.

A CHT offset (the same degrees at every operating point) is not among the terms: the model, and so the
estimator, replay and run, has no output offset; the heat and cooling scales are the terms that move an
airframe's head temperature at its operating points. What a type fit records instead is each airframe's head
against the others' at the steady inputs they share (``head_offset_c``, measured from the flights, not
applied): how far a new airframe of the type can be from the type model with no flight of its own, which
replay's warning for a type model on a new airframe states (``ecu_monitor.model.airframe_warning``).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import ParameterError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.identify.fit import IdentificationResult, polish
from ecu_monitor.identify.flights import ErrorStats, flight_errors, prepare_flight
from ecu_monitor.identify.matched import MATCH_COLUMNS, MatchedRise, matched_rise
from ecu_monitor.identify.objective import SwarmObjective, pooled_residuals
from ecu_monitor.identify.problem import DEFAULT_FREE, ParameterSpace, heat_cell_name, visited_weight_s
from ecu_monitor.identify.pso import PsoSettings
from ecu_monitor.identify.search_settings import MIN_VISIT_S, PRIOR_SCALE_C
from ecu_monitor.identify.select import MIN_GAIN, identify_flights
from ecu_monitor.model import AirframeTerms, Coefficients, SensorLag, ThermalParams, coefficients
from ecu_monitor.model.equations import PARAMETER_FIELDS
from ecu_monitor.model.params import SCALE_RANGE

__all__ = [
    "AIRFRAME_TERMS",
    "FORM_MIN_GAIN",
    "HEAT_VALUE_SIGMAS",
    "MIN_PART_S",
    "PROBE_LAG_SIGMA_S",
    "SCALE_SIGMA",
    "TERMS",
    "Adaptation",
    "AirframeFit",
    "AirframeTerm",
    "TypeFit",
    "adapt",
    "adapt_choosing",
    "airframe_model",
    "choose_heat_map_prior",
    "choose_terms",
    "describe_terms",
    "first_minutes",
    "fit_type",
    "refit_heat_map",
]

#: Prior width of an airframe's heat and cooling scales, in their logarithm (10 % from the type costs 1 sigma).
SCALE_SIGMA = math.log(1.10)
#: Prior width of an airframe's probe lag about the type's, s.
PROBE_LAG_SIGMA_S = 15.0
#: Shortest half of a flight that chooses an airframe's terms (fit on one half, score the other), s.
MIN_PART_S = 300.0
#: The first type model offered (the default form) is left only for one whose held-out halves are lower by at
#: least this fraction (the gap diagnosis's material gain): the halves of 20 minutes are ten minutes each,
#: and smaller differences between forms there need not hold on the airframe's other flights.
FORM_MIN_GAIN = 0.20
#: Prior widths an adaptation tries for the heat-map values its flights visit, each as a fraction of the type's
#: value there (0: the type's values kept); the halves of its flights choose one (:func:`choose_heat_map_prior`).
HEAT_VALUE_SIGMAS: tuple[float, ...] = (0.0, 0.05, 0.10, 0.20)
#: The type model's probe lag where it has none of its own (the prior's centre), s.
_NO_LAG_S = 0.0


@dataclass(frozen=True)
class AirframeTerm:
    """One term an airframe may have of its own: its :class:`AirframeTerms` field, its search range, whether
    it is searched in its logarithm (a scale) and its prior width (in the searched coordinate)."""

    field: str
    bounds: tuple[float, float]
    log_scaled: bool
    sigma: float


#: The terms an airframe may have of its own (module doc), by name.
TERMS: dict[str, AirframeTerm] = {
    "heat_scale": AirframeTerm("heat_scale", SCALE_RANGE, True, SCALE_SIGMA),
    "cooling_scale": AirframeTerm("cooling_scale", SCALE_RANGE, True, SCALE_SIGMA),
    "probe_lag": AirframeTerm("probe_lag_s", SensorLag.PARAMETERS["time_constant_s"].search, False, PROBE_LAG_SIGMA_S),
}
AIRFRAME_TERMS: tuple[str, ...] = tuple(TERMS)


# --------------------------------------------------------------------------------------------------
# The joint space: the type's shared coordinates (optional) and each airframe's terms
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TypeSpace:
    """Search coordinates of a type fit: ``shared``'s coordinates (None: the shared model is fixed), then
    for each of ``airframes`` airframes its ``terms`` (:data:`TERMS`: scales searched in their logarithm).
    The same interface as :class:`ParameterSpace` where the polish reads it. ``lag_prior_s``: the type's
    probe lag, the centre of an airframe's own."""

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

    def _searched(self, term: str) -> tuple[float, float, float]:
        """(lower, upper bound, prior centre) of a term in its searched coordinate."""
        spec = TERMS[term]
        if spec.log_scaled:
            return math.log(spec.bounds[0]), math.log(spec.bounds[1]), 0.0
        return spec.bounds[0], spec.bounds[1], self.lag_prior_s

    def from_unit(self, unit: NDArray[np.float64]) -> NDArray[np.float64]:
        """Coordinates (P, D): shared ones as the shared space gives them, then each airframe's term values."""
        u = np.atleast_2d(np.asarray(unit, dtype=float))
        out = np.empty_like(u)
        d = self.shared_dimension
        if self.shared is not None:
            out[:, :d] = self.shared.from_unit(u[:, :d])
        for k, term in enumerate(self.terms * self.airframes):
            lo, hi, _ = self._searched(term)
            value = lo + u[:, d + k] * (hi - lo)
            out[:, d + k] = np.exp(value) if TERMS[term].log_scaled else value
        return out

    def to_unit(self, vectors: NDArray[np.float64]) -> NDArray[np.float64]:
        """Inverse of :meth:`from_unit` (clipped to the unit cube)."""
        v = np.atleast_2d(np.asarray(vectors, dtype=float))
        out = np.empty_like(v)
        d = self.shared_dimension
        if self.shared is not None:
            out[:, :d] = self.shared.to_unit(v[:, :d])
        for k, term in enumerate(self.terms * self.airframes):
            lo, hi, _ = self._searched(term)
            value = np.log(v[:, d + k]) if TERMS[term].log_scaled else v[:, d + k]
            out[:, d + k] = (value - lo) / (hi - lo)
        return np.clip(out, 0.0, 1.0)

    def neutral(self) -> NDArray[np.float64]:
        """The airframe coordinates of "no difference from the type" (A * len(terms),)."""
        one = [1.0 if TERMS[term].log_scaled else self.lag_prior_s for term in self.terms]
        return np.asarray(one * self.airframes, dtype=float)

    def split(self, vectors: NDArray[np.float64]) -> tuple[NDArray[np.float64], dict[str, NDArray[np.float64]]]:
        """(shared coordinates (P, d), term name -> its values (P, A) for every term of :data:`TERMS`: the
        type's own, 1 or NaN for the probe lag, where the term is not searched)."""
        v = np.atleast_2d(np.asarray(vectors, dtype=float))
        d = self.shared_dimension
        own = v[:, d:].reshape(v.shape[0], self.airframes, len(self.terms))
        shape = (v.shape[0], self.airframes)
        values = {
            term: own[:, :, self.terms.index(term)]
            if term in self.terms
            else np.full(shape, 1.0 if TERMS[term].log_scaled else np.nan)
            for term in TERMS
        }
        return v[:, :d], values

    def prior_residual_matrix(self, vectors: NDArray[np.float64]) -> NDArray[np.float64]:
        """The shared space's prior terms, then each airframe term's distance from the type (degC)."""
        shared, values = self.split(vectors)
        parts = [] if self.shared is None else [self.shared.prior_residual_matrix(shared)]
        for term in self.terms:
            _, _, centre = self._searched(term)
            value = np.log(values[term]) if TERMS[term].log_scaled else values[term]
            parts.append(PRIOR_SCALE_C * (value - centre) / TERMS[term].sigma)
        return np.concatenate(parts, axis=1) if parts else np.zeros((shared.shape[0], 0))


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
        one = coefficients(self.shared)  # the fixed shared model as a swarm of p equal particles
        fields: dict[str, Any] = {name: np.full(p, float(getattr(one, name))) for name in PARAMETER_FIELDS}
        fields["heat_values_w"] = np.broadcast_to(
            np.asarray(one.heat_values_w, dtype=float), (p, *np.shape(one.heat_values_w))
        )
        return one._replace(**fields)

    def residuals(self, unit: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """Simulated minus measured CHT (P, samples of all flights) and the failure mask (P,)."""
        unit = np.atleast_2d(unit)
        shared, values = self.space.split(self.space.from_unit(unit))
        base = self._shared_coefficients(shared, unit.shape[0])
        heat = np.asarray(base.heat_values_w, dtype=float)

        def of_flight(k: int) -> Coefficients:  # the flight's airframe's terms on the shared coefficients
            group = self.groups[k]
            lag = values["probe_lag"][:, group]
            return base._replace(
                heat_values_w=np.ascontiguousarray(heat * values["heat_scale"][:, group, None, None]),
                r_ce=base.r_ce / values["cooling_scale"][:, group],
                sensor_lag_s=np.where(np.isfinite(lag), lag, base.sensor_lag_s),
            )

        residual, failed = pooled_residuals(self.grids, of_flight)
        self.evaluations += unit.shape[0]
        return residual, failed


# --------------------------------------------------------------------------------------------------
# Models of one airframe
# --------------------------------------------------------------------------------------------------


def airframe_model(type_params: ThermalParams, terms: AirframeTerms) -> ThermalParams:
    """The model of one airframe: the type's shared parameters with the airframe's terms applied (heat map
    times its heat scale, R_Ce divided by its cooling scale, its probe lag), recording the airframe and no
    engine type."""
    params = type_params.replace(engine_type="", airframes=(terms,))
    if terms.heat_scale is not None:
        params = params.replace(heat_map=params.heat_map.with_values(params.heat_map.values_array() * terms.heat_scale))
    if terms.cooling_scale is not None:
        params = params.replace(r_ce=params.r_ce / terms.cooling_scale)
    if terms.probe_lag_s is not None:
        params = params.replace(
            effects=params.effects.replace("sensor_lag", SensorLag(time_constant_s=terms.probe_lag_s))
        )
    return params


def _type_lag_s(params: ThermalParams) -> float:
    lag = params.effects.sensor_lag
    return _NO_LAG_S if lag is None else float(lag.time_constant_s)


def _fit_airframe(
    shared: ThermalParams, flights: Sequence[FlightLog], terms: Sequence[str], settings: PsoSettings, airframe: str
) -> AirframeTerms:
    """One airframe's ``terms`` fitted on ``flights`` with the shared model fixed (a least-squares polish
    from "no difference from the type")."""
    if not terms:
        return AirframeTerms(airframe)
    space = TypeSpace(None, 1, tuple(terms), _type_lag_s(shared))
    objective = TypeObjective(flights, [0] * len(flights), space, shared, settings.dt_s)
    start = space.to_unit(space.neutral()[None, :])[0]
    best, _cost = polish(objective, start, settings.polish_evaluations)
    _, values = space.split(space.from_unit(best[None, :]))
    return AirframeTerms(airframe, **{TERMS[t].field: float(values[t][0, 0]) for t in terms})


def refit_heat_map(
    params: ThermalParams, flights: Sequence[FlightLog], settings: PsoSettings, sigma: float
) -> tuple[ThermalParams, int]:
    """The heat-map values ``flights`` visit (:data:`MIN_VISIT_S` of bilinear weight or more) refitted on them
    (a least-squares polish), each held towards its value in ``params`` by a Gaussian prior ``sigma`` times
    that value wide (one sigma costs 1 degC^2 of mean squared error); the other values and every other
    parameter as they are. Returns (the model, the number of values refitted; none when ``sigma`` is 0)."""
    weight = visited_weight_s(flights, params.heat_map)
    cells = tuple((i, j) for i, j in np.argwhere(weight >= MIN_VISIT_S).tolist())
    if not cells or sigma <= 0.0:
        return params, 0
    rise = params.heat_map.values_array() * params.r_ce  # the heat map as degC above the air (the search's unit)
    low, high = SCALE_RANGE
    values = [float(rise[i, j]) for i, j in cells]
    space = ParameterSpace(
        base=params,
        names=tuple(heat_cell_name(i, j) for i, j in cells),
        lower=tuple(low * v for v in values),
        upper=tuple(high * v for v in values),
        log_scaled=(True,) * len(cells),
        prior_mean=tuple(values),
        prior_sigma=tuple(sigma * v for v in values),
        heat_cells=cells,
    )
    objective = SwarmObjective(flights, space, settings.dt_s)
    best, _cost = polish(objective, space.to_unit(space.from_params(params)), settings.polish_evaluations)
    return space.to_params(space.from_unit(best[None, :])[0]), len(cells)


def _centred(shared: ThermalParams, values: dict[str, NDArray[np.float64]]) -> ThermalParams:
    """The shared model as the type's typical airframe, the median one (an airframe unlike the others does
    not pull it): its heat map times the airframes' median heat scale, R_Ce divided by their median
    cooling scale, its probe lag their median lag (where these were fitted: ``values``, term -> (A,))."""
    heat = float(np.median(values["heat_scale"]))
    cooling = float(np.median(values["cooling_scale"]))
    shared = shared.replace(
        heat_map=shared.heat_map.with_values(shared.heat_map.values_array() * heat), r_ce=shared.r_ce / cooling
    )
    if np.all(np.isfinite(values["probe_lag"])):
        lag = SensorLag(time_constant_s=float(np.median(values["probe_lag"])))
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
            model = airframe_model(shared, _fit_airframe(shared, first, subset, settings, "-"))
            scores[subset] = _pooled_rms(model, second, settings.dt_s)
    best = min(scores.values())
    chosen = min((s for s, v in scores.items() if v <= best * (1.0 + min_gain)), key=lambda s: (len(s), scores[s]))
    return chosen, scores


def choose_heat_map_prior(
    shared: ThermalParams, flights: Sequence[FlightLog], terms: Sequence[str], settings: PsoSettings
) -> tuple[float, dict[float, float]]:
    """How far an adaptation may move the heat-map values its flights visit from the type's: for each prior
    width of :data:`HEAT_VALUE_SIGMAS`, the airframe's ``terms`` and then its heat-map values
    (:func:`refit_heat_map`) fitted on one half of each flight and scored on the other half, both ways
    (the first half predicting the second and the reverse: an operating point one half alone visits is
    tried once each way); the smallest width whose mean held-out RMS (degC) is within
    :data:`~ecu_monitor.identify.select.MIN_GAIN` of the best. Returns (the width, the held-out RMS of
    each); (0, {}) for flights too short to halve (:data:`MIN_PART_S`): the type's heat map kept."""
    parts = [h for h in (_halves(log) for log in flights) if h is not None]
    if not parts:
        return 0.0, {}
    first, second = [a for a, _ in parts], [b for _, b in parts]
    totals = dict.fromkeys(HEAT_VALUE_SIGMAS, 0.0)
    for fit_on, score_on in ((first, second), (second, first)):
        model = airframe_model(shared, _fit_airframe(shared, fit_on, terms, settings, "-"))
        for sigma in HEAT_VALUE_SIGMAS:
            refitted, _cells = refit_heat_map(model, fit_on, settings, sigma)
            totals[sigma] += _pooled_rms(refitted, score_on, settings.dt_s) / 2.0
    best = min(totals.values())
    return next(s for s in HEAT_VALUE_SIGMAS if totals[s] <= best * (1.0 + MIN_GAIN)), totals


# --------------------------------------------------------------------------------------------------
# identify --type and identify --base TYPE.yaml
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class AirframeFit:
    """One airframe of a type fit or an adaptation.

    terms: its own terms (only the kept ones are set); held_out: held-out RMS (degC) of each subset of
    terms tried (second halves; empty when the flights were too short to halve); errors: the airframe's
    model on each of its flights (the data it was fitted on); as_type: the type model as is on them.
    From an adaptation also: heat_map_prior, the prior width its heat-map values were refitted with
    (:func:`choose_heat_map_prior`; 0: the type's kept), heat_map_held_out, the held-out RMS (degC, both
    ways) of each width tried, and heat_values, the number of heat-map values refitted. From a type fit also:
    matched, its head against the type's other airframes at the steady inputs they share (None where the
    flights lack a column that reads; its offset is also ``terms.head_offset_c``).
    """

    terms: AirframeTerms
    held_out: dict[tuple[str, ...], float]
    errors: tuple[ErrorStats, ...]
    as_type: tuple[ErrorStats, ...]
    heat_map_prior: float = 0.0
    heat_map_held_out: dict[float, float] = field(default_factory=dict)
    heat_values: int = 0
    matched: MatchedRise | None = None


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
    chosen by held-out error and refitted on its flights (module doc); each airframe's head is compared with
    the others' at the steady inputs they share (:func:`~ecu_monitor.identify.matched.matched_rise`) and the
    offset recorded with its terms."""
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
            _, values = joint.split(vector)
            fitted = stage.space.to_params(vector[0, : joint.shared_dimension])
            shared = _centred(fitted, {term: v[0] for term, v in values.items()})
            joint_cost = cost
    fits: dict[str, AirframeFit] = {}
    matched = (
        matched_rise(flights, airframes)
        if all(log.has(column) for log in flights for column in MATCH_COLUMNS)
        else dict.fromkeys(names)
    )
    for name in names:
        own = [log for log, a in zip(flights, airframes, strict=True) if a == name]
        chosen, held_out = choose_terms(shared, own, candidates, settings)
        kept = _fit_airframe(shared, own, chosen, settings, name)
        model = airframe_model(shared, kept)
        head = matched[name]
        if head is not None and head.bins:
            kept = dataclasses.replace(kept, head_offset_c=head.offset_c)
        fits[name] = AirframeFit(
            kept,
            held_out,
            tuple(flight_errors(model, log) for log in own),
            tuple(flight_errors(shared, log) for log in own),
            matched=head,
        )
        say(f"airframe {name}: {describe_terms(kept)}")
    params = shared.replace(engine_type=engine_type, airframes=tuple(fits[n].terms for n in names))
    return TypeFit(params, stage, fits, joint_cost, time.perf_counter() - started)


@dataclass(frozen=True)
class Adaptation:
    """Outcome of :func:`adapt`: the airframe's model, its fit and the wall time, s; from
    :func:`adapt_choosing` also ``held_out_by_type``: the held-out RMS (degC, second halves, NaN where
    the flights were too short to halve) of the adaptation from each type model offered, and ``chosen``,
    the index of the one kept."""

    params: ThermalParams
    fit: AirframeFit
    elapsed_s: float
    held_out_by_type: tuple[float, ...] = ()
    chosen: int = 0


def adapt(
    type_params: ThermalParams,
    flights: Sequence[FlightLog],
    airframe: str,
    settings: PsoSettings,
    candidates: Sequence[str] = AIRFRAME_TERMS,
) -> Adaptation:
    """A new airframe's model from a type model and its flights: only its own terms are fitted (the type's
    shared parameters fixed), chosen among ``candidates`` by held-out error on the halves of its flights (as
    :func:`fit_type` chooses each of its airframes'); then, where those halves show it predicts better, the
    heat-map values its flights visit are refitted near the type's (:func:`choose_heat_map_prior`)."""
    if not type_params.engine_type:
        raise ParameterError("--base: not a type model (made by identify --type): it has no engine type")
    started = time.perf_counter()
    shared = type_params.replace(engine_type="", airframes=())
    chosen, held_out = choose_terms(shared, flights, candidates, settings)
    terms = _fit_airframe(shared, flights, chosen, settings, airframe)
    prior, by_prior = choose_heat_map_prior(shared, flights, chosen, settings)
    params, cells = refit_heat_map(airframe_model(shared, terms), flights, settings, prior)
    fit = AirframeFit(
        terms,
        held_out,
        tuple(flight_errors(params, log) for log in flights),
        tuple(flight_errors(shared, log) for log in flights),
        prior,
        by_prior,
        cells,
    )
    return Adaptation(params, fit, time.perf_counter() - started)


def adapt_choosing(
    type_models: Sequence[ThermalParams],
    flights: Sequence[FlightLog],
    airframe: str,
    settings: PsoSettings,
    candidates: Sequence[str] = AIRFRAME_TERMS,
) -> Adaptation:
    """:func:`adapt` from each of ``type_models`` (one type in several forms), keeping the first one's
    adaptation unless another's chosen terms predict the second halves of the flights (the held-out RMS
    :func:`choose_terms` gives) better by :data:`FORM_MIN_GAIN` or more: then the best one's. Flights too
    short to halve keep the first."""
    if not type_models:
        raise ParameterError("adapt_choosing: no type model given")
    started = time.perf_counter()
    results = [adapt(t, flights, airframe, settings, candidates) for t in type_models]
    scores = tuple(_held_out_of_kept(r.fit) for r in results)
    best_other = int(np.argmin(scores)) if all(math.isfinite(v) for v in scores) else 0
    chosen = best_other if scores[best_other] <= scores[0] * (1.0 - FORM_MIN_GAIN) else 0
    best = results[chosen]
    return Adaptation(best.params, best.fit, time.perf_counter() - started, scores, chosen)


def _held_out_of_kept(fit: AirframeFit) -> float:
    """The held-out RMS (degC) of the terms the airframe kept, NaN where its flights were not halved."""
    kept = {name for name, spec in TERMS.items() if getattr(fit.terms, spec.field) is not None}
    return next((v for subset, v in fit.held_out.items() if set(subset) == kept), math.nan)


def describe_terms(terms: AirframeTerms, heat_values: int = 0) -> str:
    """One airframe's own terms in words ("heat scale 1.042, probe lag 21.0 s" or "no terms of its own"),
    with the number of heat-map values its adaptation refitted where there are some."""
    kept = [
        f"{label} {value:.3f}" if unit == "" else f"{label} {value:.1f} {unit}"
        for label, value, unit in (
            ("heat scale", terms.heat_scale, ""),
            ("cooling scale", terms.cooling_scale, ""),
            ("probe lag", terms.probe_lag_s, "s"),
        )
        if value is not None
    ]
    if heat_values:
        kept.append(f"{heat_values} heat-map values of its own")
    return ", ".join(kept) or "no terms of its own (the type as is)"


def first_minutes(log: FlightLog, minutes: float) -> FlightLog:
    """The first ``minutes`` of a flight (from its first sample)."""
    if not (math.isfinite(minutes) and minutes > 0.0):
        raise ParameterError(f"--first-minutes: expected a positive number of minutes, got {minutes!r}")
    t0 = float(log.time_s[0])
    return log.select(t0, t0 + 60.0 * minutes)
