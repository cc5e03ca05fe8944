"""The engine events (pipeline/step.py events_step, pipeline/events.py): a four-cylinder virtual flight with
a power-off dive and one cylinder running hot, through the batch replay and the live calls."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from ecu_monitor.config import parse_config
from ecu_monitor.errors import ConfigError
from ecu_monitor.flightlog import read_csv
from ecu_monitor.model import paper_table_a1
from ecu_monitor.offline.replay import frames_from_flight, replay_frames, replay_live
from ecu_monitor.pipeline.engine import Pipeline
from ecu_monitor.pipeline.events import EVENT_COLUMNS, EVENT_KINDS, Event, events_csv
from tests.helpers import climb_and_cruise

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ROOT / "ecu_monitor" / "data" / "configs"
FOUR = yaml.safe_load((CONFIGS / "four_cylinders.yaml").read_text(encoding="utf-8"))
HOT_CYLINDER = 3
HOT_FROM_S = 60.0
#: Climb to 700 m, cruise, then a power-off dive at high speed (where shock cooling happens).
DIVE_MISSION = climb_and_cruise(
    "dive",
    ground_s=30,
    climb_to_m=700,
    climb_throttle_pct=95,
    cruise_s=60,
    cruise_mps=25,
    cruise_throttle_pct=70,
    then=(
        {"kind": "descent", "target_altitude_m": 150, "rate_mps": 8, "throttle_pct": 0, "airspeed_mps": 45},
        {"kind": "cruise", "duration_s": 20, "airspeed_mps": 23, "throttle_pct": 55},
    ),
)


def _config(**events: Any) -> Any:
    data = copy.deepcopy(FOUR)
    data["events"] = events
    return parse_config(data, CONFIGS / "four_cylinders.yaml")


@pytest.fixture(scope="module")
def dive(tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, Any, Any]:
    """(the flight, its frames under the shipped four-cylinder config, the cylinders' models): cylinder 3
    heats 60 % more than it should from 60 s on."""
    from virtual_bus.cylinders import cylinder_models
    from virtual_bus.missions import mission_from_dict
    from virtual_bus.plant import Degradation
    from virtual_bus.recorder import record

    models = cylinder_models(paper_table_a1(), 4, seed=7)
    path = tmp_path_factory.mktemp("events") / "dive.csv"
    record(mission_from_dict(DIVE_MISSION), [path], paper_table_a1(), seed=7, cylinders=models,
           degradation=[Degradation("gamma_q", 1.6, HOT_FROM_S, cylinder=HOT_CYLINDER)])  # fmt: skip
    log = read_csv(path)
    return log, frames_from_flight(log, _config()), models


def _dive_start_s(log: Any) -> float:
    """When the throttle was closed for the dive (the first time it is below 5 % after the engine ran)."""
    throttle = np.asarray(log["throttle_pct"])
    ran = int(np.argmax(throttle > 30.0))
    closed = ran + int(np.argmax(throttle[ran:] < 5.0))
    return float(np.asarray(log.time_s)[closed])


def test_the_dive_shock_cools_every_cylinder_and_the_hot_one_diverges_and_exceeds(dive: tuple[Any, Any, Any]) -> None:
    log, frames, models = dive
    config = _config(cht_divergence_c=20.0, cht_limit_c=170.0)
    events = replay_frames(config, models, frames).events
    assert events, "no event"
    start = _dive_start_s(log)
    shocks = [e for e in events if e.kind == "shock_cooling" and e.time_s >= start]
    assert sorted({e.cylinder for e in shocks}) == [1, 2, 3, 4]
    for e in shocks:  # confirmed within 30 s of the throttle closing, the limit crossed for its minimum time
        assert e.time_s + config.events.shock_cooling_min_s <= start + 30.0, e
        assert e.value < e.limit == -config.events.shock_cooling_c_per_min
        assert e.duration_s >= config.events.shock_cooling_min_s
    t = np.asarray(log.time_s)
    for e in (e for e in events if e.kind == "shock_cooling"):  # every one where the plant's head did cool fast
        true_rate = np.gradient(np.asarray(log[f"cyl{e.cylinder}_cht_true_c"]), t) * 60.0
        smooth = np.convolve(true_rate, np.ones(50) / 50, mode="same")  # 5 s at 10 Hz
        inside = (t >= e.time_s) & (t <= e.time_s + e.duration_s)
        assert smooth[inside].min() < 0.8 * e.limit, e
    divergent = {e.cylinder for e in events if e.kind == "cht_divergence"}
    assert divergent == {HOT_CYLINDER}
    hot = [e for e in events if e.kind == "cht_exceedance"]
    assert hot and {e.cylinder for e in hot} == {HOT_CYLINDER}
    assert all(e.value > 170.0 and e.limit == 170.0 for e in hot)
    # the defaults: each cylinder's model's limit
    assert {e.limit for e in replay_frames(_config(), models, frames).events if e.kind == "cht_exceedance"} <= {
        m.cht_limit_c for m in models
    }


def test_live_calls_find_the_same_events_as_the_batch_replay(dive: tuple[Any, Any, Any]) -> None:
    _, frames, models = dive
    config = _config(cht_divergence_c=20.0)
    batch = replay_frames(config, models, frames).events
    live = replay_live(config, models, frames.messages()).events
    assert sorted(live) == sorted(batch)


def test_egt_divergence_and_egt_and_oil_exceedances(dive: tuple[Any, Any, Any]) -> None:
    """The flight with EGTs and an oil temperature laid on it: cylinder 2's EGT 120 degC further above the
    others' than its normal 10 degC from 210 s to 260 s (in the steady climb, once the normal offsets are
    learned), cylinder 4's above 900 degC from 330 s to 340 s, the oil above 118 degC from 360 s."""
    log, _, models = dive
    t = np.asarray(log.time_s)
    rng = np.random.default_rng(1)
    egts = {f"egt{n}_c": 650.0 + 10.0 * n + rng.normal(0.0, 3.0, t.size) for n in range(1, 5)}
    egts["egt2_c"] = np.where((t >= 210.0) & (t < 260.0), egts["egt2_c"] + 120.0, egts["egt2_c"])
    egts["egt4_c"] = np.where((t >= 330.0) & (t < 340.0), 905.0, egts["egt4_c"])
    oil = np.where(t >= 360.0, 122.0, 95.0)
    flight = log.with_columns(oil_temp_c=oil, **egts)
    data = copy.deepcopy(FOUR)
    for n in range(1, 5):
        data["inputs"][f"egt{n}_c"] = {"signal": f"ECU_Egt1to4.EGT{n}", "unit": "degC", "stale_after_s": 1.0}
    data["inputs"]["oil_temp_c"] = {"signal": "ECU_Oil.OilTemp", "unit": "degC", "stale_after_s": 3.0}
    config = parse_config(data, CONFIGS / "four_cylinders.yaml")
    events = replay_frames(config, models, frames_from_flight(flight, config)).events
    egt = [e for e in events if e.kind == "egt_divergence"]
    assert {e.cylinder for e in egt} <= {2, 4}  # cylinder 4 at 905 degC diverges too, for its 10 s
    two = [e for e in egt if e.cylinder == 2]
    assert len(two) == 1 and abs(two[0].time_s - 210.0) < 1.0 and abs(two[0].duration_s - 50.0) < 1.5
    assert 100.0 < two[0].value < 140.0  # beyond its normal offset
    high = [e for e in events if e.kind == "egt_exceedance"]
    assert [e.cylinder for e in high] == [4] and abs(high[0].time_s - 330.0) < 1.0 and high[0].value > 900.0
    oil_events = [e for e in events if e.kind == "oil_exceedance"]
    assert len(oil_events) == 1 and oil_events[0].cylinder == 0 and abs(oil_events[0].time_s - 360.0) < 1.5
    assert oil_events[0].time_s + oil_events[0].duration_s == pytest.approx(t[-1], abs=1.5)  # held to the end
    data["inputs"]["egt5_c"] = data["inputs"]["egt1_c"]
    with pytest.raises(ConfigError, match=r"inputs\.egt5_c: an EGT of a cylinder"):
        parse_config(data, CONFIGS / "four_cylinders.yaml")


