"""The identification problem: model inputs from a flight, open-loop simulation, errors, parameter space
and the vectorised cost over a whole swarm.

Scale degeneracy (why one scale parameter is fixed). The model's energy balance
``C_w dT/dt = g Q - (T - T_e)/R_Ce - (T^4 - T_e^4)/(alpha R_e)`` is unchanged when C_w, the heat map Q,
1/R_Ce and 1/(alpha R_e) are all multiplied by the same factor: a temperature record fixes their
ratios, never their common scale. The default space keeps ``r_ce`` at the base model's value (the
scale anchor: the model's watts are in the base model's scale) and searches everything else in
coordinates the data pin, none of which carries the unobservable scale, so no bound binds on an engine
far from the base:

- ``time_constant_s`` = C_w R_Ce (log): the convective time constant, s;
- ``heat_rise_c[i,j]`` = Q_ij R_Ce (degC): the convective-only temperature rise of each heat-map breakpoint;
- ``radiation_fraction``: the share of the heat leaving by radiation at the reference operating point
  (the training data's median OAT and median CHT - OAT), 0 (no radiation) to 0.99.

Freeing ``r_ce`` with ``alpha_r_e`` fixed (the earlier anchor) is still possible; freeing all four scale
parameters at once is refused.

The heat map carries a prior (a penalty added to the cost): second differences between neighbouring
breakpoints are small (a smooth map) and the heat does not fall as the first axis (throttle or fuel
flow: power) rises. Every breakpoint is free; breakpoints the flights hardly visit follow their
neighbours instead of trading off against the rest.

Altitude exponents a, b: one flight hardly excites them (the g1000 README: a fit drives them to
their bounds), so they are fixed at the base values by default; when freed they carry a Gaussian
prior (penalty) centred on the base values.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import ParameterError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.identify.flights import (
    IDENTIFICATION_DT_S,
    REFERENCE_DT_S,
    ErrorStats,
    FlightGrid,
    flight_errors,
    measured_cht,
    model_inputs,
    prepare_flight,
    simulate_flight,
)
from ecu_monitor.identify.heat_grid import (
    heat_map_breakpoints,
    observed_rise_map,
    reference_point,
    tied_axes,
    visited_weight_s,
)
from ecu_monitor.identify.search_settings import (
    _EFFECT_FIELDS,
    _EFFECT_TYPES,
    _KNOWN_FREE,
    _SCALE_PARAMETERS,
    BOUND_TOLERANCE,
    DEFAULT_FREE,
    HEAT_MONOTONE_SIGMA_C,
    HEAT_SMOOTH_SIGMA,
    MAX_RADIATION_FRACTION,
    MIN_VISIT_S,
    PRIOR_SCALE_C,
    TIME_CONSTANT_BOUNDS_S,
)
from ecu_monitor.model import Coefficients, HeatMap, ThermalParams, coefficients
from ecu_monitor.model.effects import MixtureIndex

__all__ = [
    "DEFAULT_FREE",
    "IDENTIFICATION_DT_S",
    "REFERENCE_DT_S",
    "ErrorStats",
    "FlightGrid",
    "ParameterSpace",
    "default_space",
    "flight_errors",
    "heat_cell_name",
    "heat_map_breakpoints",
    "model_inputs",
    "observed_rise_map",
    "prepare_flight",
    "reference_point",
    "simulate_flight",
    "visited_weight_s",
]


# --------------------------------------------------------------------------------------------------
# Parameter space
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ParameterSpace:
    """The search space: coordinates, bounds, scaling and priors, over a base ThermalParams.

    names: search coordinates (see the module doc): "r_ce", "time_constant_s" (= C_w R_Ce, s),
        "c_w" (only when R_Ce is fixed), "tau_w", "alpha_r_e", "a", "b", "heat_rise_c[i,j]"
        (= Q_ij R_Ce, degC) and effect parameters "effects.<effect>.<parameter>".
    lower, upper: bounds of each coordinate (physical units of the coordinate).
    log_scaled: True where the optimiser searches the logarithm (positive scale parameters).
    prior_mean, prior_sigma: Gaussian prior of each coordinate (NaN sigma = none).
    heat_cells: (i, j) of the heat-map values identified; the other (unvisited) cells copy the value
        of the nearest identified cell when ``fill_unvisited`` (as default_space sets), else keep the base value.
    reference_rise_c, reference_oat_c: the operating point where ``radiation_fraction`` is defined
        (CHT - OAT and OAT, degC).
    heat_smooth_sigma_c, heat_monotone_sigma_c: heat-map prior (module doc), degC; NaN = no prior.
    """

    base: ThermalParams
    names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    log_scaled: tuple[bool, ...]
    prior_mean: tuple[float, ...]
    prior_sigma: tuple[float, ...]
    heat_cells: tuple[tuple[int, int], ...] = ()
    fill_unvisited: bool = False
    reference_rise_c: float = 100.0
    reference_oat_c: float = 15.0
    heat_smooth_sigma_c: float = math.nan
    heat_monotone_sigma_c: float = math.nan
    _index: dict[str, int] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        d = len(self.names)
        for label in ("lower", "upper", "log_scaled", "prior_mean", "prior_sigma"):
            if len(getattr(self, label)) != d:
                raise ParameterError(f"parameter space: {label} has {len(getattr(self, label))} entries, expected {d}")
        if d == 0:
            raise ParameterError("parameter space: no free parameter")
        if len(set(self.names)) != d:
            raise ParameterError("parameter space: repeated coordinate names")
        for name, lo, hi, logs in zip(self.names, self.lower, self.upper, self.log_scaled, strict=True):
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ParameterError(f"parameter space: {name}: expected finite bounds lower < upper, got [{lo}, {hi}]")
            if logs and lo <= 0.0:
                raise ParameterError(f"parameter space: {name}: a log-scaled coordinate needs a positive lower bound")
        object.__setattr__(self, "_index", {name: k for k, name in enumerate(self.names)})

    @property
    def dimension(self) -> int:
        """Number of search coordinates."""
        return len(self.names)

    # unit cube <-> coordinates ---------------------------------------------------------------------

    def _edges(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        logs = np.asarray(self.log_scaled, dtype=bool)
        lo = np.asarray(self.lower, dtype=float)
        hi = np.asarray(self.upper, dtype=float)
        return (
            np.where(logs, np.log(np.where(logs, lo, 1.0)), lo),
            np.where(logs, np.log(np.where(logs, hi, 1.0)), hi),
            logs,
        )

    def from_unit(self, unit: NDArray[np.float64]) -> NDArray[np.float64]:
        """Coordinates from points of the unit cube (..., D) (log-scaled ones are log-uniform)."""
        lo, hi, logs = self._edges()
        raw = lo + np.clip(unit, 0.0, 1.0) * (hi - lo)
        return np.where(logs, np.exp(np.where(logs, raw, 0.0)), raw)

    def to_unit(self, vector: NDArray[np.float64]) -> NDArray[np.float64]:
        """Points of the unit cube from coordinates (clipped to the bounds)."""
        lo, hi, logs = self._edges()
        v = np.clip(np.asarray(vector, dtype=float), self.lower, self.upper)
        raw = np.where(logs, np.log(np.where(logs, v, 1.0)), v)
        return (raw - lo) / (hi - lo)

    # coordinates <-> parameters --------------------------------------------------------------------

    def _column(self, matrix: NDArray[np.float64], name: str) -> NDArray[np.float64] | None:
        k = self._index.get(name)
        return None if k is None else matrix[:, k]

    def coefficient_arrays(self, vectors: NDArray[np.float64]) -> Coefficients:
        """Kernel coefficients of a swarm of coordinate vectors (P, D): arrays (P,), heat (P, n, m)."""
        v = np.atleast_2d(np.asarray(vectors, dtype=float))
        p = v.shape[0]
        base = coefficients(self.base)
        fields_: dict[str, Any] = {}
        for name in Coefficients._fields:
            if name in ("radiation_offset_c", "x_breakpoints", "y_breakpoints", "heat_values_w"):
                continue
            fields_[name] = np.full(p, float(getattr(base, name)))
        r_ce = self._column(v, "r_ce")
        if r_ce is not None:
            fields_["r_ce"] = r_ce.copy()
        tc = self._column(v, "time_constant_s")
        if tc is not None:
            fields_["c_w"] = tc / fields_["r_ce"]
        c_w = self._column(v, "c_w")
        if c_w is not None:
            fields_["c_w"] = c_w.copy()
        for name in ("tau_w", "a", "b"):
            col = self._column(v, name)
            if col is not None:
                fields_[name] = col.copy()
        alpha = self._column(v, "alpha_r_e")
        if alpha is not None:
            fields_["radiative_conductance"] = 1.0 / alpha
        fraction = self._column(v, "radiation_fraction")
        if fraction is not None:
            fields_["radiative_conductance"] = (
                fraction / (1.0 - fraction) * self.reference_rise_c / fields_["r_ce"] / self._reference_t4(base)
            )
        for name, (target, *_rest) in _EFFECT_FIELDS.items():
            col = self._column(v, name)
            if col is not None:
                fields_[target] = col.copy()
        heat = np.broadcast_to(self.base.heat_map.values_array(), (p, *self.base.heat_map.shape)).copy()
        if self.heat_cells:
            rises = np.stack([v[:, self._index[heat_cell_name(i, j)]] for i, j in self.heat_cells], axis=1)
            values = rises / fields_["r_ce"][:, None]
            for k, (i, j) in enumerate(self.heat_cells):
                heat[:, i, j] = values[:, k]
            if self.fill_unvisited:
                for (i, j), source in _nearest_cells(self.base.heat_map.shape, self.heat_cells).items():
                    heat[:, i, j] = heat[:, source[0], source[1]]
        fields_["heat_values_w"] = heat
        fields_["radiation_offset_c"] = base.radiation_offset_c
        fields_["x_breakpoints"] = base.x_breakpoints
        fields_["y_breakpoints"] = base.y_breakpoints
        return Coefficients(**fields_)

    def _reference_t4(self, base: Coefficients) -> float:
        """(T^4 - T_e^4) at the reference operating point, in the model's radiation units."""
        offset = base.radiation_offset_c
        t_k = self.reference_oat_c + self.reference_rise_c + offset
        e_k = self.reference_oat_c + offset
        return t_k**4 - e_k**4

    def radiation_share(self, params: ThermalParams) -> float:
        """Share of the heat leaving by radiation at the reference operating point (0..1)."""
        base = coefficients(params)
        radiated = float(base.radiative_conductance) * self._reference_t4(base)
        convected = self.reference_rise_c / params.r_ce
        return radiated / (radiated + convected)

    def to_params(self, vector: NDArray[np.float64]) -> ThermalParams:
        """The ThermalParams of one coordinate vector (raises ParameterError if outside physical ranges)."""
        c = self.coefficient_arrays(np.asarray(vector, dtype=float)[None, :])
        changes: dict[str, Any] = {name: float(np.asarray(getattr(c, name))[0]) for name in ("c_w", "r_ce", "tau_w")}
        # a and b: searched, or the base's own (the kernel's 0 when the altitude term is off is not the model's value)
        changes.update({name: float(vector[self._index[name]]) for name in ("a", "b") if name in self._index})
        changes.update(
            {
                "heat_map": self.base.heat_map.with_values(np.maximum(c.heat_values_w[0], 0.0)),
            }
        )
        if "alpha_r_e" in self._index:
            changes["alpha_r_e"] = float(vector[self._index["alpha_r_e"]])
        if "radiation_fraction" in self._index:
            conductance = float(np.asarray(c.radiative_conductance)[0])
            changes["alpha_r_e"] = 1.0 / conductance if conductance > 0.0 else math.inf
        effects = self.base.effects
        for name in _EFFECT_FIELDS:
            if name in self._index:
                effect, parameter = name.split(".")[1:]
                current = getattr(effects, effect)
                effects = effects.replace(
                    effect,
                    _EFFECT_TYPES[effect](**{**_effect_dict(current), parameter: float(vector[self._index[name]])}),
                )
        changes["effects"] = effects
        return self.base.replace(**changes)

    def from_params(self, params: ThermalParams) -> NDArray[np.float64]:
        """The coordinate vector of a ThermalParams (same axes and breakpoints as the base), unclipped."""
        if params.heat_map.shape != self.base.heat_map.shape:
            raise ParameterError("from_params: heat map shape differs from the parameter space's")
        values = params.heat_map.values_array()
        out = np.empty(self.dimension)
        for k, name in enumerate(self.names):
            if name == "time_constant_s":
                out[k] = params.c_w * params.r_ce
            elif name == "radiation_fraction":
                out[k] = self.radiation_share(params)
            elif name.startswith("heat_rise_c["):
                i, j = _parse_cell(name)
                out[k] = values[i, j] * params.r_ce
            elif name.startswith("effects."):
                effect, parameter = name.split(".")[1:]
                current = getattr(params.effects, effect)
                if current is None:
                    raise ParameterError(f"from_params: effect '{effect}' is off in the given model")
                out[k] = float(getattr(current, parameter))
            else:
                out[k] = float(getattr(params, name))
        return out

    def prior_penalty(self, vectors: NDArray[np.float64]) -> NDArray[np.float64]:
        """Prior penalty of each vector (P,), in degC^2 (added to the mean squared error)."""
        residuals = self.prior_residual_matrix(vectors)
        return np.sum(residuals * residuals, axis=1)

    def prior_residuals(self, vector: NDArray[np.float64]) -> NDArray[np.float64]:
        """Prior terms of one vector as residuals (degC), for least squares."""
        return self.prior_residual_matrix(np.asarray(vector, dtype=float)[None, :])[0]

    def prior_residual_matrix(self, vectors: NDArray[np.float64]) -> NDArray[np.float64]:
        """Prior terms as residuals (P, R), degC: Gaussian priors of single coordinates, then the heat map's."""
        v = np.atleast_2d(np.asarray(vectors, dtype=float))
        sigma = np.asarray(self.prior_sigma, dtype=float)
        has = np.isfinite(sigma) & (sigma > 0)
        mean = np.asarray(self.prior_mean, dtype=float)
        parts = [PRIOR_SCALE_C * (v[:, has] - mean[has]) / sigma[has]]
        if self.heat_cells and math.isfinite(self.heat_smooth_sigma_c):
            parts.append(self._heat_prior(v))
        return np.concatenate(parts, axis=1)

    def heat_rises(self, vectors: NDArray[np.float64]) -> NDArray[np.float64]:
        """Heat-map temperature rises Q R_Ce (P, n, m), degC, unidentified cells filled as in the model."""
        v = np.atleast_2d(np.asarray(vectors, dtype=float))
        c = self.coefficient_arrays(v)
        return np.asarray(c.heat_values_w) * np.asarray(c.r_ce, dtype=float)[:, None, None]

    def _heat_prior(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        rise = self.heat_rises(v)
        n, m = rise.shape[1:]
        parts = []
        if n >= 3:
            parts.append((rise[:, 2:, :] - 2.0 * rise[:, 1:-1, :] + rise[:, :-2, :]).reshape(v.shape[0], -1))
        if m >= 3:
            parts.append((rise[:, :, 2:] - 2.0 * rise[:, :, 1:-1] + rise[:, :, :-2]).reshape(v.shape[0], -1))
        smooth = np.concatenate(parts, axis=1) / self.heat_smooth_sigma_c if parts else np.zeros((v.shape[0], 0))
        fall = np.maximum(rise[:, :-1, :] - rise[:, 1:, :], 0.0).reshape(v.shape[0], -1)
        return PRIOR_SCALE_C * np.concatenate([smooth, fall / self.heat_monotone_sigma_c], axis=1)

    def at_bounds(self, vector: NDArray[np.float64], tolerance: float = BOUND_TOLERANCE) -> list[str]:
        """Coordinates within ``tolerance`` of the range (in search units) of a bound, as readable lines."""
        unit = self.to_unit(np.asarray(vector, dtype=float))
        out = []
        for k, name in enumerate(self.names):
            if unit[k] <= tolerance:
                out.append(f"{name} = {vector[k]:.4g} at its lower bound {self.lower[k]:.4g}")
            elif unit[k] >= 1.0 - tolerance:
                out.append(f"{name} = {vector[k]:.4g} at its upper bound {self.upper[k]:.4g}")
        return out


def heat_cell_name(i: int, j: int) -> str:
    """The search coordinate of heat-map value (i, j): its temperature rise, degC."""
    return f"heat_rise_c[{i},{j}]"


def _parse_cell(name: str) -> tuple[int, int]:
    inner = name[name.index("[") + 1 : name.index("]")]
    i, j = inner.split(",")
    return int(i), int(j)


def _effect_dict(effect: Any) -> dict[str, Any]:
    return {f.name: getattr(effect, f.name) for f in dataclasses.fields(effect)}


def _nearest_cells(shape: tuple[int, int], cells: Sequence[tuple[int, int]]) -> dict[tuple[int, int], tuple[int, int]]:
    """For every cell not in ``cells``: the nearest one in ``cells`` (grid-index distance, ties by order)."""
    chosen = set(cells)
    out: dict[tuple[int, int], tuple[int, int]] = {}
    for i in range(shape[0]):
        for j in range(shape[1]):
            if (i, j) not in chosen:
                out[(i, j)] = min(cells, key=lambda c: (c[0] - i) ** 2 + (c[1] - j) ** 2)
    return out


def default_space(
    flights: Sequence[FlightLog],
    base: ThermalParams | None = None,
    heat_axes: tuple[str, str] = ("throttle_pct", "rpm"),
    grid: tuple[int, int] | None = None,
    free: Sequence[str] = DEFAULT_FREE,
    min_visit_s: float = MIN_VISIT_S,
    heat_prior: bool = True,
) -> ParameterSpace:
    """The default search space for ``flights``.

    Base: ``base`` or the paper's Table A1. The heat map keeps the base's breakpoints when the base has
    the same axes and no ``grid`` is asked; otherwise an n x m grid (default 4 x 4) at the data's
    quantiles (:func:`heat_map_breakpoints`), started flat at the median temperature rise. Bounds:
    time constant C_w R_Ce in :data:`TIME_CONSTANT_BOUNDS_S`; radiation fraction in [0, 0.99];
    tau_w in [1, 120] s; heat rise Q R_Ce in [0, 4 x the largest observed CHT - OAT]; R_Ce within
    x30 of the base and alpha_r_e within x100 when freed instead; a, b in [0, 4] with a N(base, 0.5)
    prior; effect parameters within their physical ranges. With ``heat_prior`` every breakpoint is
    free under the smoothness and monotonicity prior; without it only breakpoints the flights visit
    (>= ``min_visit_s`` seconds of bilinear weight) are free and the others copy the nearest.
    """
    from ecu_monitor.model import paper_table_a1

    if not flights:
        raise ParameterError("identification needs at least one flight")
    unknown = [name for name in free if name not in _KNOWN_FREE]
    if unknown:
        raise ParameterError(
            f"free parameter(s) {', '.join(unknown)}: unknown (known: {', '.join(sorted(_KNOWN_FREE))})"
        )
    if set(free) >= _SCALE_PARAMETERS:
        raise ParameterError(
            "c_w, r_ce, alpha_r_e and the heat map share one scale that temperature data cannot fix:"
            " keep one of them fixed"
        )
    base = paper_table_a1() if base is None else base
    rise = np.concatenate([measured_cht(log) - np.asarray(model_inputs(log, heat_axes).oat_c) for log in flights])
    reference_oat_c, reference_rise_c = reference_point(flights)
    max_rise = max(20.0, float(np.quantile(rise, 0.99)))
    fill = True
    if grid is not None or base.heat_axes != tuple(heat_axes):
        xb, yb = heat_map_breakpoints(flights, heat_axes, grid or (4, 4))
        flat = HeatMap(heat_axes[0], heat_axes[1], xb, yb, tuple(tuple(1.0 for _ in yb) for _ in xb))
        values = observed_rise_map(flights, flat) / base.r_ce
        base = base.replace(heat_map=flat.with_values(values))
    names: list[str] = []
    lower: list[float] = []
    upper: list[float] = []
    logs: list[bool] = []
    mean: list[float] = []
    sigma: list[float] = []

    def add(
        name: str, lo: float, hi: float, log_scaled: bool, prior: tuple[float, float] = (math.nan, math.nan)
    ) -> None:
        names.append(name)
        lower.append(float(lo))
        upper.append(float(hi))
        logs.append(log_scaled)
        mean.append(prior[0])
        sigma.append(prior[1])

    free_set = set(free)
    if "r_ce" in free_set:
        add("r_ce", max(1e-4, base.r_ce / 30.0), min(100.0, base.r_ce * 30.0), True)
    if "c_w" in free_set:
        add("time_constant_s", *TIME_CONSTANT_BOUNDS_S, True)
    if "tau_w" in free_set:
        add("tau_w", 1.0, 120.0, True)
    if "alpha_r_e" in free_set and "r_ce" in free_set:
        add("alpha_r_e", base.alpha_r_e / 100.0, base.alpha_r_e * 100.0, True)
    elif "alpha_r_e" in free_set:
        add("radiation_fraction", 0.0, MAX_RADIATION_FRACTION, False)
    for name in ("a", "b"):
        if name in free_set:
            add(name, 0.0, 4.0, False, (float(getattr(base, name)), 0.5))
    for name in free:
        if name.startswith("effects."):
            effect = name.split(".")[1]
            if getattr(base.effects, effect) is None:
                raise ParameterError(f"free parameter {name}: the effect is off in the base model (switch it on first)")
            _target, lo, hi, log_scaled = _EFFECT_FIELDS[name]
            mixture = base.effects.mixture_index
            if name == "effects.mixture_index.gain" and mixture is not None:  # |gain| x typical swing <= 3
                lo, hi = -MixtureIndex.gain_reach(mixture.source), MixtureIndex.gain_reach(mixture.source)
            add(name, lo, hi, log_scaled)
    cells: list[tuple[int, int]] = []
    if "heat_map" in free_set:
        weight = visited_weight_s(flights, base.heat_map)
        threshold = 0.0 if heat_prior else min_visit_s
        tied_x, tied_y = tied_axes(grid)  # a tied axis: its first breakpoint identified, the others copy it
        weight = weight.sum(axis=0, keepdims=True) if tied_x else weight
        weight = weight.sum(axis=1, keepdims=True) if tied_y else weight
        cells = [(i, j) for i in range(weight.shape[0]) for j in range(weight.shape[1]) if weight[i, j] >= threshold]
        if not cells:
            raise ParameterError(
                f"heat map: no breakpoint is visited for {min_visit_s:g} s by the flights; choose a coarser grid"
            )
        for i, j in cells:
            add(heat_cell_name(i, j), 0.0, 4.0 * max_rise, False)
    return ParameterSpace(
        base=base,
        names=tuple(names),
        lower=tuple(lower),
        upper=tuple(upper),
        log_scaled=tuple(logs),
        prior_mean=tuple(mean),
        prior_sigma=tuple(sigma),
        heat_cells=tuple(cells),
        fill_unvisited=fill,
        reference_rise_c=reference_rise_c,
        reference_oat_c=reference_oat_c,
        heat_smooth_sigma_c=HEAT_SMOOTH_SIGMA * max_rise if heat_prior else math.nan,
        heat_monotone_sigma_c=HEAT_MONOTONE_SIGMA_C if heat_prior else math.nan,
    )
