"""A throwaway network namespace with the service config on udp_multicast, for the benchmarks that
run the daemon as a separate process (bench_cpu, bench_latency --netns).

Loopback only, multicast routed to lo so it never leaves the namespace; the namespace and the temp
directory are deleted on exit. Needs root and iproute2.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import uuid
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class MulticastNamespace:
    """name: the namespace; config: service YAML on the namespace's multicast bus; tmp: scratch dir."""

    name: str
    config: Path
    tmp: Path


@contextmanager
def multicast_namespace(group: str, port: int, why: str) -> Iterator[MulticastNamespace]:
    """Create the namespace and the shipped example.yaml rewritten onto ``udp_multicast`` group:port."""
    if os.geteuid() != 0 or shutil.which("ip") is None:
        sys.exit(f"{why} needs root and iproute2 (ip netns) to keep multicast inside a namespace")
    name = f"ecu-bench-{uuid.uuid4().hex[:8]}"
    tmp = Path(tempfile.mkdtemp(prefix="ecu-bench-"))
    data = yaml.safe_load((REPO / "ecu_monitor" / "data" / "configs" / "example.yaml").read_text())
    data["dbc"] = [str(REPO / "ecu_monitor" / "data" / "dbc" / "engine.dbc")]
    data["health_dbc"] = str(REPO / "ecu_monitor" / "data" / "dbc" / "health.dbc")
    data["bus"] = {"interface": "udp_multicast", "channel": group, "port": port}
    data["state_dir"] = str(tmp / "state")
    config = tmp / "service.yaml"
    config.write_text(yaml.safe_dump(data, sort_keys=False))
    try:
        subprocess.run(["ip", "netns", "add", name], check=True)
        subprocess.run(["ip", "-n", name, "link", "set", "lo", "up"], check=True)
        subprocess.run(["ip", "-n", name, "route", "add", "224.0.0.0/4", "dev", "lo"], check=True)
        yield MulticastNamespace(name, config, tmp)
    finally:
        subprocess.run(["ip", "netns", "delete", name], capture_output=True)
        shutil.rmtree(tmp, ignore_errors=True)


def kill_all(procs: Sequence[subprocess.Popen[str]]) -> None:
    """Kill each of ``procs`` still running and reap them all: the cleanup of a benchmark's helper processes."""
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=10)
