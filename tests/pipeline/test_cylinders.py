"""Every cylinder (pipeline/cylinders.py, the pipeline and the batch replay with cht1_c .. chtN_c): the
config, live == batch on a four-cylinder engine, a probe fault isolating one cylinder, the spread and
its alarm, the health frames and health.csv columns."""

from __future__ import annotations

import copy
import csv
import math
from pathlib import Path
from typing import Any

import cantools
import numpy as np
import pytest
import yaml

from ecu_monitor.config import load_config, parse_config
from ecu_monitor.errors import ConfigError
from ecu_monitor.estimation.detection import DetectorSettings
from ecu_monitor.flightlog import FlightLog, read_csv
from ecu_monitor.model import paper_table_a1
from ecu_monitor.offline.replay import frames_from_flight, replay_frames
from ecu_monitor.pipeline.cylinders import engine_view
from ecu_monitor.pipeline.outputs import CylinderSnapshot, ReplayResult, health_columns, rows_to_columns
from ecu_monitor.runtime.publishers import LiveMonitor as Pipeline
from tests.helpers import REPO, climb_and_cruise

CONFIGS = REPO / "ecu_monitor" / "data" / "configs"
FOUR = yaml.safe_load((CONFIGS / "four_cylinders.yaml").read_text(encoding="utf-8"))
HEALTH_DB: Any = cantools.database.load_file(str(REPO / "ecu_monitor" / "data" / "dbc" / "health.dbc"))
NUMERIC = ("cht_meas_c", "cht_est_c", "deviation", "gamma_q", "gamma_d", "headroom_s")

SHORT_MISSION = climb_and_cruise(
    "short", ground_s=40, climb_to_m=450, climb_throttle_pct=90, cruise_s=60, cruise_mps=23, cruise_throttle_pct=55
)


def _config(**changes: Any) -> Any:
    data = copy.deepcopy(FOUR)
    data["detector"] = {"symptom": "estimator", "warmup_s": 30.0}
    for key, value in changes.items():
        data[key] = value
    return parse_config(data, CONFIGS / "four_cylinders.yaml")


# --------------------------------------------------------------------------------------------------
# config
# --------------------------------------------------------------------------------------------------


def test_the_shipped_four_cylinder_config_maps_four_cylinders() -> None:
    config = load_config("four_cylinders.yaml")
    assert config.cylinder_inputs == ("cht1_c", "cht2_c", "cht3_c", "cht4_c")
    assert config.spread_limit_c == 30.0
    assert len(config.load_cylinder_params()) == 4
    assert load_config("example.yaml").cylinder_inputs == ("cht_c",)
    both = copy.deepcopy(FOUR)  # a cht_c beside the cylinders (an ECU's mean) is held, not estimated
    both["inputs"]["cht_c"] = {"signal": "ECU_Slow.CHT", "unit": "degC", "stale_after_s": 1.0}
    assert parse_config(both, CONFIGS / "four_cylinders.yaml").cylinder_inputs == config.cylinder_inputs


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: [d["inputs"].pop(f"cht{n}_c") for n in (2, 3, 4)], "inputs.cht_c: missing"),  # one: held beside
        (lambda d: d["inputs"].pop("cht2_c"), "cylinders must be numbered 1 .. N"),
        (lambda d: d["cylinders"].update(models=["paper_table_a1"]), "cylinders.models: expected a list of 4"),
        (lambda d: d["cylinders"].update(spread_limit_c=-1), "cylinders.spread_limit_c: expected a number > 0"),
        (lambda d: d["sensor_fault"].update(status_signal="ECU_Slow.EcuStatus", open_values=[3]),
         "sensor_fault.status_signal: an ECU status signal reports one probe"),
        (lambda d: d["inputs"].update(cht0_c=d["inputs"]["cht1_c"]), "unknown key 'cht0_c'"),
    ],
)  # fmt: skip
def test_bad_cylinder_configs_name_the_key(change: Any, message: str) -> None:
    data = copy.deepcopy(FOUR)
    change(data)
    with pytest.raises(ConfigError, match=message.replace(".", r"\.").replace("(", r"\(")):
        parse_config(data, CONFIGS / "four_cylinders.yaml")


