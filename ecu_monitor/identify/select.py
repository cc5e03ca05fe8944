"""Several flights make one model: leave-one-flight-out validation and the choice of the model's terms.

A *term* is a part of the model that one engine needs and another does not: an unmodelled-effect
extension (airspeed cooling with its propeller-wash floor, density cooling, probe lag, mixture
cooling, mixture index: the heat follows a logged lean/rich index, the mean EGT or else the fuel
per revolution), or a part of the paper's own form that can be removed (``altitude_factor``, the heat scaling
g(z), which a heat map driven by measured fuel flow already carries; ``radiation``, the T^4 term, for a
head that radiates nothing worth a parameter, used only when named) or changed (``radiation_kelvin``:
T^4 in kelvin instead of the paper's degC). :func:`model_form` switches terms on or off and names the
parameters to fit with them.

:func:`leave_one_flight_out` fits the model on all flights but one and scores the flight left out, for
every flight (the folds on every core). :func:`select_terms` (``identify --effects auto``) starts from
the *full* form (every candidate effect the flights can carry switched on, the paper form's parts as
the base has them), identified once per fold, and, round by round, toggles the one term whose toggle
gives the lowest mean held-out RMS error among those worth it: a term added must lower the error by
at least :data:`MIN_GAIN`, an effect removed must not raise it by more (the simpler form that predicts
as well wins), both against the current form and the *control* (the current form re-tuned by the same
refit with no toggle). A term is thus kept only when flights the fit never saw say it helps. An
effect toggled is screened by the gap diagnosis's warm-started local refit
(:func:`ecu_monitor.identify.refit.refit`: the term's own parameters, R_Ce and the heat scale) from
each fold's current fit, which was fitted without the flight it is scored on, so nothing leaks; a
part of the paper's form toggled (``altitude_factor``, ``radiation_kelvin``) changes what the whole
heat map means and is screened by a polish of the whole search space from the same fit. The folds of
the chosen form are then polished in the whole search space (the held-out errors reported) and the
chosen form is identified once on every flight (PSO and polish). Starting full rather than empty
matters: an effect screened locally from a poor fit (the paper form on an engine that needs three
terms) shows little of its worth, one removed from a good fit shows all of it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import FlightLogError, ParameterError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.identify.fit import IdentificationResult, identify, polish
from ecu_monitor.identify.library import CANDIDATE_IDS, Candidate, candidate
from ecu_monitor.identify.objective import SwarmObjective
from ecu_monitor.identify.parallel import run_tasks
from ecu_monitor.identify.problem import (
    DEFAULT_FREE,
    ErrorStats,
    default_space,
    flight_errors,
    reference_point,
)
from ecu_monitor.identify.pso import PsoSettings
from ecu_monitor.identify.refit import RefitSettings, refit
from ecu_monitor.identify.refit import prepare_flight as prepare_refit_flight
from ecu_monitor.model import EFFECT_NAMES, EFFECT_TYPES, ThermalParams

__all__ = [
    "MIN_GAIN",
    "TERM_NAMES",
    "CrossValidation",
    "Fold",
    "Selection",
    "identify_flights",
    "leave_one_flight_out",
    "model_form",
    "parse_terms",
    "select_terms",
    "split_halves",
    "term_is_on",
]

#: Terms that identification can switch on or off (module doc): every effect, and two parts of the paper's form.
TERM_NAMES: tuple[str, ...] = (*EFFECT_NAMES, "altitude_factor", "radiation", "radiation_kelvin")
#: Parts of the paper's form ``--effects auto`` does not toggle: the radiation, used only when named (its
#: removal was measured on JSBSim's engine, which radiates nothing, not on the real engines' term search).
_NOT_SEARCHED: tuple[str, ...] = ("radiation",)
#: The terms ``--effects auto`` searches (an effect declares whether: ``Effect.AUTO_SEARCH``).
AUTO_TERMS: tuple[str, ...] = tuple(
    n for n in TERM_NAMES if n not in _NOT_SEARCHED and (n not in EFFECT_TYPES or EFFECT_TYPES[n].AUTO_SEARCH)
)
#: A toggle is kept when it lowers the mean held-out RMS error by at least this fraction.
MIN_GAIN = 0.02
#: The paper's altitude exponents, used when the altitude factor is switched back on.
_PAPER_A, _PAPER_B = 1.55, 2.0
#: Term -> the parameters identification frees with it (each effect declares its own).
_TERM_FREE: dict[str, tuple[str, ...]] = {
    **{name: tuple(f"effects.{name}.{p}" for p in kind.FREE) for name, kind in EFFECT_TYPES.items()},
    "altitude_factor": (),
    "radiation": (),
    "radiation_kelvin": (),
}


def term_is_on(params: ThermalParams, name: str) -> bool:
    """Whether a term (TERM_NAMES) is part of the model."""
    if name == "altitude_factor":
        return params.a != 0.0 or params.b != 0.0
    if name == "radiation":
        return params.term_on("radiation")
    if name == "radiation_kelvin":
        return params.radiation_in_kelvin
    if name not in _TERM_FREE:
        raise ParameterError(f"effect {name!r}: unknown (known: {', '.join(TERM_NAMES)})")
    return getattr(params.effects, name) is not None


def parse_terms(text: str) -> dict[str, bool]:
    """'airspeed_cooling,-altitude_factor' -> {name: on}; a leading '-' switches a term off."""
    out: dict[str, bool] = {}
    for item in (part.strip() for part in text.split(",")):
        if not item:
            continue
        on = not item.startswith("-")
        name = item.lstrip("+-")
        if name not in TERM_NAMES:
            raise ParameterError(f"--effects {item!r}: unknown term (known: {', '.join(TERM_NAMES)}, or auto)")
        out[name] = on
    if not out:
        raise ParameterError("--effects: expected term names (e.g. airspeed_cooling,-altitude_factor) or auto")
    return out


def _set_term(params: ThermalParams, name: str, on: bool, flights: Sequence[FlightLog]) -> ThermalParams:
    """params with one term switched on (starting values from the data) or off."""
    if term_is_on(params, name) == on:
        return params
    if name == "altitude_factor":
        return params.replace(a=_PAPER_A if on else 0.0, b=_PAPER_B if on else 0.0)
    if name == "radiation":
        off = tuple(t for t in params.terms_off if t != "radiation") + (() if on else ("radiation",))
        return params.replace(terms_off=off)
    if name == "radiation_kelvin":
        return _switch_radiation_units(params, on, flights)
    if not on:
        return params.replace(effects=params.effects.replace(name, None))
    effect = EFFECT_TYPES[name].start(flights)  # the effect's own start rule
    return params.replace(effects=params.effects.replace(name, effect))


def _switch_radiation_units(params: ThermalParams, kelvin: bool, flights: Sequence[FlightLog]) -> ThermalParams:
    """Change the radiation form keeping the radiated heat at the data's reference operating point."""
    oat, rise = reference_point(flights)
    old = 273.15 if params.radiation_in_kelvin else 0.0
    new = 273.15 if kelvin else 0.0
    old_t4 = (oat + rise + old) ** 4 - (oat + old) ** 4
    new_t4 = (oat + rise + new) ** 4 - (oat + new) ** 4
    alpha = params.alpha_r_e * new_t4 / old_t4 if math.isfinite(params.alpha_r_e) else math.inf
    return params.replace(radiation_in_kelvin=kelvin, alpha_r_e=max(alpha, 1.0))


