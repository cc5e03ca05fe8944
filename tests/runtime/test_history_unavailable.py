"""The flight history read-only at start, and a disk that fills mid-flight: the service monitors on,
keeps the flight in memory and writes it once the database can be written (issue 31).

Tests run as root, which ignores file modes, so the real failures are made in a private mount
namespace: the database bind-mounted read-only, and a tiny tmpfs as state_dir filled to the last byte.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import can
import cantools
import pytest
import yaml

from ecu_monitor.config import load_config
from ecu_monitor.errors import StorageError
from ecu_monitor.runtime.daemon import Daemon
from ecu_monitor.runtime.flight_recorder import FlightRecorder
from ecu_monitor.runtime.persistence import DATABASE_NAME, StateStore
from ecu_monitor.runtime.publishers import LiveMonitor

pytestmark = pytest.mark.skipif(
    shutil.which("unshare") is None or subprocess.run(["unshare", "-m", "true"], check=False).returncode != 0,
    reason="needs unshare -m (root)",
)

SHIPPED = Path(__file__).resolve().parents[2] / "ecu_monitor" / "data"

_FEED = """
import json, math, os, subprocess, sys
from ecu_monitor.runtime.flight_recorder import FlightRecorder
from ecu_monitor.runtime.persistence import FlightRules, FlightSample, StateStore, trend_values

state = sys.argv[1]
rules = FlightRules(min_flight_s=30.0)

def feed(recorder, t0, t1, rpm):
    t = t0
    while t < t1:
        recorder.add(FlightSample(time_s=t, wall_time_s=1.7e9 + t, rpm=rpm, cht_c=150.0 + 20.0 * math.sin(t / 10.0),
                                  trends={n: 1.0 for n in trend_values()}, state="NOMINAL"))
        t += 1.0
    return t

def flights():
    with StateStore(state, readonly=True) as store:
        return [(f.status, round(f.duration_s)) for f in store.flights(None, include_running=True)]