def test_events_off_and_bad_limits() -> None:
    assert _config(enabled=False).events.enabled is False
    with pytest.raises(ConfigError, match=r"events\.shock_cooling_c_per_min"):
        _config(shock_cooling_c_per_min=-5)
    with pytest.raises(ConfigError, match=r"events.*colour"):
        _config(colour=1)


def test_the_events_table() -> None:
    text = events_csv(
        [
            Event(12.5, "shock_cooling", 3, -41.234, -33.0, 8.0),
            Event(1.0, "cht_exceedance", 1, float("nan"), 150.0, 2.0),
        ]
    )
    lines = text.splitlines()
    assert lines[0] == ",".join(EVENT_COLUMNS) == "time_s,kind,cylinder,value,limit,duration_s"
    assert lines[1] == "12.50,shock_cooling,3,-41.23,-33.00,8.00"
    assert lines[2] == "1.00,cht_exceedance,1,,150.00,2.00"
    assert set(EVENT_KINDS) >= {"shock_cooling", "cht_divergence", "cht_exceedance", "valve_advisory"}


#: A climb and a quarter of an hour's cruise at steady power (the valve advisory's ground).
CRUISE_MISSION = climb_and_cruise(
    "cruise", ground_s=30, climb_to_m=400, climb_throttle_pct=90, cruise_s=900, cruise_mps=25, cruise_throttle_pct=65
)
VALVE_ONSET_S = 300.0


