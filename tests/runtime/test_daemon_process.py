"""The daemon as a user runs it: a separate process under a test NOTIFY_SOCKET, config errors, bus faults.

Separate process: ``python -m ecu_monitor.cli run --config FILE`` with NOTIFY_SOCKET bound by the test
(READY=1, STATUS=, WATCHDOG=1 at the WATCHDOG_USEC period, STOPPING=1 on SIGTERM, exit 0, database
intact). In process, on python-can's ``virtual`` interface: a bus whose send raises (counted, not fatal,
the bus is reopened), a bus whose receive fails (reopened with backoff, BusErrors in Health_Diag), an
error raised inside the frame path (counted by the keep-alive handler, the daemon lives on).
"""

from __future__ import annotations

import itertools
import os
import signal
import socket
import sqlite3
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, ClassVar

import can
import cantools
import pytest
import yaml

from ecu_monitor.bus.checksum import frame_checksum
from ecu_monitor.bus.codec import Encoder
from ecu_monitor.pipeline.schedule import MAX_CLOCK_GAP_S
from ecu_monitor.runtime.daemon import SEND_FAILURES_TO_REOPEN, Daemon, DaemonSettings
from ecu_monitor.runtime.notify import SystemdNotifier, WatchdogGate, watchdog_period_s
from ecu_monitor.runtime.persistence import DATABASE_NAME
from tests.helpers import REPO
from tests.helpers.service import ENGINE_DBC, HEALTH_DBC, service_pipeline, write_config

HEALTH_IDS = {0x300: "Health_Status", 0x301: "Health_Isolation", 0x302: "Health_Diag"}


class EcuSender:
    """A steady engine on a bus: ECU_Fast at 50 Hz, ECU_Slow and AirData at 10 Hz, valid counters/CRC."""

    VALUES: ClassVar[dict[str, dict[str, float]]] = {
        "ECU_Fast": {"EngineSpeed": 5000.0, "ThrottlePos": 50.0, "FuelFlow": 0.5},
        "ECU_Slow": {"CHT": 150.0, "OAT": 15.0, "EcuStatus": 0, "ManifoldPressure": 0.0},
        "AirData": {"PressureAltitude": 1000.0, "CalibratedAirspeed": 23.0, "VerticalSpeed": 0.0},
    }

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.encoder = Encoder([ENGINE_DBC])
        self.counters = dict.fromkeys(self.VALUES, 0)
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def frame(self, name: str) -> can.Message:
        data = self.encoder.encode(name, self.VALUES[name], self.counters[name])
        self.counters[name] += 1
        return can.Message(arbitration_id=self.encoder.message(name).frame_id, is_extended_id=False, data=data)

    def _loop(self) -> None:
        k = 0
        next_s = time.monotonic()
        while not self._stop.is_set():
            names = ["ECU_Fast"] + (["ECU_Slow", "AirData"] if k % 5 == 0 else [])
            for name in names:
                self.bus.send(self.frame(name))
                self.sent += 1
            k += 1
            next_s += 0.02
            self._stop.wait(max(0.0, next_s - time.monotonic()))

    def __enter__(self) -> EcuSender:
        self._thread.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


class HealthReader:
    """Decodes and checks health frames: checksum, counter +1 mod 16 per id."""

    def __init__(self) -> None:
        self.db: Any = cantools.database.load_file(str(HEALTH_DBC))
        self.last_counter: dict[int, int] = {}
        self.frames: dict[str, list[dict[str, Any]]] = {name: [] for name in HEALTH_IDS.values()}
        self.counter_jumps = 0

    def take(self, msg: can.Message) -> bool:
        if msg.arbitration_id not in HEALTH_IDS:
            return False
        data = bytes(msg.data)
        assert len(data) == 8
        assert data[7] == frame_checksum(data), f"bad checksum on 0x{msg.arbitration_id:X}"
        counter = data[6] & 0x0F
        last = self.last_counter.get(msg.arbitration_id)
        if last is not None and counter != (last + 1) % 16:
            self.counter_jumps += 1
        self.last_counter[msg.arbitration_id] = counter
        name = HEALTH_IDS[msg.arbitration_id]
        self.frames[name].append(self.db.decode_message(name, data, decode_choices=False))
        return True


