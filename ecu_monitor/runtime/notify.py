"""systemd's sd_notify protocol over ``NOTIFY_SOCKET`` with the standard library socket.

The protocol (sd_notify(3)): newline-separated ``KEY=VALUE`` assignments sent as one datagram to the
unix socket named by ``NOTIFY_SOCKET``. A name starting with ``@`` is in the Linux abstract namespace
(the ``@`` stands for a leading NUL byte). ``WATCHDOG_USEC`` (microseconds) is the service's watchdog
timeout; ``WATCHDOG_PID``, when set, names the process that must ping. systemd recommends pinging at half
the timeout.

Outside systemd (no ``NOTIFY_SOCKET``) every call is a no-op that returns False, so the daemon runs the
same way from a terminal. Sends never block (a unix datagram queue holds only ~10 unread messages; a
receiver that stops reading would otherwise stall the caller), and a failed send is logged and counted,
never fatal: the notify channel going away must not take the engine monitor down with it (systemd then
restarts us on the watchdog, which is right).

``WatchdogGate`` implements the rule "WATCHDOG=1 only while the pipeline makes progress": a ping is due
when the ping period has passed AND the progress counter grew since the last ping.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

__all__ = ["SystemdNotifier", "WatchdogGate", "watchdog_period_s"]

_log = logging.getLogger(__name__)


def _socket_address(name: str) -> str | bytes:
    """Translate a ``NOTIFY_SOCKET`` value into an ``AF_UNIX`` address (``@`` -> abstract namespace)."""
    if name.startswith("@"):
        return b"\0" + name[1:].encode()
    return name


def watchdog_period_s(environ: Mapping[str, str] | None = None) -> float | None:
    """Ping period in seconds (half of ``WATCHDOG_USEC``), or None when no watchdog is set for us.

    None also when ``WATCHDOG_PID`` names another process or the value is not a positive integer.
    """
    env = os.environ if environ is None else environ
    usec_text = env.get("WATCHDOG_USEC", "").strip()
    if not usec_text:
        return None
    pid_text = env.get("WATCHDOG_PID", "").strip()
    if pid_text and pid_text != str(os.getpid()):
        return None
    try:
        usec = int(usec_text)
    except ValueError:
        _log.warning("ignoring WATCHDOG_USEC=%r: not an integer", usec_text)
        return None
    if usec <= 0:
        return None
    return usec / 1e6 / 2.0


class SystemdNotifier:
    """Sender of sd_notify datagrams; a no-op when ``NOTIFY_SOCKET`` is unset.

    ``address`` overrides ``NOTIFY_SOCKET`` (tests). ``sent`` and ``send_errors`` count datagrams.
    Use as a context manager or call ``close()`` (idempotent).
    """

    def __init__(self, address: str | None = None) -> None:
        name = os.environ.get("NOTIFY_SOCKET", "") if address is None else address
        self.address: str | bytes | None = _socket_address(name) if name else None
        self.sent = 0
        self.send_errors = 0
        self._sock: socket.socket | None = None
        if self.address is not None:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.setblocking(False)  # a receiver that stops reading must never stall the daemon

    @property
    def enabled(self) -> bool:
        """True when there is a socket to notify."""
        return self._sock is not None

    def notify(self, *assignments: str) -> bool:
        """Send ``KEY=VALUE`` assignments in one datagram; True when it was sent."""
        if self._sock is None or self.address is None:
            return False
        for item in assignments:
            if "=" not in item or "\n" in item:
                raise ValueError(f"sd_notify assignment must be one KEY=VALUE line, got {item!r}")
        payload = "\n".join(assignments).encode()
        try:
            self._sock.sendto(payload, self.address)
        except OSError as exc:
            self.send_errors += 1
            _log.warning("sd_notify to %r failed: %s", self.address, exc)
            return False
        self.sent += 1
        return True

    def ready(self, status: str | None = None) -> bool:
        """``READY=1`` (with an optional ``STATUS=``): start-up finished."""
        return self.notify("READY=1", *self._status(status))

    def status(self, text: str) -> bool:
        """``STATUS=text``: one line shown by ``systemctl status``."""
        return self.notify(*self._status(text))

    def watchdog(self) -> bool:
        """``WATCHDOG=1``: keep-alive ping."""
        return self.notify("WATCHDOG=1")

    def stopping(self, status: str | None = None) -> bool:
        """``STOPPING=1``: the service is shutting down."""
        return self.notify("STOPPING=1", *self._status(status))

    @staticmethod
    def _status(text: str | None) -> tuple[str, ...]:
        if text is None:
            return ()
        return ("STATUS=" + " ".join(text.split()),)

    def close(self) -> None:
        """Close the socket (idempotent)."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> SystemdNotifier:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


class WatchdogGate:
    """Decide when a watchdog ping is due: every ``period_s`` and only if ``progress`` grew since the last.

    ``period_s=None`` means no watchdog: ``due`` is always False.
    """

    def __init__(self, period_s: float | None) -> None:
        self.period_s = period_s
        self._last_ping_s: float | None = None
        self._last_progress: int | None = None

    def due(self, now_s: float, progress: int) -> bool:
        """True when a ping should be sent now; records the ping when it returns True."""
        if self.period_s is None:
            return False
        if self._last_ping_s is not None and now_s - self._last_ping_s < self.period_s:
            return False
        if self._last_progress is not None and progress <= self._last_progress:
            return False
        self._last_ping_s = now_s
        self._last_progress = progress
        return True