@pytest.fixture(scope="module")
def cruise(tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, Any, Any]:
    """(the cruise flight, the four-cylinder config with EGTs mapped, the models)."""
    from virtual_bus.missions import mission_from_dict
    from virtual_bus.recorder import record

    path = tmp_path_factory.mktemp("valve") / "cruise.csv"
    record(mission_from_dict(CRUISE_MISSION), [path], paper_table_a1(), seed=9)
    data = copy.deepcopy(FOUR)
    for n in range(1, 5):
        data["inputs"][f"egt{n}_c"] = {"signal": f"ECU_Egt1to4.EGT{n}", "unit": "degC", "stale_after_s": 1.0}
    config = parse_config(data, CONFIGS / "four_cylinders.yaml")
    return read_csv(path), config, config.load_cylinder_params()


def _with_egts(log: Any, oscillating: tuple[int, ...], amplitude_c: float, period_s: float) -> Any:
    """Four CHTs and four EGTs that follow the throttle (+3 degC per %) with noise; the ``oscillating``
    cylinders' EGTs swing by ``amplitude_c`` peak to peak with ``period_s`` from VALVE_ONSET_S on."""
    t = np.asarray(log.time_s)
    rng = np.random.default_rng(4)
    power = 3.0 * (np.asarray(log["throttle_pct"]) - 65.0)
    columns = {f"cht{n}_c": np.asarray(log["cht_c"]) + 3.0 * n for n in range(1, 5)}
    for n in range(1, 5):
        egt = 680.0 + 8.0 * n + power + rng.normal(0.0, 2.0, t.size)
        if n in oscillating:
            egt = egt + np.where(t >= VALVE_ONSET_S, 0.5 * amplitude_c * np.sin(2 * np.pi * t / period_s), 0.0)
        columns[f"egt{n}_c"] = np.round(egt)
    return log.with_columns(**columns)


def test_the_valve_advisory_names_the_one_oscillating_cylinder_within_ten_minutes(cruise: tuple[Any, Any, Any]) -> None:
    log, config, models = cruise
    flight = _with_egts(log, (3,), 40.0, 60.0)
    events = replay_frames(config, models, frames_from_flight(flight, config)).events
    valve = [e for e in events if e.kind == "valve_advisory"]
    assert [e.cylinder for e in valve] == [3]
    assert valve[0].time_s + config.events.valve_min_s <= VALVE_ONSET_S + 600.0
    assert 30.0 < valve[0].value < 55.0  # the amplitude, peak to peak, within the band's gain spread
    assert not [e for e in events if e.kind == "egt_divergence"]  # +-20 degC: no divergence


