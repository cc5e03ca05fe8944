"""report.html in a real headless Chromium (Debian's ``chromium``): it loads with no console error.

Skipped only where Chromium is not installed outside CI (.ci/run installs it; in CI its absence fails).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from ecu_monitor.estimation.wear import WearReference, WearSettings
from ecu_monitor.fleet.engines import engine_rows, engine_trend
from ecu_monitor.fleet.report import render_report
from ecu_monitor.fleet.spec import Fleet

_CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")

pytestmark = pytest.mark.skipif(
    _CHROMIUM is None and not os.environ.get("CI"),
    reason="no chromium on this machine (apt-get install chromium; .ci/run installs it)",
)


def _flight(n: int, wear: float) -> dict[str, object]:
    return {"log": f"logs/flight_{n:03d}.blf", "key": f"k{n}", "flight": 1, "position": n,
            "start_utc": 1.7e9 + 86400.0 * n, "duration_s": 1800.0, "ground_s": 120.0, "low_power_s": 300.0,
            "cruise_power_s": 1000.0, "high_power_s": 380.0, "max_cht_c": 180.0 + n, "max_cht_cyl_c": [180.0 + n],
            "time_above_limit_s": 0.0, "gamma_q_mean": 1.0 + wear, "gamma_q_end": 1.0 + wear, "gamma_d_mean": 1.0,
            "gamma_d_end": 1.0, "wear_index": wear, "worst_state": "NOMINAL", "degraded_s": 0.0,
            "first_degraded_s": None, "events": 0}  # fmt: skip


def _page(tmp_path: Path) -> Path:
    reference = WearReference(0.0, 0.01, 20)
    worn = engine_trend("WORN-1", [_flight(n, 0.012 * n) for n in range(1, 11)], WearSettings(), reference)
    good = engine_trend("GOOD-2", [_flight(n, 0.002 * (-1) ** n) for n in range(1, 11)], WearSettings(), reference)
    events = {"WORN-1": [{"log": "logs/flight_004.blf", "time_s": 1500.0, "kind": "shock_cooling", "cylinder": 1,
                          "value": -40.0, "limit": -33.0, "duration_s": 12.0, "serial": "WORN-1"}]}  # fmt: skip
    rows = engine_rows([good, worn], events, {"GOOD-2": 1}, {"WORN-1": (2000.0, 400.0)}, {})
    failures = [{"serial": "GOOD-2", "log": "logs/bad.blf", "reason": "logs/bad.blf: not a .blf file <&>"}]
    fleet = Fleet(tmp_path / "FLEET.yaml", (), {})
    path = tmp_path / "report.html"
    path.write_text(render_report(fleet, rows, [worn, good], events["WORN-1"], failures), encoding="utf-8")
    return path


def test_the_report_loads_in_headless_chromium_without_console_errors(tmp_path: Path) -> None:
    assert _CHROMIUM is not None, "chromium is not installed (CI installs it in .ci/run)"
    page = _page(tmp_path)
    done = subprocess.run(
        [_CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--enable-logging=stderr", "--v=0",
         f"--user-data-dir={tmp_path / 'profile'}", "--dump-dom", page.as_uri()],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    console = [line for line in done.stderr.splitlines() if re.search(r"CONSOLE|Uncaught|ERR_FILE|ERR_", line)]
    assert console == []
    dom = done.stdout
    assert "The fleet at a glance" in dom and dom.count("data:image/png;base64,") == 2
    # ranked: the worn engine first with its alert, the failure row escaped and shown
    assert dom.index("WORN-1") < dom.index("GOOD-2") and "ALERT at flight" in dom
    assert "not a .blf file &lt;&amp;&gt;" in dom
