"""Issue 31: two ``ecu-monitor run`` on one state_dir. The second is refused in one line before its
start-up recovery touches the first one's flight; the lock dies with its holder."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from ecu_monitor.errors import ConfigError
from ecu_monitor.runtime.state_lock import LOCK_NAME, StateDirLock

REPO = Path(__file__).resolve().parents[2]

HOLD = """
import sys, time
from ecu_monitor.runtime.state_lock import StateDirLock
lock = StateDirLock(sys.argv[1])
print("held", flush=True)
time.sleep(600)
"""


def test_second_lock_is_refused_and_the_first_release_frees_it(tmp_path: Path) -> None:
    with StateDirLock(tmp_path / "state") as first:
        with pytest.raises(ConfigError, match=r"another ecu-monitor run \(pid \d+\)"):
            StateDirLock(tmp_path / "state")
        first.close()
        first.close()  # idempotent
        StateDirLock(tmp_path / "state").close()


def test_the_kernel_drops_the_lock_of_a_killed_holder(tmp_path: Path) -> None:
    state = tmp_path / "state"
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(state)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with pytest.raises(ConfigError, match=f"pid {holder.pid}"):
            StateDirLock(state)
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait(timeout=10)
    StateDirLock(state).close()  # no stale lock after a SIGKILL
    assert (state / LOCK_NAME).exists()


@pytest.mark.process
def test_a_second_run_on_one_state_dir_exits_2_in_one_line(tmp_path: Path) -> None:
    data = yaml.safe_load((REPO / "ecu_monitor" / "data" / "configs" / "example.yaml").read_text())
    data["state_dir"] = str(tmp_path / "state")
    data["bus"] = {"interface": "virtual", "channel": "lock-test"}
    config = tmp_path / "service.yaml"
    config.write_text(yaml.safe_dump(data, sort_keys=False))
    with StateDirLock(tmp_path / "state"):  # the first service
        started = time.monotonic()
        proc = subprocess.run(
            [sys.executable, "-m", "ecu_monitor.cli", "run", "--config", str(config)],
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert "another ecu-monitor run" in lines[0]
    assert not (tmp_path / "state" / "ecu-monitor.sqlite3").exists()  # refused before the store opened
    assert time.monotonic() - started < 120
