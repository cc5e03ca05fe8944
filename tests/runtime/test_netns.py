"""Daemon and virtual ECU as separate processes on python-can's udp_multicast, inside a network namespace.

Each test makes its own namespace (``ip netns add ecu-test-<random>``, loopback up, multicast routed to
``lo``) so no multicast datagram leaves it, runs every process with ``ip netns exec``, and deletes the
namespace in teardown whatever happens. Inside: the daemon (``ecu-monitor run``), the emulator
(``virtual-ecu run --realtime``), a listener on the same group that prints every health frame, and
for one test a flood of garbage frames. Needs root and ``ip netns``; skipped with the reason otherwise.
"""

from __future__ import annotations

import random
import signal
import socket
import sqlite3
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import cantools
import pytest
import yaml

from ecu_monitor.bus.checksum import frame_checksum
from ecu_monitor.runtime.persistence import DATABASE_NAME
from tests.helpers import REPO
from tests.helpers.netns import Lines, Namespace

pytestmark = [pytest.mark.netns, pytest.mark.process, pytest.mark.slow]

HEALTH_DBC = REPO / "ecu_monitor" / "data" / "dbc" / "health.dbc"
GROUP = "239.74.163.2"
HEALTH_IDS = {0x300: "Health_Status", 0x301: "Health_Isolation", 0x302: "Health_Diag"}
STATE_CODES = {"NOMINAL": 0, "SUSPECT": 1, "DEGRADED": 2, "INPUT_STALE": 3, "SENSOR_FAULT": 4, "UNAVAILABLE": 5}
#: StaleInputs bits of health.dbc for the inputs the shipped example.yaml maps.
ALL_INPUT_BITS = 0b1111111


_LISTENER = textwrap.dedent(
    """
    import sys, time, can
    from ecu_monitor.bus.kernel_filter import attach_kernel_filter
    # only the health ids, dropped in the kernel otherwise: under a 4,000 frames/s flood on a loaded
    # machine the socket's queue would otherwise overflow and lose health frames the daemon did send
    filters = [{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in (0x300, 0x301, 0x302)]
    bus = can.Bus(interface="udp_multicast", channel=sys.argv[1], port=int(sys.argv[2]), can_filters=filters)
    assert attach_kernel_filter(bus, filters)
    print("listening", flush=True)
    while True:
        msg = bus.recv(0.5)
        if msg is not None and msg.arbitration_id in (0x300, 0x301, 0x302):
            print(f"{time.monotonic():.6f} {msg.arbitration_id} {bytes(msg.data).hex()}", flush=True)
    """
)

_FLOODER = textwrap.dedent(
    """
    import random, sys, time, can
    bus = can.Bus(interface="udp_multicast", channel=sys.argv[1], port=int(sys.argv[2]))
    rate, seconds, rng = float(sys.argv[3]), float(sys.argv[4]), random.Random(int(sys.argv[5]))
    known = (0x100, 0x101, 0x200)
    sent, start = 0, time.monotonic()
    while time.monotonic() - start < seconds:
        for _ in range(int(rate / 100)):
            frame_id = rng.choice(known) if rng.random() < 0.5 else rng.randrange(0x800)
            if 0x300 <= frame_id <= 0x302:
                continue  # not the health ids: the listener checks those
            dlc = rng.randrange(9)
            data = bytes(rng.randrange(256) for _ in range(dlc))
            bus.send(can.Message(arbitration_id=frame_id, is_extended_id=False, data=data))
            sent += 1
        time.sleep(0.01)
    print("sent", sent, flush=True)
    bus.shutdown()
    """
)


@dataclass
class HealthFrame:
    time_s: float
    name: str
    values: dict[str, Any]
    counter: int