def model_form(
    base: ThermalParams, flights: Sequence[FlightLog], terms: dict[str, bool], free: Sequence[str] = DEFAULT_FREE
) -> tuple[ThermalParams, tuple[str, ...]]:
    """The base with the given terms switched on/off, and the free parameters: ``free`` plus the
    parameters of every effect that is on."""
    params = base
    for name, on in terms.items():
        params = _set_term(params, name, on, flights)
    names = [n for n in free if not n.startswith("effects.")]
    if not term_is_on(params, "radiation"):  # nothing radiates: alpha_r_e is not read
        names = [n for n in names if n != "alpha_r_e"]
    for name in TERM_NAMES:
        if term_is_on(params, name):
            names += [n for n in _TERM_FREE[name] if n not in names]
    return params, tuple(names)


def _form_label(params: ThermalParams) -> str:
    on = [name for name in TERM_NAMES if term_is_on(params, name)]
    return ", ".join(on) if on else "paper form without altitude factor"


# --------------------------------------------------------------------------------------------------
# Leave one flight out
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Fold:
    """One flight held out: the model fitted on the others and its errors on the held-out flight."""

    held_out: str  # the held-out flight's source
    params: ThermalParams
    errors: ErrorStats  # on the held-out flight (reference step)
    train_cost: float  # the fit's cost on its training flights, degC


