"""The DroneCAN LogMessages a node published, decoded: what the service told, as (level, text)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import dronecan


def log_messages(frames: Iterable[Any]) -> list[tuple[int, str]]:
    """(level, text) of each ``uavcan.protocol.debug.LogMessage`` transfer the python-can ``frames`` carry."""
    manager = dronecan.transport.TransferManager()
    logs = []
    for msg in frames:
        done = manager.receive_frame(dronecan.transport.Frame(msg.arbitration_id, msg.data))
        if done:
            transfer = dronecan.transport.Transfer()
            transfer.from_frames(done)
            payload = transfer.payload
            if dronecan.get_dronecan_data_type(payload).full_name.endswith("LogMessage"):
                logs.append((payload.level.value, payload.text.decode()))
    return logs