"""


def _run(script: str, state: Path) -> dict[str, object]:
    code = textwrap.dedent(_FEED) + textwrap.dedent(script)
    done = subprocess.run(
        ["unshare", "-m", "--propagation", "private", sys.executable, "-c", code, str(state)],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_read_only_history_at_start_is_monitored_without_and_written_when_writable(tmp_path: Path) -> None:
    state = tmp_path / "state"
    out = _run(
        """
        StateStore(state).close()  # an existing database, then made read-only under the service
        db = os.path.join(state, "ecu-monitor.sqlite3")
        subprocess.run(["mount", "--bind", "-o", "ro", db, db], check=True)
        recorder = FlightRecorder(lambda: StateStore(state), "E1", 230.0, rules, retry_s=20.0)
        fault_at_start = recorder.history_fault
        t = feed(recorder, 0.0, 100.0, 2500.0)  # a flight, in memory only
        t = feed(recorder, t, t + 15.0, 0.0)  # engine stopped: finished, still in memory
        in_memory = flights()
        subprocess.run(["umount", db], check=True)  # writable again
        t = feed(recorder, t, t + 25.0, 0.0)  # the next retry writes it
        print(json.dumps({"fault": fault_at_start, "in_memory": in_memory, "after": flights(),
                          "fault_after": recorder.history_fault, "finished": recorder.finished}))
        """,
        state,
    )
    assert "readonly" in str(out["fault"]), out
    assert out["in_memory"] == []
    assert out["after"] == [["finished", 99]]
    assert out["fault_after"] is None
    assert out["finished"] == [1]


def test_a_disk_full_mid_flight_keeps_the_flight_in_memory_and_writes_it_when_space_returns(tmp_path: Path) -> None:
    state = tmp_path / "state"
    state.mkdir()
    out = _run(
        """
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", state], check=True)
        recorder = FlightRecorder(lambda: StateStore(state), "E1", 230.0, rules, retry_s=20.0)
        t = feed(recorder, 0.0, 40.0, 2500.0)  # flight 1 begun and checkpointed
        filler = os.path.join(state, "filler")
        fd = os.open(filler, os.O_WRONLY | os.O_CREAT)  # the disk fills up
        try:
            while True:
                os.write(fd, b"x" * 4096)
        except OSError:
            os.close(fd)
        t = feed(recorder, t, 200.0, 2500.0)  # checkpoints fail
        fault = recorder.history_fault
        t = feed(recorder, t, t + 15.0, 0.0)  # engine stopped: the flight finished, kept in memory
        while_full = flights()
        os.remove(filler)
        t = feed(recorder, t, t + 25.0, 0.0)
        print(json.dumps({"fault": fault, "while_full": while_full, "after": flights(),
                          "fault_after": recorder.history_fault}))
        """,
        state,
    )
    assert "full" in str(out["fault"]), out
    assert out["while_full"] == [["running", 30]]  # the last checkpoint before the disk filled
    assert out["after"] == [["finished", 199]]
    assert out["fault_after"] is None


def _service_config(tmp_path: Path, channel: str) -> Path:
    """The shipped example.yaml on a virtual bus, its state_dir under tmp_path."""
    data = yaml.safe_load((SHIPPED / "configs" / "example.yaml").read_text())
    data["dbc"] = [str(SHIPPED / "dbc" / "engine.dbc")]
    data["health_dbc"] = str(SHIPPED / "dbc" / "health.dbc")
    data["bus"] = {"interface": "virtual", "channel": channel}
    data["state_dir"] = str(tmp_path / "state")
    path = tmp_path / "service.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.mark.process
def test_run_with_a_read_only_history_monitors_and_says_so_in_status(tmp_path: Path) -> None:
    """Before: exit 2 at start (under systemd a restart loop). Now READY=1 with the fault in STATUS=."""
    config = _service_config(tmp_path, f"ro-{uuid.uuid4().hex}")
    state = tmp_path / "state"
    subprocess.run([sys.executable, "-c", f"from ecu_monitor.runtime.persistence import StateStore; "
                    f"StateStore({str(state)!r}).close()"], check=True)  # fmt: skip
    db = state / DATABASE_NAME
    name = f"ecu-monitor-test-{uuid.uuid4().hex}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(b"\0" + name.encode())
    sock.settimeout(0.2)
    env = {**os.environ, "NOTIFY_SOCKET": "@" + name, "PYTHONUNBUFFERED": "1"}
    command = f"mount --bind -o ro {db} {db} && exec {sys.executable} -m ecu_monitor.cli run --config {config}"
    proc = subprocess.Popen(["unshare", "-m", "--propagation", "private", "sh", "-c", command], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        messages: list[str] = []
        end = time.monotonic() + 120.0
        while time.monotonic() < end and proc.poll() is None and not any("READY=1" in m for m in messages):
            with contextlib.suppress(TimeoutError):
                messages.append(sock.recv(4096).decode())
        ready = [m for m in messages if "READY=1" in m]
        assert ready, f"no READY=1 (exit {proc.poll()}): {proc.stderr.read() if proc.poll() is not None else ''}"
        status = next(line for line in ready[0].splitlines() if line.startswith("STATUS="))
        assert "NO HISTORY" in status and "readonly" in status, status
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=30)
    finally:
        sock.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
    assert proc.returncode == 0, stderr
    assert "cannot write the flight history (attempt to write a readonly database)" in stderr
    assert "Traceback" not in stderr


def test_health_diag_flags_a_history_that_cannot_be_written(tmp_path: Path) -> None:
    """Health_Diag.HistoryDown is 1 while the recorder's history is down, 0 once it is written again."""
    channel = f"diag-{uuid.uuid4().hex}"
    config = load_config(_service_config(tmp_path, channel))
    pipeline = LiveMonitor(config, config.load_params())
    writable = threading.Event()

    def open_store() -> StateStore:
        if not writable.is_set():
            raise StorageError("ecu-monitor.sqlite3: cannot write the flight history (database or disk is full)")
        return StateStore(tmp_path / "state")

    recorder = FlightRecorder(open_store, config.engine_serial, 230.0, retry_s=0.5)
    daemon = Daemon(pipeline, lambda: can.Bus(interface="virtual", channel=channel), recorder=recorder)
    listener = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    health: Any = cantools.database.load_file(str(SHIPPED / "dbc" / "health.dbc"))
    diag_id = health.get_message_by_name("Health_Diag").frame_id

    def flags_after(value: int, timeout_s: float = 20.0) -> list[int]:
        """The HistoryDown flags of the two Health_Diag frames after the first one that shows ``value`` (the
        recorder's first attempt may come after a frame or two: how soon depends on the machine's load)."""
        seen: list[int] = []
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and len(seen) < 3:
            msg = listener.recv(0.05)
            if msg is not None and msg.arbitration_id == diag_id:
                flag = health.decode_message(diag_id, bytes(msg.data))["HistoryDown"]
                if seen or flag == value:
                    seen.append(flag)
        return seen[1:]

    result: list[int] = []
    thread = threading.Thread(target=lambda: result.append(daemon.run()), daemon=True)
    thread.start()
    try:
        end = time.monotonic() + 120.0  # the warm-up compiles the estimators on an empty numba cache
        while daemon.counters["bus_opens"] == 0 and time.monotonic() < end:
            time.sleep(0.05)
        assert flags_after(1) == [1, 1]
        assert "NO HISTORY" in daemon._status_line()
        writable.set()
        assert flags_after(0) == [0, 0]
        assert "NO HISTORY" not in daemon._status_line()
    finally:
        daemon.stop()
        thread.join(timeout=15)
        listener.shutdown()
    assert result == [0]