@dataclass(frozen=True)
class CrossValidation:
    """Leave-one-flight-out result: one fold per flight."""

    folds: tuple[Fold, ...]

    @property
    def rms_c(self) -> NDArray[np.float64]:
        """Held-out RMS error of each flight, degC."""
        return np.asarray([f.errors.rms_c for f in self.folds])

    @property
    def mean_rms_c(self) -> float:
        """Mean held-out RMS error over the flights, degC (inf if any fold failed)."""
        values = self.rms_c
        return float(values.mean()) if np.all(np.isfinite(values)) else math.inf


def _fold_flights(flights: Sequence[FlightLog], k: int) -> list[FlightLog]:
    return [log for i, log in enumerate(flights) if i != k]


@dataclass(frozen=True)
class _Shared:
    """What every fold task reads (a forked worker inherits it): the flights and the settings."""

    flights: tuple[FlightLog, ...]
    settings: PsoSettings
    error_dt_s: float | None
    free: tuple[str, ...] = DEFAULT_FREE


def _identify_fold(shared: _Shared, task: tuple[int, ThermalParams, tuple[str, ...], tuple[str, str], Any]) -> Fold:
    """Identify (PSO and polish) on every flight but ``k`` from ``base``; score flight ``k``."""
    k, base, free, heat_axes, grid = task
    train = _fold_flights(shared.flights, k)
    result = identify(train, base=base, heat_axes=heat_axes, free=free, grid=grid, settings=shared.settings)
    errors = flight_errors(result.params, shared.flights[k], shared.error_dt_s)
    return Fold(shared.flights[k].source, result.params, errors, result.best_cost)


def leave_one_flight_out(
    flights: Sequence[FlightLog],
    base: ThermalParams | Sequence[ThermalParams],
    free: Sequence[str],
    heat_axes: tuple[str, str],
    grid: tuple[int, int] | None,
    settings: PsoSettings,
    error_dt_s: float | None = None,
    progress: Callable[[str], None] | None = None,
) -> CrossValidation:
    """Identify on every flight but one and score the one left out, for each flight (at least 2), the
    folds on every core. ``base``: one start for every fold, or one per fold (a warm start that has not
    seen its held-out flight; the swarm holds it as one particle)."""
    if len(flights) < 2:
        raise ParameterError("leave-one-flight-out needs at least 2 flights")
    bases = [base] * len(flights) if isinstance(base, ThermalParams) else list(base)
    shared = _Shared(tuple(flights), settings, error_dt_s)
    tasks = [(k, bases[k], tuple(free), heat_axes, grid) for k in range(len(flights))]
    folds = run_tasks(_identify_fold, shared, tasks, "leave-one-flight-out identifications", progress)
    return CrossValidation(tuple(folds))


def _screen_entries(name: str, on: bool) -> list[Candidate]:
    """The library candidates whose parameters the screening refit frees with a toggle: the term's own
    when it is switched on (the altitude exponents for the altitude factor), none for a removal (the
    refit then re-tunes only R_Ce and the heat scale, as the gap's control does)."""
    if not on:
        return []
    if name == "altitude_factor":
        return [candidate("heat_altitude_scaling")]
    return [candidate(name)] if name in CANDIDATE_IDS else []


def _screen_fold(shared: _Shared, task: tuple[int, ThermalParams, str, bool]) -> Fold:
    """Fold ``k``'s current fit with one effect toggled (none for ``name`` ""), refitted locally (the gap's
    joint least squares of the term's parameters, R_Ce and the heat scale,
    :func:`ecu_monitor.identify.refit.refit`) on the fold's training flights; scored on the flight held out.
    A part of the paper's form toggled is polished in the whole search space instead."""
    k, params, name, on = task
    train = _fold_flights(shared.flights, k)
    start = _set_term(params, name, on, train) if name else params  # "": the control
    if name and name not in EFFECT_TYPES:
        # a part of the paper's form (the altitude factor, the radiation's units) changes what the whole
        # heat map means: two scale factors cannot judge it, a polish of the whole search space can
        return _polish_fold(shared, (k, start, model_form(start, train, {}, shared.free)[1]))
    dt = shared.settings.dt_s
    prepared = [prepare_refit_flight(log, start.heat_axes, dt, start.effects.mixture_index) for log in train]
    fit = refit(start, prepared, _screen_entries(name, on), {}, RefitSettings(dt_s=dt))
    errors = flight_errors(fit.params, shared.flights[k], shared.error_dt_s)
    return Fold(shared.flights[k].source, fit.params, errors, fit.train_rms_c)