# --------------------------------------------------------------------------------------------------
# engine view
# --------------------------------------------------------------------------------------------------


def _cyl(number: int, est: float, state: str = "NOMINAL") -> CylinderSnapshot:
    return CylinderSnapshot(
        number=number,
        cht_meas_c=est,
        cht_est_c=est,
        deviation=0.0,
        state=state,
        gamma_q=1.0,
        gamma_d=1.0,
        headroom_s=6000.0,
    )


def test_engine_view_lead_spread_hottest_and_alarm() -> None:
    cyls = [_cyl(1, 150.0), _cyl(2, 171.0), _cyl(3, 400.0, "SENSOR_FAULT"), _cyl(4, 140.0)]
    view = engine_view(cyls, 30.0)
    assert view.lead == 2  # the faulty probe leads the engine's state
    assert view.hottest == 2 and view.spread_c == pytest.approx(31.0) and view.alarm  # its reading does not count
    assert not engine_view(cyls, 31.5).alarm and not engine_view(cyls, None).alarm
    healthy = [_cyl(1, 150.0), _cyl(2, 171.0), _cyl(3, 160.0, "DEGRADED")]
    assert engine_view(healthy, None).lead == 2  # a degraded cylinder leads hotter healthy ones
    alone = engine_view([_cyl(1, 150.0), _cyl(2, math.nan, "UNAVAILABLE")], 10.0)
    assert alone.lead == 0 and alone.hottest == 1 and math.isnan(alone.spread_c) and not alone.alarm


# --------------------------------------------------------------------------------------------------
# live == batch on four cylinders, one probe failing
# --------------------------------------------------------------------------------------------------

OFFSETS_C = (0.0, 12.0, -6.0, 20.0)  # per-cylinder CHT offsets from the recorded engine
PROBE_FAULT_S = 120.0  # cylinder 3's probe reads full scale (open) from here


@pytest.fixture(scope="module")
def four_cylinder_flight(tmp_path_factory: pytest.TempPathFactory) -> FlightLog:
    """A ~3 min virtual flight whose CHT is spread over four cylinders; cylinder 3's probe fails open."""
    from virtual_bus.missions import mission_from_dict
    from virtual_bus.recorder import record

    path = tmp_path_factory.mktemp("cyl") / "flight.csv"
    record(mission_from_dict(SHORT_MISSION), [path], paper_table_a1(), seed=3)
    log = read_csv(path)
    t = log.time_s
    columns = {f"cht{n}_c": np.asarray(log["cht_c"]) + offset for n, offset in enumerate(OFFSETS_C, start=1)}
    columns["cht3_c"] = np.where(t >= PROBE_FAULT_S, 369.5, columns["cht3_c"])
    return log.with_columns(**columns)


SPREAD_LIMIT_C = 22.0  # between the spread before the fault (26 degC) and after it (20 degC)


@pytest.fixture(scope="module")
def live_run(four_cylinder_flight: FlightLog) -> tuple[Any, Any, list[Any], ReplayResult]:
    """The flight through the live pipeline frame by frame: (config, frames in, health frames out, rows)."""
    config = _config(cylinders={"spread_limit_c": SPREAD_LIMIT_C})
    frames = frames_from_flight(four_cylinder_flight, config)
    pipeline = Pipeline(config, config.load_cylinder_params())
    sent: list[Any] = []
    rows = []
    for msg in frames.messages():
        sent += pipeline.advance_to(msg.timestamp)
        pipeline.feed(msg)
        rows.extend(pipeline.drain_rows())
    assert len(rows) > 1000
    return config, frames, sent, ReplayResult(rows_to_columns(rows, 4), dict(pipeline.counters))