def wait_until(condition: Callable[[], bool], timeout_s: float) -> bool:
    """Poll ``condition`` every 20 ms until it holds or ``timeout_s`` passes (a loaded CI machine is slow)."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def run_daemon_thread(daemon: Daemon) -> tuple[threading.Thread, list[int]]:
    """Start ``daemon.run()`` in a thread; returns once the daemon has warmed up and made its first bus open."""
    result: list[int] = []
    thread = threading.Thread(target=lambda: result.append(daemon.run()), daemon=True)
    thread.start()
    # the warm-up compiles the estimators on an empty numba cache (seconds): the timed part starts after it
    assert wait_until(lambda: daemon.counters["bus_opens"] + daemon.counters["open_errors"] > 0, 120.0)
    return thread, result


def stop_daemon(daemon: Daemon, thread: threading.Thread, result: list[int]) -> None:
    daemon.stop()
    thread.join(timeout=10)
    assert not thread.is_alive(), "daemon did not stop within 10 s"
    assert result == [0]


def collect(bus: can.BusABC, reader: HealthReader, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        msg = bus.recv(0.05)
        if msg is not None:
            reader.take(msg)


# --- in process: bus faults and the keep-alive handler ------------------------------------------------


class FlakyBus(can.BusABC):
    """A virtual bus whose send and/or receive can be made to fail (can.CanOperationError)."""

    def __init__(self, channel: str, fail_send: Callable[[], bool], fail_recv: Callable[[], bool]) -> None:
        self.inner = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.fail_send = fail_send
        self.fail_recv = fail_recv
        self.channel_info = f"flaky {channel}"
        super().__init__(channel=channel)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.fail_send():
            raise can.CanOperationError("send failed (test)")
        self.inner.send(msg, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self.fail_recv():
            time.sleep(0.01)
            raise can.CanOperationError("receive failed (test)")
        return self.inner.recv(timeout), False

    def shutdown(self) -> None:
        self.inner.shutdown()
        super().shutdown()


def test_send_failures_are_counted_not_fatal(tmp_path: Path) -> None:
    channel = f"send-{uuid.uuid4().hex}"
    failing = threading.Event()
    failing.set()
    opened: list[FlakyBus] = []

    def open_bus() -> can.BusABC:
        opened.append(FlakyBus(channel, failing.is_set, lambda: False))
        return opened[-1]

    pipeline = service_pipeline(tmp_path, channel)
    daemon = Daemon(pipeline, open_bus, settings=DaemonSettings(backoff_initial_s=0.05, backoff_max_s=0.2))
    listener = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    thread, result = run_daemon_thread(daemon)
    try:
        # ~13 health frames/s, every send raising: 20 failures in a row reopen the bus, the daemon lives on
        assert wait_until(lambda: len(opened) >= 2, 15.0)
        assert thread.is_alive()
        assert daemon.counters["send_errors"] >= SEND_FAILURES_TO_REOPEN
        assert pipeline.counters["send_errors"] == daemon.counters["send_errors"]
        failing.clear()
        reader = HealthReader()
        collect(listener, reader, 2.5)
        assert len(reader.frames["Health_Status"]) >= 15
        diag = reader.frames["Health_Diag"]
        assert diag and diag[-1]["BusErrors"] == min(daemon.counters["bus_errors"], 255) > 0
    finally:
        stop_daemon(daemon, thread, result)
        listener.shutdown()


class RecordingStop(threading.Event):
    """The daemon's stop event, recording each wait the supervisor thread asks for (its backoff), s."""

    def __init__(self) -> None:
        super().__init__()
        self.supervisor: threading.Thread | None = None
        self.waits: list[float] = []

    def wait(self, timeout: float | None = None) -> bool:
        if threading.current_thread() is self.supervisor and timeout is not None:
            self.waits.append(timeout)
        return super().wait(timeout)


