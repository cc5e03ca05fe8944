"""Leave-one-out without ``--model``: every fold's own swarm (nothing of its held-out flight in it), and
pairs re-identified from the lead's joint fit on the same fold, with the longer polish."""

from __future__ import annotations

import pytest

from ecu_monitor.flightlog import FlightLog
from ecu_monitor.gap.diagnosis import JOINT_REFIT
from ecu_monitor.gap.folds import swarm_nominals
from ecu_monitor.identify import PsoSettings, identify
from ecu_monitor.identify.library import candidate, flight_references
from ecu_monitor.identify.refit import RefitSettings, prepare_flight, reidentify
from ecu_monitor.model import AirspeedCooling, SensorLag, paper_table_a1
from virtual_bus.plant import fly
from virtual_bus.random_missions import random_mission

#: A swarm this short finds no good model; it is enough to tell which flights a model was fitted on.
TINY = PsoSettings(particles=4, iterations=2, polish=False)


@pytest.fixture(scope="module")
def logs() -> list[FlightLog]:
    truth = paper_table_a1()
    truth = truth.replace(effects=truth.effects.replace("sensor_lag", SensorLag(10.0)))
    truth = truth.replace(effects=truth.effects.replace("airspeed_cooling", AirspeedCooling(0.02, floor=0.5)))
    return [fly(random_mission(seed, 900.0), truth, seed=seed, record_dt_s=1.0) for seed in (21, 22, 23)]


def test_each_fold_nominal_is_its_own_swarm_on_the_other_flights(logs: list[FlightLog]) -> None:
    axes = paper_table_a1().heat_axes
    folds, every = swarm_nominals(logs, axes, TINY)
    assert len(folds) == len(logs)
    for k, params in enumerate(folds):
        others = [log for i, log in enumerate(logs) if i != k]
        assert params == identify(others, heat_axes=axes, settings=TINY).params
    # the model on every flight: the first fold's polished on all of them (no swarm of its own)
    joint = PsoSettings(particles=JOINT_REFIT.particles, iterations=0, seed=TINY.seed)
    assert every == identify(logs, base=folds[0], heat_axes=axes, settings=joint).params


def test_a_pair_re_identified_from_the_lead_starts_from_the_leads_fit(logs: list[FlightLog]) -> None:
    """The pair starts where the lead's joint fit ended (its effect's fitted values, the whole model), not
    at the library's start for the lead's effect."""
    nominal = paper_table_a1()
    trains = tuple(prepare_flight(log, nominal.heat_axes, 1.0) for log in logs[:2])
    refs = flight_references(logs[0])
    fast = PsoSettings(particles=JOINT_REFIT.particles, iterations=0, polish_evaluations=20, dt_s=1.0)
    lead = reidentify(nominal, trains, [candidate("airspeed_cooling")], refs, pso=fast)
    start = candidate("airspeed_cooling").free[0]
    fitted = lead.values["airspeed_cooling"][start.name]
    assert fitted != pytest.approx(start.start, rel=0.05)
    # no search, no polish: the pair is its start particle (one particle: the given model)
    frozen = PsoSettings(particles=2, iterations=0, polish=False, dt_s=1.0)
    entries = [candidate("airspeed_cooling"), candidate("sensor_lag")]
    pair = reidentify(lead.params, trains, entries, refs, RefitSettings(dt_s=1.0, max_evaluations=1), frozen)
    assert pair.values["airspeed_cooling"][start.name] == pytest.approx(fitted, rel=1e-6)


def test_a_pair_is_polished_longer_than_a_single(monkeypatch: pytest.MonkeyPatch) -> None:
    """A pair's joint re-identification (from the lead's fit, or from the nominal model for model.yaml)
    polishes PAIR_POLISH_FACTOR times the singles' budget; a single and the control the budget itself."""
    import importlib

    from ecu_monitor.gap.diagnosis import PAIR_POLISH_FACTOR, GapSettings
    from ecu_monitor.gap.scoring import RefitFold

    gap_diagnose = importlib.import_module("ecu_monitor.gap.diagnose")  # the package's `diagnose` is the function
    budgets: list[tuple[tuple[str, ...], object, int]] = []

    def record(base, trains, entries, references, settings, pso):  # type: ignore[no-untyped-def]
        budgets.append((tuple(e.id for e in entries), base, pso.polish_evaluations))

    monkeypatch.setattr(gap_diagnose, "reidentify", record)
    nominal, lead = paper_table_a1(), paper_table_a1().replace(tau_w=12.0)
    settings = GapSettings(refit_mode="reidentify", pso=PsoSettings(particles=4, iterations=0, polish_evaluations=40))
    work = gap_diagnose._FitWork((RefitFold(nominal, (), {}, ()),), settings)
    pair = ("airspeed_cooling", "no_altitude_factor")
    for task in [(0, (), None), (0, ("airspeed_cooling",), None), (0, pair, lead), (0, pair, None)]:
        gap_diagnose._fit_task(work, task)
    assert budgets == [
        ((), nominal, 40),
        (("airspeed_cooling",), nominal, 40),
        (pair, lead, 40 * PAIR_POLISH_FACTOR),
        (pair, nominal, 40 * PAIR_POLISH_FACTOR),
    ]
