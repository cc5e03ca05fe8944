"""The library of candidate effects the gap diagnosis tries, each mapped to ecu_monitor.model.effects.

A candidate names one physical extension of the nominal model, the parameters refitted with it (its
*free* parameters, with start values and bounds) and the parameters it fixes from the train flight
(a reference airspeed or density, so that the nominal R_Ce keeps its meaning at the flight's typical
condition). Every candidate, and the effect-free *control*, also re-tunes the same two nominal
parameters, :data:`RETUNED_NOMINAL`: a factor on R_Ce and a factor on the whole heat map. That way a
candidate wins only by what its own term adds, not by re-tuning the nominal model (the control gets
the same re-tuning and is the yardstick of the significance test).

The candidate of each model effect is made from that effect's declarations (ecu_monitor.model.effects:
its gap text and the parameters it declares a ``GapRefit`` for); the parameters it fixes are in
:data:`REFERENCE_KEYS`. Candidates:

- ``airspeed_cooling``: conductance ``x max(floor, 1 + gain (v - v_ref))``; free gain_per_mps and
  floor; v_ref = median airborne airspeed of the train flight.
- ``density_cooling``: conductance ``x (rho/rho_ref)^exponent``; free exponent; rho_ref = median air
  density of the train flight.
- ``sensor_lag``: first-order probe lag; free time_constant_s.
- ``mixture_cooling``: heat ``x (1 - fraction * clip((load - onset)/(1 - onset), 0, 1))`` with load
  the first heat-map axis normalised over its breakpoints; free fraction and onset.

Added for real data (not in the default set, :data:`DEFAULT_CANDIDATE_IDS`; ask for it with
``--candidates``):

- ``heat_altitude_scaling``: re-fits the nominal altitude exponents a and b of
  ``g(z) = (p/p_SL)^a (T_SL/T_e)^b`` (no new term: the model's own parameters, started from the
  nominal values). It is the candidate for a heat map on fuel flow, where the fuel flow already
  carries the charge density and the paper's throttle-based exponents (a 1.55, b 2) double-count it.
- ``mixture_index``: heat ``x exp(gain (index - index_ref))``, the mixture read from the fuel/air ratio
  where the flights log the manifold pressure (the heat per unit of fuel a power of the ratio), else from
  the logged exhaust gas temperature (a richer mixture, lower EGT, cools the head); free gain;
  index_ref = the index's median over the train flights. Tried by default when every flight logs either.
- ``no_altitude_factor``: a removal candidate: the same altitude factor switched off (a = b = 0,
  nothing new fitted), the simpler answer to the same double count.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ecu_monitor.errors import ParameterError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.model import EFFECT_TYPES, Effects, air_density_kg_m3, isa_pressure_pa
from ecu_monitor.model.effects import MIXTURE_COLUMNS, MIXTURE_SOURCES, Effect, MixtureIndex, mixture_index, running_rpm

__all__ = [
    "CANDIDATES",
    "CANDIDATE_IDS",
    "CANDIDATE_SOURCES",
    "DEFAULT_CANDIDATE_IDS",
    "REFERENCE_KEYS",
    "RETUNED_NOMINAL",
    "Candidate",
    "FreeParameter",
    "candidate",
    "candidate_index",
    "candidates_for",
    "effects_for",
    "flight_references",
]

#: Nominal quantities re-tuned with every candidate (and the control): log-factors on R_Ce and on the
#: heat map, bounded to +-0.5 (a factor 0.61-1.65).
RETUNED_NOMINAL: tuple[str, ...] = ("r_ce_log_factor", "heat_log_factor")
RETUNED_BOUNDS: tuple[float, float] = (-0.5, 0.5)


@dataclass(frozen=True)
class FreeParameter:
    """A parameter refitted with its candidate: start value, bounds, and further start values
    (``restarts``) for a cost with local minima (the refit keeps the best train fit over all starts)."""

    name: str
    start: float
    low: float
    high: float
    restarts: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        for value in (self.start, *self.restarts):
            if not self.low <= value <= self.high:
                raise ParameterError(f"{self.name}: start {value} outside [{self.low}, {self.high}]")


@dataclass(frozen=True)
class Candidate:
    """One library entry: the model effect it switches on (``effect``, a field of
    ecu_monitor.model.Effects) and its free parameters; or, with ``effect`` = "nominal", nominal
    ThermalParams fields re-fitted from their nominal values (``FreeParameter.start`` is then unused)
    and/or set to ``fixed`` values (a removal candidate: a term of the nominal model switched off)."""

    id: str
    effect: str
    description: str
    free: tuple[FreeParameter, ...]
    fixed: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        if self.fixed and self.effect != "nominal":
            raise ParameterError(f"gap candidate {self.id!r}: fixed values only for nominal parameters")


def _effect_candidate(name: str, kind: type[Effect]) -> Candidate:
    """The candidate of one model effect, made from its declarations: its gap text, and the parameters it
    declares a gap refit for (:class:`ecu_monitor.model.effects.GapRefit`)."""
    free = tuple(
        FreeParameter(parameter, spec.gap.start, spec.gap.low, spec.gap.high, spec.gap.restarts)
        for parameter, spec in kind.PARAMETERS.items()
        if spec.gap is not None
    )
    return Candidate(name, name, kind.GAP_TEXT, free)


CANDIDATES: tuple[Candidate, ...] = (
    *(_effect_candidate(name, kind) for name, kind in EFFECT_TYPES.items()),
    Candidate(
        "heat_altitude_scaling",
        "nominal",
        "altitude exponents a, b of the heat into the head re-fitted (heat map on fuel flow)",
        (
            FreeParameter("a", 1.55, 0.0, 4.0),
            FreeParameter("b", 2.0, 0.0, 4.0),
        ),
    ),
    Candidate(
        "no_altitude_factor",
        "nominal",
        "removal: the altitude factor g(z) of the heat into the head switched off (a = b = 0)",
        (),
        fixed=(("a", 0.0), ("b", 0.0)),
    ),
)
CANDIDATE_IDS: tuple[str, ...] = tuple(c.id for c in CANDIDATES)
#: The candidates tried by default: the four the gap.json contract names (docs/contracts.md section 3).
DEFAULT_CANDIDATE_IDS: tuple[str, ...] = (
    "airspeed_cooling",
    "density_cooling",
    "sensor_lag",
    "mixture_cooling",
)


def candidates_for(heat_axes: Sequence[str], flights: Sequence[FlightLog]) -> tuple[str, ...]:
    """The candidates tried when the user names none: :data:`DEFAULT_CANDIDATE_IDS`, plus the removal
    ``no_altitude_factor`` when the heat map is on fuel flow (the fuel flow already carries the charge
    density that the altitude factor models: the paper's form may double-count it), plus
    ``mixture_index`` when every flight logs a mixture reading (:func:`candidate_index`)."""
    ids = list(DEFAULT_CANDIDATE_IDS)
    if "fuel_flow_lph" in heat_axes:
        ids.append("no_altitude_factor")
    if flights and candidate_index(flights) is not None:
        ids.append("mixture_index")
    return tuple(ids)


#: The indices the mixture_index candidate reads, the first whose columns every flight logs: the fuel/air
#: ratio (with the manifold pressure), else the EGT as logged.
CANDIDATE_SOURCES: tuple[str, ...] = ("fuel_air", "egt_c")


def candidate_index(flights: Sequence[FlightLog]) -> MixtureIndex | None:
    """The mixture index the flights give the mixture_index candidate (:data:`CANDIDATE_SOURCES`; None: no
    reading), when the model has none of its own; its gain and reference are unused (each model carries its own,
    fixed from :func:`flight_references`)."""
    for source in CANDIDATE_SOURCES:
        if all(log.has(name) for log in flights for name in MIXTURE_COLUMNS[source]):
            return MixtureIndex(source=source, gain=0.0, reference=MIXTURE_SOURCES[source][1])
    return None


def candidate(candidate_id: str) -> Candidate:
    """The library entry ``candidate_id``; ParameterError if unknown."""
    for entry in CANDIDATES:
        if entry.id == candidate_id:
            return entry
    raise ParameterError(f"gap candidate {candidate_id!r}: unknown (known: {', '.join(CANDIDATE_IDS)})")


def flight_references(train: FlightLog, ground_airspeed_mps: float = 12.0) -> dict[str, float]:
    """Reference conditions of the train flight: median airborne airspeed (m/s), median density (kg/m^3),
    median running engine speed (rev/min), and the median of the mixture_index candidate's index when it is
    logged (``reference_<source>``: the log of the fuel/air ratio, or the EGT in degC)."""
    airspeed = np.asarray(train["airspeed_mps"], dtype=float)
    airborne = airspeed[airspeed >= ground_airspeed_mps]
    reference_mps = float(np.median(airborne)) if airborne.size else 23.0
    pressure = np.asarray(isa_pressure_pa(np.asarray(train["altitude_m"], dtype=float)))
    density = np.asarray(air_density_kg_m3(pressure, np.asarray(train["oat_c"], dtype=float)))
    references = {
        "reference_mps": float(np.clip(reference_mps, 1.0, 200.0)),
        "reference_kg_m3": float(np.clip(np.median(density), 0.3, 1.6)),
        "reference_rpm": running_rpm([train]),
    }
    mixture = candidate_index([train])
    if mixture is not None:
        index = mixture_index(mixture.source, {name: train[name] for name in MIXTURE_COLUMNS[mixture.source]})
        _unit, low, high, _swing = MIXTURE_SOURCES[mixture.source]
        references[f"reference_{mixture.source}"] = float(np.clip(np.nanmedian(index), low, high))
    return references


#: The effect parameters the gap fixes from the train flights (not refitted): effect -> parameter -> the
#: key of :func:`flight_references` that gives it.
REFERENCE_KEYS: dict[str, dict[str, str]] = {
    "airspeed_cooling": {"reference_mps": "reference_mps"},
    "density_cooling": {"reference_kg_m3": "reference_kg_m3"},
    "mass_flow_cooling": {"reference_kg_m3": "reference_kg_m3"},
    "engine_speed_cooling": {"reference_rpm": "reference_rpm"},
    "mixture_index": {"reference": "reference_<source>"},  # the source of candidate_index
}


def _make(entry: Candidate, values: Mapping[str, float], references: Mapping[str, float]) -> Effect:
    fixed: dict[str, Any] = {}
    keys = REFERENCE_KEYS.get(entry.effect, {})
    if entry.effect == "mixture_index":  # the index whose reference the train flights gave
        given = [source for source in CANDIDATE_SOURCES if f"reference_{source}" in references]
        source = given[0] if given else CANDIDATE_SOURCES[-1]
        fixed["source"] = source
        keys = {"reference": f"reference_{source}"}
    for parameter, key in keys.items():
        if key not in references:
            raise ParameterError(f"gap candidate {entry.id!r}: the train flights give no {key}")
        fixed[parameter] = float(references[key])
    return EFFECT_TYPES[entry.effect](**fixed, **{name: float(value) for name, value in values.items()})


def effects_for(
    base: Effects,
    entries: Sequence[Candidate],
    values: Mapping[str, Mapping[str, float]],
    references: Mapping[str, float],
) -> Effects:
    """``base`` with each candidate's effect switched on at ``values[candidate.id]``; an effect ``base``
    already has keeps its other fields (its reference, a propeller wash, its index source) and takes the
    values (a warm start from an identified model keeps the form that model was identified with)."""
    effects = base
    for entry in entries:
        if entry.effect == "nominal":
            continue
        current = getattr(base, entry.effect)
        if current is not None:
            fitted = {name: float(value) for name, value in values[entry.id].items()}
            effects = effects.replace(entry.effect, dataclasses.replace(current, **fitted))
        else:
            effects = effects.replace(entry.effect, _make(entry, values[entry.id], references))
    return effects
