"""The frames an ECU would have sent for a flight log: how a canonical flight CSV is replayed through the
same path as a CAN log (:func:`frames_from_flight`)."""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.bus.canlog import GAP_S, FrameArrays
from ecu_monitor.bus.codec import Encoder
from ecu_monitor.config import ServiceConfig
from ecu_monitor.errors import FlightLogError
from ecu_monitor.flightlog import FlightLog

_log = logging.getLogger(__name__)

#: (flight, column, range) already warned about by :func:`_warn_clipped`: calibrate replays a flight once per
#: cylinder and per overlay, and one warning per flight says it all.
_CLIPPED_WARNED: set[tuple[str, str, float, float]] = set()


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

    With ``protocol: dronecan`` the frames are DroneCAN transfers instead (:func:`dronecan_frames_from_flight`).
    """
    if len(log) < 2:
        raise FlightLogError(f"{log.source}: at least 2 rows are needed to replay (the log has {len(log)})")
    if config.protocol == "dronecan":
        return dronecan_frames_from_flight(log, config, required)
    encoder = Encoder(config.dbc_paths)
    by_message: dict[str, list[tuple[str, str]]] = {}
    for spec in config.inputs:
        if not log.has(spec.name):
            continue
        by_message.setdefault(spec.message, []).append((spec.signal, spec.name))
    needed = set(required) if required is not None else {s.name for s in config.inputs} - {"fuel_flow_lph"}
    missing = [spec.name for spec in config.inputs if not log.has(spec.name) and spec.name in needed]
    if missing:
        raise _missing_columns(log, missing, config)
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
            _warn_clipped(log, column, name, message.get_signal_by_name(signal), unit.from_canonical(log[column]))
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


#: DroneCAN: every mapped message is sent at this period, s (the virtual ECU's 10 Hz).
DRONECAN_PERIOD_S = 0.1
#: DroneCAN: the node the frames of a flight log come from when the config accepts any node.
DRONECAN_SOURCE_NODE = 20


def dronecan_frames_from_flight(
    log: FlightLog, config: ServiceConfig, required: Iterable[str] | None = None
) -> FrameArrays:
    """The DroneCAN frames an engine and an air-data node would have sent for a flight log: each message
    type the config's inputs use, every :data:`DRONECAN_PERIOD_S` (outside the log's holes), its mapped
    fields from the latest row (converted back from the canonical unit; a pressure altitude back to
    its standard pressure), every other float field NaN (DSDL: unknown), sent by the first of
    ``dronecan.source_node_ids`` (else node :data:`DRONECAN_SOURCE_NODE`) through the one DroneCAN
    encoder. An array element named by a reduction (``cylinder_status[mean]``) is element 0, unless a
    column the log carries names elements of that array itself (``cht1_c`` -> ``cylinder_status[0]``).
    ``required`` as for :func:`frames_from_flight`.
    """
    from ecu_monitor.bus.dronecan import DroneCanEncoder, parse_field
    from ecu_monitor.units import standard_pressure_kpa

    needed = set(required) if required is not None else {s.name for s in config.inputs} - {"fuel_flow_lph"}
    missing = [spec.name for spec in config.inputs if not log.has(spec.name) and spec.name in needed]
    if missing:
        raise _missing_columns(log, missing, config)
    sources = config.dronecan.source_node_ids
    encoder = DroneCanEncoder(sources[0] if sources else DRONECAN_SOURCE_NODE)
    by_type: dict[str, list[tuple[tuple[str | int, ...], np.ndarray]]] = {}
    explicit: set[tuple[str, tuple[str | int, ...]]] = set()  # arrays whose elements a present column names
    for spec in config.inputs:
        if not log.has(spec.name):
            continue
        path = parse_field(f"{spec.message}.{spec.signal}")
        unit = spec.signal_spec().conversion()
        column = np.asarray(log[spec.name], dtype=float)
        if unit.quantity == "pressure" and spec.name == "altitude_m":
            column = standard_pressure_kpa(column)
        by_type.setdefault(path.type_name, []).append((path.steps, unit.from_canonical(column)))
        for i, step in enumerate(path.steps):
            if isinstance(step, int):
                explicit.add((path.type_name, path.steps[:i]))
    t = log.time_s
    holes = np.flatnonzero(np.diff(t) > GAP_S)
    runs = list(zip([0, *(holes + 1).tolist()], [*holes.tolist(), t.size - 1], strict=True))
    stamps = np.concatenate(
        [
            t[a] + DRONECAN_PERIOD_S * np.arange(math.floor((t[b] - t[a]) / DRONECAN_PERIOD_S + 1e-9) + 1)
            for a, b in runs
        ]
    )
    rows = np.searchsorted(t, stamps + 1e-9, side="right") - 1
    frames: list[tuple[float, int, bytes]] = []
    for stamp, row in zip(stamps.tolist(), rows.tolist(), strict=True):
        for type_name, fields in by_type.items():
            values: dict[str, object] = {}
            for steps, column in fields:
                if any(s in ("mean", "max", "min") for s in steps) and any(
                    (type_name, steps[:i]) in explicit for i, s in enumerate(steps) if s in ("mean", "max", "min")
                ):
                    continue  # the log's own cylinders fill that array
                _put(values, steps, float(column[row]))
            for msg in encoder.frames(type_name, values, stamp):
                frames.append((stamp, msg.arbitration_id, bytes(msg.data)))
    n = len(frames)
    data = np.zeros((n, 8), dtype=np.uint8)
    for i, (_, _, payload) in enumerate(frames):
        data[i, : len(payload)] = np.frombuffer(payload, dtype=np.uint8)
    return FrameArrays(
        np.array([f[0] for f in frames], dtype=np.float64),
        np.array([f[1] for f in frames], dtype=np.int64),
        np.ones(n, dtype=bool),
        np.array([len(f[2]) for f in frames], dtype=np.int64),
        data,
        np.zeros(n, dtype=bool),
    )


def _put(values: dict[str, object], steps: tuple[str | int, ...], value: float) -> None:
    """Set ``value`` at ``steps`` in nested field mappings (array steps: lists of mappings; a
    reduction step is element 0)."""
    node: Any = values
    for i, step in enumerate(steps):
        last = i == len(steps) - 1
        if isinstance(step, str) and step not in ("mean", "max", "min"):
            if last:
                node[step] = value
            elif isinstance(steps[i + 1], int) or steps[i + 1] in ("mean", "max", "min"):
                node = node.setdefault(step, [])
            else:
                node = node.setdefault(step, {})
        else:
            index = step if isinstance(step, int) else 0
            while len(node) <= index:
                node.append(math.nan if last else {})
            if last:
                node[index] = value
            else:
                node = node[index]


def _warn_clipped(log: FlightLog, column: str, message: str, signal: Any, values: NDArray[np.float64]) -> None:
    """Log one warning (once per flight and column in a process) when a column holds values outside its DBC
    signal's range: the encoder clamps them (as the ECU would send them), so the pipeline reads the range's
    end there, not the logged value."""
    low = -math.inf if signal.minimum is None else float(signal.minimum)
    high = math.inf if signal.maximum is None else float(signal.maximum)
    values = np.asarray(values, dtype=float)
    outside = (values < low) | (values > high)
    count = int(np.count_nonzero(outside))
    key = (str(log.source), column, low, high)
    if count == 0 or key in _CLIPPED_WARNED:
        return
    _CLIPPED_WARNED.add(key)
    unit = f" {signal.unit}" if signal.unit else ""
    _log.warning(
        "%s: column '%s' outside the range [%g, %g]%s of the DBC signal %s.%s it is sent in, in %d of %d rows"
        " (%.4g to %.4g%s): sent clamped to the range, so the replay reads the range's end there; map the"
        " input to a signal with a wider range",
        log.source,
        column,
        low,
        high,
        unit,
        message,
        signal.name,
        count,
        values.size,
        float(np.min(values[outside])),
        float(np.max(values[outside])),
        unit,
    )


def _missing_columns(log: FlightLog, missing: list[str], config: ServiceConfig) -> FlightLogError:
    """The one-line error for a flight CSV without a column the replay must send; a log with fuel flow but
    no throttle (a G1000's) replayed on a throttle heat map is told which model it needs."""
    hint = ""
    if "throttle_pct" in missing and log.has("fuel_flow_lph"):
        hint = (
            "; the model's heat map reads throttle_pct: for a log without throttle give a model identified with"
            " --heat-axes fuel_flow_lph,rpm (--model)"
        )
    return FlightLogError(f"{log.source}: missing column(s) {', '.join(missing)} mapped in {config.source}{hint}")