class Setup:
    """Daemon + listener (+ emulator) in one namespace; parses and checks every health frame."""

    def __init__(self, ns: Namespace, min_flight_s: float = 3.0) -> None:
        self.ns = ns
        self.port = random.Random(ns.name).randrange(40000, 50000)
        self.config = ns.tmp / "service.yaml"
        data = yaml.safe_load((REPO / "ecu_monitor" / "data" / "configs" / "example.yaml").read_text())
        data["dbc"] = [str(REPO / "ecu_monitor" / "data" / "dbc" / "engine.dbc")]
        data["health_dbc"] = str(HEALTH_DBC)
        data["bus"] = {"interface": "udp_multicast", "channel": GROUP, "port": self.port}
        data["state_dir"] = str(ns.tmp / "state")
        self.config.write_text(yaml.safe_dump(data, sort_keys=False))
        self.db: Any = cantools.database.load_file(str(HEALTH_DBC))
        self.notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.notify_path = str(ns.tmp / "notify.sock")  # a path socket: reachable from inside the namespace
        self.notify.bind(self.notify_path)
        self.notify.settimeout(0.2)
        self.notifications: list[str] = []
        self._reading = True
        self._reader = threading.Thread(target=self._read_notifications, daemon=True)
        self._reader.start()
        self.listener = Lines(ns.popen([sys.executable, "-c", _LISTENER, GROUP, str(self.port)]))
        assert self.listener.wait_for(lambda lines: "listening\n" in lines, 20), "listener did not start"
        self.daemon = ns.popen(
            [sys.executable, "-m", "ecu_monitor.cli", "run", "--config", str(self.config),
             "--min-flight-s", str(min_flight_s)],
            env={"NOTIFY_SOCKET": self.notify_path, "WATCHDOG_USEC": "1000000"},
        )  # fmt: skip
        self.emulator: subprocess.Popen[str] | None = None

    def _read_notifications(self) -> None:
        while self._reading:  # always drain, as systemd does
            try:
                self.notifications.append(self.notify.recv(4096).decode())
            except TimeoutError:
                continue
            except OSError:
                return

    def wait_notification(self, text: str, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if any(text in m for m in list(self.notifications)):
                return True
            time.sleep(0.05)
        return any(text in m for m in list(self.notifications))

    def wait_state(self, state: str, timeout_s: float) -> bool:
        """Wait until a Health_Status frame reports ``state`` (True) or ``timeout_s`` passes (False)."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            status = [f for f in self.health() if f.name == "Health_Status"]
            if status and status[-1].values["DegradationState"] == STATE_CODES[state]:
                return True
            time.sleep(0.1)
        return False

    def start_emulator(self, speed: float = 1.0) -> None:
        self.emulator = self.ns.popen(
            [sys.executable, "-m", "virtual_bus.cli", "run", "--config", str(self.config), "--mission", "default",
             "--realtime", "--speed", str(speed)]
        )  # fmt: skip

    def health(self, since_s: float = 0.0) -> list[HealthFrame]:
        """Every health frame received after ``since_s`` (listener clock), decoded, checksum checked."""
        frames = []
        for line in list(self.listener.lines):
            parts = line.split()
            if len(parts) != 3:
                continue
            stamp, frame_id, payload = float(parts[0]), int(parts[1]), bytes.fromhex(parts[2])
            if stamp < since_s:
                continue
            name = HEALTH_IDS[frame_id]
            assert len(payload) == 8, f"{name}: {len(payload)} bytes"
            assert payload[7] == frame_checksum(payload), f"{name}: bad checksum {payload.hex()}"
            values = self.db.decode_message(name, payload, decode_choices=False)
            frames.append(HealthFrame(stamp, name, values, payload[6] & 0x0F))
        return frames

    def now(self) -> float:
        return time.monotonic()  # the listener prints CLOCK_MONOTONIC too: same clock, other namespace

    def stop_daemon(self) -> tuple[int, str]:
        self.daemon.send_signal(signal.SIGTERM)
        _, stderr = self.daemon.communicate(timeout=15)
        return self.daemon.returncode, stderr

    def close(self) -> None:
        self._reading = False
        self._reader.join(timeout=2)
        self.notify.close()


@pytest.fixture
def setup(ns: Namespace) -> Iterator[Setup]:
    made = Setup(ns)
    try:
        yield made
    finally:
        made.close()


def check_counters(frames: list[HealthFrame]) -> None:
    """Each message's rolling counter goes up by one, modulo 16, from frame to frame."""
    last: dict[str, int] = {}
    for frame in frames:
        if frame.name in last:
            assert frame.counter == (last[frame.name] + 1) % 16, f"{frame.name}: {last[frame.name]} -> {frame.counter}"
        last[frame.name] = frame.counter


def rate_hz(frames: list[HealthFrame], name: str) -> float:
    times = [f.time_s for f in frames if f.name == name]
    return (len(times) - 1) / (times[-1] - times[0]) if len(times) > 2 else 0.0


def test_health_frames_over_multicast_then_sigterm_keeps_the_flight(setup: Setup) -> None:
    assert setup.wait_notification("READY=1", 25), f"no READY=1: {setup.notifications}"
    setup.start_emulator()
    assert setup.wait_notification("WATCHDOG=1", 10)
    # the estimator starts once every input has been heard: wait for it (a loaded machine starts the
    # emulator's process late), then measure
    assert setup.wait_state("NOMINAL", 30), [f.values["DegradationState"] for f in setup.health()][-5:]
    start = setup.now()
    time.sleep(5.0)
    frames = setup.health(since_s=start)
    check_counters(frames)
    status = [f for f in frames if f.name == "Health_Status"]
    assert rate_hz(frames, "Health_Status") == pytest.approx(10.0, rel=0.1)
    assert rate_hz(frames, "Health_Isolation") == pytest.approx(2.0, rel=0.25)
    assert len([f for f in frames if f.name == "Health_Diag"]) >= 4
    assert all(f.values["DegradationState"] == STATE_CODES["NOMINAL"] for f in status), [
        f.values["DegradationState"] for f in status
    ]
    assert all(0.0 < f.values["ChtEstimate"] < 150.0 for f in status), [f.values for f in status[:3]]  # warm-up
    diag = [f for f in frames if f.name == "Health_Diag"]
    assert all(f.values["StaleInputs"] == 0 and f.values["BusErrors"] == 0 for f in diag)
    code, stderr = setup.stop_daemon()
    assert code == 0, stderr
    assert setup.wait_notification("STOPPING=1", 2)
    conn = sqlite3.connect(setup.ns.tmp / "state" / DATABASE_NAME)
    try:
        assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        rows = conn.execute("SELECT status, end_reason, duration_s, max_cht_c FROM flights").fetchall()
    finally:
        conn.close()
    assert len(rows) == 1, rows
    status_text, reason, duration_s, max_cht = rows[0]
    assert (status_text, reason) == ("finished", "service_stop")
    # the flight began before `start` and ended after the 5 s window; stored to 0.1 s (>= 4.5 leaves room for it)
    assert duration_s >= 4.5, duration_s
    assert max_cht > 20.0
    history = subprocess.run(
        [sys.executable, "-m", "ecu_monitor.cli", "history", "--config", str(setup.config)],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert history.returncode == 0, history.stderr
    assert "engine UAV-ENG-0001: 1 flights" in history.stdout


def test_emulator_killed_mid_flight_inputs_reported_stale_daemon_stays_up(setup: Setup) -> None:
    assert setup.wait_notification("READY=1", 25)
    setup.start_emulator(speed=2.0)
    assert setup.wait_state("NOMINAL", 30), [f.values["DegradationState"] for f in setup.health()][-5:]
    time.sleep(1.0)
    assert setup.emulator is not None
    setup.emulator.send_signal(signal.SIGKILL)
    killed = setup.now()
    time.sleep(4.0)
    frames = setup.health(since_s=killed - 2.0)
    check_counters(frames)
    before = [f for f in frames if f.name == "Health_Status" and f.time_s < killed]
    after = [f for f in frames if f.name == "Health_Status" and f.time_s > killed + 2.5]
    assert before and before[-1].values["DegradationState"] == STATE_CODES["NOMINAL"]
    assert after and all(f.values["DegradationState"] == STATE_CODES["INPUT_STALE"] for f in after)
    stale_diag = [f for f in frames if f.name == "Health_Diag" and f.time_s > killed + 2.5]
    assert stale_diag and stale_diag[-1].values["StaleInputs"] == ALL_INPUT_BITS
    assert rate_hz([f for f in frames if f.time_s > killed], "Health_Status") == pytest.approx(10.0, rel=0.1)
    assert setup.daemon.poll() is None
    code, stderr = setup.stop_daemon()
    assert code == 0, stderr


def test_garbage_flood_is_counted_and_health_rate_kept(setup: Setup) -> None:
    assert setup.wait_notification("READY=1", 25)
    setup.start_emulator()
    time.sleep(3.0)
    flood_start = setup.now()
    flooder = Lines(setup.ns.popen([sys.executable, "-c", _FLOODER, GROUP, str(setup.port), "4000", "5", "7"]))
    assert flooder.wait_for(lambda lines: any(line.startswith("sent") for line in lines), 20)
    flood_end = setup.now()
    time.sleep(1.5)
    sent = int(next(line for line in flooder.lines if line.startswith("sent")).split()[1])
    assert sent >= 10_000
    frames = setup.health(since_s=flood_start - 1.0)
    check_counters(frames)
    during = [f for f in frames if flood_start + 0.5 < f.time_s < flood_end]
    assert rate_hz(during, "Health_Status") == pytest.approx(10.0, rel=0.1)
    diag = [f for f in frames if f.name == "Health_Diag"]
    assert diag[-1].values["MalformedFrames"] > 1000  # half the flood uses engine ids with random payloads
    assert setup.daemon.poll() is None
    code, stderr = setup.stop_daemon()
    assert code == 0, stderr
    assert "Traceback" not in stderr
