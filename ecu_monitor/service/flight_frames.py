"""The frames an ECU would have sent for a flight log: how a canonical flight CSV is replayed through the
same path as a CAN log (:func:`frames_from_flight`)."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.bus.canlog import GAP_S, FrameArrays
from ecu_monitor.bus.codec import Encoder
from ecu_monitor.errors import FlightLogError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.service.config import ServiceConfig


def frames_from_flight(log: FlightLog, config: ServiceConfig, required: Iterable[str] | None = None) -> FrameArrays:
    """The frames the ECU would have sent for a flight log: every message the config's inputs use, at
    its DBC cycle time (default 100 ms), carrying the latest row at or before the frame time
    (converted from the canonical unit to the signal's unit), other signals 0, counter and checksum.

    ``required``: the columns the log must hold (default: every mapped input but fuel flow); a mapped
    input the log lacks and the model does not need (throttle for a fuel-flow heat map) stays unsent.

    No frame is sent inside a hole of the log (rows more than :data:`~ecu_monitor.bus.canlog.GAP_S`
    apart): the ECU was silent there, so the replay sees the inputs go stale (and, past the
    pipeline's clock-restart limit, a new segment), and the frames are proportional to the data. A
    log of fewer than 2 rows is a FlightLogError.
    """
    if len(log) < 2:
        raise FlightLogError(f"{log.source}: at least 2 rows are needed to replay (the log has {len(log)})")
    encoder = Encoder(config.dbc_paths)
    by_message: dict[str, list[tuple[str, str]]] = {}
    for spec in config.inputs:
        if not log.has(spec.name):
            continue
        by_message.setdefault(spec.message, []).append((spec.signal, spec.name))
    needed = set(required) if required is not None else {s.name for s in config.inputs} - {"fuel_flow_lph"}
    missing = [spec.name for spec in config.inputs if not log.has(spec.name) and spec.name in needed]
    if missing:
        raise FlightLogError(f"{log.source}: missing column(s) {', '.join(missing)} mapped in {config.source}")
    t = log.time_s
    holes = np.flatnonzero(np.diff(t) > GAP_S)
    runs = list(zip([0, *(holes + 1).tolist()], [*holes.tolist(), t.size - 1], strict=True))  # rows [a, b]
    parts: list[tuple[NDArray[np.float64], int, int, bool, NDArray[np.uint8]]] = []
    for order, (name, signals) in enumerate(by_message.items()):
        message = encoder.message(name)
        cycle_s = (message.cycle_time or 100) / 1000.0
        stamps = np.concatenate(
            [t[a] + cycle_s * np.arange(math.floor((t[b] - t[a]) / cycle_s + 1e-9) + 1) for a, b in runs]
        )
        count = stamps.size
        rows = np.searchsorted(t, stamps + 1e-9, side="right") - 1
        columns = {}
        for signal, column in signals:
            unit = config.input(column).signal_spec().conversion()
            columns[signal] = unit.from_canonical(np.asarray(log[column], dtype=float)[rows])
        data = np.zeros((count, 8), dtype=np.uint8)
        payloads = encoder.encode_rows(name, {**{sig.name: np.zeros(count) for sig in message.signals}, **columns})
        data[:, : message.length] = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(count, message.length)
        parts.append((stamps, order, int(message.frame_id), bool(message.is_extended_frame), data))
    time_s = np.concatenate([p[0] for p in parts])
    order_key = np.concatenate([np.full(p[0].size, p[1]) for p in parts])
    sort = np.lexsort((order_key, time_s))
    ids = np.concatenate([np.full(p[0].size, p[2]) for p in parts])
    ext = np.concatenate([np.full(p[0].size, p[3]) for p in parts])
    data = np.concatenate([p[4] for p in parts])
    lengths = np.concatenate(
        [np.full(p[0].size, encoder.message(n).length) for n, p in zip(by_message, parts, strict=True)]
    )
    return FrameArrays(time_s[sort], ids[sort].astype(np.int64), ext[sort], lengths[sort].astype(np.int64),
                       data[sort], np.zeros(time_s.size, dtype=bool))  # fmt: skip
