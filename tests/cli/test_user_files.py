"""Issue 31, the files a user hands us and the files we write: special files and huge YAML refused in one
line, outputs written atomically (nothing left on failure, a link replaced and never written through),
an output that is the input refused, no pickle of a user's file."""

from __future__ import annotations

import os
import pickle
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from ecu_monitor.cli import main

DATA = Path(__file__).resolve().parents[1] / "data"
FLIGHT = DATA / "flight_small.csv"


def _fails_in_one_line(capsys: pytest.CaptureFixture[str], argv: list[str], *words: str) -> str:
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


@pytest.mark.parametrize("option", ["--model", "--config"])
def test_dev_zero_as_model_or_config_is_refused(capsys, tmp_path, option):
    _fails_in_one_line(
        capsys, ["replay", str(FLIGHT), option, "/dev/zero", "--out", str(tmp_path / "h.csv")], "character device"
    )


def test_fifo_as_model_is_refused_without_waiting(capsys, tmp_path):
    fifo = tmp_path / "model.yaml"
    os.mkfifo(fifo)
    _fails_in_one_line(
        capsys, ["simulate", str(FLIGHT), "--model", str(fifo), "--out", str(tmp_path / "s.csv")], "FIFO"
    )


def test_fifo_or_dev_zero_as_dbc_is_refused(capsys, tmp_path):
    fifo = tmp_path / "engine.dbc"
    os.mkfifo(fifo)
    for dbc in (str(fifo), "/dev/zero"):
        config = tmp_path / "config.yaml"
        text = (Path(__file__).resolve().parents[2] / "ecu_monitor/data/configs/example.yaml").read_text()
        config.write_text(text.replace("dbc: [engine.dbc]", f"dbc: [{dbc}]"))
        assert f"dbc: [{dbc}]" in config.read_text()
        _fails_in_one_line(capsys, ["replay", str(FLIGHT), "--config", str(config), "--out", str(tmp_path / "h.csv")])


def test_a_directory_as_log_says_so(capsys, tmp_path):
    _fails_in_one_line(capsys, ["replay", str(tmp_path), "--out", str(tmp_path / "h.csv")], "a directory")


def test_alias_bomb_in_model_is_refused_at_once(capsys, tmp_path):
    lines = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for i in range(1, 9):
        prev, name = chr(96 + i), chr(97 + i)
        lines.append(f"{name}: &{name} [{', '.join([f'*{prev}'] * 9)}]")
    lines.append("c_w: *i")
    model = tmp_path / "model.yaml"
    model.write_text("\n".join(lines) + "\n")
    _fails_in_one_line(
        capsys, ["simulate", str(FLIGHT), "--model", str(model), "--out", str(tmp_path / "s.csv")], "aliases"
    )


def test_deep_nesting_in_model_is_refused(capsys, tmp_path):
    model = tmp_path / "model.yaml"
    model.write_text("c_w: " + "[" * 50_000 + "\n")
    _fails_in_one_line(
        capsys, ["simulate", str(FLIGHT), "--model", str(model), "--out", str(tmp_path / "s.csv")], "nested"
    )


def test_replay_and_simulate_refuse_to_overwrite_their_input(capsys, tmp_path):
    flight = tmp_path / "same.csv"
    flight.write_bytes(FLIGHT.read_bytes())
    _fails_in_one_line(capsys, ["replay", str(flight), "--out", str(flight)], "is the input")
    _fails_in_one_line(capsys, ["simulate", str(flight), "--out", str(flight)], "is the input")
    assert flight.read_bytes() == FLIGHT.read_bytes()


def test_output_link_is_replaced_not_written_through(capsys, tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me\n")
    link = tmp_path / "sim.csv"
    link.symlink_to(victim)
    planted = tmp_path / "sim.csv.tmp"  # the fixed temporary name an older writer used
    planted.symlink_to(victim)
    assert main(["simulate", str(FLIGHT), "--out", str(link)]) == 0
    assert victim.read_text() == "keep me\n"
    assert not link.is_symlink() and link.read_text().startswith("time_s,")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sim.csv", "sim.csv.tmp", "victim.txt"]


def test_a_failed_write_leaves_nothing(tmp_path, tmp_path_factory):
    """A full disk, made with a file-size limit (EFBIG as ENOSPC would be): exit 2, no health.csv, no
    temporary file."""
    warm = tmp_path_factory.mktemp("warm") / "health.csv"
    assert main(["replay", str(FLIGHT), "--out", str(warm)]) == 0  # compiled kernels cached before the limit
    assert warm.stat().st_size > 2000
    out = tmp_path / "health.csv"

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (2000, 2000))

    done = subprocess.run(
        [sys.executable, "-m", "ecu_monitor.cli", "replay", str(FLIGHT), "--out", str(out)],
        preexec_fn=limit,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert done.returncode == 2, done.stderr
    assert "cannot write" in done.stderr and "Traceback" not in done.stderr
    assert list(tmp_path.iterdir()) == []


def test_flights_cache_is_never_unpickled(capsys, tmp_path):
    marker = tmp_path / "ran"

    class Payload:
        def __reduce__(self):
            return (Path.touch, (marker,))

    cache = tmp_path / "cache.npz"
    cache.write_bytes(pickle.dumps(Payload()))
    _fails_in_one_line(
        capsys,
        ["evaluate", "--hours", "2", "--flights-cache", str(cache), "--out", str(tmp_path / "out")],
        "not a flights cache",
    )
    assert not marker.exists()


def test_a_plot_replaces_a_link_and_never_writes_its_target(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me\n")
    plot = tmp_path / "health.png"
    plot.symlink_to(victim)
    assert main(["replay", str(FLIGHT), "--out", str(tmp_path / "h.csv"), "--plot", str(plot)]) == 0
    assert victim.read_text() == "keep me\n"
    assert not plot.is_symlink() and plot.read_bytes().startswith(b"\x89PNG")
