"""``calibrate --write-config``'s copy of the service config (offline/calibration.config_copy_yaml) goes to
the machine that runs the service: its files named relative to it, and a test bus flagged (issue 31)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from ecu_monitor.config import load_config
from ecu_monitor.estimation.detection import DetectorSettings, ThresholdCalibration
from ecu_monitor.model.params import save_model
from ecu_monitor.offline.calibration import CalibrationResult, config_copy_yaml

SHIPPED = Path(__file__).resolve().parents[2] / "ecu_monitor" / "data"


def _result() -> CalibrationResult:
    c = ThresholdCalibration(4.5, 4.5, 4.5, 1.0, 0.1, 0, 1.0)
    return CalibrationResult(calibration=c, method="test", flights=(), current=DetectorSettings(baseline_s=300.0))


def test_the_written_config_names_its_files_relative_to_itself_and_flags_a_virtual_bus(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    work = tmp_path / "laptop" / "work"
    (work / "dbc").mkdir(parents=True)
    (work / "models").mkdir()
    shutil.copy(SHIPPED / "dbc" / "engine.dbc", work / "dbc" / "mine.dbc")
    shutil.copy(SHIPPED / "configs" / "example.yaml", work / "service.yaml")
    data = yaml.safe_load((work / "service.yaml").read_text())
    data.update(dbc=["dbc/mine.dbc"], health_dbc="health.dbc", state_dir="/var/lib/ecu-monitor")
    data["bus"] = {"interface": "virtual", "channel": "test"}
    (work / "service.yaml").write_text(yaml.safe_dump(data), encoding="utf-8")
    model = load_config(work / "service.yaml").load_params()
    save_model(model, work / "models" / "fitted.yaml")
    (work / "deploy").mkdir()
    out = work / "deploy" / "service.yaml"
    monkeypatch.chdir(work)  # --model models/fitted.yaml, given from the working directory
    text = config_copy_yaml(work / "service.yaml", out, _result(), 1.0, ["f.csv"], "0" * 16, "models/fitted.yaml")
    body = [line for line in text.splitlines() if not line.startswith("#")]
    assert str(tmp_path) not in "\n".join(body)  # no path of this machine in the settings
    written = yaml.safe_load(text)
    assert written["model"] == "../models/fitted.yaml"
    assert written["dbc"] == ["../dbc/mine.dbc"]
    assert written["health_dbc"] == "health.dbc"  # the shipped file's name
    assert written["state_dir"] == "/var/lib/ecu-monitor"  # absolute: the target's own path, kept
    lines = text.splitlines()
    comment = lines[next(i for i, line in enumerate(lines) if line.startswith("bus:")) - 1]
    assert comment.startswith("# bus: 'virtual'") and "socketcan" in comment
    out.write_text(text, encoding="utf-8")
    moved = tmp_path / "aircraft" / "opt"  # the folder copied whole to the aircraft
    shutil.copytree(work, moved)
    shutil.rmtree(tmp_path / "laptop")
    config = load_config(moved / "deploy" / "service.yaml")
    assert config.dbc_paths == (moved / "deploy" / ".." / "dbc" / "mine.dbc",)
    assert config.detector.threshold == 4.5
    assert config.load_params() == model


def test_a_real_bus_gets_no_comment(tmp_path: Path) -> None:
    source = tmp_path / "service.yaml"
    data = yaml.safe_load((SHIPPED / "configs" / "example.yaml").read_text())
    data["bus"] = {"interface": "socketcan", "channel": "can0"}
    source.write_text(yaml.safe_dump(data), encoding="utf-8")
    text = config_copy_yaml(source, tmp_path / "copy.yaml", _result(), 1.0, ["f.csv"], "0" * 16)
    assert "# bus:" not in text