@pytest.mark.parametrize(
    ("oscillating", "amplitude_c", "period_s"),
    [((), 0.0, 60.0), ((1, 3), 40.0, 60.0), ((3,), 8.0, 60.0), ((3,), 40.0, 600.0)],
    ids=["steady", "two-cylinders", "small", "too-slow"],
)
def test_no_valve_advisory_without_one_cylinder_oscillating_in_the_band(
    cruise: tuple[Any, Any, Any], oscillating: tuple[int, ...], amplitude_c: float, period_s: float
) -> None:
    log, config, models = cruise
    flight = _with_egts(log, oscillating, amplitude_c, period_s)
    events = replay_frames(config, models, frames_from_flight(flight, config)).events
    assert not [e for e in events if e.kind == "valve_advisory"]


def test_each_event_starts_once_it_has_held_its_minimum_time_then_ends(dive: tuple[Any, Any, Any]) -> None:
    """The live calls: the start record of every event comes at its start + its minimum time (what the health
    outputs publish), its end record later, with the same start, kind and cylinder."""
    _, frames, models = dive
    config = _config(cht_divergence_c=20.0)
    pipeline = Pipeline(config, models)
    seen: list[tuple[float, Event]] = []  # (the clock's time when taken, the record)
    for msg in frames.messages():
        pipeline.advance_to(msg.timestamp)
        pipeline.feed(msg)
        seen += [(pipeline.now_s, e) for e in pipeline.take_events()]
    seen += [(pipeline.now_s, e) for e in pipeline.close_events()]
    starts = [(t, e) for t, e in seen if e.ongoing]
    ends = [(t, e) for t, e in seen if not e.ongoing]
    assert starts and len(starts) == len(ends)
    min_s = {"shock_cooling": config.events.shock_cooling_min_s, "cht_divergence": config.events.divergence_min_s,
             "cht_exceedance": config.events.exceedance_min_s}  # fmt: skip
    for taken, start in starts:
        end_taken, end = next((t, e) for t, e in ends if e[:3] == start[:3])
        assert start.duration_s == pytest.approx(min_s[start.kind], abs=0.11)  # one filter period
        assert taken <= start.time_s + min_s[start.kind] + 0.2 <= end_taken + 0.2
        assert end.duration_s >= start.duration_s
        assert start.start_text().startswith(f"ENGINE cyl {start.cylinder}: {start.kind.replace('_', ' ')}")
        assert len(start.start_text()) <= 50


def test_a_cylinder_whose_egt_always_runs_apart_does_not_diverge(dive: tuple[Any, Any, Any]) -> None:
    """Cylinder 2's EGT 150 degC below the others all flight long (its normal spread): no EGT divergence."""
    log, _, models = dive
    t = np.asarray(log.time_s)
    rng = np.random.default_rng(2)
    egts = {f"egt{n}_c": 680.0 + 10.0 * n + rng.normal(0.0, 3.0, t.size) - (150.0 if n == 2 else 0.0)
            for n in range(1, 5)}  # fmt: skip
    data = copy.deepcopy(FOUR)
    for n in range(1, 5):
        data["inputs"][f"egt{n}_c"] = {"signal": f"ECU_Egt1to4.EGT{n}", "unit": "degC", "stale_after_s": 1.0}
    config = parse_config(data, CONFIGS / "four_cylinders.yaml")
    events = replay_frames(config, models, frames_from_flight(log.with_columns(**egts), config)).events
    assert not [e for e in events if e.kind == "egt_divergence"]


def test_the_live_monitor_sends_an_event_frame_as_each_event_starts(dive: tuple[Any, Any, Any]) -> None:
    """The daemon's monitor over the dive: one Health_Event frame per start record, in order, from it."""
    from ecu_monitor.runtime.publishers import LiveMonitor

    _, frames, models = dive
    monitor = LiveMonitor(_config(cht_divergence_c=20.0), models)
    sent = []
    for msg in frames.messages():
        sent += monitor.advance_to(msg.timestamp)
        monitor.feed(msg)
    starts = [e for e in monitor.drain_events() if e.ongoing]
    message = monitor.publishers[0].encoder.message("Health_Event")
    decoded = [message.decode(bytes(f.data)) for f in sent if f.arbitration_id == message.frame_id]
    assert starts and [(d["EventKind"], d["EventCylinder"]) for d in decoded] == [(e.kind, e.cylinder) for e in starts]
    assert monitor.drain_events() == []
