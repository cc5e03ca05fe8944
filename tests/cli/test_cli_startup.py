"""``ecu-monitor --help`` and ``virtual-ecu --help`` (and every subcommand's help) import nothing heavy.

Structural, not timed: a fresh interpreter prints each help and then lists which of numpy, numba,
scipy, matplotlib, tqdm, python-can and cantools it imported; none may be there (the command's run
imports them). The start-up time itself is measured by benchmarks/bench_cli_start.py.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from ecu_monitor.cli import COMMANDS

HEAVY = ("numpy", "numba", "scipy", "matplotlib", "tqdm", "can", "cantools", "pandas", "pyarrow")

_PROBE = """
import contextlib, io, json, sys
from {module} import {parser}
helps = {{}}
for argv in {argvs!r}:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
        {parser}({only}).parse_args(argv)
    helps[" ".join(argv)] = out.getvalue()
print(json.dumps({{"helps": helps, "heavy": sorted(m for m in {heavy!r} if m in sys.modules)}}))
"""


def _probe(module: str, parser: str, argvs: list[list[str]], only: str = "") -> dict[str, object]:
    code = _PROBE.format(module=module, parser=parser, argvs=argvs, only=only, heavy=HEAVY)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    return dict(json.loads(done.stdout))


def test_ecu_monitor_help_and_every_subcommand_help_import_nothing_heavy() -> None:
    argvs = [["--help"], *([name, "--help"] for name in COMMANDS)]
    found = _probe("ecu_monitor.cli", "build_parser", argvs)
    helps = found["helps"]
    assert isinstance(helps, dict)
    assert "usage: ecu-monitor" in helps["--help"]
    for name in COMMANDS:
        assert f"usage: ecu-monitor {name}" in helps[f"{name} --help"], name
    assert found["heavy"] == []


@pytest.mark.parametrize("name", ["replay", "identify", "run"])
def test_one_subcommands_help_alone_imports_nothing_heavy(name: str) -> None:
    """As ``main`` builds it for ``ecu-monitor NAME --help``: only that command's module."""
    found = _probe("ecu_monitor.cli", "build_parser", [[name, "--help"]], only=repr(name))
    assert found["heavy"] == []


def test_virtual_ecu_help_imports_nothing_heavy() -> None:
    found = _probe("virtual_bus.cli", "build_parser", [["--help"], ["record", "--help"], ["run", "--help"]])
    helps = found["helps"]
    assert isinstance(helps, dict)
    assert "default, " in helps["record --help"]  # the shipped missions are listed
    assert found["heavy"] == []


def test_help_lists_equal_their_sources() -> None:
    """ecu_monitor/commands/names.py copies these values for the light help: each copy is current."""
    from ecu_monitor.commands import names
    from ecu_monitor.estimation.registry import ESTIMATORS
    from ecu_monitor.identify import DEFAULT_FREE, REFERENCE_DT_S, PsoSettings
    from ecu_monitor.offline.calibration_channel import DEFAULT_RATE_PER_100H

    assert set(names.ESTIMATOR_NAMES) <= set(ESTIMATORS)
    assert names.IDENTIFY_DEFAULT_FREE == DEFAULT_FREE
    defaults = PsoSettings()
    assert (
        defaults.particles,
        defaults.iterations,
        defaults.dt_s,
    ) == (names.PSO_PARTICLES, names.PSO_ITERATIONS, names.PSO_DT_S)
    assert names.SIMULATE_DT_S == REFERENCE_DT_S
    assert names.CALIBRATE_RATE_PER_100H == DEFAULT_RATE_PER_100H


def test_shipped_estimators_are_all_named() -> None:
    """Every estimator the registry ships at import is in the help's list (a fresh interpreter:
    tests may register more)."""
    code = "from ecu_monitor.estimation.registry import ESTIMATORS; print(','.join(ESTIMATORS))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    from ecu_monitor.commands.names import ESTIMATOR_NAMES

    assert tuple(done.stdout.strip().split(",")) == ESTIMATOR_NAMES
