"""``ecu-monitor calibrate``: the detector threshold from the user's own nominal flights.

Two nominal virtual-ECU flights (random missions with the evaluation's residual unmodelled effects,
1.17 h and 1.25 h: 2 whole hours of statistic after the 600 s warm-ups) are written once as .blf CAN
logs (the frames replay makes from their CSVs), so each calibration replays them in about a second.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import math

import can
import numpy as np
import pytest
import yaml

from ecu_monitor.bus.canlog import read_frames
from ecu_monitor.cli import main
from ecu_monitor.commands.replay import DEFAULT_CONFIG
from ecu_monitor.estimation.detection import DetectorSettings, calibrate_threshold, cusum_path
from ecu_monitor.flightlog import write_csv
from ecu_monitor.model import paper_table_a1, save_model
from ecu_monitor.research.evaluation import residual_effects
from ecu_monitor.service.config import load_config
from ecu_monitor.service.pipeline import STATES
from ecu_monitor.service.replay import frames_from_flight, replay_file
from virtual_bus.missions import random_mission
from virtual_bus.plant import fly

SEEDS = (11, 12)


@pytest.fixture(scope="module")
def nominal(tmp_path_factory):
    """Two nominal flights as .blf logs, one as a canonical CSV too (its first 20 min)."""
    folder = tmp_path_factory.mktemp("calibrate")
    config = load_config(DEFAULT_CONFIG)
    paths = []
    for seed in SEEDS:
        log = fly(random_mission(seed, 3600.0), effects=residual_effects(seed), seed=seed)
        frames = frames_from_flight(log, config)
        path = folder / f"nominal_{seed}.blf"
        with can.BLFWriter(str(path)) as writer:
            for msg in frames.messages():
                writer.on_message_received(msg)
        paths.append(path)
        if seed == SEEDS[0]:
            write_csv(log.select(log.time_s[0], log.time_s[0] + 1200.0), folder / "short.csv")
            write_csv(log, folder / "nominal.csv")
    return folder, paths


def _calibrate(args):
    """Run the CLI in process: (exit code, stdout)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(["calibrate", *args])
    return code, out.getvalue()


@pytest.fixture(scope="module")
def calibrated(nominal):
    """``calibrate`` with the default config (true model), fragment + plot; and with --write-config."""
    folder, paths = nominal
    flights = [str(p) for p in paths]
    fragment = folder / "detector.yaml"
    plot = folder / "statistic.png"
    code, printed = _calibrate([*flights, "--out", str(fragment), "--plot", str(plot)])
    written = folder / "service.yaml"
    code_config, _ = _calibrate([*flights, "--write-config", "--out", str(written)])
    return {"code": code, "printed": printed, "fragment": fragment, "plot": plot, "written": written,
            "code_config": code_config, "flights": flights}  # fmt: skip


def test_calibrate_prints_a_table_and_writes_the_fragment(calibrated):
    assert calibrated["code"] == 0 and calibrated["code_config"] == 0
    lines = calibrated["printed"].splitlines()
    assert lines[0].split()[:5] == ["flight", "hours", "whole", "h", "max"]
    assert "alarms at h=7.77" in lines[0]
    rows = {line.split()[0]: line.split() for line in lines[1:4]}
    assert set(rows) == {"nominal_11.blf", "nominal_12.blf", "total"}
    assert float(rows["nominal_11.blf"][1]) == pytest.approx(1.17, abs=0.01)
    assert rows["total"][2] == "2"  # whole hours of statistic
    assert any(line.startswith("threshold h = ") and "current 7.77" in line for line in lines)
    assert any("fewer than the 100 h of one expected alarm" in line for line in lines)
    fragment = yaml.safe_load(calibrated["fragment"].read_text())
    assert set(fragment) == {"detector"} and fragment["detector"]["symptom"] == "estimator"
    # the whole detector block the threshold holds for: merged into the config it gives the settings used
    shipped = load_config(DEFAULT_CONFIG).detector
    calibrated_settings = {k: v for k, v in fragment["detector"].items() if k != "symptom"}
    assert DetectorSettings(**calibrated_settings) == dataclasses.replace(
        shipped, threshold=fragment["detector"]["threshold"]
    )
    text = calibrated["fragment"].read_text()
    assert "nominal_11.blf" in text and "nominal_12.blf" in text and "# method:" in text
    assert calibrated["plot"].stat().st_size > 10_000


