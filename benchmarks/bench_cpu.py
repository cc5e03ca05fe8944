"""CPU use of the daemon at 50 Hz in steady state with other traffic on the bus, against idle python-can
Notifier processes on the same bus.

    sudo .venv/bin/python benchmarks/bench_cpu.py [--warmup 10] [--seconds 20] [--traffic 4000] [--protocol dbc] \
        [--events on|off]

Everything runs inside a network namespace made for the run (loopback only, multicast routed to lo,
deleted at the end), on python-can's udp_multicast interface:

* the daemon, ``ecu-monitor run --config ...`` (the shipped example.yaml, or with ``--protocol dronecan``
  dronecan.yaml, on that bus, state in a temp dir); the others start once it has sent systemd's READY=1
  (``NOTIFY_SOCKET``: after its compiled code is loaded, or compiled on a fresh install);
* the virtual ECU, ``virtual-ecu run --mission default --realtime`` on the same config (DBC: ECU_Fast
  50 Hz, ECU_Slow and AirData 10 Hz; DroneCAN: the ICE status and the three air-data messages at 10 Hz);
* the baseline: a process with a python-can Notifier on the same bus and a listener that does nothing;
* the same idle Notifier with the daemon's receive filters in the kernel
  (:func:`ecu_monitor.bus.kernel_filter.attach_kernel_filter`, which the daemon attaches on udp_multicast);
* ``--traffic N`` (default 4,000, issue 25's figure): one more process sending N frames/s of other ids
  (0x400-0x7FF, bursts every 2.5 ms, as ``bench_latency.py``). udp_multicast itself has no kernel filter: the
  plain idle Notifier receives and unpacks every one of them before python-can's id filter drops them; the
  daemon and the filtered Notifier have them dropped by their socket filter in the kernel (as socketcan would).

``--events off`` runs the daemon with ``events: {enabled: false}`` (the engine events off; default on, as
shipped), to measure what the events cost.

After ``--warmup`` seconds, utime + stime of each process are read from /proc/<pid>/stat at the start and
the end of ``--seconds``; CPU % = (delta ticks / CLK_TCK) / wall seconds * 100 (100 % = one core).
Needs root (ip netns).
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import yaml
from netns import kill_all, multicast_namespace

REPO = Path(__file__).resolve().parent.parent
GROUP = "239.74.163.2"

_TRAFFIC = textwrap.dedent(
    """
    import random, signal, sys, time, can
    bus = can.Bus(interface="udp_multicast", channel=sys.argv[1], port=int(sys.argv[2]))
    per_burst, rng = int(sys.argv[3]), random.Random(4000)
    frames = [can.Message(arbitration_id=rng.randrange(0x400, 0x800), is_extended_id=False, data=rng.randbytes(8))
              for _ in range(1000)]
    k, next_s = 0, time.perf_counter()
    signal.signal(signal.SIGUSR1, lambda *args: print(k * per_burst, flush=True))  # frames sent so far
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

_IDLE_NOTIFIER = textwrap.dedent(
    """
    import sys, threading, can
    bus = can.Bus(interface="udp_multicast", channel=sys.argv[1], port=int(sys.argv[2]))
    notifier = can.Notifier(bus, [lambda msg: None], timeout=1.0)
    threading.Event().wait()
    """
)

_IDLE_NOTIFIER_KERNEL_FILTER = textwrap.dedent(
    """
    import sys, threading, can
    from ecu_monitor.bus.kernel_filter import attach_kernel_filter
    from ecu_monitor.config import load_config
    from ecu_monitor.runtime.publishers import LiveMonitor
    config = load_config(sys.argv[3])
    filters = LiveMonitor(config, config.load_cylinder_params()).receive_filters()  # the daemon's
    bus = can.Bus(interface="udp_multicast", channel=sys.argv[1], port=int(sys.argv[2]))
    bus.set_filters(filters)
    assert attach_kernel_filter(bus, filters)
    notifier = can.Notifier(bus, [lambda msg: None], timeout=1.0)
    threading.Event().wait()
    """
)


