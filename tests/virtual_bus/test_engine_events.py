"""The virtual engine's EGTs and oil temperature and the injected engine events (virtual_bus/engine_events.py)."""

from __future__ import annotations

import numpy as np
import pytest

from ecu_monitor.flightlog import FlightLog
from virtual_bus.engine_events import EGT_LAG_S, Injections, event_mission, with_exhaust_and_oil


def _steady_log(seconds: float = 900.0, throttle: float = 60.0) -> FlightLog:
    t = np.arange(0.0, seconds, 0.1)
    columns = {"time_s": t, "throttle_pct": np.full(t.size, throttle), "oat_c": np.full(t.size, 15.0)}
    return FlightLog(columns, source="test")


def test_each_cylinder_has_its_egt_and_the_engine_its_oil_that_follow_the_power() -> None:
    log = with_exhaust_and_oil(_steady_log(), 4, seed=3)
    t = np.asarray(log.time_s)
    settled = t > 5 * EGT_LAG_S
    egts = [np.asarray(log[f"egt{n}_c"])[settled] for n in range(1, 5)]
    means = [float(e.mean()) for e in egts]
    assert all(550.0 < m < 660.0 for m in means) and max(means) - min(means) > 1.0  # each its own offset
    assert all(float(np.std(e)) < 3.0 for e in egts)  # probe noise, steady power
    oil = np.asarray(log["oil_true_c"])
    assert oil[-1] > oil[0] and 60.0 < oil[-1] < 118.0  # warming towards its cruise value, under the limit
    again = with_exhaust_and_oil(_steady_log(), 4, seed=3)
    assert np.array_equal(np.asarray(again["egt2_c"]), np.asarray(log["egt2_c"]))  # deterministic for a seed


def test_the_valve_swings_one_cylinder_and_the_oil_excursion_heats_the_oil() -> None:
    injections = Injections(valve_cylinder=2, valve_pp_c=40.0, valve_period_s=60.0, valve_start_s=300.0,
                            valve_end_s=800.0, oil_to_c=130.0, oil_start_s=400.0, oil_s=300.0)  # fmt: skip
    plain = with_exhaust_and_oil(_steady_log(), 4, seed=3)
    log = with_exhaust_and_oil(_steady_log(), 4, seed=3, injections=injections)
    t = np.asarray(log.time_s)
    swing = np.asarray(log["egt2_true_c"]) - np.asarray(plain["egt2_true_c"])
    inside = (t >= 300.0) & (t < 800.0)
    assert np.ptp(swing[inside]) == pytest.approx(40.0, abs=0.5) and not swing[~inside].any()
    for n in (1, 3, 4):
        assert np.array_equal(np.asarray(log[f"egt{n}_true_c"]), np.asarray(plain[f"egt{n}_true_c"]))
    rise = np.asarray(log["oil_true_c"]) - np.asarray(plain["oil_true_c"])
    assert rise[t < 400.0].max() == 0.0 and np.asarray(log["oil_true_c"]).max() > 118.0


def test_the_event_mission_injects_every_event_inside_the_flight() -> None:
    mission, injections = event_mission(5, 4)
    assert mission == event_mission(5, 4)[0] and injections == event_mission(5, 4)[1]
    assert injections.dive and any(s.kind == "descent" and s.throttle_pct == 0.0 for s in mission.segments)
    assert 1 <= injections.valve_cylinder <= 4 and 25.0 <= injections.valve_pp_c <= 55.0
    assert 20.0 <= injections.valve_period_s <= 120.0  # 0.5-3 cycles a minute
    assert injections.valve_start_s < injections.valve_end_s < injections.oil_start_s
    assert injections.divergence is not None and injections.divergence.cylinder in (1, 2, 3, 4)
