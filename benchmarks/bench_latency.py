"""Live latency: ECU frame -> the health frame it causes, p50/p99, with 4,000 frames/s of other traffic.

    .venv/bin/python benchmarks/bench_latency.py [--seconds 30] [--traffic 4000] [--pace-study] [--gc-study]
        [--switch-interval MS]
    sudo .venv/bin/python benchmarks/bench_latency.py --netns [--seconds 30] [--nice -10]   # across processes

In one process (default), on python-can's ``virtual`` interface (three bus objects on one channel):

* an ECU thread sends ECU_Fast at 50 Hz and ECU_Slow/AirData at 10 Hz (valid counters and CRC),
  recording ``perf_counter()`` just before each send;
* a traffic thread sends ``--traffic`` frames/s of other ids (0x400-0x7FF, random payloads), in bursts
  every 2.5 ms;
* the daemon under test (:class:`~ecu_monitor.runtime.daemon.Daemon` with the real Pipeline from
  the shipped example.yaml) runs with its 20 ms tick switched off (``tick_s`` = 1 h), so every health frame
  is emitted inside the Notifier callback of the ECU frame that made its step fall due: the health
  frame's latency is measured from that frame's send (the latest ECU send before it);
* a receiver thread stamps each health frame with ``perf_counter()`` on ``recv``.

Baseline in the same run, same traffic: a bare Notifier listener that answers every ECU_Fast frame
with one frame (no pipeline): the virtual-bus round trip the daemon cannot beat. "No frame lost":
every ECU frame sent is counted in by the daemon and every health frame sent is received.

CPU, % of one core: utime + stime of the daemon's threads (its Notifier thread, the tick and the
supervisor) or of the echo's Notifier thread, over the measured seconds (/proc/self/task/<tid>/stat).
The targets of issue 13 are checked at the end of each report: in one process p99 < 1 ms and at most
2.5x the echo's p99; across processes p99 within 1.5x of the echo process's; daemon CPU < 3 %.

``--step-cpu``: the pipeline alone, the CPU time of the steps that send health frames: back to back, one
frame per 20 ms, and one per 20 ms with ``Pipeline.rehearse`` 0.6 ms before (docs/performance.md).
``--step-bytecodes``: the Python bytecodes those steps execute, and the functions that execute most.

``--pace-study``: the pipeline alone (no bus, no thread) on the same frames back to back, one frame
per 20 ms asleep or spinning on the clock in between, one per 1 ms, and with garbage collection off:
what makes a paced step cost more (docs/performance.md).

``--netns``: the same measurement across processes on python-can's udp_multicast interface inside a
network namespace made for the run (loopback only, multicast routed to lo, deleted at the end): the
daemon (or the echo baseline) is one process, the other traffic another, and the measuring process
(ECU sender + health receiver, one clock) a third. Every process on the group receives every frame, so
the daemon's receive thread unpacks all 4,000 frames/s before its id filter drops them (on socketcan
the kernel would filter them). The CPU figure there is the whole daemon (or echo) process
(/proc/<pid>/stat). The report also splits the daemon's slowest health frames (:func:`tail_anatomy`: send ->
the daemon's feed, its step, -> the receiver). Needs root.
"""

from __future__ import annotations

import argparse
import bisect
import gc
import json
import math
import os
import random
import signal
import statistics
import subprocess
import sys
import textwrap
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import can
import yaml
from netns import kill_all, multicast_namespace

from ecu_monitor.bus.codec import Encoder
from ecu_monitor.config import parse_config
from ecu_monitor.runtime.daemon import Daemon, DaemonSettings
from ecu_monitor.runtime.publishers import LiveMonitor as Pipeline

REPO = Path(__file__).resolve().parent.parent
HEALTH_IDS = (0x300, 0x301, 0x302)
ECU_FAST_ID = 0x100
ECU_VALUES = {
    "ECU_Fast": {"EngineSpeed": 5500.0, "ThrottlePos": 60.0, "FuelFlow": 0.6},
    "ECU_Slow": {"CHT": 160.0, "OAT": 15.0, "EcuStatus": 0},
    "AirData": {"PressureAltitude": 1500.0, "CalibratedAirspeed": 23.0, "VerticalSpeed": 0.0},
}


def _config(channel: str) -> Any:
    data = yaml.safe_load((REPO / "ecu_monitor" / "data" / "configs" / "example.yaml").read_text())
    data["dbc"] = [str(REPO / "ecu_monitor" / "data" / "dbc" / "engine.dbc")]
    data["health_dbc"] = str(REPO / "ecu_monitor" / "data" / "dbc" / "health.dbc")
    data["bus"] = {"interface": "virtual", "channel": channel, "receive_own_messages": False}
    data["state_dir"] = "/tmp/ecu-monitor-bench-unused"
    return parse_config(data, REPO / "ecu_monitor" / "data" / "configs" / "bench.yaml")


class Periodic(threading.Thread):
    """Runs ``step(k)`` every ``period_s`` on an absolute schedule until stopped."""

    def __init__(self, period_s: float, step: Callable[[int], None]) -> None:
        super().__init__(daemon=True)
        self.period_s = period_s
        self.step = step
        self.stop_event = threading.Event()

    def run(self) -> None:
        k = 0
        next_s = time.perf_counter()
        while not self.stop_event.is_set():
            self.step(k)
            k += 1
            next_s += self.period_s
            delay = next_s - time.perf_counter()
            if delay > 0:
                time.sleep(delay)


def _ecu_sender(bus: can.BusABC, sent_at: list[float], counts: dict[str, int]) -> Callable[[int], None]:
    encoder = Encoder([REPO / "ecu_monitor" / "data" / "dbc" / "engine.dbc"])
    counters = dict.fromkeys(ECU_VALUES, 0)
    ids = {name: encoder.message(name).frame_id for name in ECU_VALUES}

    def step(k: int) -> None:
        for name in ("ECU_Fast", "ECU_Slow", "AirData") if k % 5 == 0 else ("ECU_Fast",):
            data = encoder.encode(name, ECU_VALUES[name], counters[name])
            counters[name] += 1
            msg = can.Message(arbitration_id=ids[name], is_extended_id=False, data=data)
            if name == "ECU_Fast":  # first of its burst: the frame whose callback runs the step that falls due
                sent_at.append(time.perf_counter())
            bus.send(msg)
            counts["ecu"] += 1

    return step


def _traffic_sender(bus: can.BusABC, per_burst: int, counts: dict[str, int], seed: int) -> Callable[[int], None]:
    rng = random.Random(seed)
    frames = [
        can.Message(arbitration_id=rng.randrange(0x400, 0x800), is_extended_id=False, data=rng.randbytes(8))
        for _ in range(1000)
    ]

    def step(k: int) -> None:
        for i in range(per_burst):
            bus.send(frames[(k * per_burst + i) % len(frames)])
        counts["traffic"] += per_burst

    return step


def _receiver(bus: can.BusABC, stop: threading.Event, got: list[tuple[float, int]]) -> threading.Thread:
    def loop() -> None:
        while not stop.is_set():
            msg = bus.recv(0.05)
            if msg is not None and msg.arbitration_id in HEALTH_IDS:
                got.append((time.perf_counter(), msg.arbitration_id))

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    return thread


def thread_cpu_s(native_ids: list[int]) -> float:
    """utime + stime of threads of this process, s (fields 14 and 15 of /proc/self/task/<tid>/stat)."""
    total = 0
    for tid in native_ids:
        try:
            stat = Path(f"/proc/self/task/{tid}/stat").read_text()
        except FileNotFoundError:  # the thread has ended
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        total += int(fields[11]) + int(fields[12])
    return total / os.sysconf("SC_CLK_TCK")