def test_four_cylinders_live_equals_batch_and_a_probe_fault_isolates_its_cylinder(
    live_run: tuple[Any, Any, list[Any], ReplayResult], tmp_path: Path
) -> None:
    config, frames, _, live = live_run
    batch = replay_frames(config, config.load_cylinder_params(), frames)
    assert set(batch.columns) == set(live.columns)
    assert len(batch) == len(live) > 1000
    for key, b in batch.columns.items():
        v = live.columns[key]
        if b.dtype.kind == "f":
            assert np.array_equal(np.isnan(b), np.isnan(v)), key
            assert np.nanmax(np.abs(b - v), initial=0.0) < 1e-9, key
        else:
            assert np.array_equal(b, v), key
    c = batch.columns
    t = c["time_s"]
    after = t > PROBE_FAULT_S + 1.0
    before = (t > 20.0) & (t < PROBE_FAULT_S)
    states = {n: c[f"cyl{n}_state"] for n in range(1, 5)}
    fault = 4  # STATES.index("SENSOR_FAULT")
    assert np.all(states[3][after] == fault) and not np.any(states[3][before] == fault)
    for n in (1, 2, 4):  # the others keep running on their own probes
        assert not np.any(states[n] == fault)
        est = c[f"cyl{n}_cht_est_c"][after]
        meas = c[f"cyl{n}_cht_meas_c"][after]
        assert np.all(np.isfinite(est)) and np.sqrt(np.mean((est - meas) ** 2)) < 1.5
    assert np.all(c["sensor_fault"][after]) and not np.any(c["sensor_fault"][before])
    # the spread and the hottest cylinder leave the faulty probe out
    assert np.all(c["hottest_cylinder"][before] == 4) and np.all(c["hottest_cylinder"][after] == 4)
    assert np.nanmedian(c["cht_spread_c"][before]) == pytest.approx(26.0, abs=1.5)  # 4 (+20) minus 3 (-6)
    assert np.nanmedian(c["cht_spread_c"][after]) == pytest.approx(20.0, abs=1.5)  # 4 (+20) minus 1 (+0)
    assert np.array_equal(c["spread_alarm"], c["cht_spread_c"] > SPREAD_LIMIT_C)
    assert c["spread_alarm"][before].mean() > 0.9 and not c["spread_alarm"][after].any()
    out = tmp_path / "health.csv"
    batch.write_csv(out)
    with open(out, newline="", encoding="utf-8") as handle:
        header = next(csv.reader(handle))
    assert tuple(header) == health_columns(4)
    assert header[15:17] == ["cyl1_cht_meas_c", "cyl1_cht_est_c"] and header[-3:] == [
        "cht_spread_c", "hottest_cylinder", "spread_alarm"]  # fmt: skip


def test_four_cylinder_health_frames(live_run: tuple[Any, Any, list[Any], ReplayResult]) -> None:
    _, _, sent, _ = live_run
    spread = HEALTH_DB.get_message_by_name("Health_Spread")
    cylinder = HEALTH_DB.get_message_by_name("Health_Cylinder")
    spreads = [spread.decode(f.data) for f in sent if f.arbitration_id == spread.frame_id]
    cyls = [cylinder.decode(f.data, decode_choices=False) for f in sent if f.arbitration_id == cylinder.frame_id]
    assert len(cyls) == 4 * len(spreads) > 100  # one frame per cylinder per period
    assert [c["CylinderNumber"] for c in cyls[:8]] == [1, 2, 3, 4, 1, 2, 3, 4]
    last = spreads[-1]
    assert last["HottestCylinder"] == 4 and last["CylinderCount"] == 4 and last["FaultyCylinders"] == 0b0100
    assert any(s["SpreadAlarm"] == 1 for s in spreads) and last["SpreadAlarm"] == 0
    # cylinder 3 faulty; cylinder 4 runs on (its +20 degC offset is not in the shared model: it may be flagged)
    assert cyls[-2]["CylState"] == 4 and cyls[-1]["CylState"] != 4


ONSET_S = 150.0  # gamma_Q 1.5 in cylinder 2 from here


