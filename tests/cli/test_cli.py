"""The ecu-monitor dispatcher: every subcommand registers, errors exit 2 with one line."""

from __future__ import annotations

import subprocess
import sys

import pytest

from ecu_monitor.cli import COMMANDS, build_parser, main


def test_every_subcommand_registers():
    parser = build_parser()
    subparsers = next(a for a in parser._actions if a.dest == "command")
    assert set(subparsers.choices) == set(COMMANDS)  # type: ignore[union-attr]


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_each_subcommand_builds_alone(name):
    parser = build_parser(only=name)
    subparsers = next(a for a in parser._actions if a.dest == "command")
    assert list(subparsers.choices) == [name]  # type: ignore[union-attr]


def test_no_command_prints_help_and_exits_2(capsys):
    assert main([]) == 2
    assert "COMMAND" in capsys.readouterr().out


def test_version_prints_the_installed_version(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    assert capsys.readouterr().out.strip() == f"ecu-monitor {version('ecu-monitor')}"


def test_unknown_command_exits_2_with_one_line():
    result = subprocess.run(
        [sys.executable, "-m", "ecu_monitor.cli", "warp-drive"], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 2
    assert "invalid choice" in result.stderr


def test_user_input_error_is_one_line_exit_2(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "ecu_monitor.cli", "simulate", "--model", str(tmp_path / "none.yaml"),
         str(tmp_path / "none.csv"), "--out", str(tmp_path / "sim.csv")],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("ecu-monitor: error:")


@pytest.mark.parametrize(("name", "folder"), [("results", "results-out"), ("evaluate", "evaluate-out")])
def test_results_and_evaluate_default_to_a_new_folder_not_docs_results(name, folder):
    """Run in a checkout, the default must not overwrite the committed docs/results."""
    args = build_parser(only=name).parse_args([name])
    assert args.out == folder
    assert "docs" not in args.out


def test_output_into_a_closed_pipe_ends_quietly() -> None:
    """``ecu-monitor files | head -1``: the reader closes the pipe early; no traceback, exit 141."""
    import subprocess
    import sys

    script = "import sys; from ecu_monitor.cli import main; sys.exit(main(['files']))"
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # before the command writes: every write of its list meets a closed pipe
    stderr = proc.stderr.read().decode()
    assert proc.wait(timeout=60) in (0, 141), stderr
    assert "Traceback" not in stderr
