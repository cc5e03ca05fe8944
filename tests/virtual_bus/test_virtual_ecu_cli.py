"""The ``virtual-ecu`` command line (record, run) and the first ``ecu-monitor demo``."""

from __future__ import annotations

import subprocess
import sys
import uuid
from pathlib import Path
from typing import Any

import can
import pytest

from ecu_monitor.flightlog import read_csv
from virtual_bus.cli import main

SHORT_MISSION = """\
name: tiny
segments:
  - {kind: ground_run, duration_s: 5, throttle_pct: 30}
  - {kind: takeoff, duration_s: 10, ground_roll_s: 5}
"""


@pytest.fixture
def tiny_mission(tmp_path: Path) -> Path:
    path = tmp_path / "tiny.yaml"
    path.write_text(SHORT_MISSION, encoding="utf-8")
    return path


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["record", "--mission", "no_such_mission", "--out", "f.csv"], "no_such_mission"),
        (["record", "--out", "f.csv", "--degrade", "gamma_q=1.2"], "--degrade"),
        (["record", "--out", "f.csv", "--degrade", "gamma_q=1.2@x"], "--degrade"),
        (["record", "--out", "f.csv", "--effect", "warp_drive"], "warp_drive"),
        (["record", "--out", "f.csv", "--effect", "sensor_lag:tau=3"], "tau"),
        (["record", "--out", "f.xyz"], "f.xyz"),
        (["record"], "--out"),
        (["record", "--out", "f.csv", "--model", "missing_model.yaml"], "missing_model.yaml"),
        (["run", "--mission", "default"], "--config"),
        (["run", "--interface", "nosuchbus", "--channel", "x"], "nosuchbus"),
    ],
)
def test_bad_input_prints_one_line_and_exits_2(
    argv: list[str], needle: str, capsys: pytest.CaptureFixture[str], tmp_path: Path, monkeypatch: Any
):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.startswith("virtual-ecu: error:") and needle in err
    assert not (tmp_path / "f.csv").exists()


def test_bad_mission_file_names_file_and_key(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    bad = tmp_path / "bad.yaml"
    bad.write_text("segments:\n  - {kind: climb, target_altitude_m: 100, climb_rate_mps: -3}\n", encoding="utf-8")
    assert main(["record", "--mission", str(bad), "--out", str(tmp_path / "f.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(bad) in err and "segments[0].climb_rate_mps" in err


def test_record_writes_every_output_and_a_summary(tiny_mission: Path, tmp_path: Path, capsys: Any):
    outs = [tmp_path / name for name in ("f.csv", "f.asc", "f.log")]
    argv = ["record", "--mission", str(tiny_mission), "--seed", "4", "--degrade", "gamma_d=1.1@2:ramp=5"]
    argv += ["--effect", "sensor_lag:time_constant_s=12"]
    for out in outs:
        argv += ["--out", str(out)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "max CHT" in text and "frames" in text and "rows" in text and "sensor_lag" in text
    log = read_csv(outs[0])
    assert log["gamma_d"][-1] == pytest.approx(1.1)
    with can.LogReader(str(outs[1])) as reader:
        assert sum(1 for _ in reader) == 15 * 70


@pytest.mark.slow
@pytest.mark.process
def test_record_default_mission_from_a_subprocess(tmp_path: Path):
    out = tmp_path / "f.csv"
    exe = Path(sys.executable).with_name("virtual-ecu")
    command = [str(exe)] if exe.exists() else [sys.executable, "-m", "virtual_bus.cli"]
    done = subprocess.run(
        [*command, "record", "--mission", "default", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=240,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert "max CHT" in done.stdout
    log = read_csv(out)
    assert log.duration_s > 3000.0 and log.has("cht_true_c")
    assert log["altitude_m"].max() > 3900.0


def test_run_emits_onto_the_configured_bus(tiny_mission: Path, tmp_path: Path, make_bus: Any, capsys: Any):
    channel = f"vecu-cli-{uuid.uuid4().hex[:8]}"
    config = tmp_path / "bus.yaml"
    config.write_text(f"engine: {{serial: X}}\nbus: {{interface: virtual, channel: {channel}}}\n", encoding="utf-8")
    receiver = make_bus(channel)
    assert main(["run", "--config", str(config), "--mission", str(tiny_mission)]) == 0
    count = 0
    while receiver.recv(timeout=0.2) is not None:
        count += 1
    assert count == 15 * 70
    assert f"sent {count} frames (0 send errors)" in capsys.readouterr().out


def test_run_with_interface_options_and_realtime(tiny_mission: Path, make_bus: Any, capsys: Any):
    channel = f"vecu-cli-{uuid.uuid4().hex[:8]}"
    receiver = make_bus(channel)
    argv = ["run", "--interface", "virtual", "--channel", channel, "--mission", str(tiny_mission)]
    assert main([*argv, "--realtime", "--speed", "50"]) == 0
    first = receiver.recv(timeout=0.5)
    assert first is not None and first.arbitration_id in (0x100, 0x101, 0x200)
    # a daemon on the bus runs on the wall clock: faster than real time is warned, once, in one line
    warnings = [line for line in capsys.readouterr().err.splitlines() if "faster than real time" in line]
    assert len(warnings) == 1 and "--speed 50" in warnings[0] and "replay" in warnings[0]


@pytest.mark.parametrize("option", ["--dt", "--record-dt"])
@pytest.mark.parametrize("value", ["0", "nan", "-0.02", "inf"])
def test_record_refuses_a_zero_or_nan_step_in_one_line(tmp_path: Path, capsys: Any, option: str, value: str):
    out = tmp_path / "flight.csv"
    assert main(["record", option, value, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    assert err.startswith("virtual-ecu: error: ") and option.lstrip("-").replace("-", "_") in err
    assert not out.exists()


@pytest.mark.slow
def test_demo_raises_what_the_service_side_raised_instead_of_waiting(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A failure in the service's frame handling (a bug) stops the demo with it: the ECU side must not wait
    for ever for a service that no longer takes frames."""
    from ecu_monitor.cli import main as ecu_main
    from ecu_monitor.runtime.publishers import LiveMonitor

    def broken(self: LiveMonitor, t_s: float) -> list[can.Message]:
        raise RuntimeError("the step broke")

    monkeypatch.setattr(LiveMonitor, "advance_to", broken)
    with pytest.raises(RuntimeError, match="the step broke"):
        ecu_main(["demo", "--out", str(tmp_path / "demo"), "--mission", "short_hop"])


def test_demo_writes_csv_and_plot(tmp_path: Path, capsys: Any):
    """The demo as a user runs it, on a short mission to keep the suite fast (the default mission is
    the same code path, ~70 min of flight)."""
    from ecu_monitor.cli import main as ecu_main

    out = tmp_path / "demo"
    args = ["demo", "--out", str(out), "--seed", "1", "--mission", "short_hop", "--inject-at", "700"]
    assert ecu_main(args) == 0
    log = read_csv(out / "flight.csv")
    assert log["gamma_q"][0] == 1.0 and log["gamma_q"][-1] == pytest.approx(1.2)
    for name in ("cht.png", "detection.png", "gammas.png", "headroom.png"):
        png = (out / name).read_bytes()
        assert png.startswith(b"\x89PNG") and len(png) > 20_000, name
    health = (out / "health.csv").read_text().splitlines()
    assert health[0].startswith("time_s") and len(health) > 1000
    printed = capsys.readouterr().out
    assert "DEGRADED" in printed and "detected after" in printed and "wrote" in printed
