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


def climb_and_cruise(
    name: str,
    *,
    ground_s: float,
    climb_to_m: float,
    climb_throttle_pct: float,
    cruise_s: float,
    cruise_mps: float,
    cruise_throttle_pct: float,
    then: tuple[dict[str, object], ...] = (),
) -> dict[str, object]:
    """A short mission for the virtual ECU: ground run, take-off, climb (3 m/s, 21 m/s), cruise, then ``then``."""
    return {
        "name": name,
        "segments": [
            {"kind": "ground_run", "duration_s": ground_s, "throttle_pct": 35},
            {"kind": "takeoff", "duration_s": 20, "ground_roll_s": 8, "throttle_pct": 100, "airspeed_mps": 20,
             "climb_rate_mps": 3},
            {"kind": "climb", "target_altitude_m": climb_to_m, "climb_rate_mps": 3,
             "throttle_pct": climb_throttle_pct, "airspeed_mps": 21},
            {"kind": "cruise", "duration_s": cruise_s, "airspeed_mps": cruise_mps,
             "throttle_pct": cruise_throttle_pct},
            *then,
        ],
    }  # fmt: skip