def test_receive_failure_reopens_the_bus_with_backoff(tmp_path: Path) -> None:
    channel = f"recv-{uuid.uuid4().hex}"
    opens: list[float] = []
    received = threading.Event()

    def open_bus() -> can.BusABC:
        opens.append(time.monotonic())
        if len(opens) in (2, 3):
            raise can.CanInitializationError("device gone (test)")  # the bus comes back on the 4th open
        if len(opens) == 1:  # the first bus fails its receive once frames have flowed
            return FlakyBus(channel, lambda: False, received.is_set)
        return FlakyBus(channel, lambda: False, lambda: False)

    pipeline = service_pipeline(tmp_path, channel)
    settings = DaemonSettings(backoff_initial_s=0.2, backoff_max_s=0.4)
    daemon = Daemon(pipeline, open_bus, settings=settings)
    stop = RecordingStop()
    daemon._stop = stop  # the backoff is read from the waits asked for, not from a loaded machine's clock
    listener = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    sender_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    thread, result = run_daemon_thread(daemon)
    stop.supervisor = thread
    try:
        with EcuSender(sender_bus):
            assert wait_until(lambda: daemon.counters["frames_in"] > 0, 30.0)
            received.set()
            assert wait_until(lambda: len(opens) >= 4, 30.0)
            before = daemon.counters["frames_in"]
            assert wait_until(lambda: daemon.counters["frames_in"] > before + 100, 30.0)  # frames flow again
            assert thread.is_alive()
            assert len(opens) == 4
            # first retry after 0.2 s, then doubled to the 0.4 s maximum and capped there (uncapped: 0.8 s);
            # between retries the supervisor keeps its period
            backoff = [w for w in stop.waits if w != settings.supervise_s]
            assert backoff == [0.2, 0.4, 0.4]
            assert daemon.counters["receive_errors"] == 1
            assert daemon.counters["open_errors"] == 2
            reader = HealthReader()
            collect(listener, reader, 1.5)
        status = reader.frames["Health_Status"]
        assert len(status) >= 10
        assert reader.frames["Health_Diag"][-1]["BusErrors"] >= 3
    finally:
        stop_daemon(daemon, thread, result)
        listener.shutdown()
        sender_bus.shutdown()


class BuggyRecvBus(FlakyBus):
    """A bus whose recv raises what python-can's contract does not name (a bug in an interface), once."""

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self.fail_recv():
            raise RuntimeError("a bug in the interface (test)")
        return super()._recv_internal(timeout)