def cpu_seconds(pid: int) -> float:
    """utime + stime of a process, s (fields 14 and 15 of /proc/<pid>/stat)."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    fields = stat[stat.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def wait_ready(notify: socket.socket, daemon: subprocess.Popen[bytes], limit_s: float = 300.0) -> None:
    """Wait for the daemon's READY=1 on ``notify`` (its NOTIFY_SOCKET); exit if it ends or takes over ``limit_s``."""
    deadline = time.monotonic() + limit_s
    while daemon.poll() is None and time.monotonic() < deadline:
        try:
            if b"READY=1" in notify.recv(4096):
                return
        except TimeoutError:
            continue
    sys.exit(f"the daemon did not send READY=1 (exit code {daemon.poll()})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--warmup", type=float, default=10.0)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--traffic", type=float, default=4000.0, help="other frames per second on the bus")
    parser.add_argument("--protocol", choices=("dbc", "dronecan"), default="dbc")
    parser.add_argument("--events", choices=("on", "off"), default="on", help="the engine events (default on)")
    args = parser.parse_args()
    port = 43000 + os.getpid() % 1000
    procs: dict[str, subprocess.Popen[bytes]] = {}
    with multicast_namespace(GROUP, port, "bench_cpu", args.protocol) as space:
        ns, config = space.name, space.config
        if args.events == "off":
            data = yaml.safe_load(config.read_text(encoding="utf-8"))
            config.write_text(yaml.safe_dump({**data, "events": {"enabled": False}}, sort_keys=False))
        notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        notify.bind(str(space.tmp / "notify"))  # a path, not an abstract name: those are per network namespace
        notify.settimeout(1.0)
        try:

            def start(name: str, argv: list[str], env: dict[str, str] | None = None) -> None:
                out = subprocess.PIPE if name == "other traffic" else subprocess.DEVNULL
                procs[name] = subprocess.Popen(
                    ["ip", "netns", "exec", ns, *argv], stdout=out, stderr=subprocess.DEVNULL, env=env
                )

            def traffic_sent() -> int:
                proc = procs.get("other traffic")
                if proc is None or proc.stdout is None:
                    return 0
                proc.send_signal(signal.SIGUSR1)
                return int(proc.stdout.readline())

            python = sys.executable
            env = {**os.environ, "NOTIFY_SOCKET": str(space.tmp / "notify")}
            start("daemon (ecu-monitor run)", [python, "-m", "ecu_monitor.cli", "run", "--config", str(config)], env)
            wait_ready(notify, procs["daemon (ecu-monitor run)"])
            start("baseline: idle Notifier", [python, "-c", _IDLE_NOTIFIER, GROUP, str(port)])
            start(
                "idle Notifier, the daemon's filters in the kernel",
                [python, "-c", _IDLE_NOTIFIER_KERNEL_FILTER, GROUP, str(port), str(config)],
            )
            time.sleep(3.0)
            if args.traffic > 0:
                start("other traffic", [python, "-c", _TRAFFIC, GROUP, str(port), str(round(args.traffic * 0.0025))])
            start("virtual ECU (emitter)", [python, "-m", "virtual_bus.cli", "run", "--config", str(config),
                                            "--mission", "default", "--realtime"])  # fmt: skip
            time.sleep(args.warmup)
            for name, proc in procs.items():
                if proc.poll() is not None:
                    sys.exit(f"{name} exited early with {proc.returncode}")
            before = {name: cpu_seconds(proc.pid) for name, proc in procs.items()}
            sent_before = traffic_sent()
            start_s = time.monotonic()
            time.sleep(args.seconds)
            wall = time.monotonic() - start_s
            after = {name: cpu_seconds(proc.pid) for name, proc in procs.items()}
            traffic_hz = (traffic_sent() - sent_before) / wall
            load = os.getloadavg()[0]
        finally:
            kill_all(list(procs.values()))
            notify.close()
    usage = {name: (after[name] - before[name]) / wall * 100.0 for name in before}
    print(
        f"udp_multicast in a network namespace, {args.protocol}, events {args.events}, {wall:.1f} s after"
        f" {args.warmup:g} s warm-up, "
        f"other traffic {args.traffic:g} frames/s asked, {traffic_hz:.0f} sent, load {load:.1f}\n"
    )
    print("| process | CPU, % of one core |")
    print("|---|---|")
    for name, value in usage.items():
        print(f"| {name} | {value:.2f} |")
    daemon = usage["daemon (ecu-monitor run)"]
    floor = usage["idle Notifier, the daemon's filters in the kernel"]
    print(f"\ndaemon - idle Notifier with the daemon's kernel filters: {daemon - floor:.2f} % points of a core")
    verdict = "met" if daemon < 3.0 else "NOT met"
    print(f"target < 3 % of one core at 4,000 frames/s of other traffic (issue 25): {verdict} at {traffic_hz:.0f}/s")


if __name__ == "__main__":
    main()