def process_cpu_s(pid: int) -> float:
    """utime + stime of a whole process, s (fields 14 and 15 of /proc/<pid>/stat)."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    fields = stat[stat.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _notifier_threads(notifier: can.Notifier | None) -> list[int]:
    readers = getattr(notifier, "_readers", []) if notifier is not None else []
    return [r.native_id for r in readers if isinstance(r, threading.Thread) and r.native_id is not None]


def _percentiles(values_us: list[float]) -> tuple[float, float, float]:
    ordered = sorted(values_us)
    q = statistics.quantiles(ordered, n=100, method="inclusive")
    return q[49], q[98], ordered[-1]


def _stats(name: str, sent_at: list[float], got: list[tuple[float, int]], since: float = -math.inf) -> dict[str, Any]:
    """Latencies of the frames received from ``since`` on (perf_counter, s): the first second is the start-up."""
    latencies_us = []
    by_id: dict[int, list[float]] = {}
    for received, frame_id in got:
        if received < since:
            continue
        index = bisect.bisect_left(sent_at, received) - 1
        if index >= 0:
            latencies_us.append((received - sent_at[index]) * 1e6)
            by_id.setdefault(frame_id, []).append(latencies_us[-1])
    p50, p99, worst = _percentiles(latencies_us)
    per_frame = {
        f"0x{frame_id:X}": {
            "samples": len(values),
            **dict(zip(("p50_us", "p99_us", "max_us"), _percentiles(values), strict=True)),
        }
        for frame_id, values in sorted(by_id.items())
        if len(values) > 1
    }
    return {
        "case": name, "p50_us": p50, "p99_us": p99, "max_us": worst, "samples": len(latencies_us),
        "per_frame": per_frame, "latencies_us": latencies_us,
    }  # fmt: skip


def p99_ratio_interval(
    daemon_us: list[float], echo_us: list[float], level: float = 0.9, draws: int = 2000
) -> tuple[float, float]:
    """Bootstrap interval (``level``, percentile method) of the ratio p99(daemon) / p99(echo): each side's
    latencies (us) resampled with replacement, independently. The p99 of a 30 s run rests on its 3-4
    slowest health frames, so one run's ratio alone says little; the interval says how much."""
    import numpy as np

    rng = np.random.default_rng(0)
    daemon, echo = np.asarray(daemon_us), np.asarray(echo_us)
    ratios = np.percentile(rng.choice(daemon, (draws, daemon.size)), 99, axis=1) / np.percentile(
        rng.choice(echo, (draws, echo.size)), 99, axis=1
    )
    low, high = np.percentile(ratios, [50 * (1 - level), 50 * (1 + level)])
    return float(low), float(high)


