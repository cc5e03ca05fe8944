"""Helpers shared by test modules of several rooms (a test module never imports another test module).

``REPO`` is the checkout's root; ``netns`` the network-namespace processes, ``fuzz`` the exit-code check of
the fuzz tests, ``service`` the daemon's config and pipeline on a test bus; :func:`run_cli` runs
``ecu-monitor`` as a separate process.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def run_cli(*args: str | Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``python -m ecu_monitor.cli ARGS`` in ``cwd``: its exit code and output (60 s at most)."""
    return subprocess.run(
        [sys.executable, "-m", "ecu_monitor.cli", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=60,
        check=False,
    )