def _polish_fold(shared: _Shared, task: tuple[int, ThermalParams, tuple[str, ...]]) -> Fold:
    """Fold ``k``'s fit polished in the whole search space (every free parameter, the heat map
    breakpoints) on the fold's training flights, and scored on the flight held out."""
    k, start, free = task
    train = _fold_flights(shared.flights, k)
    space = default_space(train, base=start, heat_axes=start.heat_axes, free=free)
    objective = SwarmObjective(train, space, shared.settings.dt_s)
    unit, cost = polish(objective, space.to_unit(space.from_params(start)), shared.settings.polish_evaluations)
    params = space.to_params(space.from_unit(unit))
    return Fold(shared.flights[k].source, params, flight_errors(params, shared.flights[k], shared.error_dt_s), cost)


#: Shortest half-flight ``--effects auto`` splits a single flight into, s.
MIN_HALF_S = 600.0


def split_halves(log: FlightLog) -> list[FlightLog]:
    """A single flight cut at its middle time into two flights (for held-out choices on one flight)."""
    t = np.asarray(log.time_s, dtype=float)
    middle = t[0] + 0.5 * (t[-1] - t[0])
    if middle - t[0] < MIN_HALF_S:
        raise ParameterError(
            f"{log.source}: --effects auto on one flight needs {2 * MIN_HALF_S:.0f} s at least (two halves that"
            " predict each other); give more flights or name the terms"
        )
    first = log.select(t[0], middle)
    second = log.select(float(t[t > middle][0]), t[-1])
    return [first, second]


@dataclass(frozen=True)
class Selection:
    """Outcome of :func:`select_terms`.

    terms: the chosen on/off state of every term; steps: (toggle, mean held-out RMS degC) of each
    candidate tried, round by round ("start" = the base form), and whether it was kept.
    cross_validation: the folds of the chosen form (polished fold fits).
    """

    terms: dict[str, bool]
    steps: tuple[tuple[int, str, float, bool], ...]
    cross_validation: CrossValidation
    elapsed_s: float


def _full_form(base: ThermalParams, flights: Sequence[FlightLog], candidates: Sequence[str]) -> dict[str, bool]:
    """Every candidate effect switched on that the flights can start (a term that needs a column the flights
    lack stays off and out of the search); the paper form's parts as the base has them."""
    terms = {}
    for name in candidates:
        if name not in EFFECT_TYPES:
            continue
        try:
            _set_term(base, name, True, flights)
        except (FlightLogError, ParameterError):
            continue
        terms[name] = True
    return terms


def _passes(name: str, on: bool, trial: float, reference: float, min_gain: float) -> bool:
    """Whether a toggle is worth keeping: a term added must lower the held-out error by ``min_gain``; an
    effect removed must not raise it by more than that (the simpler form that predicts as well wins)."""
    if not on and name in EFFECT_TYPES:
        return trial < reference * (1.0 + min_gain)
    return trial < reference * (1.0 - min_gain)


