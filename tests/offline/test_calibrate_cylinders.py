"""``ecu-monitor calibrate`` on an engine monitored per cylinder: one detector per cylinder.

Two nominal virtual flights (random missions with residual unmodelled effects, 2 whole hours of
statistic after the warm-ups) as a two-cylinder CSV: cylinder 1 reads the CHT the true model explains,
cylinder 2 the same CHT run on a model whose heat map is 15 % too high (a cylinder whose model fits
worse). Each cylinder's threshold must be the one the single-channel calibration gives on its own
channel and model, and the service must run each cylinder on its own.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import io
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from ecu_monitor.cli import main
from ecu_monitor.commands.replay import fit_warnings
from ecu_monitor.config import load_config, parse_config
from ecu_monitor.errors import ConfigError
from ecu_monitor.flightlog import write_csv
from ecu_monitor.model import load_model, paper_table_a1, save_model
from ecu_monitor.offline.calibration import model_fingerprint
from ecu_monitor.offline.replay import replay_file
from ecu_monitor.pipeline.output_table import STATES
from ecu_monitor.research.evaluation import residual_effects
from ecu_monitor.runtime.publishers import LiveMonitor as Pipeline
from tests.helpers import REPO
from virtual_bus.plant import fly
from virtual_bus.random_missions import random_mission

pytestmark = pytest.mark.slow  # over a minute in all: scheduled first (tests/conftest.py)

CONFIGS = REPO / "ecu_monitor" / "data" / "configs"
SEEDS = (11, 12)


def _two_cylinder_data() -> dict[str, Any]:
    data = yaml.safe_load((CONFIGS / "four_cylinders.yaml").read_text(encoding="utf-8"))
    for n in (3, 4):
        del data["inputs"][f"cht{n}_c"]
    data["detector"] = {"symptom": "estimator"}
    data["state_dir"] = "/nonexistent-ecu-monitor-state"
    return data


def _calibrate(args: list[str]) -> tuple[int, str]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(["calibrate", *args])
    return code, out.getvalue()


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    folder = tmp_path_factory.mktemp("calibrate_cylinders")
    config_path = folder / "two_cylinders.yaml"
    data = _two_cylinder_data()
    config_path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    flights, single_flights = [], []
    for seed in SEEDS:
        log = fly(random_mission(seed, 3600.0), effects=residual_effects(seed), seed=seed)
        path = folder / f"nominal_{seed}.csv"
        write_csv(log.with_columns(cht1_c=log["cht_c"], cht2_c=log["cht_c"]), path)
        flights.append(str(path))
        single_flights.append(str(folder / f"cyl2_{seed}.csv"))  # cylinder 2's channel as cht_c
        write_csv(log, single_flights[-1])
    params = paper_table_a1()
    heat = dataclasses.replace(params.heat_map, values_w=np.asarray(params.heat_map.values_w) * 1.15)
    true_model, wrong_model = folder / "true.yaml", folder / "wrong.yaml"
    save_model(params, true_model)
    save_model(params.replace(heat_map=heat), wrong_model)
    written = folder / "calibrated.yaml"
    code, printed = _calibrate(
        [*flights, "--config", str(config_path), "--models", str(true_model), str(wrong_model),
         "--baseline-s", "600", "--cross", "--write-config", "--out", str(written)]
    )  # fmt: skip
    single = folder / "cylinder2.yaml"
    one_channel = _two_cylinder_data()  # the same engine monitored on cylinder 2's probe alone
    one_channel["inputs"]["cht_c"] = one_channel["inputs"].pop("cht2_c")
    del one_channel["inputs"]["cht1_c"], one_channel["cylinders"]
    for message in ("Health_Spread", "Health_Cylinder"):
        del one_channel["health"][message]
    one_channel_path = folder / "one_channel.yaml"
    one_channel_path.write_text(yaml.safe_dump(one_channel, sort_keys=False), encoding="utf-8")
    code_single, _ = _calibrate(
        [*single_flights, "--config", str(one_channel_path), "--model", str(wrong_model), "--baseline-s", "600",
         "--out", str(single)]
    )  # fmt: skip
    return {"code": code, "printed": printed, "written": written, "single": single, "code_single": code_single,
            "flights": flights, "models": (true_model, wrong_model)}  # fmt: skip


def test_each_cylinder_is_calibrated_on_its_own_channel_and_model(calibrated: dict[str, Any]) -> None:
    assert calibrated["code"] == 0 and calibrated["code_single"] == 0
    printed = calibrated["printed"]
    assert "== cylinder 1 of 2 (cht1_c) ==" in printed and "== cylinder 2 of 2 (cht2_c) ==" in printed
    config = load_config(calibrated["written"])
    first, second = config.cylinder_detectors
    single = yaml.safe_load(calibrated["single"].read_text())["detector"]
    assert second.threshold == single["threshold"]  # the same procedure as one channel, on cylinder 2's
    assert second.threshold > 2.0 * first.threshold  # the worse model needs the higher threshold
    assert first.baseline_s == second.baseline_s == 600.0
    assert config.cylinder_models == tuple(str(p.resolve()) for p in calibrated["models"])
    assert config.detector == parse_config(_two_cylinder_data(), CONFIGS / "x.yaml").detector  # kept as it was
    entries = yaml.safe_load(calibrated["written"].read_text())["cylinders"]["detectors"]
    assert [e["calibrated_for"] for e in entries] == [model_fingerprint(load_model(m)) for m in calibrated["models"]]


def test_the_cross_cylinder_detectors_are_calibrated_per_cylinder(calibrated: dict[str, Any]) -> None:
    from ecu_monitor.offline.calibration import calibrate_flights
    from ecu_monitor.offline.calibration_cross import cross_feeds, leave_one_out

    printed = calibrated["printed"]
    assert "== cross-cylinder detectors" in printed and "alarms when held out" in printed
    config = load_config(calibrated["written"])
    assert len(config.cross_detectors) == 2
    # each cylinder's threshold is the single-channel procedure on what its cross-cylinder detector is fed
    shipped = parse_config(_two_cylinder_data(), CONFIGS / "x.yaml")
    feeds = cross_feeds(calibrated["flights"], shipped, [load_model(m) for m in calibrated["models"]])
    for number, flights in enumerate(feeds, start=1):
        settings = shipped.cross_detector(number)
        assert settings is not None
        expected = calibrate_flights([f.statistic_for(settings) for f in flights], 1.0, settings).calibration
        assert config.cross_detector(number).threshold == pytest.approx(expected.threshold, abs=1e-4)
        assert config.cross_detector(number).baseline_s == settings.baseline_s
    # two cylinders: each one's cross symptom is the other's negated, so their statistics differ
    assert config.cross_detector(1).threshold != config.cross_detector(2).threshold
    checks = leave_one_out(feeds, shipped, 1.0)
    assert [len(c.thresholds) for c in checks] == [2, 2]  # one whole hour per flight: too few to hold one out
    assert all(np.isnan(h) for c in checks for h in c.thresholds)


def test_the_service_runs_each_cylinder_on_its_own_detector(calibrated: dict[str, Any], tmp_path: Path) -> None:
    config = load_config(calibrated["written"])
    pipeline = Pipeline(config, config.load_cylinder_params())
    settings = pipeline.pipeline.engine.settings["detector"]
    assert list(settings["threshold"]) == [d.threshold for d in config.cylinder_detectors]
    assert list(settings["baseline_s"]) == [d.baseline_s for d in config.cylinder_detectors]
    # cylinder 1 keeps its calibrated threshold (no alarm on its nominal flight), cylinder 2 gets a tiny
    # one: only cylinder 2 goes DEGRADED, so the replay runs each cylinder on its own detector
    flight = calibrated["flights"][0]
    degraded = STATES.index("DEGRADED")
    tiny = config.replace(
        cylinder_detectors=(
            config.cylinder_detectors[0],
            dataclasses.replace(config.cylinder_detectors[1], threshold=0.05),
        )
    )
    result = replay_file(flight, tiny, tiny.load_cylinder_params(), keep_feeds=True)
    assert not np.any(result.columns["cyl1_state"] == degraded)
    assert np.any(result.columns["cyl2_state"] == degraded)
    # replay's warning checks each cylinder's threshold against its own model
    models = config.load_cylinder_params()
    assert not [w for w in fit_warnings(config, models[0], result, models) if "calibrated" in w]
    swapped = [w for w in fit_warnings(config, models[0], result, models[::-1]) if "calibrated" in w]
    assert [w.split("'")[0] for w in swapped] == ["cylinder 1", "cylinder 2"]


def test_cylinder_detectors_config_is_checked() -> None:
    data = _two_cylinder_data()
    data["detector"] = {"symptom": "estimator", "threshold": 5.0, "warmup_s": 120}
    data["cylinders"]["detectors"] = [{"threshold": 3.0}, {"threshold": 9.0, "baseline_s": 300}]
    config = parse_config(copy.deepcopy(data), CONFIGS / "four_cylinders.yaml")
    assert [d.threshold for d in config.cylinder_detectors] == [3.0, 9.0]
    assert config.cylinder_detector(2).baseline_s == 300.0 and config.cylinder_detector(2).warmup_s == 120.0
    assert config.cylinder_detector(1).baseline_s == config.detector.baseline_s
    for bad, message in (
        ([{"threshold": 3.0}], "cylinders.detectors: expected a list of 2 detectors"),
        ([{"threshold": 3.0}, {"thresh": 1.0}], r"cylinders.detectors\[1\].thresh: unknown key"),
        ([{"threshold": 3.0}, {"calibrated_for": "x"}], r"cylinders.detectors\[1\].calibrated_for: expected 16 hex"),
        ([{"threshold": 3.0}, "nine"], r"cylinders.detectors\[1\]: expected a mapping"),
    ):
        data["cylinders"]["detectors"] = bad
        with pytest.raises(ConfigError, match=message):
            parse_config(copy.deepcopy(data), CONFIGS / "four_cylinders.yaml")