def test_threshold_is_calibrate_threshold_on_the_services_own_statistic(calibrated):
    """The statistic is recomputed here from the replay's detector input with cusum_path (no alarm),
    then calibrate_threshold: the command's threshold is that one (written rounded up to 1e-4)."""
    config = load_config(DEFAULT_CONFIG)
    params = config.load_params()
    unbounded = dataclasses.replace(config.detector, threshold=1e300)
    paths = []
    for flight in calibrated["flights"]:
        result = replay_file(flight, config, params)
        assert len(result.detector_feed) == 1  # one clock segment
        time_s, symptom = result.detector_feed[0]
        paths.append(cusum_path(time_s, symptom, unbounded)[1])
    expected = calibrate_threshold(paths, 1.0, sample_period_s=config.detector.block_s)
    assert expected.hours == 2
    threshold = yaml.safe_load(calibrated["fragment"].read_text())["detector"]["threshold"]
    assert threshold == pytest.approx(expected.threshold, abs=1.01e-4) and threshold >= expected.threshold
    assert f"threshold h = {expected.threshold:.3f}" in calibrated["printed"]
    # the flights never come near the shipped 7.77 (the reference model is the monitor's model here)
    assert expected.threshold < config.detector.threshold


def test_written_config_loads_and_replay_uses_the_new_threshold(calibrated, tmp_path, capsys):
    written = calibrated["written"]
    config = load_config(written)
    threshold = yaml.safe_load(calibrated["fragment"].read_text())["detector"]["threshold"]
    assert config.detector.threshold == threshold
    original = load_config(DEFAULT_CONFIG)
    assert config.detector == dataclasses.replace(original.detector, threshold=threshold)
    assert config.dbc_paths[0].resolve() == original.dbc_paths[0].resolve()  # relative paths made absolute
    for flight in calibrated["flights"]:
        assert main(["replay", flight, "--config", str(written), "--out", str(tmp_path / "health.csv")]) == 0
        summary = capsys.readouterr().out
        assert "DEGRADED" not in summary and "SUSPECT" in summary  # the statistic passes h/2, never h


def test_the_statistic_is_the_one_the_service_alarms_on(calibrated):
    """With h below the flight's peak statistic, replay goes DEGRADED where the calibration path first
    crosses h (the row after the crossing: rows every 0.1 s)."""
    config = load_config(calibrated["written"])
    params = config.load_params()
    flight = calibrated["flights"][0]
    time_s, symptom = replay_file(flight, config, params).detector_feed[0]
    ends, stat, _ = cusum_path(time_s, symptom, dataclasses.replace(config.detector, threshold=1e300))
    low = 0.6 * float(stat.max())
    crossing = float(ends[np.argmax(stat >= low)])
    lowered = config.replace(detector=dataclasses.replace(config.detector, threshold=low))
    columns = replay_file(flight, lowered, params).columns
    degraded = np.flatnonzero(columns["state"] == STATES.index("DEGRADED"))
    assert degraded.size and crossing <= columns["time_s"][degraded[0]] <= crossing + 0.1 + 1e-6


def test_a_wrong_model_needs_a_higher_threshold(nominal, calibrated, tmp_path):
    """Heat map 15 % too high: larger residual at every power change, so the statistic and the
    calibrated threshold grow (measured 3.72 -> 22.8 on these flights)."""
    _, paths = nominal
    true = yaml.safe_load(calibrated["fragment"].read_text())["detector"]["threshold"]
    params = paper_table_a1()
    heat = dataclasses.replace(params.heat_map, values_w=np.asarray(params.heat_map.values_w) * 1.15)
    wrong = tmp_path / "wrong.yaml"
    save_model(params.replace(heat_map=heat), wrong)
    out = tmp_path / "wrong_detector.yaml"
    code, _ = _calibrate([*map(str, paths), "--model", str(wrong), "--out", str(out)])
    assert code == 0
    assert yaml.safe_load(out.read_text())["detector"]["threshold"] > 2.0 * true


def test_csv_flights_go_through_the_same_path(nominal):
    """A canonical CSV of the same flight gives the same statistic peak as its .blf (the frames are
    the ones replay makes from the CSV)."""
    folder, paths = nominal
    config = load_config(DEFAULT_CONFIG)
    params = config.load_params()
    blf = replay_file(paths[0], config, params)
    assert len(read_frames(paths[0])) > 100_000
    csv = replay_file(folder / "nominal.csv", config, params)
    assert np.array_equal(blf.columns["state"], csv.columns["state"])
    for (t_a, x_a), (t_b, x_b) in zip(blf.detector_feed, csv.detector_feed, strict=True):
        assert np.allclose(t_a, t_b) and np.allclose(x_a, x_b, equal_nan=True)


