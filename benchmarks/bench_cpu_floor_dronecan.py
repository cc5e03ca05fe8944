"""The daemon's CPU on a DroneCAN bus against the DBC bus, decomposed across processes (issue 14).

    sudo .venv/bin/python benchmarks/bench_cpu_floor_dronecan.py [--seconds 15] [--repeat 3]

bench_latency_dronecan.py --netns measures the whole daemon process of each bus. This benchmark puts a
floor under that figure, in the same namespace and run, with the same traffic per protocol: the ECU frames
of bench_latency_dronecan (DBC: ECU_Fast at 50 Hz, ECU_Slow and AirData at 10 Hz; DroneCAN: the ICE status
at 50 Hz as a 7-frame transfer, the three air-data messages at 10 Hz) from a sender process, and 4,000
frames/s of other ids from a traffic process, all on udp_multicast in a network namespace made for the run
(benchmarks/netns.py: multicast stays inside it). The measured process is, level by level:

* ``socket``: python-can's own socket wait and read only (``bus._multicast.recv``: ``select`` and
  ``recvmsg`` with its timestamp), on the same bus with the same kernel filter: the system calls, the
  kernel's delivery and the thread's wake-up per frame, without python-can's unpacking;
* ``bare``: python-can's receive path only: the daemon's bus config (``can.Bus(**config.bus)``), its receive
  filters (``Pipeline.receive_filters()``, as ``ecu-monitor run`` installs them) set in python-can and in the
  kernel (:func:`ecu_monitor.bus.kernel_filter.attach_kernel_filter`), ``recv()`` in a loop on one thread,
  nothing done with the frames;
* ``sends``: ``bare`` plus the frames the daemon sends (its health frames and, on DroneCAN, the node's
  NodeStatus and KeyValue transfers), the very frames, recorded from the pipeline run offline on the same ECU
  frames, sent at the daemon's times (the first frame received after each 20 ms step time sends that step's
  frames): python-can's send path and the kernel's loopback of the node's own output;
* ``feed``: ``sends`` plus ``Pipeline.feed`` of every frame received (the decoder: DBC unpacking, DroneCAN
  reassembly, CRC and field reading), no step;
* ``daemon``: the service's daemon (``Daemon`` + ``Pipeline`` as ``ecu-monitor run`` builds them, the 20 ms
  tick off as in bench_latency) without any timing wrapper: the receive thread's lock, ``feed``,
  ``advance_to`` with the steps and the node's publications, the rehearsal, the supervisor thread.

``--timed``: instead of the levels, the daemon alone with the CPU of each part of its receive thread timed inside
it (``time.thread_time`` around ``Pipeline.feed``, ``Pipeline.advance_to`` (the steps), inside the steps the
DroneCAN node's encoding (``DroneCanNode.frames`` and ``step_frames``), ``Daemon._send_locked`` and
``Pipeline.rehearse``; the rest of the receive thread is python-can's ``recv`` and the daemon's dispatch; the
other threads are the supervisor's), over the same window (the driver signals its start and end): the paced
cost of each part, which the warm offline figures understate. The timing adds two ``thread_time`` calls
per wrapped call (well under 1 us each).

Each level runs per round as (dbc, dronecan, dbc') (A B A: the two DBC runs are the A/A pair whose ratio is
the run-to-run noise). The CPU of the measured process is the sum over its threads of the scheduler's run
time (/proc/<pid>/task/*/schedstat, ns: user and system together, the kernel's receive and send work done
in the process's context included), over ``--seconds`` once the sender has run 2 s. Then per level the
medians over the rounds and the differences between levels: the decomposition
daemon = floor + sends + per-frame decoding + (dispatch, steps, node encoding, other threads), per protocol,
and whether DroneCAN's excess over DBC is the floor's excess within the noise.

Also, offline and warm (no bus, one thread, the pipeline fed the same frames at the daemon's clock): the
CPU per second of ``feed``, of ``advance_to`` (the steps) and, inside the steps, of the DroneCAN node's
encoding (``DroneCanNode.frames`` and ``step_frames``), and the frames sent per second.
Needs root (ip netns).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import statistics
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import bench_latency  # this folder's modules (run as a script)
import bench_latency_dronecan as bld
import can
import yaml
from netns import kill_all, multicast_namespace

LEVELS = ("socket", "bare", "sends", "feed", "daemon")
CASES = bld.CASES  # (dbc, dronecan, dbc')
WARM_S = 2.0  # the sender runs this long before the CPU window opens

#: the measured process of the levels bare, sends and feed (argv: spec JSON, level)
_RECEIVER = textwrap.dedent(
    """
    import gc, json, signal, sys, threading, time, can
    from ecu_monitor.bus.kernel_filter import attach_kernel_filter
    spec, level = json.loads(open(sys.argv[1]).read()), sys.argv[2]
    feed = None
    if level == "feed":
        from ecu_monitor.config import load_config
        from ecu_monitor.runtime.publishers import LiveMonitor as Pipeline
        config = load_config(spec["config"])
        feed = Pipeline(config, config.load_params()).feed
    outputs = [[can.Message(arbitration_id=i, is_extended_id=e, data=bytes.fromhex(d)) for i, e, d in step]
               for step in spec["outputs"]]
    bus = can.Bus(**spec["bus"])
    bus.set_filters(spec["filters"])
    if not attach_kernel_filter(bus, spec["filters"]):
        sys.exit("no kernel filter")
    counts = {"in": 0, "out": 0}
    stop = threading.Event()

    def receive_only(recv):  # bare: python-can's bus.recv; socket: its select + recvmsg, no unpacking
        stopped = stop.is_set
        n = 0
        while not stopped():
            if recv(0.2) is not None:
                n += 1
        counts["in"] = n

    def with_sends():
        recv, stopped, clock, send = bus.recv, stop.is_set, time.monotonic, bus.send
        n = sent = j = 0
        next_s = None
        while not stopped():
            msg = recv(0.2)
            if msg is None:
                continue
            n += 1
            now = clock()
            if feed is not None:
                msg.timestamp = now
                feed(msg)
            if next_s is None:
                next_s = now
            while now >= next_s:  # the first frame after a step time sends that step's frames, as the daemon
                for frame in outputs[j % len(outputs)]:
                    send(frame, timeout=0.01)
                    sent += 1
                j += 1
                next_s += 0.02
        counts["in"], counts["out"] = n, sent

    if level in ("bare", "socket"):
        recv = bus.recv if level == "bare" else bus._multicast.recv
        thread = threading.Thread(target=receive_only, args=(recv,), daemon=True)
    else:
        thread = threading.Thread(target=with_sends, daemon=True)
    signal.signal(signal.SIGTERM, lambda *args: stop.set())
    gc.collect()
    gc.freeze()
    thread.start()
    print("ready", flush=True)
    while not stop.wait(1.0):
        pass
    thread.join()
    bus.shutdown()
    print(json.dumps(counts), flush=True)
    """
)

#: the measured process of the level daemon (argv: config): bench_latency's daemon process without its timing
#: wrappers, with the receive filters ``ecu-monitor run`` installs
_DAEMON = textwrap.dedent(
    """
    import signal, sys, json, threading, time, can
    from ecu_monitor.config import load_config
    from ecu_monitor.runtime.daemon import Daemon, DaemonSettings
    from ecu_monitor.runtime.publishers import LiveMonitor as Pipeline
    config = load_config(sys.argv[1])
    pipeline = Pipeline(config, config.load_params())
    daemon = Daemon(pipeline, lambda: can.Bus(**dict(config.bus)), settings=DaemonSettings(tick_s=3600.0),
                    receive_filters=pipeline.receive_filters())
    signal.signal(signal.SIGTERM, lambda *args: daemon.stop())
    def announce():
        while daemon.counters["bus_opens"] == 0:
            time.sleep(0.05)
        print("ready", flush=True)
    threading.Thread(target=announce, daemon=True).start()
    daemon.run()
    print(json.dumps({"in": daemon.counters["frames_in"], "out": daemon.counters["health_sent"]}), flush=True)
    """
)


#: the level timed (--timed): the daemon with its receive thread's parts timed (module docstring)
_TIMED = _DAEMON.replace(
    "signal.signal(signal.SIGTERM",
    textwrap.dedent(
        """
        spent = {"feed": 0.0, "advance_to": 0.0, "node": 0.0, "send": 0.0, "rehearse": 0.0}
        marks = []
        def wrap(obj, name, key, clock=time.thread_time):
            original = getattr(obj, name)
            def timed(*args):
                started = clock()
                try:
                    return original(*args)
                finally:
                    spent[key] += clock() - started
            setattr(obj, name, timed)
        wrap(pipeline, "feed", "feed")
        wrap(pipeline, "advance_to", "advance_to")
        wrap(pipeline, "rehearse", "rehearse")
        wrap(daemon, "_send_locked", "send")
        if getattr(pipeline, "_node", None) is not None:
            wrap(pipeline._node, "frames", "node")
            wrap(pipeline._node, "step_frames", "node")
        signal.signal(signal.SIGUSR1, lambda *args: marks.append(dict(spent)))
        """
    ).strip()
    + "\nsignal.signal(signal.SIGTERM",
).replace('"out": daemon.counters["health_sent"]}', '"out": daemon.counters["health_sent"], "marks": marks}')


def _sender(port: int, seconds: float, protocol: str) -> None:
    """Inside the namespace: the ECU frames of ``protocol`` for ``seconds`` (bench_latency_dronecan's senders)."""
    bus = can.Bus(interface="udp_multicast", channel=bench_latency.GROUP, port=port)
    counts = {"ecu": 0}
    make = bld._dronecan_sender if protocol == "dronecan" else bench_latency._ecu_sender
    ecu = bench_latency.Periodic(0.02, make(bus, [], counts))
    ecu.start()
    time.sleep(seconds)
    ecu.stop_event.set()
    ecu.join()
    bus.shutdown()
    print(json.dumps(counts), flush=True)


def _config(protocol: str, channel: str) -> Any:
    return bld._dronecan_config(channel) if protocol == "dronecan" else bench_latency._config(channel)


def offline(protocol: str, steps: int = 2000, keep: int = 500) -> dict[str, Any]:
    """The pipeline fed ``steps`` steps of ``protocol``'s ECU frames at the daemon's clock (one thread, warm):
    the frames it sends in the last ``keep`` steps, one list per step (id, extended, data hex), the filters it
    installs, and CPU us per second of feed, advance_to and the node's encoding over the last ``keep`` steps."""
    from ecu_monitor.runtime.publishers import LiveMonitor as Pipeline

    config = _config(protocol, "unused")
    pipeline = Pipeline(config, config.load_params())
    pipeline.warm_up()
    spent = {"feed": 0.0, "advance_to": 0.0, "node": 0.0}
    node = getattr(pipeline, "_node", None)
    if node is not None:  # the node's encoding, timed inside the steps
        for name in ("frames", "step_frames"):
            original = getattr(node, name)

            def timed(*args: Any, _original: Any = original) -> Any:
                started = time.thread_time()
                try:
                    return _original(*args)
                finally:
                    spent["node"] += time.thread_time() - started

            setattr(node, name, timed)
    outputs: list[list[tuple[int, bool, str]]] = []
    bursts = bld._frames_of(protocol, steps)
    for k, burst in enumerate(bursts):
        if k == steps - keep:
            spent = dict.fromkeys(spent, 0.0)
        sent: list[tuple[int, bool, str]] = []
        for i, msg in enumerate(burst):
            now = 1000.0 + 0.02 * (k + 1) + 1e-5 * i
            msg.timestamp = now
            started = time.thread_time()
            pipeline.feed(msg)
            fed = time.thread_time()
            frames = pipeline.advance_to(now)
            spent["feed"] += fed - started
            spent["advance_to"] += time.thread_time() - fed
            sent += [(f.arbitration_id, f.is_extended_id, bytes(f.data).hex()) for f in frames]
        if k >= steps - keep:
            outputs.append(sent)
    seconds = keep * 0.02
    return {
        "outputs": outputs,
        "filters": pipeline.receive_filters(),
        "frames_in_per_s": sum(len(b) for b in bursts[-keep:]) / seconds,
        "frames_out_per_s": sum(len(s) for s in outputs) / seconds,
        "us_per_s": {name: spent[name] / seconds * 1e6 for name in spent},
    }


def _cpu_ns(pid: int) -> dict[int, int]:
    """Run time, ns, of each thread of process ``pid`` (first field of /proc/<pid>/task/<tid>/schedstat)."""
    out = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        with contextlib.suppress(OSError, ValueError, IndexError):  # a thread that ended meanwhile
            out[int(tid)] = int(Path(f"/proc/{pid}/task/{tid}/schedstat").read_text().split()[0])
    return out


def run(seconds: float, repeat: int, levels: tuple[str, ...] = LEVELS) -> list[dict[str, dict[str, dict[str, Any]]]]:
    """``repeat`` rounds; each: every level of ``levels`` (or ``timed``), each as (dbc, dronecan, dbc').
    Returns rounds[level][case]."""
    port = 46000 + os.getpid() % 1000
    procs: list[subprocess.Popen[str]] = []
    rounds: list[dict[str, dict[str, dict[str, Any]]]] = []
    with multicast_namespace(bench_latency.GROUP, port, "bench_cpu_floor_dronecan") as space:
        ns = space.name
        bus = {"interface": "udp_multicast", "channel": bench_latency.GROUP, "port": port}
        data = bld._dronecan_data()
        data["bus"] = bus
        data["state_dir"] = str(space.tmp / "state-dronecan")
        dronecan_yaml = space.tmp / "dronecan.yaml"
        dronecan_yaml.write_text(yaml.safe_dump(data, sort_keys=False))
        configs = {"dbc": space.config, "dronecan": dronecan_yaml}
        specs = {}
        for protocol in ("dbc", "dronecan"):
            found = offline(protocol)
            spec = {"bus": bus, "config": str(configs[protocol]), **found}
            path = space.tmp / f"spec-{protocol}.json"
            path.write_text(json.dumps(spec))
            specs[protocol] = path
            print(
                f"offline {protocol}: {found['frames_in_per_s']:.0f} frames/s in, {found['frames_out_per_s']:.0f}"
                " sent; CPU us per s (warm, one thread): "
                + ", ".join(f"{name} {us:.0f}" for name, us in found["us_per_s"].items()),
                flush=True,
            )

        def start(argv: list[str]) -> subprocess.Popen[str]:
            proc = subprocess.Popen(["ip", "netns", "exec", ns, *argv], stdout=subprocess.PIPE, text=True)
            procs.append(proc)
            return proc

        try:
            traffic = start([sys.executable, "-c", bench_latency._TRAFFIC, bench_latency.GROUP, str(port), "10"])
            for r in range(repeat):
                results: dict[str, dict[str, dict[str, Any]]] = {}
                for level in levels:
                    results[level] = {}
                    for case, protocol in CASES:
                        if level in ("daemon", "timed"):
                            script = _TIMED if level == "timed" else _DAEMON
                            argv = [sys.executable, "-c", script, str(configs[protocol])]
                        else:
                            argv = [sys.executable, "-c", _RECEIVER, str(specs[protocol]), level]
                        peer = start(argv)
                        assert peer.stdout is not None
                        if peer.stdout.readline().strip() != "ready":
                            sys.exit(f"{level} {case}: the measured process did not start")
                        sender = start([sys.executable, __file__, "--send", str(port), str(seconds + WARM_S + 0.5),
                                        protocol])  # fmt: skip
                        time.sleep(WARM_S)
                        if level == "timed":
                            os.kill(peer.pid, signal.SIGUSR1)
                        before, wall = _cpu_ns(peer.pid), time.monotonic()
                        time.sleep(seconds)
                        if level == "timed":
                            os.kill(peer.pid, signal.SIGUSR1)
                        after, wall = _cpu_ns(peer.pid), time.monotonic() - wall
                        sent = json.loads(sender.communicate(timeout=60)[0].strip().splitlines()[-1])
                        peer.send_signal(signal.SIGTERM)
                        counts = json.loads(peer.communicate(timeout=30)[0].strip().splitlines()[-1])
                        threads = sorted((after[t] - before.get(t, 0) for t in after), reverse=True)
                        row = {
                            "cpu_pct": 100.0 * sum(threads) / 1e9 / wall,
                            "busiest_pct": 100.0 * threads[0] / 1e9 / wall,
                            "in": counts["in"],
                            "out": counts["out"],
                            "ecu": sent["ecu"],
                        }
                        if level == "timed":
                            start_mark, end_mark = counts["marks"][:2]
                            row["parts_pct"] = {
                                key: 100.0 * (end_mark[key] - start_mark[key]) / wall for key in start_mark
                            }
                        results[level][case] = row
                        print(
                            f"round {r + 1} {level:6s} {case:8s} CPU {row['cpu_pct']:5.2f} % (busiest thread "
                            f"{row['busiest_pct']:5.2f} %), ECU frames {row['ecu']} sent / {row['in']} received,"
                            f" {row['out']} sent"
                            + (
                                "; parts, % of a core: "
                                + ", ".join(f"{k} {v:.3f}" for k, v in row["parts_pct"].items())
                                if "parts_pct" in row
                                else ""
                            ),
                            flush=True,
                        )
                rounds.append(results)
            traffic.kill()
        finally:
            kill_all(procs)
    return rounds


def report(rounds: list[dict[str, dict[str, dict[str, Any]]]]) -> list[str]:
    """Per level: A/A band, DroneCAN/DBC ratio and DroneCAN - DBC difference; then the decomposition table."""
    lines = []
    med: dict[str, dict[str, float]] = {}
    for level in LEVELS:
        per = [r[level] for r in rounds]
        aa = [p["dbc'"]["cpu_pct"] / p["dbc"]["cpu_pct"] for p in per]
        spread = max(max(x, 1 / x) for x in aa)
        dbc = [math.sqrt(p["dbc"]["cpu_pct"] * p["dbc'"]["cpu_pct"]) for p in per]
        ratio = [p["dronecan"]["cpu_pct"] / d for p, d in zip(per, dbc, strict=True)]
        diff = [p["dronecan"]["cpu_pct"] - d for p, d in zip(per, dbc, strict=True)]
        aa_diff = [p["dbc'"]["cpu_pct"] - p["dbc"]["cpu_pct"] for p in per]
        med[level] = {
            "dbc": statistics.median(dbc),
            "dronecan": statistics.median(p["dronecan"]["cpu_pct"] for p in per),
            "diff": statistics.median(diff),
        }
        lines.append(
            f"{level:6s}: dbc {med[level]['dbc']:.2f} %, dronecan {med[level]['dronecan']:.2f} % (medians);"
            f" A/A dbc'/dbc {' '.join(f'{x:.2f}' for x in aa)} (band {1 / spread:.2f}-{spread:.2f},"
            f" dbc'-dbc {' '.join(f'{x:+.2f}' for x in aa_diff)} points); dronecan/dbc"
            f" {' '.join(f'{x:.2f}' for x in ratio)}, median {statistics.median(ratio):.2f};"
            f" dronecan-dbc {' '.join(f'{x:+.2f}' for x in diff)} points, median {med[level]['diff']:+.2f}"
        )
    parts = (
        ("python-can's select + recvmsg: system calls, kernel, wake-ups (socket)", "socket", None),
        ("+ python-can's unpacking: msgpack, checked Message, filter match (bare - socket)", "bare", "socket"),
        ("+ the daemon's sends (sends - bare)", "sends", "bare"),
        ("+ per-frame decoding, Pipeline.feed (feed - sends)", "feed", "sends"),
        ("+ dispatch, steps, node encoding, other threads (daemon - feed)", "daemon", "feed"),
    )
    lines.append("| part, % of a core (medians over the rounds) | DBC | DroneCAN | DroneCAN - DBC |")
    lines.append("|---|---|---|---|")
    for label, level, below in parts:
        cells = []
        for key in ("dbc", "dronecan", "diff"):
            value = med[level][key] - (med[below][key] if below else 0.0)
            cells.append(f"{value:+.2f}" if key == "diff" or below else f"{value:.2f}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines.append(
        f"| python-can receive floor (bare) | {med['bare']['dbc']:.2f} | {med['bare']['dronecan']:.2f} |"
        f" {med['bare']['diff']:+.2f} |"
    )
    lines.append(
        f"| the daemon process | {med['daemon']['dbc']:.2f} | {med['daemon']['dronecan']:.2f} |"
        f" {med['daemon']['diff']:+.2f} |"
    )
    share = med["bare"]["diff"] / med["daemon"]["diff"] if med["daemon"]["diff"] else math.nan
    lines.append(f"the floor's DroneCAN-DBC difference is {share:.0%} of the daemon's")
    return lines


def report_timed(rounds: list[dict[str, dict[str, dict[str, Any]]]]) -> list[str]:
    """--timed: per part of the daemon, % of a core, medians over the rounds (DBC: the geometric mean of its
    round's two runs), and DroneCAN - DBC."""

    def parts(row: dict[str, Any]) -> dict[str, float]:
        p = row["parts_pct"]
        steps = p["advance_to"] - p["node"]
        timed = p["feed"] + p["advance_to"] + p["send"] + p["rehearse"]
        return {
            "python-can recv + the daemon's dispatch (receive thread, untimed)": row["busiest_pct"] - timed,
            "Pipeline.feed (decoding)": p["feed"],
            "steps (advance_to without the node's encoding)": steps,
            "the node's encoding (DroneCanNode.frames, step_frames)": p["node"],
            "sends (Daemon._send_locked)": p["send"],
            "rehearsal": p["rehearse"],
            "other threads (supervisor)": row["cpu_pct"] - row["busiest_pct"],
            "the daemon process": row["cpu_pct"],
        }

    per = [r["timed"] for r in rounds]
    table = {case: [parts(p[case]) for p in per] for case, _ in CASES}
    lines = ["| part, % of a core (medians over the rounds) | DBC | DroneCAN | DroneCAN - DBC | DBC A/A (dbc' - dbc) |"]
    lines.append("|---|---|---|---|---|")
    for key in table["dbc"][0]:
        dbc = [(a[key] + b[key]) / 2 for a, b in zip(table["dbc"], table[bld.DBC2], strict=True)]
        dronecan = [x[key] for x in table["dronecan"]]
        diff = [d - c for d, c in zip(dronecan, dbc, strict=True)]
        aa = [b[key] - a[key] for a, b in zip(table["dbc"], table[bld.DBC2], strict=True)]
        lines.append(
            f"| {key} | {statistics.median(dbc):.3f} | {statistics.median(dronecan):.3f} |"
            f" {statistics.median(diff):+.3f} ({' '.join(f'{x:+.3f}' for x in diff)}) |"
            f" {' '.join(f'{x:+.3f}' for x in aa)} |"
        )
    return lines


def main() -> int:
    if len(sys.argv) == 5 and sys.argv[1] == "--send":
        _sender(int(sys.argv[2]), float(sys.argv[3]), sys.argv[4])
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n", 1)[0])
    parser.add_argument("--seconds", type=float, default=15.0, help="CPU window of each case")
    parser.add_argument("--repeat", type=int, default=3, help="rounds")
    parser.add_argument("--timed", action="store_true", help="the daemon alone, its receive thread's parts timed")
    args = parser.parse_args()
    if args.timed:
        for line in report_timed(run(args.seconds, args.repeat, ("timed",))):
            print(line)
        return 0
    for line in report(run(args.seconds, args.repeat)):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
