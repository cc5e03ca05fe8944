"""Issue 31, bad input a user hands us by mistake: each one line naming what to do instead, exit 2."""

from __future__ import annotations

from pathlib import Path

import pytest

from ecu_monitor.cli import main
from ecu_monitor.model import paper_table_a1, save_model

DATA = Path(__file__).resolve().parents[1] / "data"
FLIGHT = DATA / "flight_small.csv"
EXAMPLE = Path(__file__).resolve().parents[2] / "ecu_monitor" / "data" / "configs" / "example.yaml"


def _one_line(capsys: pytest.CaptureFixture[str], argv: list[str], *words: str) -> str:
    code = main(argv)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def test_a_model_given_as_config_and_a_config_as_model(capsys, tmp_path):
    model = tmp_path / "model.yaml"
    save_model(paper_table_a1(), model)
    out = str(tmp_path / "h.csv")
    _one_line(capsys, ["replay", str(FLIGHT), "--config", str(model), "--out", out], "a model file", "--model")
    _one_line(capsys, ["replay", str(FLIGHT), "--model", str(EXAMPLE), "--out", out], "a service config", "--config")


def test_an_unknown_csv_layout_names_a_command_that_exists(capsys, tmp_path):
    flight = tmp_path / "mycols.csv"
    lines = FLIGHT.read_text().splitlines()
    flight.write_text("\n".join([",".join(f"my_{c}" for c in lines[0].split(",")), *lines[1:]]) + "\n")
    line = _one_line(capsys, ["replay", str(flight), "--out", str(tmp_path / "h.csv")], "ecu-monitor import")
    assert "--mapping" in line
    with pytest.raises(SystemExit):
        main(["import", "--help"])
    assert "--mapping" in capsys.readouterr().out


def test_time_in_milliseconds_is_refused_saying_so(capsys, tmp_path):
    lines = FLIGHT.read_text().splitlines()
    rows = [line.split(",") for line in lines[1:]]
    for row in rows:
        row[0] = repr(float(row[0]) * 1000.0)
    flight = tmp_path / "ms.csv"
    flight.write_text("\n".join([lines[0], *(",".join(r) for r in rows)]) + "\n")
    _one_line(capsys, ["replay", str(flight), "--out", str(tmp_path / "h.csv")], "milliseconds", "every 1 s")


def test_history_of_a_file_that_is_no_database(capsys, tmp_path):
    (tmp_path / "ecu-monitor.sqlite3").write_text("not a database\n")
    _one_line(capsys, ["history", "--state-dir", str(tmp_path)], "cannot open the flight database")
