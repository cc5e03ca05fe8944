"""A MAVLink link as the daemon uses a bus: ``recv(timeout)`` gives the next pymavlink message (or None),
``send(msg)`` packs one of the service's messages with its own system and component ids, ``shutdown()``
closes the link. The link is a connection string as MAVProxy takes it (bus/mavlink.py,
``open_connection``); the service's messages go back over it, or over ``mavlink.output`` when set."""

from __future__ import annotations

import contextlib
import threading
import time
from typing import Any

from ecu_monitor.bus.mavlink import open_connection
from ecu_monitor.bus.mavlink_settings import MavlinkSettings

__all__ = ["MavlinkLink"]


class MavlinkLink:
    """The daemon's "bus" on ``protocol: mavlink`` (module docstring)."""

    def __init__(self, settings: MavlinkSettings) -> None:
        self.settings = settings
        self._in = open_connection(settings.connection, source_system=settings.system_id,
                                   source_component=settings.component_id)  # fmt: skip
        self._out = (
            open_connection(settings.output, source_system=settings.system_id, source_component=settings.component_id)
            if settings.output
            else self._in
        )
        self._send_lock = threading.Lock()
        self.channel_info = f"MAVLink {settings.connection}" + (f" -> {settings.output}" if settings.output else "")

    def recv(self, timeout: float | None = None) -> Any:
        """The next message within ``timeout`` s (None: none came); bytes that are not a message are the
        decoder's business (the parser skips them)."""
        deadline = time.monotonic() + (timeout or 0.0)
        while True:
            msg = self._in.recv_msg()
            if msg is not None:
                return None if msg.get_type() == "BAD_DATA" else msg
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                return None
            self._in.select(min(remaining, 0.05))

    def send(self, msg: Any, timeout: float | None = None) -> None:
        """Pack ``msg`` (a pymavlink message) with the service's ids and sequence, and write it."""
        del timeout
        with self._send_lock:
            self._out.mav.send(msg, force_mavlink1=self.settings.mavlink1)

    def set_filters(self, filters: Any) -> None:
        """Nothing to filter in the kernel: the decoder filters by message type and sender."""
        del filters

    def shutdown(self) -> None:
        """Close the link (idempotent)."""
        for link in {id(self._in): self._in, id(self._out): self._out}.values():
            with contextlib.suppress(OSError):
                link.close()
