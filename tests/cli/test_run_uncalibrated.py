"""``run`` refuses a detector not calibrated for its model (exit 2, one line), unless the config accepts it
for a test bench (then every status line warns)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from ecu_monitor.cli import main
from ecu_monitor.commands.run import uncalibrated_warning
from ecu_monitor.config import load_config
from ecu_monitor.shipped import DEFAULT_CONFIG


def _config(tmp_path: Path, **detector: object) -> Path:
    data = yaml.safe_load(Path(DEFAULT_CONFIG).read_text(encoding="utf-8"))
    data["detector"] = {"symptom": "estimator", **detector}
    data["state_dir"] = str(tmp_path / "state")
    path = tmp_path / "service.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def test_run_exits_2_with_one_line_for_an_uncalibrated_detector(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _config(tmp_path, calibrated_for="0123456789abcdef")
    assert main(["run", "--config", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "was not calibrated for this model" in err and "uncalibrated: accept" in err and str(path) in err


def test_a_test_bench_accepts_it_with_a_warning(tmp_path: Path) -> None:
    config = load_config(_config(tmp_path, uncalibrated="accept"))
    warning = uncalibrated_warning(config, config.load_cylinder_params())
    assert warning.startswith("UNCALIBRATED detector") and "no detector.calibrated_for" in warning


def test_a_calibrated_detector_runs_without_a_word() -> None:
    config = load_config(DEFAULT_CONFIG)
    assert uncalibrated_warning(config, config.load_cylinder_params()) == ""
