"""``virtual-ecu jsbsim``: a JSBSim piston aircraft flown to a canonical CSV that our loader reads."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ecu_monitor.flightlog import CANONICAL_COLUMNS, ENGINE_COLUMNS, load_csv
from virtual_bus.cli import main

pytest.importorskip("jsbsim", reason="the jsbsim package is not installed (pip install 'ecu-monitor[jsbsim]')")


@pytest.fixture(scope="module")
def flown(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("jsbsim")
    out = folder / "c172x.csv"
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(folder)
        assert main(["jsbsim", "--aircraft", "c172x", "--mission", "pattern", "--seed", "1", "--out", "c172x.csv"]) == 0
    assert [p.name for p in folder.iterdir()] == ["c172x.csv"]  # nothing else (JSBSim's own output files)
    return out


def test_flown_csv_loads_with_sane_columns(flown: Path) -> None:
    log = load_csv(flown)
    for name in (*CANONICAL_COLUMNS, *ENGINE_COLUMNS[2:], "fuel_flow_lph", "egt_c", "mixture_pct"):
        assert log.has(name), name
        assert np.all(np.isfinite(log[name])), name
    dt = np.diff(log.time_s)
    assert np.allclose(dt, 1.0, atol=0.02)
    assert 600.0 < log.duration_s < 2400.0
    cht, oat = log["cht_c"], log["oat_c"]
    assert abs(cht[0] - oat[0]) < 5.0  # a cold engine at the start
    assert 150.0 < cht.max() < 400.0  # JSBSim's O-320 climbs at about 300 degC
    assert np.array_equal(cht, np.round(cht))  # the sensor's 1 degC steps
    assert log["airspeed_mps"][0] == 0.0 and log["airspeed_mps"].max() > 35.0  # took off
    assert log["altitude_m"].max() - log["altitude_m"][0] > 250.0  # climbed
    assert log["rpm"].max() > 2200.0 and log["throttle_pct"].max() == pytest.approx(100.0)
    assert 0.0 < np.median(log["fuel_flow_lph"]) < 60.0


@pytest.mark.parametrize(
    ("argv", "needle"),
    [(["--aircraft", "concorde"], "concorde"), (["--mission", "moon"], "moon")],
)
def test_bad_choice_is_one_line(
    argv: list[str], needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["jsbsim", *argv, "--out", str(tmp_path / "f.csv")]) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err
