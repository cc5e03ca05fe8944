"""The fuzz tests' shared rule: a command fed random input exits 0 or 2, never a traceback, and leaves
its output whole (exit 0) or absent (exit 2). ``ECU_FUZZ_EXAMPLES`` examples per property (default 3);
the full search by hand: ``ECU_FUZZ_EXAMPLES=500 .venv/bin/python -m pytest -q tests/cli/test_bad_input_fuzz.py``.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, settings

from ecu_monitor.cli import main

EXAMPLES = int(os.environ.get("ECU_FUZZ_EXAMPLES", "3"))


def fuzz_settings(examples: int) -> settings:
    """Hypothesis settings for ``examples`` examples: the suite's few are the same every run (no flaky test)."""
    return settings(
        max_examples=examples,
        deadline=None,
        derandomize=EXAMPLES <= 20,
        # capsys is read (and so emptied) once per example
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.function_scoped_fixture],
        database=None,
    )


def check_cli_outcome(argv: list[str], out: Path, workdir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Run ``ecu-monitor argv``: exit 0 or 2, no traceback, no stray file, ``out`` whole or absent."""
    before = set(workdir.iterdir())
    code = main(argv)
    err = capsys.readouterr().err
    assert code in (0, 2), f"exit {code} for {argv}: {err[-2000:]}"
    assert "Traceback" not in err, err[-2000:]
    left = set(workdir.iterdir()) - before - {out}
    assert not left, f"stray files after {argv}: {sorted(p.name for p in left)}"
    if code == 2:
        assert not out.exists(), f"{out.name} left behind after exit 2 ({err.strip()[-300:]})"
        error_lines = [line for line in err.splitlines() if "error" in line]
        assert len(error_lines) >= 1
        return
    if out.exists():  # exit 0: whole rows with as many fields as the header, ending in a newline
        text = out.read_text(encoding="utf-8")
        if out.suffix == ".csv":
            lines = text.splitlines()
            assert text.endswith("\n") and lines, f"{out.name} is cut"
            width = lines[0].count(",")
            assert all(line.count(",") == width for line in lines), f"{out.name} has a short row"
        else:
            yaml.safe_load(text)