def test_any_error_of_recv_is_a_receive_error_and_reopens_the_bus(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    channel = f"recv-bug-{uuid.uuid4().hex}"
    opened: list[can.BusABC] = []
    received = threading.Event()
    raised = threading.Event()

    def raise_once() -> bool:
        if received.is_set() and not raised.is_set():
            raised.set()
            return True
        return False

    def open_bus() -> can.BusABC:
        opened.append(BuggyRecvBus(channel, lambda: False, raise_once if not opened else lambda: False))
        return opened[-1]

    pipeline = service_pipeline(tmp_path, channel)
    daemon = Daemon(pipeline, open_bus, settings=DaemonSettings(backoff_initial_s=0.05, backoff_max_s=0.2))
    sender_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    thread, result = run_daemon_thread(daemon)
    try:
        with EcuSender(sender_bus):
            assert wait_until(lambda: daemon.counters["frames_in"] > 0, 30.0)
            received.set()
            assert wait_until(lambda: len(opened) >= 2, 30.0)  # handled as python-can's Notifier would: reopen
            before = daemon.counters["frames_in"]
            assert wait_until(lambda: daemon.counters["frames_in"] > before + 50, 30.0)  # frames flow again
        assert thread.is_alive()
        assert daemon.counters["receive_errors"] == 1
        assert daemon.counters["daemon_errors"] == 1
        logged = [r for r in caplog.records if "unexpected error in the receive path" in r.getMessage()]
        assert len(logged) == 1 and logged[0].exc_info
    finally:
        stop_daemon(daemon, thread, result)
        sender_bus.shutdown()


class StrayDatagramBus(FlakyBus):
    """A bus on which, now and then, a datagram arrives that is no CAN frame: python-can's udp_multicast
    raises CanOperationError("could not unpack received message") from the decoder's error."""

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self.fail_recv():
            try:
                raise ValueError("unpack(b) received extra data (test)")
            except ValueError as exc:
                raise can.CanOperationError("could not unpack received message") from exc
        return self.inner.recv(timeout), False


def test_a_datagram_that_is_no_can_frame_is_counted_and_the_bus_kept(tmp_path: Path) -> None:
    """Issue 31: one non-CAN datagram every few frames used to close and reopen the bus (~0.5 s each)."""
    channel = f"stray-{uuid.uuid4().hex}"
    every_tenth = itertools.cycle([False] * 9 + [True]).__next__
    opens = []
    bus = StrayDatagramBus(channel, lambda: False, every_tenth)
    daemon = Daemon(service_pipeline(tmp_path, channel), lambda: opens.append(bus) or bus)
    thread, result = run_daemon_thread(daemon)
    with can.Bus(interface="virtual", channel=channel, receive_own_messages=False) as sender_bus:
        try:
            with EcuSender(sender_bus):
                assert wait_until(lambda: daemon.counters["bad_datagrams"] >= 20, 30.0)
                assert wait_until(lambda: daemon.counters["frames_in"] > 200, 30.0)
            assert thread.is_alive()
            assert len(opens) == 1 and daemon.counters["receive_errors"] == 0
            assert daemon.counters["bus_errors"] == daemon.counters["bad_datagrams"]
        finally:
            stop_daemon(daemon, thread, result)


def test_error_in_the_frame_path_is_counted_and_the_daemon_lives(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    channel = f"keepalive-{uuid.uuid4().hex}"
    pipeline = service_pipeline(tmp_path, channel)
    real_feed = pipeline.feed
    calls = {"n": 0}

    def buggy_feed(msg: can.Message) -> None:
        calls["n"] += 1
        if calls["n"] % 10 == 0:
            raise RuntimeError("a bug in the pipeline (test)")
        real_feed(msg)

    pipeline.feed = buggy_feed  # type: ignore[method-assign]
    daemon = Daemon(pipeline, lambda: can.Bus(interface="virtual", channel=channel, receive_own_messages=False))
    sender_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    thread, result = run_daemon_thread(daemon)
    try:
        with EcuSender(sender_bus):
            assert wait_until(lambda: calls["n"] >= 200, 60.0)  # progress, not a time: 20 errors raised
        assert thread.is_alive()
        assert daemon.counters["daemon_errors"] == calls["n"] // 10 > 10
        assert pipeline.snapshot().state == "NOMINAL"  # the good frames kept the estimator running
        logged = [r for r in caplog.records if "unexpected error in the frame path" in r.getMessage()]
        assert [r.getMessage().split("occurrence ")[1].split()[0] for r in logged] == ["1", "10"]
        assert all(r.exc_info for r in logged)  # with the traceback
    finally:
        stop_daemon(daemon, thread, result)
        sender_bus.shutdown()


def test_a_silent_bus_is_warned_once_per_silence(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A virtual bus with no sender (the README pair before multicast.yaml): one warning naming the
    virtual interface's limit; frames coming back re-arm it; the next silence is warned once more.
    The daemon's clock is the test's: a silence is a jump of that clock, not a sleep."""
    channel = f"silent-{uuid.uuid4().hex}"
    offset = [0.0]
    # far beyond any real delay of a loaded machine: only the clock jumps reach it; each jump (limit_s / 2 and
    # more) is longer than the pipeline's MAX_CLOCK_GAP_S, so it restarts the schedule rather than run every step
    # of the jump under the lock (500 s were 25,000 steps: more than the 30 s wait on a machine at load 25)
    limit_s = 1400.0
    assert limit_s / 2 > MAX_CLOCK_GAP_S

    def clock() -> float:
        return time.monotonic() + offset[0]

    pipeline = service_pipeline(tmp_path, channel)
    open_bus = lambda: can.Bus(interface="virtual", channel=channel, receive_own_messages=False)  # noqa: E731
    daemon = Daemon(pipeline, open_bus, settings=DaemonSettings(no_frames_warning_s=limit_s), clock=clock)
    sender_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)

    def warnings() -> list[str]:
        return [r.getMessage() for r in caplog.records if r.getMessage().startswith("no frames on")]

    stop = RecordingStop()
    daemon._stop = stop  # its waits count the supervisor's passes
    thread, result = run_daemon_thread(daemon)
    stop.supervisor = thread
    try:
        with caplog.at_level("INFO", logger="ecu_monitor.runtime.daemon"):
            # the supervisor's first wait comes after run() started the silence at the first open
            # (bus_opens, which run_daemon_thread waits for, is counted just before): no race with it
            assert wait_until(lambda: len(stop.waits) > 0, 30.0)
            offset[0] += limit_s / 2  # half the limit: real time (a loaded machine) cannot make up the rest
            polls = len(stop.waits)
            assert wait_until(lambda: len(stop.waits) > polls + 3, 30.0)  # the supervisor looked
            assert warnings() == []
            offset[0] += limit_s / 2  # now at the limit, whatever real time has passed
            assert wait_until(lambda: daemon.counters["silence_warnings"] == 1, 30.0)
            first = warnings()
            assert len(first) == 1 and "virtual interface" in first[0] and "multicast.yaml" in first[0]
            offset[0] += 3 * limit_s  # the same silence goes on: no second warning
            polls = len(stop.waits)
            assert wait_until(lambda: len(stop.waits) > polls + 3, 30.0)
            assert daemon.counters["silence_warnings"] == 1
            with EcuSender(sender_bus):
                assert wait_until(
                    lambda: any("frames again" in r.getMessage() for r in caplog.records), 30.0
                )  # frames resumed: re-armed
            offset[0] += limit_s + 1.0
            assert wait_until(lambda: daemon.counters["silence_warnings"] == 2, 30.0)
            assert len(warnings()) == 2
    finally:
        stop_daemon(daemon, thread, result)
        sender_bus.shutdown()


class _ScriptedBus:
    """A bus for the receive loop on the test's clock: ``recv(timeout)`` records (time, timeout), then moves the
    clock on (to the next frame's time, or by the timeout; by 20 us for a poll, timeout 0) and hands over the
    frame once its time has come; the loop is stopped after the last frame and one more recv."""

    def __init__(self, now: list[float], frames: list[tuple[float, can.Message]], stop: threading.Event) -> None:
        self.now, self.frames, self.stop, self.calls = now, list(frames), stop, []

    def recv(self, timeout: float) -> can.Message | None:
        self.calls.append((self.now[0], timeout))
        if not self.frames:
            self.stop.set()
            return None
        due, msg = self.frames[0]
        self.now[0] = min(due, self.now[0] + (timeout if timeout > 0 else 20e-6))
        if self.now[0] >= due:
            self.frames.pop(0)
            return msg
        return None


# --- sd_notify pieces ----------------------------------------------------------------------------------


def test_watchdog_pings_only_while_progress_grows() -> None:
    gate = WatchdogGate(period_s=1.0)
    assert gate.due(0.0, progress=10)
    assert not gate.due(0.5, progress=20)  # too early
    assert gate.due(1.0, progress=20)
    assert not gate.due(2.0, progress=20)  # no progress since the last ping: no ping, however long
    assert not gate.due(9.0, progress=20)
    assert gate.due(9.1, progress=21)
    assert not WatchdogGate(period_s=None).due(100.0, progress=1)


def test_watchdog_period_from_the_environment() -> None:
    assert watchdog_period_s({"WATCHDOG_USEC": "10000000"}) == 5.0
    assert watchdog_period_s({"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": str(os.getpid())}) == 5.0
    assert watchdog_period_s({"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": "1"}) is None  # another process's
    assert watchdog_period_s({"WATCHDOG_USEC": "soon"}) is None
    assert watchdog_period_s({}) is None


def test_notifier_path_socket_and_no_socket(tmp_path: Path) -> None:
    path = tmp_path / "notify"
    receiver = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    receiver.bind(str(path))
    receiver.settimeout(1.0)
    try:
        with SystemdNotifier(address=str(path)) as notifier:
            assert notifier.ready(status="up  and\nrunning")
            assert receiver.recv(4096) == b"READY=1\nSTATUS=up and running"
            for _ in range(50):  # nobody reads: the queue fills, sends fail and are counted, never block
                notifier.watchdog()
            assert notifier.send_errors > 0
        with SystemdNotifier(address="") as silent:
            assert not silent.enabled
            assert not silent.ready()
    finally:
        receiver.close()


# --- separate process: sd_notify, watchdog, SIGTERM ---------------------------------------------------


@pytest.fixture
def notify_socket() -> Iterator[tuple[socket.socket, str]]:
    """A unix datagram socket in the abstract namespace, as systemd binds it; yields (socket, NOTIFY_SOCKET)."""
    name = f"@ecu-monitor-test-{uuid.uuid4().hex}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(b"\0" + name[1:].encode())
    sock.settimeout(0.2)
    try:
        yield sock, name
    finally:
        sock.close()


def read_notifications(sock: socket.socket, until: Callable[[list[str]], bool], timeout_s: float) -> list[str]:
    messages: list[str] = []
    end = time.monotonic() + timeout_s
    while time.monotonic() < end and not until(messages):
        try:
            messages.append(sock.recv(4096).decode())
        except TimeoutError:
            continue
    return messages


def kill(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.wait(timeout=10)


@pytest.mark.process
def test_ready_watchdog_and_sigterm(tmp_path: Path, notify_socket: tuple[socket.socket, str]) -> None:
    sock, name = notify_socket
    config = write_config(tmp_path, {"interface": "virtual", "channel": "idle"})
    env = {**os.environ, "NOTIFY_SOCKET": name, "WATCHDOG_USEC": "400000", "PYTHONUNBUFFERED": "1"}
    env.pop("WATCHDOG_PID", None)
    proc = subprocess.Popen(
        [sys.executable, "-m", "ecu_monitor.cli", "run", "--config", str(config)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        # READY comes after the start-up (imports, the compiled step loaded or compiled): allow a loaded machine
        messages = read_notifications(sock, lambda m: sum("WATCHDOG=1" in x for x in m) >= 5, timeout_s=120)
        ready = [m for m in messages if "READY=1" in m]
        assert ready, f"no READY=1 in {messages}"
        assert any(line.startswith("STATUS=running") for line in ready[0].splitlines())
        pings = [i for i, m in enumerate(messages) if m == "WATCHDOG=1"]
        assert len(pings) >= 5 and pings[0] > messages.index(ready[0])
        proc.send_signal(signal.SIGTERM)
        stopping = read_notifications(sock, lambda m: any("STOPPING=1" in x for x in m), timeout_s=30)
        assert any("STOPPING=1" in m for m in stopping)
        _, stderr = proc.communicate(timeout=15)
    finally:
        kill(proc)
    assert proc.returncode == 0, stderr
    assert "signal SIGTERM: stopping" in stderr
    assert "Traceback" not in stderr
    conn = sqlite3.connect(tmp_path / "state" / DATABASE_NAME)
    try:
        assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        assert conn.execute("SELECT serial FROM engines").fetchall() == [("UAV-ENG-0001",)]
    finally:
        conn.close()


def _bad_configs(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    """Config files with one mistake each -> (path, a word the one-line error must contain)."""
    bus = {"interface": "virtual", "channel": "bad"}
    cases: dict[str, tuple[Path, str]] = {}
    cases["missing file"] = (tmp_path / "nope.yaml", "no such config file")
    bad_yaml = tmp_path / "bad_yaml.yaml"
    bad_yaml.write_text("engine: {serial: [unclosed\n")
    cases["not yaml"] = (bad_yaml, "not valid YAML")
    cases["unknown top key"] = (write_config(tmp_path, bus, "k.yaml", colour="red"), "colour")
    cases["unknown interface"] = (write_config(tmp_path, {"interface": "nocan", "channel": "x"}, "i.yaml"), "nocan")
    cases["missing channel"] = (write_config(tmp_path, {"interface": "virtual"}, "c.yaml"), "bus.channel")
    inputs = yaml.safe_load((REPO / "ecu_monitor" / "data" / "configs" / "example.yaml").read_text())["inputs"]
    wrong_signal = {**inputs, "rpm": {"signal": "ECU_Fast.Nope", "unit": "rpm", "stale_after_s": 0.5}}
    cases["unknown signal"] = (write_config(tmp_path, bus, "s.yaml", inputs=wrong_signal), "Nope")
    wrong_unit = {**inputs, "oat_c": {"signal": "ECU_Slow.OAT", "unit": "furlong", "stale_after_s": 2}}
    cases["bad unit"] = (write_config(tmp_path, bus, "u.yaml", inputs=wrong_unit), "inputs.oat_c.unit")
    no_cht = {k: v for k, v in inputs.items() if k != "cht_c"}
    cases["missing input"] = (write_config(tmp_path, bus, "m.yaml", inputs=no_cht), "cht_c")
    cases["bad rate"] = (
        write_config(tmp_path, bus, "r.yaml", health={"Health_Status": {"rate_hz": 7}}),
        "Health_Status.rate_hz",
    )
    cases["missing model file"] = (write_config(tmp_path, bus, "mm.yaml", model="missing.yaml"), "model")
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    cases["unusable state_dir"] = (write_config(tmp_path, bus, "sd.yaml", state_dir=str(blocker / "db")), "state_dir")
    cases["udp bad group"] = (
        write_config(tmp_path, {"interface": "udp_multicast", "channel": "not-an-address"}, "g.yaml"),
        "bus",
    )
    return cases


BAD_CONFIGS = (
    "missing file",
    "not yaml",
    "unknown top key",
    "unknown interface",
    "missing channel",
    "unknown signal",
    "bad unit",
    "missing input",
    "bad rate",
    "missing model file",
    "unusable state_dir",
    "udp bad group",
)


@pytest.mark.process
@pytest.mark.parametrize("label", BAD_CONFIGS)
def test_every_config_error_exits_2_with_one_line(tmp_path: Path, label: str) -> None:
    path, word = _bad_configs(tmp_path)[label]
    proc = subprocess.run(
        [sys.executable, "-m", "ecu_monitor.cli", "run", "--config", str(path)],
        capture_output=True,
        text=True,
        timeout=25,
    )
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("ecu-monitor: error: ")
    assert word in lines[0]


WARM_UP_SCRIPT = """
import sys, threading
import can
sys.path.insert(0, sys.argv[1])
from tests.helpers.service import service_pipeline
from ecu_monitor.pipeline import step
from ecu_monitor.runtime.daemon import Daemon
from pathlib import Path

def compiled():
    functions = step.compiled()
    return len(functions.replay_loop.signatures)

pipeline = service_pipeline(Path(sys.argv[2]), "warm-up")
seen = []
def open_bus():
    seen.append(compiled())
    daemon.stop()
    return can.Bus(interface="virtual", channel="warm-up")
before = compiled()
daemon = Daemon(pipeline, open_bus)
daemon.run()
print(before, seen[0], pipeline.steps_done, pipeline.counters["frames"])
"""


@pytest.mark.process
def test_daemon_loads_the_estimator_before_it_opens_the_bus(tmp_path: Path) -> None:
    """A new process has none of the step's compiled code in memory: the daemon must load it (from numba's
    disk cache, or compile it on a fresh install: tests/cli/test_compile_cache.py) before frames flow.
    The suite's own cache, so the step is not compiled once more for this test."""
    result = subprocess.run(
        [sys.executable, "-c", WARM_UP_SCRIPT, str(REPO), str(tmp_path)],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("0 1 "), result.stdout  # nothing loaded, then the step at the open
    assert result.stdout.split()[-2:] == ["0", "0"]  # the warm-up left the pipeline's own state alone
