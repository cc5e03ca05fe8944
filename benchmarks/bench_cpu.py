"""CPU use of the daemon at 50 Hz in steady state, against an idle python-can Notifier process.

    sudo .venv/bin/python benchmarks/bench_cpu.py [--warmup 10] [--seconds 20] [--traffic 4000]

Everything runs inside a network namespace made for the run (loopback only, multicast routed to lo,
deleted at the end), on python-can's udp_multicast interface:

* the virtual ECU, ``virtual-ecu run --mission default --realtime`` (ECU_Fast 50 Hz, ECU_Slow and
  AirData 10 Hz: 70 frames/s);
* the daemon, ``ecu-monitor run --config ...`` (the shipped example.yaml on that bus, state in a temp dir);
* the baseline: a process with a python-can Notifier on the same bus and a listener that does nothing;
* the same idle Notifier with the ECU's ids as a kernel socket filter
  (:func:`ecu_monitor.bus.kernel_filter.attach_kernel_filter`, which the daemon attaches on udp_multicast);
* with ``--traffic N``: one more process sending N frames/s of other ids (0x400-0x7FF, bursts every
  2.5 ms, as ``bench_latency.py``). udp_multicast itself has no kernel filter: the plain idle Notifier
  receives and unpacks every one of them before python-can's id filter drops them; the daemon and the
  filtered Notifier have them dropped by their socket filter in the kernel (as socketcan would).

After ``--warmup`` seconds, utime + stime of each process are read from /proc/<pid>/stat at the start and
the end of ``--seconds``; CPU % = (delta ticks / CLK_TCK) / wall seconds * 100 (100 % = one core).
Needs root (ip netns).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

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
    bus = can.Bus(interface="udp_multicast", channel=sys.argv[1], port=int(sys.argv[2]))
    filters = [{"can_id": i, "can_mask": 0x1FFFFFFF} for i in (0x100, 0x101, 0x200)]  # the ECU's ids
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--warmup", type=float, default=10.0)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--traffic", type=float, default=0.0, help="other frames per second on the bus")
    args = parser.parse_args()
    port = 43000 + os.getpid() % 1000
    procs: dict[str, subprocess.Popen[bytes]] = {}
    with multicast_namespace(GROUP, port, "bench_cpu") as space:
        ns, config = space.name, space.config
        try:

            def start(name: str, argv: list[str]) -> None:
                out = subprocess.PIPE if name == "other traffic" else subprocess.DEVNULL
                procs[name] = subprocess.Popen(
                    ["ip", "netns", "exec", ns, *argv], stdout=out, stderr=subprocess.DEVNULL
                )

            def traffic_sent() -> int:
                proc = procs.get("other traffic")
                if proc is None or proc.stdout is None:
                    return 0
                proc.send_signal(signal.SIGUSR1)
                return int(proc.stdout.readline())

            python = sys.executable
            start("daemon (ecu-monitor run)", [python, "-m", "ecu_monitor.cli", "run", "--config", str(config)])
            start("baseline: idle Notifier", [python, "-c", _IDLE_NOTIFIER, GROUP, str(port)])
            start(
                "idle Notifier, ECU ids filtered in the kernel",
                [python, "-c", _IDLE_NOTIFIER_KERNEL_FILTER, GROUP, str(port)],
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
    usage = {name: (after[name] - before[name]) / wall * 100.0 for name in before}
    print(
        f"udp_multicast in a network namespace, {wall:.1f} s after {args.warmup:g} s warm-up, other traffic "
        f"{args.traffic:g} frames/s asked, {traffic_hz:.0f} sent, load {load:.1f}\n"
    )
    print("| process | CPU, % of one core |")
    print("|---|---|")
    for name, value in usage.items():
        print(f"| {name} | {value:.2f} |")
    daemon = usage["daemon (ecu-monitor run)"]
    baseline = usage["baseline: idle Notifier"]
    print(
        f"\ndaemon / idle Notifier: {daemon / baseline:.1f}x; daemon - idle Notifier: {daemon - baseline:.2f} % points"
    )
    print(f"target < 3 % of one core (issue 13): {'met' if daemon < 3.0 else 'NOT met'}")


if __name__ == "__main__":
    main()
