"""The shipped systemd unit (ecu_monitor/data/systemd/ecu-monitor.service): systemd-analyze verify is
clean and the security exposure is <= 2.0.

The unit is verified as installed: it is copied into a throwaway root (``--root``) beside the host's
unit files and an executable at its ExecStart path, so the check covers every directive, not just the
syntax. Skipped, with the reason, where systemd-analyze is not installed (apt-get install systemd).
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers import REPO

UNIT = REPO / "ecu_monitor" / "data" / "systemd" / "ecu-monitor.service"
ANALYZE = shutil.which("systemd-analyze")
needs_analyze = pytest.mark.skipif(ANALYZE is None, reason="systemd-analyze not installed (apt-get install systemd)")


def directives(text: str) -> dict[str, list[str]]:
    """Key -> values of the unit file (comments and section headers dropped)."""
    found: dict[str, list[str]] = {}
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith(("#", ";", "[")):
            continue
        key, _, value = line.partition("=")
        found.setdefault(key.strip(), []).append(value.strip())
    return found


def test_unit_has_the_required_hardening() -> None:
    unit = directives(UNIT.read_text())
    expected = {
        "Type": "notify",
        "DynamicUser": "yes",
        "StateDirectory": "ecu-monitor",
        "ProtectSystem": "strict",
        "ProtectHome": "yes",
        "PrivateTmp": "yes",
        "NoNewPrivileges": "yes",
        "CapabilityBoundingSet": "",
        "RestrictAddressFamilies": "AF_UNIX AF_CAN AF_NETLINK",
        "SystemCallArchitectures": "native",
        "Restart": "on-failure",
    }
    for key, value in expected.items():
        assert unit.get(key) == [value], f"{key}: {unit.get(key)}"
    assert unit["SystemCallFilter"] == ["@system-service", "~@privileged @resources"]
    assert re.fullmatch(r"\d+s", unit["WatchdogSec"][0])
    assert unit["ExecStart"][0].split()[:3] == ["/opt/ecu-monitor/venv/bin/ecu-monitor", "run", "--config"]
    assert "MemoryDenyWriteExecute" not in unit  # numba needs W+X pages: off on purpose (see the unit's comment)


def test_numba_cache_is_inside_the_units_cache_directory() -> None:
    """ProtectSystem=strict leaves the CacheDirectory= writable and the dynamic user has no writable home:
    NUMBA_CACHE_DIR must lie inside the cache directory (%C = /var/cache), or every start compiles again."""
    unit = directives(UNIT.read_text())
    assert unit["CacheDirectory"] == ["ecu-monitor"]
    environment = dict(item.split("=", 1) for line in unit["Environment"] for item in line.split())
    assert environment["NUMBA_CACHE_DIR"] == "%C/ecu-monitor/numba"
    assert unit["ProtectSystem"] == ["strict"]  # the reason it must: nothing else is writable


def _install_root(tmp_path: Path) -> Path:
    """A root with the host's unit files, our unit, and an executable at the ExecStart path."""
    root = tmp_path / "root"
    host_units = Path("/usr/lib/systemd/system")
    if host_units.is_dir():
        shutil.copytree(host_units, root / "usr/lib/systemd/system", symlinks=True)
    (root / "etc/systemd/system").mkdir(parents=True)
    shutil.copy(UNIT, root / "etc/systemd/system/ecu-monitor.service")
    entry = root / "opt/ecu-monitor/venv/bin/ecu-monitor"
    entry.parent.mkdir(parents=True)
    installed = Path(sys.executable).parent / "ecu-monitor"
    shutil.copy(installed if installed.exists() else sys.executable, entry)
    entry.chmod(0o755)
    return root


@needs_analyze
def test_systemd_analyze_verify_is_clean(tmp_path: Path) -> None:
    assert ANALYZE is not None
    root = _install_root(tmp_path)
    proc = subprocess.run(
        [ANALYZE, "verify", f"--root={root}", "ecu-monitor.service"], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.strip() == "", proc.stderr


@needs_analyze
def test_security_exposure_at_most_2(tmp_path: Path) -> None:
    assert ANALYZE is not None
    proc = subprocess.run(
        [ANALYZE, "security", "--offline=true", str(UNIT)], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0, proc.stderr
    match = re.search(r"Overall exposure level for ecu-monitor\.service: (\d+\.\d+)", proc.stdout)
    assert match, proc.stdout[-500:]
    assert float(match.group(1)) <= 2.0, proc.stdout
