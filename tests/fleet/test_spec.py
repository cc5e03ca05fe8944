"""FLEET.yaml: validated into settings, one-line errors naming the file and the key (exit 2 on the CLI)."""

from __future__ import annotations

from pathlib import Path

import pytest

from ecu_monitor.errors import ConfigError
from ecu_monitor.fleet.spec import load_fleet
from ecu_monitor.shipped import DEFAULT_CONFIG
from tests.helpers import run_cli


def _write(folder: Path, text: str) -> Path:
    path = folder / "FLEET.yaml"
    path.write_text(text)
    return path


def test_engines_logs_and_defaults_resolve_relative_to_the_fleet_file(tmp_path: Path) -> None:
    (tmp_path / "logs").mkdir()
    for name in ("b.csv", "a.csv"):
        (tmp_path / "logs" / name).write_text("time_s\n0\n")
    (tmp_path / "detector.yaml").write_text("wear: {reference: {mean: 0.0, sd: 0.01, flights: 12}}\n")
    fleet = load_fleet(_write(tmp_path, (
        "defaults: {detector: detector.yaml, tbo_hours: 1800}\n"
        "engines:\n"
        "  - {serial: E-1, logs: ['logs/*.csv', logs/a.csv], overhaul_hours: 100}\n"
        "  - {serial: E-2, logs: ['nothing/*.blf'], tbo_hours: 2000, model: paper_table_a1}\n"
    )))  # fmt: skip
    first, second = fleet.engines
    assert first.config == DEFAULT_CONFIG and first.detector == tmp_path / "detector.yaml"
    assert (first.tbo_hours, first.overhaul_hours) == (1800, 100)
    assert (second.tbo_hours, second.model) == (2000, "paper_table_a1")
    jobs, empty = fleet.jobs()
    assert [(j.serial, j.name, j.position) for j in jobs] == [("E-1", "logs/a.csv", 0), ("E-1", "logs/b.csv", 1)]
    assert len({j.key for j in jobs}) == 1  # same content, same engine: one key (processed once)
    assert empty == [f"{tmp_path / 'FLEET.yaml'}: engine E-2: no log matches 'nothing/*.blf'"]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("engines: []\n", "engines: expected a list"),
        ("engines:\n  - {serial: 'a/b', logs: [x]}\n", "engines[0].serial: expected a serial of letters"),
        ("engines:\n  - {serial: A, logs: [x], colour: red}\n", "engines[0].colour: unknown key 'colour'"),
        ("engines:\n  - {serial: A}\n", "engines[0].logs: missing"),
        ("engines:\n  - {serial: A, logs: [x]}\n  - {serial: A, logs: [y]}\n", "engines[1].serial: 'A' is"),
        ("engines:\n  - {serial: A, logs: [x], model: none.yaml}\n", "engines[0].model: no such file 'none.yaml'"),
        ("engines:\n  - {serial: A, logs: [x], tbo_hours: -5}\n", "tbo_hours: expected a number > 0"),
    ],
)
def test_a_bad_fleet_file_is_one_line_naming_the_key(tmp_path: Path, text: str, message: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as caught:
        load_fleet(path)
    assert str(caught.value).startswith(f"{path}: ") and message in str(caught.value)
    assert "\n" not in str(caught.value)


def test_cli_exits_2_with_the_line(tmp_path: Path) -> None:
    path = _write(tmp_path, "engines:\n  - {serial: A, logs: [x], colour: red}\n")
    done = run_cli("fleet", "run", path, "--out", tmp_path / "out", cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1].startswith(f"ecu-monitor: error: {path}: engines[0].colour")