class GcPauses:
    """Longest pause and count of the cyclic collector's runs per generation (gc.callbacks)."""

    def __init__(self) -> None:
        self.pauses: dict[int, list[float]] = {0: [], 1: [], 2: []}
        self._start = 0.0

    def __call__(self, phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            self._start = time.perf_counter()
        else:
            self.pauses[info["generation"]].append((time.perf_counter() - self._start) * 1e3)

    def summary(self) -> str:
        return ", ".join(
            f"gen{g} {len(p)} runs, longest {max(p):.1f} ms" if p else f"gen{g} 0 runs" for g, p in self.pauses.items()
        )


class PhaseTimedDaemon(Daemon):
    """The daemon with its frame callback timed by phase, for the frames whose step emits health frames."""

    phases: list[tuple[float, float, float]]
    #: per ECU_Fast callback: perf_counter at entry, after the lock, feed, advance_to and send, the
    #: thread's CPU time in the callback (s), the ids of the frames sent
    timeline: list[tuple[float, float, float, float, float, float, tuple[int, ...]]]
    emitted: list[int]  # per health frame sent, in order: the index of its ECU_Fast callback in timeline
    events: list[tuple[float, float, str]]  # (start, end, what) of the supervisor's periods

    def _on_frame(self, msg: can.Message) -> None:  # same steps as Daemon._on_frame, with clocks between
        entered, cpu = time.perf_counter(), time.thread_time()
        now = self._clock()
        msg.timestamp = now
        with self._lock:
            self.counters["frames_in"] += 1
            self._silence.frame(now)  # as Daemon._on_frame (without it: "no frames for 10 s" warnings mid-run)
            started = time.perf_counter()
            self.pipeline.feed(msg)
            fed = time.perf_counter()
            frames = self.pipeline.advance_to(now)
            advanced = time.perf_counter()
            self._send_locked(frames)
            sent = time.perf_counter()
            schedule = getattr(self, "_schedule_rehearsal", None)  # older checkouts: no rehearsal
            if schedule is not None:
                schedule(now)
        if frames:
            self.phases.append(((fed - started) * 1e6, (advanced - fed) * 1e6, (sent - advanced) * 1e6))
        if msg.arbitration_id == ECU_FAST_ID:
            ids = tuple(f.arbitration_id for f in frames)
            self.timeline.append((entered, started, fed, advanced, sent, time.thread_time() - cpu, ids))
            self.emitted.extend([len(self.timeline) - 1] * len(frames))

    def _supervise_once(self, now: float) -> None:
        started = time.perf_counter()
        super()._supervise_once(now)
        self.events.append((started, time.perf_counter(), "supervisor period"))

    def phase_summary(self) -> str:
        parts = []
        for index, name in enumerate(("feed", "advance_to", "send")):
            values = sorted(p[index] for p in self.phases)
            parts.append(f"{name} p50 {values[len(values) // 2]:.0f} us")
        return ", ".join(parts)


#: Seconds after the ECU starts sending before latencies count: the daemon's first frame runs the steps
#: missed since it started (its tick is off here), a start-up transient, not the steady state.
SETTLE_S = 1.0


def run_case(
    name: str,
    seconds: float,
    traffic_hz: float,
    with_pipeline: bool,
    freeze_heap: bool = True,
    switch_interval_s: float | None = None,
) -> dict[str, Any]:
    """One measurement: the daemon (with_pipeline) or the bare echo listener under the same traffic.

    ``switch_interval_s``: the daemon's setting (DaemonSettings); the echo case runs with the process
    switched to the same interval, so both share one GIL regime (None: the interpreter's default)."""
    channel = f"bench-{uuid.uuid4().hex}"
    # one sending bus for the ECU and the traffic threads: a virtual bus queues every frame the others
    # send, so a second never-read bus would pile up 4,000 frames/s on this process's heap
    ecu_bus = traffic_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    rx_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    rx_bus.set_filters([{"can_id": i, "can_mask": 0x7FF} for i in HEALTH_IDS])
    sent_at: list[float] = []
    got: list[tuple[float, int]] = []
    counts = {"ecu": 0, "traffic": 0}
    stop_rx = threading.Event()
    receiver = _receiver(rx_bus, stop_rx, got)
    daemon: Daemon | None = None
    echo_notifier: can.Notifier | None = None
    echo_bus: can.BusABC | None = None
    echo_sent = [0]
    echo_in = [0]
    if with_pipeline:
        config = _config(channel)
        pipeline = Pipeline(config, config.load_params())
        daemon = PhaseTimedDaemon(
            pipeline,
            lambda: can.Bus(interface="virtual", channel=channel, receive_own_messages=False),
            settings=DaemonSettings(
                tick_s=3600.0,
                freeze_heap=freeze_heap,
                # only when asked: this script also measures older checkouts, whose daemon has no such setting
                **({"switch_interval_s": switch_interval_s} if switch_interval_s is not None else {}),
                **DAEMON_OPTIONS,
            ),
            receive_ids=pipeline.decoder.frame_ids,
        )
        daemon.phases, daemon.timeline, daemon.emitted, daemon.events = [], [], [], []
        daemon_thread = threading.Thread(target=daemon.run, daemon=True)
        daemon_thread.start()
        deadline = time.monotonic() + 120.0
        while daemon._tick_thread is None and time.monotonic() < deadline:  # warmed up, heap frozen: running
            time.sleep(0.05)
        time.sleep(0.5)  # past the daemon's start-up collection
        tick, receive = daemon._tick_thread, daemon._receiver
        threads = [t.native_id for t in (daemon_thread, tick, receive) if t is not None and t.native_id is not None]
    else:
        default_interval = sys.getswitchinterval()
        if switch_interval_s is not None:
            sys.setswitchinterval(switch_interval_s)
        echo_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        echo_bus.set_filters([{"can_id": i, "can_mask": 0x7FF} for i in (0x100, 0x101, 0x200)])
        reply = can.Message(arbitration_id=0x300, is_extended_id=False, data=bytes(8))

        def echo(msg: can.Message) -> None:
            echo_in[0] += 1
            if msg.arbitration_id == 0x100:
                echo_bus.send(reply)
                echo_sent[0] += 1

        echo_notifier = can.Notifier(echo_bus, [echo], timeout=0.2)
        threads = _notifier_threads(echo_notifier)
    time.sleep(0.5)
    gc_pauses = GcPauses()
    gc.callbacks.append(gc_pauses)
    per_burst = round(traffic_hz * 0.0025)  # 0: no other traffic
    traffic = Periodic(0.0025, _traffic_sender(traffic_bus, per_burst, counts, seed=4000))
    ecu = Periodic(0.02, _ecu_sender(ecu_bus, sent_at, counts))
    traffic.start()
    ecu.start()
    settled = time.perf_counter() + SETTLE_S
    cpu_before, wall_before = thread_cpu_s(threads), time.monotonic()
    time.sleep(seconds)
    cpu_pct = 100.0 * (thread_cpu_s(threads) - cpu_before) / (time.monotonic() - wall_before)
    ecu.stop_event.set()
    ecu.join()
    traffic.stop_event.set()
    traffic.join()
    time.sleep(0.5)
    gc.callbacks.remove(gc_pauses)
    stop_rx.set()
    receiver.join()
    if daemon is not None:
        daemon.stop()
        daemon_thread.join(timeout=10)
        frames_in, health_sent = daemon.counters["frames_in"], daemon.counters["health_sent"]
        rehearsals = daemon.counters.get("rehearsals", 0)
    else:
        assert echo_notifier is not None and echo_bus is not None
        echo_notifier.stop()
        echo_bus.shutdown()
        sys.setswitchinterval(default_interval)
        frames_in, health_sent = echo_in[0], echo_sent[0]
    for bus in (ecu_bus, rx_bus):
        bus.shutdown()
    return {
        **_stats(name, sent_at, got, since=settled),
        "ecu_sent": counts["ecu"],
        "ecu_in": frames_in,
        "out_sent": health_sent,
        "out_received": len(got),
        "traffic_hz": counts["traffic"] / seconds,
        "cpu_pct": cpu_pct,
        **({"rehearsals": rehearsals} if daemon is not None else {}),
        "gc": gc_pauses.summary(),
        "phases": daemon.phase_summary() if isinstance(daemon, PhaseTimedDaemon) else "",
        "anatomy": anatomy(daemon, sent_at, got, settled) if isinstance(daemon, PhaseTimedDaemon) else "",
    }


def anatomy(daemon: PhaseTimedDaemon, sent_at: list[float], got: list[tuple[float, int]], since: float) -> str:
    """What each health frame's latency is made of, exactly (each frame matched to the ECU_Fast callback that
    sent it; the virtual bus keeps order and loses nothing): send -> callback entry (the Notifier thread's
    wake-up, the GIL, the frames queued before it), the callback's phases and its thread CPU time (wall
    minus CPU: time the thread waited), callback end -> recv (the receiver's wake-up and GIL). The slowest
    1 % are listed with the step's frames and the supervisor periods and collections overlapping them."""
    if len(got) != len(daemon.emitted):
        return f"anatomy skipped: {len(got)} health frames received, {len(daemon.emitted)} sent"
    rows = []
    for (received, frame_id), index in zip(got, daemon.emitted, strict=True):
        entered, started, fed, advanced, sent, cpu_s, ids = daemon.timeline[index]
        if received < since:
            continue
        ecu_sent = sent_at[index]
        rows.append({
            "latency": received - ecu_sent, "to callback": entered - ecu_sent, "feed": fed - started,
            "advance_to": advanced - fed, "send": sent - advanced, "callback CPU": cpu_s, "to recv": received - sent,
            "id": frame_id, "ids": ids, "from": ecu_sent, "until": received,
        })  # fmt: skip
    lines = ["| part (us) | p50 | p99 |", "|---|---|---|"]
    for key in ("latency", "to callback", "feed", "advance_to", "send", "callback CPU", "to recv"):
        values = sorted(row[key] * 1e6 for row in rows)
        lines.append(f"| {key} | {values[len(values) // 2]:.0f} | {values[int(0.99 * (len(values) - 1))]:.0f} |")
    lines.append("\nslowest 1 % (us): latency = to callback + callback (feed, advance_to, send; its CPU) + to recv")
    for row in sorted(rows, key=lambda r: -r["latency"])[: max(3, len(rows) // 100)]:
        overlapping = [what for start, end, what in daemon.events if end > row["from"] and start < row["until"]]
        lines.append(
            f"- {row['latency'] * 1e6:.0f} = {row['to callback'] * 1e6:.0f} + ({row['feed'] * 1e6:.0f}, "
            f"{row['advance_to'] * 1e6:.0f}, {row['send'] * 1e6:.0f}; CPU {row['callback CPU'] * 1e6:.0f}) + "
            f"{row['to recv'] * 1e6:.0f}: frame 0x{row['id']:X} of a step sending "
            f"{', '.join(f'0x{i:X}' for i in row['ids'])}, {row['from'] - sent_at[0]:.2f} s after the first ECU frame;"
            f" overlapping: {', '.join(overlapping) or 'nothing'}"
        )
    return "\n".join(lines)


def pace_study(steps: int = 600) -> None:
    """Why a paced step costs more than a back-to-back one: the same frames and steps, waits between them."""
    print("| pipeline alone, feed + advance_to of a frame whose step emits health frames | p50 | p99 |")
    print("|---|---|---|")
    for name, kwargs in (
        ("back to back", {}),
        ("one frame per 20 ms, asleep in between", {"pace_s": 0.02}),
        ("one frame per 20 ms, spinning on the clock in between", {"pace_s": 0.02, "spin": True}),
        ("one frame per 1 ms, asleep in between", {"pace_s": 0.001}),
        ("one frame per 20 ms, asleep, garbage collection off", {"pace_s": 0.02, "gc_off": True}),
        ("back to back again", {}),
    ):
        p50, p99 = pipeline_cost(steps=steps if kwargs else 3000, **kwargs)  # type: ignore[arg-type]
        print(f"| {name} | {p50:.0f} us | {p99:.0f} us |", flush=True)
    print()


def dispatch_study(calls: int = 300, pace_s: float = 0.02) -> None:
    """What entering a compiled (numba) function costs, by argument list, warm and one call per 20 ms asleep
    (cold, as live): functions whose body is one store, called with the live filter call's arguments as they
    were (five arrays, 18 scalars and the model's Coefficients namedtuple, which numba types in Python at every
    call), as they were next (the coefficients as four arrays: ``ecu_monitor.model.pack_coefficients``), with
    three arrays, and with one array through the dispatcher or through the compiled entry point of its one
    signature (``service/live_call.py``'s workspace)."""
    import numba
    import numpy as np

    from ecu_monitor.model import coefficients, pack_coefficients, scalar_coefficients

    config = _config("unused")
    coeffs = scalar_coefficients(coefficients(config.load_params()))
    packed = pack_coefficients(coeffs)

    @numba.njit
    def with_namedtuple(s, d, i, r, o, a1, a2, a3, a4, a5, a6, z, m, co, dt, q, rr, a, b, c, tau, ud, rc, st):  # type: ignore[no-untyped-def]
        o[0] = s[0] + co.c_w

    @numba.njit
    def with_packed(s, d, i, r, o, a1, a2, a3, a4, a5, a6, z, m, cs, hv, xb, yb, dt, q, rr, a, b, c, tau, ud, rc, st):  # type: ignore[no-untyped-def]
        o[0] = s[0] + cs[0]

    @numba.njit
    def three_arrays(s, d, i):  # type: ignore[no-untyped-def]
        s[0] = d[0] + i[0]

    @numba.njit
    def one_array(w):  # type: ignore[no-untyped-def]
        w[0] = w[1] + 1.0

    s, d, i, r, o = np.zeros(7), np.zeros(5), np.zeros((6, 1)), np.zeros((4, 1)), np.zeros(3)
    scalars = (0.02, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, True, 0, 5)
    cases = {
        "5 arrays, 18 scalars, Coefficients namedtuple (before)": (
            with_namedtuple,
            (s, d, i, r, o, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 1.0, True, coeffs, *scalars),
        ),
        "5 arrays, 18 scalars, coefficients as 4 arrays (next)": (
            with_packed,
            (s, d, i, r, o, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 1.0, True, *packed, *scalars),
        ),
        "3 arrays": (three_arrays, (s, d, d)),
        "1 array through the dispatcher": (one_array, (s,)),
        # what service/live_call.py calls: the compiled entry point of the one signature (no per-call typing)
        "1 array, compiled entry point (LiveCall)": (one_array.compile("(float64[::1],)"), (s,)),
    }
    for function, arguments in cases.values():
        function(*arguments)  # compiled before timing
    print("| compiled function entered with | warm p50 | one call per 20 ms, p50 |")
    print("|---|---|---|")
    for name, (function, arguments) in cases.items():
        timings: dict[bool, list[float]] = {False: [], True: []}
        for k in range(2 * calls):
            paced = k % 2 == 1
            if paced:
                time.sleep(pace_s)
            started = time.perf_counter()
            function(*arguments)
            timings[paced].append((time.perf_counter() - started) * 1e6)
        warm, cold = (statistics.median(timings[paced]) for paced in (False, True))
        print(f"| {name} | {warm:.1f} us | {cold:.1f} us |", flush=True)
    print()


def step_profile(steps: int = 700, pace_s: float = 0.02) -> None:
    """The pipeline alone, one frame per ``pace_s`` asleep (as live): each part of a step timed by wrapping
    the function that does it (p50 / p99 over the steps after the estimator's start; the wrappers add ~1 us
    each). The two ThermalEKF calls of a step are the open-loop reference (first) and the estimator."""
    from ecu_monitor.bus import codec
    from ecu_monitor.estimation import detection, ekf, isolation
    from ecu_monitor.runtime import pipeline as pipeline_module

    timings: dict[str, list[float]] = {}
    originals: list[tuple[Any, str, Any]] = []

    def wrap(owner: Any, attribute: str, label: str) -> None:
        function = getattr(owner, attribute, None)
        if function is None:  # a part an older (or newer) checkout does not have
            return
        originals.append((owner, attribute, function))

        def timed(*args: Any, **kwargs: Any) -> Any:
            started = time.perf_counter()
            result = function(*args, **kwargs)
            timings.setdefault(label, []).append((time.perf_counter() - started) * 1e6)
            return result

        setattr(owner, attribute, timed)

    for owner, attribute, label in (
        (codec.Decoder, "decode", "decode (one frame)"),
        (pipeline_module.Pipeline, "_stale", "staleness"),
        (pipeline_module, "supervise", "supervision"),
        (ekf.ThermalEKF, "estimate", "ThermalEKF call"),
        (isolation.IsolationFilter, "estimate", "isolation filter call"),
        (detection.Detector, "update", "detector"),
        (detection.Detector, "step", "detector"),  # the pipeline's call since 2026-11-28
        (pipeline_module, "time_to_limit_s", "headroom"),
        (pipeline_module.Pipeline, "_build_snapshot", "snapshot"),
        (pipeline_module.Pipeline, "_frame", "one health frame (values packed, can.Message)"),
    ):
        wrap(owner, attribute, label)
    live_call = getattr(pipeline_module, "LiveCall", None)  # older checkouts: three calls, no LiveCall
    if live_call is not None:
        wrap(live_call, "call", "one compiled call: reference, supervision, estimator, isolation")
    totals: dict[int, list[float]] = {}

    def after_the_estimators_start(k: int) -> None:
        if k == 100:
            timings.clear()
            totals.clear()

    try:
        config = _config("unused")
        pipeline = Pipeline(config, config.load_params())
        for sent, cost_us in paced_steps(pipeline, steps, pace_s, before_step=after_the_estimators_start):
            if sent:
                totals.setdefault(sent, []).append(cost_us)
    finally:
        for owner, attribute, function in originals:
            setattr(owner, attribute, function)
    calls = timings.pop("ThermalEKF call", [])
    if calls:
        timings["ThermalEKF call, first of the step (open-loop reference)"] = calls[0::2]
        timings["ThermalEKF call, second (estimator)"] = calls[1::2]
    print(f"| pipeline alone, one frame per {pace_s * 1e3:g} ms: part of a step | calls | p50 | p99 |")
    print("|---|---|---|---|")
    for label, values in timings.items():
        if len(values) < 2:
            continue
        p50, p99, _ = _percentiles(values)
        print(f"| {label} | {len(values)} | {p50:.1f} us | {p99:.1f} us |")
    for count, values in sorted(totals.items()):
        p50, p99, _ = _percentiles(values)
        print(f"| feed + advance_to of a step sending {count} frame(s) | {len(values)} | {p50:.0f} us | {p99:.0f} us |")
    print()


def full_collection_ms() -> tuple[float, float, int]:
    """A full gc.collect() in a process holding the daemon's modules and a running pipeline, ms:
    (heap as is, after gc.freeze() and 20 s more of pipeline steps, objects tracked before the freeze)."""
    pipeline_cost(steps=500)
    tracked = len(gc.get_objects())
    started = time.perf_counter()
    gc.collect()
    plain_ms = (time.perf_counter() - started) * 1e3
    gc.freeze()
    pipeline_cost(steps=1000)
    started = time.perf_counter()
    gc.collect()
    frozen_ms = (time.perf_counter() - started) * 1e3
    gc.unfreeze()
    return plain_ms, frozen_ms, tracked


def pipeline_cost(
    steps: int = 3000, pace_s: float = 0.0, spin: bool = False, gc_off: bool = False
) -> tuple[float, float]:
    """p50, p99 (us) of feed + advance_to for the frames whose step emits health frames, no bus, no threads.

    ``pace_s`` > 0 waits that long before each step, as live frames come 20 ms apart: asleep, or with
    ``spin`` busy on the clock (the core stays awake at full clock; other processes still get it when
    the scheduler preempts). ``gc_off``: automatic garbage collection off during the loop."""
    config = _config("unused")
    pipeline = Pipeline(config, config.load_params())
    if gc_off:
        gc.disable()
    costs = [cost_us for sent, cost_us in paced_steps(pipeline, steps, pace_s, spin=spin) if sent]
    gc.enable()
    p50, p99, _ = _percentiles(costs[50:])  # after the estimator's start
    return p50, p99


def paced_steps(
    pipeline: Pipeline,
    steps: int,
    pace_s: float,
    spin: bool = False,
    before_step: Callable[[int], None] | None = None,
    prewarm: Callable[[int, float, list[can.Message]], None] | None = None,
    lead_s: float = 0.0,
    clock: Callable[[], float] = time.perf_counter,
) -> Iterator[tuple[int, float]]:
    """Feed ``pipeline`` the ECU frames of ``steps`` 20 ms steps (ECU_Fast each step, ECU_Slow and AirData
    every fifth), ``feed`` then ``advance_to`` per frame as the daemon does, waiting ``pace_s`` before each
    step (asleep, or with ``spin`` busy on the clock: the core stays awake at full clock). Yields, per
    frame, (health frames that step sent, its feed + advance_to in us). ``before_step(k)`` runs after the
    wait, before step k's frames. ``prewarm(k, t, frames)``, when given, runs ``lead_s`` before step k's
    frames (asleep ``pace_s - lead_s``, then it, then asleep ``lead_s``). ``clock``: what the cost is read on
    (``time.thread_time``: the thread's CPU time)."""
    encoder = Encoder([REPO / "ecu_monitor" / "data" / "dbc" / "engine.dbc"])
    counters = dict.fromkeys(ECU_VALUES, 0)

    def ecu_frames(k: int) -> list[can.Message]:
        messages = []
        for name in ("ECU_Fast", "ECU_Slow", "AirData") if k % 5 == 0 else ("ECU_Fast",):
            data = encoder.encode(name, ECU_VALUES[name], counters[name])
            counters[name] += 1
            messages.append(can.Message(arbitration_id=encoder.message(name).frame_id, is_extended_id=False, data=data))
        return messages

    t = 0.0
    pipeline.advance_to(t)
    for k in range(steps):
        t += 0.02
        if prewarm is not None:  # the frames exist before the wait (the prewarm may read them)
            messages = ecu_frames(k)
            time.sleep(pace_s - lead_s)
            prewarm(k, t, messages)
            time.sleep(lead_s)
        elif pace_s > 0.0 and spin:
            until = time.perf_counter() + pace_s
            while time.perf_counter() < until:
                pass
        elif pace_s > 0.0:
            time.sleep(pace_s)
        if before_step is not None:
            before_step(k)
        for msg in messages if prewarm is not None else ecu_frames(k):
            started = clock()
            pipeline.feed(msg)
            frames = pipeline.advance_to(t)
            yield len(frames), (clock() - started) * 1e6


def step_bytecodes(steps: int = 1200) -> None:
    """Python bytecodes executed by feed + advance_to of the frames whose step sends health frames (the pipeline
    alone, ``sys.settrace`` opcode events: a count of the interpreter's work that no noise moves), by the number of
    frames sent, and the functions that execute most of them on the steps sending one frame."""
    config = _config("unused")
    pipeline = Pipeline(config, config.load_params())
    encoder = Encoder([REPO / "ecu_monitor" / "data" / "dbc" / "engine.dbc"])
    counters = dict.fromkeys(ECU_VALUES, 0)
    per_function: dict[tuple[str, str], int] = {}

    def tracer(frame: Any, event: str, arg: Any) -> Any:
        if event == "call":
            frame.f_trace_opcodes = True
        elif event == "opcode":
            key = (Path(frame.f_code.co_filename).name, frame.f_code.co_name)
            per_function[key] = per_function.get(key, 0) + 1
        return tracer

    totals: dict[int, list[int]] = {}
    one_frame: dict[tuple[str, str], int] = {}
    t = 0.0
    pipeline.advance_to(t)
    for k in range(steps):
        t += 0.02
        for name in ("ECU_Fast", "ECU_Slow", "AirData") if k % 5 == 0 else ("ECU_Fast",):
            data = encoder.encode(name, ECU_VALUES[name], counters[name])
            counters[name] += 1
            msg = can.Message(arbitration_id=encoder.message(name).frame_id, is_extended_id=False, data=data)
            per_function.clear()
            sys.settrace(tracer)
            pipeline.feed(msg)
            frames = pipeline.advance_to(t)
            sys.settrace(None)
            if frames and k >= steps // 2:  # the estimator running
                totals.setdefault(len(frames), []).append(sum(per_function.values()))
                if len(frames) == 1:
                    for key, count in per_function.items():
                        one_frame[key] = one_frame.get(key, 0) + count
    print("| pipeline alone: bytecodes of feed + advance_to | frames sent | steps | mean |")
    print("|---|---|---|---|")
    for sent, values in sorted(totals.items()):
        print(f"| a step sending {sent} frame(s) | {sent} | {len(values)} | {statistics.mean(values):.0f} |")
    n = len(totals.get(1, [])) or 1
    top = sorted(one_frame.items(), key=lambda item: -item[1])[:12]
    print("\nmost of a one-frame step's: " + ", ".join(f"{f}:{name} {c / n:.0f}" for (f, name), c in top) + "\n")


def step_cpu(steps: int = 1000) -> None:
    """The CPU time (``time.thread_time``) of feed + advance_to of the frames whose step sends health frames, the
    pipeline alone, by the number of frames sent: back to back, one frame per 20 ms asleep, and the same with
    ``Pipeline.rehearse`` 0.6 ms before each frame that may run the step (as the daemon does across processes).
    p50 / p99 after the estimator's start; the heap frozen and collection off, as in the daemon."""
    config = _config("unused")
    params = config.load_params()

    def rehearsal_of(pipeline: Pipeline) -> Callable[[int, float, list[can.Message]], None]:
        def run(k: int, t: float, messages: list[can.Message]) -> None:
            if math.isfinite(pipeline.rehearsal_frame_s(t - 0.02)):  # as the daemon decides, after the last frame
                pipeline.rehearse()

        return run

    print("| pipeline alone: CPU of feed + advance_to | frames sent | samples | p50 | p99 |")
    print("|---|---|---|---|---|")
    for name, count, pace_s, rehearsed in (
        ("back to back", 5 * steps, 0.0, False),
        ("one frame per 20 ms asleep", steps, 0.02, False),
        ("one frame per 20 ms, Pipeline.rehearse 0.6 ms before", steps, 0.02, True),
    ):
        pipeline = Pipeline(config, params)
        pipeline.warm_up()
        costs: dict[int, list[float]] = {}
        gc.collect()
        gc.freeze()
        gc.disable()
        try:
            prewarm = rehearsal_of(pipeline) if rehearsed else None
            lead = 0.0006 if rehearsed else 0.0
            for k, (sent, cost_us) in enumerate(
                paced_steps(pipeline, count, pace_s, prewarm=prewarm, lead_s=lead, clock=time.thread_time)
            ):
                if sent and k > 500:  # after the estimator's start
                    costs.setdefault(sent, []).append(cost_us)
        finally:
            gc.enable()
            gc.unfreeze()
        for sent, values in sorted(costs.items()):
            p50, p99, _ = _percentiles(values)
            print(f"| {name} | {sent} | {len(values)} | {p50:.1f} us | {p99:.1f} us |")
    print()


def prewarm_study(steps: int = 500, rounds: int = 3) -> None:
    """Does running code shortly before a frame bring that frame's paced step down toward its 1 ms-paced
    cost? The pipeline alone, one frame per 20 ms asleep; before each frame, ``lead`` ms earlier: nothing
    (baseline), or a second pipeline (the twin) fed the same frames (every part of the step's code run, on
    the twin's own data: what any rehearsal of the code could at most gain), or the pipeline's own
    ``rehearse`` where it has one; and one frame per 1 ms for reference. Modes alternate, ``rounds`` times;
    p50 / p99 of feed + advance_to of the frames whose step emits health frames, after the estimator's start."""
    config = _config("unused")
    params = config.load_params()

    def twin_of(pipeline: Pipeline) -> Callable[[int, float, list[can.Message]], None]:
        twin = Pipeline(config, params)
        twin.advance_to(0.0)

        def run(k: int, t: float, messages: list[can.Message]) -> None:
            for msg in messages:
                twin.feed(msg)
                twin.advance_to(t)

        return run

    def rehearsal_of(pipeline: Pipeline) -> Callable[[int, float, list[can.Message]], None] | None:
        rehearse = getattr(pipeline, "rehearse", None)
        if rehearse is None:
            return None

        def run(k: int, t: float, messages: list[can.Message]) -> None:
            if math.isfinite(pipeline.rehearsal_frame_s(t - 0.02)):  # as the daemon decides, after the last frame
                rehearse()

        return run

    modes: list[tuple[str, float, float, Any]] = [
        (
            "one frame per 20 ms asleep (baseline: the frames built first, nothing run 1 ms before)",
            0.02,
            0.001,
            lambda pipeline: lambda k, t, messages: None,
        ),
        ("the twin pipeline steps the same frames 1 ms before", 0.02, 0.001, twin_of),
        ("the twin 0.3 ms before", 0.02, 0.0003, twin_of),
        ("Pipeline.rehearse 1 ms before", 0.02, 0.001, rehearsal_of),
        ("Pipeline.rehearse 0.6 ms before", 0.02, 0.0006, rehearsal_of),
        ("Pipeline.rehearse 0.3 ms before", 0.02, 0.0003, rehearsal_of),
        ("one frame per 1 ms asleep", 0.001, 0.0, None),
    ]
    results: dict[str, list[float]] = {}
    for _ in range(rounds):
        for name, pace_s, lead_s, make in modes:
            pipeline = Pipeline(config, params)
            prewarm = make(pipeline) if make is not None else None
            if make is not None and prewarm is None:
                continue
            costs = [c for sent, c in paced_steps(pipeline, steps, pace_s, prewarm=prewarm, lead_s=lead_s) if sent]
            results.setdefault(name, []).extend(costs[50:])
    print("| pipeline alone: feed + advance_to of a frame whose step emits health frames | samples | p50 | p99 |")
    print("|---|---|---|---|")
    for name, values in results.items():
        p50, p99, _ = _percentiles(values)
        print(f"| {name} | {len(values)} | {p50:.0f} us | {p99:.0f} us |")
    print()


# --- across processes, udp_multicast in a network namespace -------------------------------------------

GROUP = "239.74.163.2"

_DAEMON = textwrap.dedent(
    """
    import json, signal, sys, threading, time, can
    from ecu_monitor.config import load_config
    from ecu_monitor.runtime.daemon import Daemon, DaemonSettings
    from ecu_monitor.runtime.publishers import LiveMonitor as Pipeline
    config = load_config(sys.argv[1])
    pipeline = Pipeline(config, config.load_params())
    settings = DaemonSettings(tick_s=3600.0, **json.loads(sys.argv[2]))
    daemon = Daemon(pipeline, lambda: can.Bus(**dict(config.bus)), settings=settings,
                    receive_ids=pipeline.decoder.frame_ids)
    # the daemon's own timings (perf_counter, s): feed + advance_to of the frames whose step sends health
    # frames, and each rehearsal's start and end
    steps, rehearsals, fed = [], [], [0.0]
    feed, advance = pipeline.feed, pipeline.advance_to
    def timed_feed(msg):
        fed[0] = time.perf_counter()
        feed(msg)
    def timed_advance(t_s):
        frames = advance(t_s)
        if frames:
            steps.append((fed[0], time.perf_counter()))
        return frames
    pipeline.feed, pipeline.advance_to = timed_feed, timed_advance
    if hasattr(pipeline, "rehearse"):
        rehearse = pipeline.rehearse
        def timed_rehearse():
            started = time.perf_counter()
            rehearse()
            rehearsals.append((started, time.perf_counter()))
        pipeline.rehearse = timed_rehearse
    supervised = []  # the supervisor's periods (perf_counter, s): the tail analysis of run_netns
    supervise_once = daemon._supervise_once
    def timed_supervise(now):
        started = time.perf_counter()
        supervise_once(now)
        supervised.append((started, time.perf_counter()))
    daemon._supervise_once = timed_supervise
    signal.signal(signal.SIGTERM, lambda *args: daemon.stop())
    def announce():
        while daemon.counters["bus_opens"] == 0:
            time.sleep(0.05)
        print("ready", flush=True)
    threading.Thread(target=announce, daemon=True).start()
    daemon.run()
    counts = {"in": daemon.counters["frames_in"], "out": daemon.counters["health_sent"],
              "rehearsals": daemon.counters.get("rehearsals", 0), "steps": steps, "rehearsal_spans": rehearsals,
              "supervisor_spans": supervised}
    print(json.dumps(counts), flush=True)
    """
)

_ECHO = textwrap.dedent(
    """
    import json, signal, sys, threading, can
    bus = can.Bus(interface="udp_multicast", channel=sys.argv[1], port=int(sys.argv[2]))
    bus.set_filters([{"can_id": i, "can_mask": 0x7FF} for i in (0x100, 0x101, 0x200)])
    reply = can.Message(arbitration_id=0x300, is_extended_id=False, data=bytes(8))
    counts = {"in": 0, "out": 0}
    def echo(msg):
        counts["in"] += 1
        if msg.arbitration_id == 0x100:
            bus.send(reply)
            counts["out"] += 1
    notifier = can.Notifier(bus, [echo], timeout=0.2)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *args: done.set())
    print("ready", flush=True)
    done.wait()
    notifier.stop()
    bus.shutdown()
    print(json.dumps(counts), flush=True)
    """
)

_TRAFFIC = textwrap.dedent(
    """
    import random, sys, time, can
    bus = can.Bus(interface="udp_multicast", channel=sys.argv[1], port=int(sys.argv[2]))
    per_burst, rng = int(sys.argv[3]), random.Random(4000)
    frames = [can.Message(arbitration_id=rng.randrange(0x400, 0x800), is_extended_id=False, data=rng.randbytes(8))
              for _ in range(1000)]
    k, next_s = 0, time.perf_counter()
    while True:
        for i in range(per_burst):
            bus.send(frames[(k * per_burst + i) % 1000])
        k += 1
        next_s += 0.0025
        delay = next_s - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
    """
)


def _own_timings(steps: list[list[float]], rehearsals: list[list[float]]) -> str:
    """The daemon process's own timings across processes: feed + advance_to of the frames whose step sends
    health frames (after the start-up), each rehearsal, and from the end of the rehearsal before such a frame
    to that frame's feed (short: the frame waited for the rehearsal)."""
    costs = [(end - start) * 1e6 for start, end in steps[20:]]
    text = "feed + advance_to p50 {:.0f} us, p99 {:.0f} us".format(*_percentiles(costs)[:2])
    if rehearsals:
        spans = [(end - start) * 1e6 for start, end in rehearsals[20:]]
        ends = [end for _, end in rehearsals]
        gaps = []
        for start, _ in steps[20:]:
            before = bisect.bisect_right(ends, start) - 1
            if before >= 0 and start - ends[before] < 0.01:
                gaps.append((start - ends[before]) * 1e6)
        text += "; rehearsal p50 {:.0f} us, p99 {:.0f} us".format(*_percentiles(spans)[:2])
        if gaps:
            text += (
                f"; {len(gaps)} of {len(costs)} such frames had a rehearsal in the 10 ms before, ended p50 "
                f"{statistics.median(gaps):.0f} us before the frame's feed ({sum(g < 50 for g in gaps)} under 50 us)"
            )
    return text


def measure_inner(port: int, seconds: float, name: str) -> None:
    """Inside the namespace: send the ECU frames, receive the health frames, print the statistics (JSON)."""
    ecu_bus = can.Bus(interface="udp_multicast", channel=GROUP, port=port)
    rx_bus = can.Bus(interface="udp_multicast", channel=GROUP, port=port)
    rx_bus.set_filters([{"can_id": i, "can_mask": 0x7FF} for i in HEALTH_IDS])
    sent_at: list[float] = []
    got: list[tuple[float, int]] = []
    counts = {"ecu": 0, "traffic": 0}
    stop_rx = threading.Event()
    receiver = _receiver(rx_bus, stop_rx, got)
    ecu = Periodic(0.02, _ecu_sender(ecu_bus, sent_at, counts))
    ecu.start()
    settled = time.perf_counter() + SETTLE_S
    time.sleep(seconds)
    ecu.stop_event.set()
    ecu.join()
    time.sleep(0.5)
    stop_rx.set()
    receiver.join()
    ecu_bus.shutdown()
    rx_bus.shutdown()
    raw = []  # (sent, received) of each health frame counted, perf_counter s: for tail_anatomy
    for received, _ in got:
        index = bisect.bisect_left(sent_at, received) - 1
        if received >= settled and index >= 0:
            raw.append((sent_at[index], received))
    stats = _stats(name, sent_at, got, since=settled)
    print(json.dumps({**stats, "ecu_sent": counts["ecu"], "out_received": len(got), "raw": raw}))


def _socket_drops(ns: str, pid: int) -> int:
    """Datagrams the kernel dropped on the UDP sockets of process ``pid`` (full receive queue)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        target = os.readlink(fd)
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    table = subprocess.run(["ip", "netns", "exec", ns, "cat", "/proc/net/udp"], capture_output=True, text=True)
    drops = 0
    for line in table.stdout.splitlines()[1:]:
        fields = line.split()
        if fields[9] in inodes:
            drops += int(fields[-1])
    return drops


def run_netns(seconds: float, traffic_hz: float, nice: int = 0) -> list[dict[str, Any]]:
    """Both cases across processes inside a fresh network namespace; returns their statistics."""
    port = 44000 + os.getpid() % 1000
    rows = []
    procs: list[subprocess.Popen[str]] = []

    def start(argv: list[str]) -> subprocess.Popen[str]:
        proc = subprocess.Popen(["ip", "netns", "exec", ns, *argv], stdout=subprocess.PIPE, text=True)
        procs.append(proc)
        return proc

    with multicast_namespace(GROUP, port, "--netns") as space:
        ns, config = space.name, space.config
        try:
            per_burst = round(traffic_hz * 0.0025)  # 0: no other traffic
            for name, argv in (
                ("bare Notifier echo (baseline), separate process", [sys.executable, "-c", _ECHO, GROUP, str(port)]),
                (
                    "daemon + pipeline, separate process",
                    [sys.executable, "-c", _DAEMON, str(config), json.dumps(DAEMON_OPTIONS)],
                ),
            ):
                peer = start(["nice", "-n", str(nice), *argv] if nice else argv)
                assert peer.stdout is not None
                if peer.stdout.readline().strip() != "ready":
                    sys.exit(f"{name}: did not start")
                traffic = start([sys.executable, "-c", _TRAFFIC, GROUP, str(port), str(per_burst)])
                time.sleep(1.0)
                inner = start([sys.executable, __file__, "--inner", str(port), str(seconds), name])
                time.sleep(1.0)  # the measuring process's start-up
                cpu_before, wall_before = process_cpu_s(peer.pid), time.monotonic()
                time.sleep(max(0.0, seconds - 2.0))
                cpu_pct = 100.0 * (process_cpu_s(peer.pid) - cpu_before) / (time.monotonic() - wall_before)
                out, _ = inner.communicate(timeout=seconds + 60)
                peer_drops = _socket_drops(ns, peer.pid)
                traffic.kill()
                traffic.wait(timeout=10)
                peer.send_signal(signal.SIGTERM)
                peer_out, _ = peer.communicate(timeout=30)
                peer_counts = json.loads(peer_out.strip().splitlines()[-1])
                row = json.loads(out.strip().splitlines()[-1])
                row.update(ecu_in=peer_counts["in"], out_sent=peer_counts["out"], traffic_hz=per_burst / 0.0025)
                if "rehearsals" in peer_counts:
                    row["rehearsals"] = peer_counts["rehearsals"]
                if "steps" in peer_counts:
                    row["own"] = _own_timings(peer_counts["steps"], peer_counts["rehearsal_spans"])
                if "supervisor_spans" in peer_counts:
                    row["tail"] = tail_anatomy(row["raw"], peer_counts["steps"], peer_counts["supervisor_spans"])
                row.pop("raw", None)
                row["socket_drops"] = peer_drops
                row["cpu_pct"] = cpu_pct
                rows.append(row)
        finally:
            kill_all(procs)
    return rows


def tail_anatomy(raw: list[list[float]], steps: list[list[float]], supervised: list[list[float]]) -> str:
    """Where the daemon's slowest 2 % of health frames across processes spent their time, against the median
    (one clock: perf_counter is CLOCK_MONOTONIC in every process): from the ECU frame's send to the daemon's
    feed of it, its feed + advance_to, and from there to the receiver's recv; and how many of them had the
    daemon's supervisor thread running on their way (it wakes every 0.1 s, the Health_Status period)."""
    feeds = [start for start, _ in steps]
    spans = sorted((start, end) for start, end in supervised)
    starts = [start for start, _ in spans]

    def supervisor_during(begin: float, end: float) -> bool:
        index = bisect.bisect_right(starts, end) - 1
        return index >= 0 and spans[index][1] > begin

    rows = []
    for sent, received in raw:
        index = bisect.bisect_right(feeds, received) - 1
        if index < 0 or steps[index][0] < sent:
            continue
        fed, done = steps[index]
        rows.append((received - sent, fed - sent, done - fed, received - done, supervisor_during(sent, received), sent))
    if len(rows) < 50:
        return f"too few samples ({len(rows)})"
    rows.sort()
    tail = rows[-max(1, len(rows) // 50) :]
    start = min(row[5] for row in rows)
    median = "/".join(f"{1e6 * statistics.median(row[i] for row in rows):.0f}" for i in range(4))
    slowest = "; ".join(
        f"{1e6 * r[0]:.0f}/{1e6 * r[1]:.0f}/{1e6 * r[2]:.0f}/{1e6 * r[3]:.0f} {'S' if r[4] else '-'} {r[5] - start:.1f}"
        for r in tail
    )
    return (
        f"total / send->feed / feed + advance_to / ->recv, us: median of {len(rows)} {median}; the slowest "
        f"{len(tail)} (S: the supervisor ran on its way; at s): {slowest}; the supervisor ran during "
        f"{sum(r[4] for r in rows)} of all, {sum(r[4] for r in tail)} of the slowest"
    )


#: Targets of issue 13 (ratios against the echo baseline of the same run).
P99_LIMIT_US = 1000.0
P99_RATIO_IN_PROCESS = 2.5
P99_RATIO_ACROSS = 1.5
CPU_LIMIT_PCT = 3.0


def report(title: str, baseline: dict[str, Any], daemon: dict[str, Any], across: bool = False) -> None:
    print(f"{title}, load average {os.getloadavg()[0]:.1f}\n")
    print("| case | p50 | p99 | max | samples | ECU frames sent / in | replies sent / received | CPU, % of a core |")
    print("|---|---|---|---|---|---|---|---|")
    for row in (baseline, daemon):
        print(
            f"| {row['case']} | {row['p50_us']:.0f} us | {row['p99_us']:.0f} us | {row['max_us']:.0f} us | "
            f"{row['samples']} | {row['ecu_sent']} / {row['ecu_in']} | {row['out_sent']} / {row['out_received']} | "
            f"{row.get('cpu_pct', math.nan):.2f} |"
        )
    for row in (baseline, daemon):
        per_frame = row.get("per_frame", {})
        if len(per_frame) > 1:  # every health frame id the step sends, each with its own latency
            print(
                f"\n{row['case']}, each frame id (samples, p50 / p99 / max, us): "
                + "; ".join(
                    f"{name} ({v['samples']}) {v['p50_us']:.0f} / {v['p99_us']:.0f} / {v['max_us']:.0f}"
                    for name, v in per_frame.items()
                )
            )
    p99_ratio = daemon["p99_us"] / baseline["p99_us"]
    print(f"\nratio daemon / baseline: p50 {daemon['p50_us'] / baseline['p50_us']:.2f}x, p99 {p99_ratio:.2f}x")
    if daemon.get("latencies_us") and baseline.get("latencies_us"):
        low, high = p99_ratio_interval(daemon["latencies_us"], baseline["latencies_us"])
        print(
            f"p99 ratio, 90 % bootstrap interval {low:.2f}-{high:.2f}x ({daemon['samples']} daemon and"
            f" {baseline['samples']} echo samples: a longer --seconds narrows it)"
        )
    for row in (baseline, daemon):
        if "socket_drops" in row:
            print(
                f"{row['case']}: {row['socket_drops']} datagrams dropped by the kernel on its socket (a full queue, or"
                " the daemon's receive filter: bus/kernel_filter.py)"
            )
        if row.get("own"):
            print(f"{row['case']}: its own timings: {row['own']}")
        if row.get("tail"):
            print(f"{row['case']}, its slowest health frames: {row['tail']}")
        if row.get("phases"):
            print(f"{row['case']}: callback of a frame whose step emits health frames: {row['phases']}")
        if "gc" in row:
            print(f"{row['case']}: garbage collections in the process during the run: {row['gc']}")
        if row.get("anatomy"):
            print(f"\n{row['case']}, what its latency is made of:\n\n{row['anatomy']}\n")
    lost = daemon["ecu_sent"] - daemon["ecu_in"] + daemon["out_sent"] - daemon["out_received"]
    print(f"frames lost: {lost}")
    if "rehearsals" in daemon:
        lead = DAEMON_OPTIONS.get("rehearse_lead_s", getattr(DaemonSettings(), "rehearse_lead_s", None))
        shown = "off" if lead is None else f"rehearse_lead_s {lead * 1e3:g} ms; the daemon does none on `virtual`"
        print(f"rehearsals of the Health_Status step ({shown}): {daemon['rehearsals']}")
    if across:
        checks = [(f"p99 within {P99_RATIO_ACROSS}x of the echo process's", p99_ratio <= P99_RATIO_ACROSS)]
    else:
        checks = [
            (f"p99 < {P99_LIMIT_US:.0f} us", daemon["p99_us"] < P99_LIMIT_US),
            (f"p99 at most {P99_RATIO_IN_PROCESS}x the echo's", p99_ratio <= P99_RATIO_IN_PROCESS),
        ]
    checks.append((f"daemon CPU < {CPU_LIMIT_PCT:g} % of a core", daemon.get("cpu_pct", math.inf) < CPU_LIMIT_PCT))
    print("targets: " + "; ".join(f"{name}: {'met' if ok else 'NOT met'}" for name, ok in checks) + "\n")


#: DaemonSettings given on the command line (--rehearse-lead), for the daemon in one process and across; empty:
#: the defaults (older checkouts' DaemonSettings lack the newer fields)
DAEMON_OPTIONS: dict[str, Any] = {}


def main() -> None:
    if len(sys.argv) == 5 and sys.argv[1] == "--inner":
        measure_inner(int(sys.argv[2]), float(sys.argv[3]), sys.argv[4])
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--traffic", type=float, default=4000.0, help="other frames per second")
    parser.add_argument("--netns", action="store_true", help="across processes on udp_multicast in a netns")
    parser.add_argument("--gc-study", action="store_true", help="also run the daemon without gc.freeze")
    parser.add_argument("--nice", type=int, default=0, help="with --netns: run the daemon and the echo at this nice")
    parser.add_argument("--pace-study", action="store_true", help="also time the pipeline alone under other pacings")
    parser.add_argument(
        "--step-profile", action="store_true", help="only: each part of a paced step of the pipeline alone, timed"
    )
    parser.add_argument(
        "--prewarm-study", action="store_true", help="only: the paced step after code run shortly before the frame"
    )
    parser.add_argument(
        "--step-cpu", action="store_true", help="only: the CPU time of the health steps, paced, rehearsed, back to back"
    )
    parser.add_argument("--step-bytecodes", action="store_true", help="only: the bytecodes a health step executes")
    parser.add_argument(
        "--dispatch-study", action="store_true", help="only: what entering a compiled function costs, by argument list"
    )
    parser.add_argument(
        "--rehearse-lead",
        type=float,
        default=None,
        help="ms: the daemon's DaemonSettings.rehearse_lead_s (0: no rehearsal; default: the daemon's default)",
    )
    parser.add_argument(
        "--spin",
        type=float,
        default=None,
        help="ms: the daemon's DaemonSettings.spin_s (poll without sleeping after a rehearsal; default: the daemon's)",
    )
    parser.add_argument(
        "--switch-interval",
        type=float,
        default=(getattr(DaemonSettings(), "switch_interval_s", None) or 0.0) * 1e3,
        help="ms: the daemon's DaemonSettings.switch_interval_s, the echo's too (0: the interpreter's default)",
    )
    args = parser.parse_args()
    if args.rehearse_lead is not None:
        DAEMON_OPTIONS["rehearse_lead_s"] = args.rehearse_lead * 1e-3 if args.rehearse_lead > 0 else None
    if args.spin is not None:
        DAEMON_OPTIONS["spin_s"] = args.spin * 1e-3
    if args.dispatch_study:
        dispatch_study()
        return
    if args.step_profile:
        step_profile()
        return
    if args.prewarm_study:
        prewarm_study()
        return
    if args.step_cpu:
        step_cpu()
        return
    if args.step_bytecodes:
        step_bytecodes()
        return
    if args.netns:
        baseline, daemon = run_netns(args.seconds, args.traffic, args.nice)
        title = f"udp_multicast across processes in a netns (nice {args.nice}), {args.seconds:g} s per case"
        report(f"{title}, other traffic {daemon['traffic_hz']:.0f} frames/s", baseline, daemon, across=True)
        return
    interval = args.switch_interval * 1e-3 if args.switch_interval > 0 else None
    baseline = run_case("bare Notifier echo (baseline)", args.seconds, args.traffic, False, switch_interval_s=interval)
    daemon = run_case("daemon + pipeline", args.seconds, args.traffic, True, switch_interval_s=interval)
    shown = f"{args.switch_interval:g} ms" if interval else f"the interpreter's {sys.getswitchinterval() * 1e3:g} ms"
    title = f"virtual interface, one process, {args.seconds:g} s per case, switch interval {shown}"
    cost_p50, cost_p99 = pipeline_cost()
    paced_p50, paced_p99 = pipeline_cost(steps=600, pace_s=0.02)
    print(
        f"pipeline alone, feed + advance_to of a frame whose step emits health frames: back to back "
        f"p50 {cost_p50:.0f} us, p99 {cost_p99:.0f} us; one frame per 20 ms p50 {paced_p50:.0f} us, "
        f"p99 {paced_p99:.0f} us\n"
    )
    report(f"{title}, other traffic {daemon['traffic_hz']:.0f} frames/s", baseline, daemon)
    if args.pace_study:
        pace_study()
    if args.gc_study:
        plain_ms, frozen_ms, tracked = full_collection_ms()
        print(f"full gc.collect(), {tracked} objects tracked: {plain_ms:.1f} ms; after gc.freeze(): {frozen_ms:.2f} ms")
        unfrozen = run_case(
            "daemon, heap not frozen", args.seconds, args.traffic, with_pipeline=True, freeze_heap=False
        )
        report("same, without gc.freeze (DaemonSettings.freeze_heap=False)", baseline, unfrozen)


if __name__ == "__main__":
    main()
