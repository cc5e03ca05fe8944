"""Each effect carries its own definition (ecu_monitor.model.effects.Effect): the coefficients, the
validation, identification's terms, free parameters, search space and start, the gap library's wording
and the virtual plant's draws are all made from it, so a new effect is one entry there (plus its term)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ecu_monitor.errors import ParameterError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.identify import search_settings
from ecu_monitor.identify.library import CANDIDATES
from ecu_monitor.identify.select import TERM_NAMES, model_form
from ecu_monitor.model import EFFECT_COEFFICIENTS, EFFECT_TYPES, Coefficients, coefficients, paper_table_a1
from virtual_bus.faults import PLANT_EFFECTS, random_effects


def _flight(egt: bool) -> FlightLog:
    rng = np.random.default_rng(5)
    n = 400
    columns = {
        "time_s": np.arange(n, dtype=float),
        "throttle_pct": rng.uniform(20, 100, n),
        "rpm": rng.uniform(2000, 5500, n),
        "fuel_flow_lph": rng.uniform(5, 30, n),
        "altitude_m": rng.uniform(0, 3000, n),
        "airspeed_mps": rng.uniform(0, 45, n),
        "oat_c": rng.uniform(-5, 30, n),
        "cht_c": rng.uniform(90, 150, n),
    }
    if egt:
        columns["egt_c"] = rng.uniform(550, 750, n)
    return FlightLog(columns)


@pytest.mark.parametrize("name", list(EFFECT_TYPES))
def test_every_declared_parameter_is_a_field_with_a_coefficient_and_ranges(name: str) -> None:
    kind = EFFECT_TYPES[name]
    numeric = [f.name for f in dataclasses.fields(kind) if f.name != "source"]
    assert list(kind.PARAMETERS) == numeric  # every numeric field declared, in field order
    assert set(kind.FREE) <= set(kind.PARAMETERS)
    assert kind.GAP_TEXT
    default = kind()
    for parameter, spec in kind.PARAMETERS.items():
        assert spec.coefficient in Coefficients._fields
        assert EFFECT_COEFFICIENTS[f"{name}.{parameter}"] == (spec.coefficient, spec.neutral)
        assert spec.search[0] < spec.search[1]
        if spec.valid is not None:
            low, high = spec.valid
            assert low <= spec.search[0] and spec.search[1] <= high  # the search stays physical
            assert low <= getattr(default, parameter) <= high
            with pytest.raises(ParameterError, match=rf"effects\.{name}\.{parameter}: expected a number in"):
                kind(**{parameter: high + 1.0 + abs(high)})


@pytest.mark.parametrize("name", list(EFFECT_TYPES))
def test_identification_starts_and_frees_each_effect_from_its_declaration(name: str) -> None:
    flights = [_flight(egt=True), _flight(egt=False)] if name != "mixture_index" else [_flight(egt=True)]
    terms = {"airspeed_cooling": True, name: True} if name == "mass_flow_cooling" else {name: True}  # it needs it
    params, free = model_form(paper_table_a1(), flights, terms)
    effect = getattr(params.effects, name)
    assert isinstance(effect, EFFECT_TYPES[name])
    assert effect == EFFECT_TYPES[name].start(flights)
    own = [n for n in free if n.startswith(f"effects.{name}.")]
    assert own == [f"effects.{name}.{p}" for p in EFFECT_TYPES[name].FREE]
    for parameter, spec in EFFECT_TYPES[name].PARAMETERS.items():
        field, low, high, _log = search_settings._EFFECT_FIELDS[f"effects.{name}.{parameter}"]
        assert (field, (low, high)) == (spec.coefficient, spec.search)
    # the model's coefficients carry the started values; an effect off carries the neutral ones
    on = coefficients(params)
    off = coefficients(paper_table_a1())
    for parameter, spec in EFFECT_TYPES[name].PARAMETERS.items():
        assert getattr(on, spec.coefficient) == getattr(effect, parameter)
        assert getattr(off, spec.coefficient) == spec.neutral
    assert name in TERM_NAMES


def test_mixture_index_starts_on_fuel_per_rev_without_egt() -> None:
    flights = [_flight(egt=False)]
    effect = EFFECT_TYPES["mixture_index"].start(flights)
    log = flights[0]
    expected = np.median(np.asarray(log["fuel_flow_lph"]) * (1000.0 / 60.0) / np.asarray(log["rpm"]))
    assert effect.source == "fuel_per_rev" and effect.gain == 0.0
    assert math.isclose(effect.reference, float(expected), rel_tol=1e-12)


def test_the_gap_library_and_the_virtual_plant_read_the_declarations() -> None:
    for candidate in CANDIDATES:
        if candidate.effect in EFFECT_TYPES:
            assert candidate.description == EFFECT_TYPES[candidate.effect].GAP_TEXT
    drawn = random_effects(11)
    assert set(drawn.active) == set(PLANT_EFFECTS)
    for name in PLANT_EFFECTS:
        kind = EFFECT_TYPES[name]
        for parameter, spec in kind.PARAMETERS.items():
            value = getattr(getattr(drawn, name), parameter)
            if spec.plant is None:
                assert value == getattr(kind(), parameter)
            else:
                assert spec.plant[0] <= value <= spec.plant[1]
    assert "mixture_index" not in PLANT_EFFECTS  # nothing in the plant to read it from