def _one_line_exit_2(args, capsys):
    code, _ = _calibrate(args)
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2, err
    assert len(err) == 1 and err[0].startswith("ecu-monitor: error:"), err
    return err[0]


def test_fewer_than_two_hours_exits_2_with_the_hours(nominal, capsys):
    folder, _ = nominal
    line = _one_line_exit_2([str(folder / "short.csv"), "--out", str(folder / "x.yaml")], capsys)
    assert "0.33 flight hours" in line and "0 whole hour" in line and "at least 2" in line
    assert not (folder / "x.yaml").exists()


def test_missing_file_exits_2(tmp_path, capsys):
    line = _one_line_exit_2([str(tmp_path / "none.csv"), "--out", str(tmp_path / "x.yaml")], capsys)
    assert "none.csv: no such file" in line


def test_unreadable_flights_exit_2(tmp_path, capsys):
    garbage_blf = tmp_path / "garbage.blf"
    garbage_blf.write_bytes(b"LOGG" + bytes(range(200)))
    assert "garbage.blf" in _one_line_exit_2([str(garbage_blf), "--out", str(tmp_path / "x.yaml")], capsys)
    text_csv = tmp_path / "text.csv"
    text_csv.write_text("time_s,rpm\nfoo,bar\n")
    assert "text.csv" in _one_line_exit_2([str(text_csv), "--out", str(tmp_path / "x.yaml")], capsys)
    assert "not a file" in _one_line_exit_2([str(tmp_path), "--out", str(tmp_path / "x.yaml")], capsys)
    other = tmp_path / "flight.txt"
    other.write_text("not a log\n")
    assert "unknown log format" in _one_line_exit_2([str(other), "--out", str(tmp_path / "x.yaml")], capsys)


def test_csv_without_the_models_inputs_exits_2(nominal, tmp_path, capsys):
    folder, _ = nominal
    lines = (folder / "short.csv").read_text().splitlines()
    header = lines[0].split(",")
    drop = header.index("rpm")
    stripped = tmp_path / "no_rpm.csv"
    stripped.write_text("\n".join(",".join(c for i, c in enumerate(r.split(",")) if i != drop) for r in lines) + "\n")
    line = _one_line_exit_2([str(stripped), "--out", str(tmp_path / "x.yaml")], capsys)
    assert "no_rpm.csv" in line and "'rpm': required column missing" in line  # a canonical column
    # a model whose heat map reads the fuel flow (optional in a canonical CSV) on a CSV without it
    drop = header.index("fuel_flow_lph")
    no_fuel = tmp_path / "no_fuel.csv"
    no_fuel.write_text("\n".join(",".join(c for i, c in enumerate(r.split(",")) if i != drop) for r in lines) + "\n")
    params = paper_table_a1()
    heat = dataclasses.replace(params.heat_map, x_axis="fuel_flow_lph", x_breakpoints=(5.0, 10.0, 20.0, 30.0, 40.0))
    model = tmp_path / "fuel.yaml"
    save_model(params.replace(heat_map=heat), model)
    line = _one_line_exit_2([str(no_fuel), "--model", str(model), "--out", str(tmp_path / "x.yaml")], capsys)
    assert "no_fuel.csv: missing column(s) fuel_flow_lph" in line


def test_option_errors_exit_2(nominal, tmp_path, capsys):
    folder, _ = nominal
    flight = str(folder / "short.csv")
    assert "--write-config" in _one_line_exit_2([flight, "--write-config"], capsys)
    assert "input config" in _one_line_exit_2(
        [flight, "--write-config", "--config", str(DEFAULT_CONFIG), "--out", str(DEFAULT_CONFIG)], capsys
    )
    assert "--rate" in _one_line_exit_2([flight, "--rate", "0", "--out", str(tmp_path / "x.yaml")], capsys)
    assert "--rate" in _one_line_exit_2([flight, "--rate", "nan", "--out", str(tmp_path / "x.yaml")], capsys)
    assert math.isclose(load_config(DEFAULT_CONFIG).detector.threshold, 7.77)  # the input config is untouched