def test_the_cross_cylinder_detector_live_equals_batch_and_flags_the_one_cylinder(tmp_path: Path) -> None:
    from virtual_bus.cylinders import cylinder_models
    from virtual_bus.missions import mission_from_dict
    from virtual_bus.plant import Degradation
    from virtual_bus.recorder import record

    models = cylinder_models(paper_table_a1(), 4, seed=11)
    path = tmp_path / "flight.csv"
    record(mission_from_dict(SHORT_MISSION), [path], paper_table_a1(), seed=11, cylinders=models,
           degradation=[Degradation("gamma_q", 1.5, ONSET_S, cylinder=2)])  # fmt: skip
    cross = {"threshold": 1.0, "warmup_s": 30.0}
    config = _config(cylinders={"cross_detector": cross})
    assert config.cross_detector(2) == config.cross_detector(4) and config.cross_detector(1).threshold == 1.0
    frames = frames_from_flight(read_csv(path), config)
    batch = replay_frames(config, models, frames)
    pipeline = Pipeline(config, models)
    rows = []
    for msg in frames.messages():
        pipeline.advance_to(msg.timestamp)
        pipeline.feed(msg)
        rows.extend(pipeline.drain_rows())
    live = rows_to_columns(rows, 4)
    for key in ("state", *(f"cyl{n}_state" for n in range(1, 5))):
        assert np.array_equal(batch.columns[key], live[key]), key
    degraded = 2  # STATES.index("DEGRADED")
    c = batch.columns
    hit = c["time_s"][c["cyl2_state"] == degraded]
    assert hit.size and ONSET_S < hit[0] < ONSET_S + 60.0
    assert not any(np.any(c[f"cyl{n}_state"] == degraded) for n in (1, 3, 4))
    # the own-symptom detectors alone (the shipped threshold) see it later
    own = replay_frames(_config(cylinders={}), models, frames).columns
    own_hit = own["time_s"][own["cyl2_state"] == degraded]
    assert not own_hit.size or own_hit[0] > hit[0] + 5.0, (own_hit[:1], hit[0])


def test_bad_cross_detector_configs_name_the_key() -> None:
    with pytest.raises(ConfigError, match=r"cylinders\.cross_detector\.treshold: unknown key"):
        _config(cylinders={"cross_detector": {"treshold": 1.0}})
    with pytest.raises(ConfigError, match=r"cylinders\.cross_detectors: expected a list of 4"):
        _config(cylinders={"cross_detectors": [{"threshold": 1.0}]})
    with pytest.raises(ConfigError, match=r"cylinders\.cross_detectors\[1\]\.threshold: expected a number, got str"):
        _config(cylinders={"cross_detectors": [{"threshold": 1.0}, {"threshold": "x"}, {}, {}]})
    with pytest.raises(ConfigError, match=r"cylinders\.cross_detectors\[1\]: detector: threshold and block_s must"):
        _config(cylinders={"cross_detectors": [{"threshold": 1.0}, {"threshold": -1.0}, {}, {}]})
    single = yaml.safe_load((CONFIGS / "example.yaml").read_text(encoding="utf-8"))
    single["cylinders"] = {"cross_detector": {"threshold": 1.0}}
    with pytest.raises(ConfigError, match=r"cylinders\.cross_detector: compares cylinders"):
        parse_config(single, CONFIGS / "example.yaml")
    per = _config(cylinders={"cross_detector": {"threshold": 2.0}, "cross_detectors": [{}, {"threshold": 3.0}, {}, {}]})
    assert [per.cross_detector(n).threshold for n in (1, 2)] == [2.0, 3.0]
    assert _config(cylinders={}).cross_detector(1) is None and _config().cross_detector(1) is not None  # shipped on
    off = _config(cylinders={"cross_detectors": [{"threshold": 2.0}, None, {}, {}]})
    assert off.cross_detector(2) is None and off.cross_detector(3) == DetectorSettings()


