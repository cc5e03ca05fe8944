"""Processes in a network namespace of their own: loopback only, multicast routed to ``lo``.

Each namespace has its own network stack, so tests in different namespaces may use the same multicast
group and ports at the same time (the suite runs them in parallel). Needs root and ``ip netns``.
"""

from __future__ import annotations

import contextlib
import functools
import os
import shutil
import subprocess
import tempfile
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path


@functools.cache
def netns_unavailable() -> str | None:
    """Why this host cannot run the namespace tests, or None when it can (asked once per process)."""
    if os.geteuid() != 0:
        return "needs root to create a network namespace (ip netns add)"
    if shutil.which("ip") is None:
        return "iproute2 'ip' command not found (apt-get install iproute2)"
    probe = f"ecu-probe-{uuid.uuid4().hex[:8]}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True, timeout=10)
    if made.returncode != 0:
        return f"ip netns add failed here: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "delete", probe], capture_output=True, timeout=10)
    try:
        import msgpack  # noqa: F401  (python-can's udp_multicast needs it)
    except ImportError:
        return "python-can's udp_multicast interface needs the msgpack package"
    return None


@dataclass
class Namespace:
    """A network namespace with only loopback, multicast routed to lo; its processes die with it."""

    name: str = field(default_factory=lambda: f"ecu-test-{uuid.uuid4().hex[:10]}")
    procs: list[subprocess.Popen[str]] = field(default_factory=list)
    tmp: Path = field(default_factory=lambda: Path(tempfile.mkdtemp(prefix="ecu-ns-")))

    def create(self) -> None:
        subprocess.run(["ip", "netns", "add", self.name], check=True, timeout=10)
        subprocess.run(["ip", "-n", self.name, "link", "set", "lo", "up"], check=True, timeout=10)
        subprocess.run(["ip", "-n", self.name, "route", "add", "224.0.0.0/4", "dev", "lo"], check=True, timeout=10)

    def popen(self, args: list[str], env: dict[str, str] | None = None) -> subprocess.Popen[str]:
        proc = subprocess.Popen(
            ["ip", "netns", "exec", self.name, *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
        )
        self.procs.append(proc)
        return proc

    def close(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.kill()
            with contextlib.suppress(subprocess.TimeoutExpired, ValueError):
                proc.communicate(timeout=10)
        subprocess.run(["ip", "netns", "delete", self.name], capture_output=True, timeout=10)
        shutil.rmtree(self.tmp, ignore_errors=True)


class Lines:
    """Collects a process's stdout lines in a thread."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.lines: list[str] = []
        assert proc.stdout is not None
        stream = proc.stdout
        self._thread = threading.Thread(target=lambda: self.lines.extend(iter(stream.readline, "")), daemon=True)
        self._thread.start()

    def wait_for(self, predicate: Callable[[list[str]], bool], timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if predicate(self.lines):
                return True
            time.sleep(0.05)
        return predicate(self.lines)
