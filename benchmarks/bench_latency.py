"""Live latency: ECU frame -> the health frame it causes, p50/p99, with 4,000 frames/s of other traffic.

    .venv/bin/python benchmarks/bench_latency.py [--seconds 30] [--traffic 4000]

In one process, on python-can's ``virtual`` interface (three bus objects on one channel):

* an ECU thread sends ECU_Fast at 50 Hz and ECU_Slow/AirData at 10 Hz (valid counters and CRC),
  recording ``perf_counter()`` just before each send;
* a traffic thread sends ``--traffic`` frames/s of other ids (0x400-0x7FF, random payloads), in bursts
  every 2.5 ms;
* the daemon under test (:class:`~ecu_monitor.service.daemon.Daemon` with the real Pipeline from
  configs/example.yaml) runs with its 20 ms tick switched off (``tick_s`` = 1 h), so every health frame
  is emitted inside the Notifier callback of the ECU frame that made its step fall due: the health
  frame's latency is measured from that frame's send (the latest ECU send before it);
* a receiver thread stamps each health frame with ``perf_counter()`` on ``recv``.

Baseline in the same run, same traffic: a bare Notifier listener that answers every ECU_Fast frame
with one frame (no pipeline): the virtual-bus round trip the daemon cannot beat. "No frame lost":
every ECU frame sent is counted in by the daemon and every health frame sent is received.
"""

from __future__ import annotations

import argparse
import bisect
import random
import statistics
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import yaml

from ecu_monitor.bus.codec import Encoder
from ecu_monitor.service.config import parse_config
from ecu_monitor.service.daemon import Daemon, DaemonSettings
from ecu_monitor.service.pipeline import Pipeline

REPO = Path(__file__).resolve().parent.parent
HEALTH_IDS = (0x300, 0x301, 0x302)
ECU_VALUES = {
    "ECU_Fast": {"EngineSpeed": 5500.0, "ThrottlePos": 60.0, "FuelFlow": 0.6},
    "ECU_Slow": {"CHT": 160.0, "OAT": 15.0, "EcuStatus": 0},
    "AirData": {"PressureAltitude": 1500.0, "CalibratedAirspeed": 23.0, "VerticalSpeed": 0.0},
}


def _config(channel: str) -> Any:
    data = yaml.safe_load((REPO / "configs" / "example.yaml").read_text())
    data["dbc"] = [str(REPO / "dbc" / "engine.dbc")]
    data["health_dbc"] = str(REPO / "dbc" / "health.dbc")
    data["bus"] = {"interface": "virtual", "channel": channel, "receive_own_messages": False}
    data["state_dir"] = "/tmp/ecu-monitor-bench-unused"
    return parse_config(data, REPO / "configs" / "bench.yaml")


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
    encoder = Encoder([REPO / "dbc" / "engine.dbc"])
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


def _percentiles(values_us: list[float]) -> tuple[float, float, float]:
    ordered = sorted(values_us)
    q = statistics.quantiles(ordered, n=100, method="inclusive")
    return q[49], q[98], ordered[-1]


def run_case(name: str, seconds: float, traffic_hz: float, with_pipeline: bool) -> dict[str, Any]:
    """One measurement: the daemon (with_pipeline) or the bare echo listener under the same traffic."""
    channel = f"bench-{uuid.uuid4().hex}"
    ecu_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    traffic_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
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
    if with_pipeline:
        config = _config(channel)
        pipeline = Pipeline(config, config.load_params())
        daemon = Daemon(
            pipeline,
            lambda: can.Bus(interface="virtual", channel=channel, receive_own_messages=False),
            settings=DaemonSettings(tick_s=3600.0),
            receive_ids=pipeline.decoder.frame_ids,
        )
        daemon_thread = threading.Thread(target=daemon.run, daemon=True)
        daemon_thread.start()
    else:
        echo_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        echo_bus.set_filters([{"can_id": 0x100, "can_mask": 0x7FF}])
        reply = can.Message(arbitration_id=0x300, is_extended_id=False, data=bytes(8))

        def echo(msg: can.Message) -> None:
            echo_bus.send(reply)  # type: ignore[union-attr]
            echo_sent[0] += 1

        echo_notifier = can.Notifier(echo_bus, [echo], timeout=0.2)
    time.sleep(0.5)
    per_burst = max(1, round(traffic_hz * 0.0025))
    traffic = Periodic(0.0025, _traffic_sender(traffic_bus, per_burst, counts, seed=4000))
    ecu = Periodic(0.02, _ecu_sender(ecu_bus, sent_at, counts))
    traffic.start()
    ecu.start()
    time.sleep(seconds)
    ecu.stop_event.set()
    ecu.join()
    traffic.stop_event.set()
    traffic.join()
    time.sleep(0.5)
    stop_rx.set()
    receiver.join()
    if daemon is not None:
        daemon.stop()
        daemon_thread.join(timeout=10)
        frames_in, health_sent = daemon.counters["frames_in"], daemon.counters["health_sent"]
    else:
        assert echo_notifier is not None and echo_bus is not None
        echo_notifier.stop()
        echo_bus.shutdown()
        frames_in, health_sent = counts["ecu"], echo_sent[0]
    for bus in (ecu_bus, traffic_bus, rx_bus):
        bus.shutdown()
    latencies_us = []
    for received, _ in got:
        index = bisect.bisect_left(sent_at, received) - 1
        if index >= 0:
            latencies_us.append((received - sent_at[index]) * 1e6)
    p50, p99, worst = _percentiles(latencies_us)
    return {
        "case": name,
        "p50_us": p50,
        "p99_us": p99,
        "max_us": worst,
        "samples": len(latencies_us),
        "ecu_sent": counts["ecu"],
        "ecu_in": frames_in,
        "out_sent": health_sent,
        "out_received": len(got),
        "traffic_hz": counts["traffic"] / seconds,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--traffic", type=float, default=4000.0, help="other frames per second")
    args = parser.parse_args()
    baseline = run_case("bare Notifier echo (baseline)", args.seconds, args.traffic, with_pipeline=False)
    daemon = run_case("daemon + pipeline", args.seconds, args.traffic, with_pipeline=True)
    print(f"virtual interface, {args.seconds:g} s per case, other traffic {daemon['traffic_hz']:.0f} frames/s\n")
    print("| case | p50 | p99 | max | samples | ECU frames sent / in | replies sent / received |")
    print("|---|---|---|---|---|---|---|")
    for row in (baseline, daemon):
        print(
            f"| {row['case']} | {row['p50_us']:.0f} us | {row['p99_us']:.0f} us | {row['max_us']:.0f} us | "
            f"{row['samples']} | {row['ecu_sent']} / {row['ecu_in']} | {row['out_sent']} / {row['out_received']} |"
        )
    print(
        f"\nratio daemon / baseline: p50 {daemon['p50_us'] / baseline['p50_us']:.2f}x, "
        f"p99 {daemon['p99_us'] / baseline['p99_us']:.2f}x"
    )
    lost = daemon["ecu_sent"] - daemon["ecu_in"] + daemon["out_sent"] - daemon["out_received"]
    print(f"frames lost: {lost}; target p99 < 2000 us: {'met' if daemon['p99_us'] < 2000 else 'NOT met'}")


if __name__ == "__main__":
    main()