def select_terms(
    flights: Sequence[FlightLog],
    base: ThermalParams,
    heat_axes: tuple[str, str],
    grid: tuple[int, int] | None,
    settings: PsoSettings,
    candidates: Sequence[str] = AUTO_TERMS,
    free: Sequence[str] = DEFAULT_FREE,
    min_gain: float = MIN_GAIN,
    error_dt_s: float | None = None,
    progress: Callable[[str], None] | None = None,
) -> Selection:
    """Choose the terms by leave-one-flight-out held-out error (module doc); needs at least 2 flights."""
    started = time.perf_counter()
    say = progress or (lambda line: None)
    full = _full_form(base, flights, candidates)
    usable = [name for name in candidates if name in full or name not in EFFECT_TYPES]
    start, names = model_form(base, flights, full, free)
    say(f"start ({_form_label(start)}): one identification per held-out flight")
    cv = leave_one_flight_out(flights, start, names, heat_axes, grid, settings, error_dt_s, progress)
    steps: list[tuple[int, str, float, bool]] = [(0, "start: " + _form_label(start), cv.mean_rms_c, True)]
    say(f"start ({_form_label(start)}): held-out mean RMS {cv.mean_rms_c:.2f} degC")
    state = {name: term_is_on(start, name) for name in usable}
    shared = _Shared(tuple(flights), settings, error_dt_s, tuple(free))
    n = len(cv.folds)
    for round_ in range(1, len(usable) + 1):
        toggles = [(name, not state[name]) for name in usable if name not in _toggled(steps)]
        if not toggles:
            break
        # the control (no toggle, the same local re-tuning) first: a toggle is judged against it too
        tasks = [(k, fold.params, name, on) for name, on in [("", False), *toggles] for k, fold in enumerate(cv.folds)]
        label = f"round {round_}: {len(toggles)} term(s) and the control x {n} folds (local refits)"
        screened = run_tasks(_screen_fold, shared, tasks, label, progress)
        trials = [CrossValidation(tuple(screened[i * n : (i + 1) * n])) for i in range(len(toggles) + 1)]
        control = trials[0]
        reference = min(cv.mean_rms_c, control.mean_rms_c)
        say(f"round {round_}: control (current form re-tuned): held-out mean RMS {control.mean_rms_c:.2f} degC")
        best: tuple[float, str, CrossValidation] | None = None
        for (name, on), trial in zip(toggles, trials[1:], strict=True):
            label = ("+" if on else "-") + name
            steps.append((round_, label, trial.mean_rms_c, False))
            say(f"round {round_}: {label}: held-out mean RMS {trial.mean_rms_c:.2f} degC")
            if _passes(name, on, trial.mean_rms_c, reference, min_gain) and (
                best is None or trial.mean_rms_c < best[0]
            ):
                best = (trial.mean_rms_c, name, trial)
        if best is None:
            break
        _, name, cv = best
        state[name] = not state[name]
        label = ("+" if state[name] else "-") + name
        steps = [(r, s, v, kept or (r == round_ and s == label)) for r, s, v, kept in steps]
    chosen, names = model_form(base, flights, state, free)
    say(f"chosen ({_form_label(chosen)}): each fold polished in the whole search space")
    tasks_polish = [(k, fold.params, names) for k, fold in enumerate(cv.folds)]
    polished = run_tasks(_polish_fold, shared, tasks_polish, "polish of the chosen form's folds", progress)
    return Selection(state, tuple(steps), CrossValidation(tuple(polished)), time.perf_counter() - started)


def _toggled(steps: Sequence[tuple[int, str, float, bool]]) -> set[str]:
    """Terms toggled in a kept step (a term toggled once is not toggled back)."""
    return {label[1:] for r, label, _, kept in steps if kept and r > 0}


def identify_flights(
    flights: Sequence[FlightLog],
    *,
    base: ThermalParams,
    heat_axes: tuple[str, str],
    grid: tuple[int, int] | None,
    settings: PsoSettings,
    terms: dict[str, bool] | str | None = None,
    candidates: Sequence[str] = AUTO_TERMS,
    free: Sequence[str] = DEFAULT_FREE,
    lofo: bool = True,
    error_dt_s: float | None = None,
    progress: Callable[[str], None] | None = None,
    pso_progress: Callable[[int, float, float], None] | None = None,
) -> tuple[IdentificationResult, CrossValidation | None, Selection | None]:
    """The normal real-data path: choose the terms (``"auto"`` among ``candidates``, a dict, or None =
    the base's form), fit one model on every flight, and (``lofo`` with 2+ flights) its
    leave-one-flight-out errors. With one flight, ``"auto"`` chooses on its two halves (each predicts
    the other) and fits the chosen form on the whole flight. ``progress`` gets lines on the folds and
    the term search, ``pso_progress`` the swarm's iterations of the final identification."""
    selection = None
    if terms == "auto":
        chosen_on = list(flights) if len(flights) >= 2 else split_halves(flights[0])
        selection = select_terms(chosen_on, base, heat_axes, grid, settings, candidates=candidates, free=free,
                                 error_dt_s=error_dt_s, progress=progress)  # fmt: skip
        chosen = selection.terms
    else:
        chosen = dict(terms) if isinstance(terms, dict) else {}
    form, names = model_form(base, flights, chosen, free)
    cv = selection.cross_validation if selection is not None and len(flights) >= 2 else None
    if cv is None and lofo and len(flights) >= 2:
        cv = leave_one_flight_out(flights, form, names, heat_axes, grid, settings, error_dt_s, progress)
    result = identify(
        flights, base=form, heat_axes=heat_axes, free=names, grid=grid, settings=settings, progress=pso_progress
    )
    return result, cv, selection
