"""Issue 28 item 4: every command that writes checks its output paths before the work, in one line and
in well under a second of CPU (``identify --out DIR/`` used to fit for minutes and only then fail). CPU
time, not wall time: the machine is shared, and what the check must not do is work."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from ecu_monitor.cli import main
from ecu_monitor.errors import UserInputError
from ecu_monitor.userfiles import check_output_file, prepare_output_dir

FLIGHT = Path(__file__).resolve().parents[1] / "data" / "flight_small.csv"

#: (command line with {dir} a directory that exists, {file} a regular file, {missing} a folder that does
#: not) -> words of the one error line
CASES = [
    (["identify", str(FLIGHT), "--out", "{dir}/", "--quiet"], "--out"),
    (["identify", str(FLIGHT), "--out", "{missing}/model.yaml", "--quiet"], "no such folder"),
    (["identify", str(FLIGHT), "--out", "{dir}/m.yaml", "--plots", "{file}", "--quiet"], "--plots"),
    (["gap", "--train", str(FLIGHT), "--test", str(FLIGHT), "--out", "{file}"], "not a directory"),
    (["calibrate", str(FLIGHT), "--out", "{dir}"], "--out"),
    (["calibrate", str(FLIGHT), "--out", "{dir}/d.yaml", "--plot", "{missing}/p.png"], "--plot"),
    (["replay", str(FLIGHT), "--out", "{dir}"], "--out"),
    (["replay", str(FLIGHT), "--out", "{dir}/h.csv", "--events", "{missing}/e.csv"], "--events"),
    (["simulate", str(FLIGHT), "--out", "{missing}/sim.csv"], "no such folder"),
    (["import", str(FLIGHT), "--out", "{dir}/"], "--out"),
    (["evaluate", "--out", "{file}"], "not a directory"),
    (["evaluate", "--out", "{dir}/e", "--flights-cache", "{missing}/f.npz"], "--flights-cache"),
    (["results", "--out", "{file}"], "not a directory"),
    (["demo", "--out", "{file}"], "not a directory"),
    (["history", "--state-dir", "{dir}", "--plot", "{dir}"], "--plot"),
]


@pytest.mark.parametrize(("argv", "word"), CASES, ids=[" ".join(c[0][:1] + c[0][-2:]) for c in CASES])
def test_a_bad_output_fails_before_the_work_in_one_line(tmp_path, capsys, argv, word):
    folder = tmp_path / "out"
    folder.mkdir()
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    names = {"dir": str(folder), "file": str(blocker), "missing": str(tmp_path / "nowhere")}
    args = [a.format(**names) for a in argv]
    started = time.process_time()
    code = main(args)
    elapsed = time.process_time() - started
    err = capsys.readouterr().err
    lines = [line for line in err.strip().splitlines() if "compiling" not in line]
    assert code == 2, err
    assert len(lines) == 1 and "Traceback" not in err, err
    assert word in lines[0], lines[0]
    assert elapsed < 1.0, f"{elapsed:.2f} s of CPU before the output was refused"


def test_the_checks_name_what_is_wrong(tmp_path):
    with pytest.raises(UserInputError, match="a directory; give a file name"):
        check_output_file(tmp_path, "--out")
    with pytest.raises(UserInputError, match="no such folder"):
        check_output_file(tmp_path / "no" / "x.csv", "--out")
    assert check_output_file(tmp_path / "x.csv", "--out") == tmp_path / "x.csv"
    assert not (tmp_path / "x.csv").exists()  # checked, not written
    made = prepare_output_dir(tmp_path / "a" / "b", "--out")
    assert made.is_dir()
    (tmp_path / "f").write_text("")
    with pytest.raises(UserInputError, match="a file, not a directory"):
        prepare_output_dir(tmp_path / "f", "--out")
    with pytest.raises(UserInputError, match="no such folder"):
        check_output_file(tmp_path / "f" / "x.csv", "--out")