# --------------------------------------------------------------------------------------------------
# the virtual ECU: N differing cylinders, degradation per cylinder, frames and CSV columns
# --------------------------------------------------------------------------------------------------


def test_cylinder_models_differ_and_one_cylinder_is_the_base() -> None:
    from virtual_bus.cylinders import cylinder_models

    base = paper_table_a1()
    assert cylinder_models(base, 1) == (base,)
    four = cylinder_models(base, 4, seed=7)
    scales = [m.heat_map.values_w[1][1] / base.heat_map.values_w[1][1] for m in four]
    assert len(set(scales)) == 4 and all(0.92 <= s <= 1.08 for s in scales)
    assert len({m.c_w for m in four}) == 4
    assert cylinder_models(base, 4, seed=7) == four != cylinder_models(base, 4, seed=8)


def test_a_degradation_in_one_cylinder_changes_that_cylinder_alone(tmp_path: Path) -> None:
    from virtual_bus.cylinders import cylinder_models
    from virtual_bus.missions import mission_from_dict
    from virtual_bus.plant import Degradation, fly
    from virtual_bus.recorder import record

    mission = mission_from_dict(SHORT_MISSION)
    models = cylinder_models(paper_table_a1(), 3, seed=4)
    nominal = fly(mission, paper_table_a1(), seed=9, cylinders=models, max_duration_s=100.0)
    path = tmp_path / "degraded.csv"
    record(mission, [path, tmp_path / "degraded.blf"], paper_table_a1(), seed=9, cylinders=models,
           degradation=[Degradation.parse("gamma_q=1.3@50:cylinder=2")])  # fmt: skip
    degraded = read_csv(path)
    rows = slice(0, len(nominal))
    t = nominal.time_s
    for n in (1, 3):  # the same seed and the same inputs: the other cylinders fly exactly as before
        assert np.array_equal(degraded[f"cyl{n}_cht_true_c"][rows], nominal[f"cyl{n}_cht_true_c"])
        assert np.all(degraded[f"cyl{n}_gamma_q"] == 1.0)
    rise = degraded["cyl2_cht_true_c"][rows] - nominal["cyl2_cht_true_c"]
    assert np.all(rise[t < 50.0] == 0.0) and rise[-1] > 2.0
    assert np.all(degraded["cyl2_gamma_q"][degraded.time_s >= 50.0] == 1.3)
    # the measured cylinders are the CSV's cylinder columns; cht_c is their mean
    heads = np.vstack([degraded[f"cht{n}_c"] for n in (1, 2, 3)])
    assert np.allclose(degraded["cht_c"], heads.mean(axis=0))
    assert np.all(np.abs(heads - np.vstack([degraded[f"cyl{n}_cht_true_c"] for n in (1, 2, 3)])) < 2.0)
    # the .blf carries them in ECU_Cht1to4 (cylinder 4's signal unused: the range minimum)
    from ecu_monitor.bus.canlog import read_frames

    frames = read_frames(tmp_path / "degraded.blf")
    db: Any = cantools.database.load_file(str(REPO / "ecu_monitor" / "data" / "dbc" / "cylinders.dbc"))
    message = db.get_message_by_name("ECU_Cht1to4")
    carried = [message.decode(bytes(d)) for i, d in zip(frames.arbitration_id, frames.data, strict=True) if i == 0x102]
    assert len(carried) == pytest.approx(len(degraded), rel=0.01)
    assert {c["CHT4"] for c in carried} == {-40.0}
    assert np.allclose([c["CHT2"] for c in carried[10:20]], degraded["cht2_c"][10:20], atol=0.051)


def test_the_demo_config_for_n_cylinders() -> None:
    from ecu_monitor.commands.demo import cylinder_config

    assert cylinder_config(2).cylinder_inputs == ("cht1_c", "cht2_c")
    assert cylinder_config(4).cylinder_inputs == load_config("four_cylinders.yaml").cylinder_inputs
    with pytest.raises(ConfigError, match="--cylinders: expected 1 to 4"):
        cylinder_config(5)
