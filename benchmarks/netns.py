"""A throwaway network namespace with the service config on udp_multicast, for the benchmarks that
run the daemon as a separate process (bench_cpu, bench_latency).

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
from typing import Any

import yaml

REPO = Path(__file__).resolve().parent.parent
DATA = REPO / "ecu_monitor" / "data"


@dataclass(frozen=True)
class MulticastNamespace:
    """name: the namespace; config: service YAML on the namespace's multicast bus; tmp: scratch dir."""

    name: str
    config: Path
    tmp: Path


def service_config(
    protocol: str, bus: dict[str, Any], state_dir: Path, dbc_health_frames: bool = False
) -> dict[str, Any]:
    """The shipped example.yaml (protocol dbc) or dronecan.yaml on ``bus``, its DBC paths absolute, state in
    ``state_dir``; ``dbc_health_frames``: a DroneCAN node that also sends the health.dbc frames."""
    data: dict[str, Any] = yaml.safe_load(
        (DATA / "configs" / f"{'dronecan' if protocol == 'dronecan' else 'example'}.yaml").read_text()
    )
    if "dbc" in data:
        data["dbc"] = [str(DATA / "dbc" / "engine.dbc")]
    data["health_dbc"] = str(DATA / "dbc" / "health.dbc")
    if dbc_health_frames:
        data["dronecan"]["dbc_health_frames"] = True
    data["bus"] = bus
    data["state_dir"] = str(state_dir)
    return data


@contextmanager
def multicast_namespace(
    group: str, port: int, why: str, protocol: str = "dbc", dbc_health_frames: bool = False
) -> Iterator[MulticastNamespace]:
    """Create the namespace and :func:`service_config` of ``protocol`` on ``udp_multicast`` group:port."""
    if os.geteuid() != 0 or shutil.which("ip") is None:
        sys.exit(f"{why} needs root and iproute2 (ip netns) to keep multicast inside a namespace")
    name = f"ecu-bench-{uuid.uuid4().hex[:8]}"
    tmp = Path(tempfile.mkdtemp(prefix="ecu-bench-"))
    bus = {"interface": "udp_multicast", "channel": group, "port": port}
    config = tmp / "service.yaml"
    data = service_config(protocol, bus, tmp / "state", dbc_health_frames)
    config.write_text(yaml.safe_dump(data, sort_keys=False))
    try:
        subprocess.run(["ip", "netns", "add", name], check=True)
        subprocess.run(["ip", "-n", name, "link", "set", "lo", "up"], check=True)
        subprocess.run(["ip", "-n", name, "route", "add", "224.0.0.0/4", "dev", "lo"], check=True)
        yield MulticastNamespace(name, config, tmp)
    finally:
        subprocess.run(["ip", "netns", "delete", name], capture_output=True)
        shutil.rmtree(tmp, ignore_errors=True)


def kill_all(procs: Sequence[subprocess.Popen[Any]]) -> None:
    """Kill each of ``procs`` still running and reap them all: the cleanup of a benchmark's helper processes."""
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=10)
