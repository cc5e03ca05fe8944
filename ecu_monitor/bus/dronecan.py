"""DroneCAN (UAVCAN v0) on the CAN bus: message fields in, the service's node publications out.

The message layouts are the ``dronecan`` package's DSDL definitions, prepared once per data type into
:class:`ecu_monitor.bus.dronecan_codec.MessageCodec` (integer and struct arithmetic, checked bit for bit
against the package), and so are the data type ids and the transfer CRC seeds. The frames are reassembled
here as the package's ``TransferManager`` and ``Transfer.from_frames`` do (a transfer keyed by CAN id and
transfer id, restarted by a start frame, ended by an end frame, toggle bits alternating from 0, the transfer
CRC of a multi-frame transfer), without their per-frame objects. This module adds what a monitor needs
around them: the choice of frames, a source-node filter, a timeout for transfers left half-way, counts of
every frame by what became of it, field paths and unit conversion. ``dronecan`` is imported on first use
(``import dronecan`` parses its DSDL tree, ~0.3 s), so the DBC path of the service never pays for it.

* :class:`DroneCanDecoder` (the counterpart of :class:`ecu_monitor.bus.codec.Decoder`, same interface):
  a value is ``Type.field.path`` of a broadcast message, e.g.
  ``uavcan.equipment.ice.reciprocating.Status.engine_speed_rpm``. An array element is ``name[i]``
  (0-based; a missing element is no value), ``name[mean]``, ``name[max]`` or ``name[min]`` reduce
  over the elements that carry a finite value (``cylinder_status[mean].cylinder_head_temperature``:
  the mean CHT of the cylinders reported). Each value is converted once to its canonical unit
  through :mod:`ecu_monitor.units`; a value whose quantity is a length given in a pressure unit is a
  pressure altitude (:func:`ecu_monitor.units.pressure_altitude_m`, standard atmosphere).

  Frames, in order of the checks: a frame that is not a 29-bit broadcast of a mapped data type
  (11-bit, service, anonymous, other types) is ``unknown_id``; from a node outside
  ``source_node_ids``: ``filtered_node``; then, counted as malformed: ``bad_dlc`` (no tail byte),
  ``orphan_frame`` (a continuation without a transfer in progress: joined mid-transfer or lost its
  first frame), ``transfer_timeout`` (the frames of a transfer that did not end within
  :data:`TRANSFER_TIMEOUT_S`, or pushed out by more than :data:`MAX_PENDING_TRANSFERS` in progress),
  ``bad_toggle`` (toggle bit out of sequence: a frame lost or repeated), ``bad_crc`` (transfer CRC of a
  multi-frame transfer), ``bad_transfer`` (other tail-byte errors: kept among the keys, the reassembly
  cannot produce them) and ``decode_error`` (the payload does not unpack: too short for its fields, a
  multi-frame transfer shorter than its CRC, an array longer than its DSDL capacity). A completed
  transfer counts its frames ``ok``. A field that is NaN or infinite (DSDL: unknown) gives no value
  (counted ``unknown_value``, not malformed), so that input goes stale rather than take a made-up
  number. Transfers are keyed by CAN id (priority, type, source node) and 5-bit transfer id, so
  transfers of several nodes interleave and the transfer id wraps 31 -> 0.

* :class:`DroneCanEncoder`: values -> the frames of one transfer (the service's NodeStatus, KeyValue
  and LogMessage; the virtual ECU's engine and air-data messages), transfer id per data type.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from can.typechecking import CanFilter

from ecu_monitor.bus.codec import MALFORMED_REASONS, BatchDecoded, SignalSpec
from ecu_monitor.bus.dronecan_codec import (
    MessageCodec,
    PayloadError,
    column_values,
    dronecan_module,
    message_codec,
    service_codec,
    take_bits,
    transfer_crc,
    transfer_crc_rows,
    transfer_frames,
)
from ecu_monitor.errors import ConfigError
from ecu_monitor.units import QUANTITY_OF_COLUMN, Unit, pressure_altitude_m

__all__ = [
    "DRONECAN_REASONS",
    "MAX_PENDING_TRANSFERS",
    "TRANSFER_TIMEOUT_S",
    "DroneCanDecoder",
    "DroneCanEncoder",
    "FieldPath",
    "dronecan_module",
    "looks_like_dronecan",
    "parse_field",
]

#: A transfer whose last frame has not come this long (s) after its first is dropped (libcanard's 2 s).
TRANSFER_TIMEOUT_S = 2.0
#: At most this many transfers in progress at once; the oldest is dropped beyond (bounds memory on garbage).
MAX_PENDING_TRANSFERS = 64
#: Reasons a DroneCAN frame is counted as malformed (keys of :attr:`DroneCanDecoder.counters`).
DRONECAN_REASONS: tuple[str, ...] = (
    "bad_dlc",
    "orphan_frame",
    "transfer_timeout",
    "bad_toggle",
    "bad_crc",
    "bad_transfer",
    "decode_error",
)
_REDUCTIONS = ("mean", "max", "min")
_STEP = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+|mean|max|min)\])?$")
_CAN_ID_MASK = 0x1FFFFFFF
#: payload lengths per data type for which the live decoder keeps field readers (beyond: decoded whole)
_MAX_READER_SIZES = 256


class FieldPath(NamedTuple):
    """A checked ``Type.field.path``: the data type's full name, its id, and the steps below it
    (a field name, or an array step: an element index or one of ``mean``, ``max``, ``min``)."""

    type_name: str
    data_type_id: int
    steps: tuple[str | int, ...]

    @property
    def text(self) -> str:
        out = self.type_name
        for step in self.steps:
            out += f"[{step}]" if isinstance(step, int) or step in _REDUCTIONS else f".{step}"
        return out


def parse_field(ref: str) -> FieldPath:
    """``Type.field.path`` checked against the DSDL definitions; ConfigError (one line) if it is not
    a numeric field of a broadcast message type."""
    dronecan = dronecan_module()
    if not isinstance(ref, str) or not ref.strip():
        raise ConfigError(f"expected 'data.type.Name.field', got {ref!r}")
    parts = ref.strip().split(".")
    dtype = None
    k = 0
    for k in range(1, len(parts) + 1):
        dtype = dronecan.TYPENAMES.get(".".join(parts[:k]))
        if dtype is not None:
            break
    if dtype is None:
        raise ConfigError(
            f"{ref}: no DroneCAN data type named by its start (e.g. uavcan.equipment.air_data.StaticPressure)"
        )
    type_name = ".".join(parts[:k])
    if dtype.kind != dtype.KIND_MESSAGE or not dtype.default_dtid:
        raise ConfigError(f"{ref}: {type_name} is not a broadcast message with a data type id")
    steps: list[str | int] = []
    current = dtype
    for text in parts[k:]:
        match = _STEP.match(text)
        if match is None:
            raise ConfigError(f"{ref}: '{text}' is not a field name (name, name[i], name[mean|max|min])")
        name, index = match.groups()
        fields = {f.name: f.type for f in getattr(current, "fields", ()) if f.name}
        if name not in fields:
            known = ", ".join(fields) or "none"
            raise ConfigError(
                f"{ref}: {getattr(current, 'full_name', current)} has no field '{name}' (fields: {known})"
            )
        current = fields[name]
        steps.append(name)
        is_array = hasattr(current, "value_type")
        if index is not None:
            if not is_array:
                raise ConfigError(f"{ref}: '{name}' is not an array")
            steps.append(int(index) if index.isdigit() else index)
            current = current.value_type
        elif is_array:
            raise ConfigError(f"{ref}: '{name}' is an array: give an element, name[i] or name[mean|max|min]")
    if not k < len(parts):
        raise ConfigError(f"{ref}: name a field of {type_name}")
    if not isinstance(current, dronecan.dsdl.PrimitiveType):
        raise ConfigError(f"{ref}: not a number field (a compound value: name one of its fields)")
    return FieldPath(type_name, int(dtype.default_dtid), tuple(steps))


def _value(node: Any, steps: tuple[str | int, ...]) -> float:
    """The number at ``steps`` below a decoded value (field name -> value; NaN if absent or not finite)."""
    for i, step in enumerate(steps):
        if isinstance(step, int):
            if step >= len(node):
                return math.nan
            node = node[step]
        elif step in _REDUCTIONS:
            rest = steps[i + 1 :]
            values = [v for v in (_value(item, rest) for item in node) if math.isfinite(v)]
            if not values:
                return math.nan
            if step == "mean":
                return math.fsum(values) / len(values)
            return max(values) if step == "max" else min(values)
        else:
            node = node[step]
    value = float(node)
    return value if math.isfinite(value) else math.nan


class _Field(NamedTuple):
    output: int
    steps: tuple[str | int, ...]
    unit: Unit
    to_altitude: bool  # a pressure (canonical kPa) turned into a pressure altitude, m


@dataclass
class _Reassembly:
    """Transfers in progress: (CAN id, transfer id) -> the frames so far, and the frame time each one started."""

    active: dict[tuple[int, int], list[bytes]]
    started: dict[tuple[int, int], float]


class DroneCanDecoder:
    """Frames -> named values through the DroneCAN DSDL definitions (see the module docstring).

    ``specs``: the values wanted (``message`` = the data type's full name, ``signal`` = the field path
    below it). ``source_node_ids``: accept only these senders (empty: any). :attr:`counters` counts
    frames per outcome since construction (the keys of :class:`~ecu_monitor.bus.codec.Decoder` plus
    :data:`DRONECAN_REASONS`, ``filtered_node`` and ``unknown_value``).
    """

    def __init__(self, specs: Sequence[SignalSpec], source_node_ids: Sequence[int] = ()) -> None:
        self.names: tuple[str, ...] = tuple(s.name for s in specs)
        if len(set(self.names)) != len(self.names):
            raise ConfigError(f"duplicate value names in {self.names}")
        plans: dict[int, list[_Field]] = {}
        self._type_names: dict[int, str] = {}
        for index, spec in enumerate(specs):
            try:
                path = parse_field(f"{spec.message}.{spec.signal}")
                unit = spec.conversion()
            except (ConfigError, ValueError) as exc:
                raise ConfigError(f"{spec.name}: {exc}") from None
            to_altitude = unit.quantity == "pressure" and QUANTITY_OF_COLUMN.get(spec.name) == "length"
            plans.setdefault(path.data_type_id, []).append(_Field(index, path.steps, unit, to_altitude))
            self._type_names[path.data_type_id] = path.type_name
        self._plans = {dtid: tuple(fields) for dtid, fields in plans.items()}
        self._codecs: dict[int, MessageCodec] = {dtid: message_codec(name) for dtid, name in self._type_names.items()}
        self.source_node_ids: frozenset[int] = frozenset(int(n) for n in source_node_ids)
        for node in self.source_node_ids:
            if not 1 <= node <= 127:
                raise ConfigError(f"source node id {node}: expected 1..127")
        self._live = self._new_reassembly()
        self.counters: dict[str, int] = _new_counts()
        # (data type id, payload bytes) -> a reader per mapped field (:meth:`_prepare_readers`); () where the
        # layout depends on the content or the length does not unpack (then the whole payload is decoded)
        self._readers: dict[tuple[int, int], tuple[Callable[[bytes], float], ...]] = {}

    @property
    def frame_ids(self) -> tuple[int, ...]:
        """The DroneCAN data type ids this decoder reads."""
        return tuple(sorted(self._plans))

    def can_filters(self) -> list[CanFilter]:
        """python-can receive filters: 29-bit message frames of the mapped data types, any priority; from
        any node, or with ``source_node_ids`` from those nodes only (one exact filter per type and node, so
        the frames of other nodes stop at the bus, in the kernel where it filters)."""
        if self.source_node_ids:
            return [
                {"can_id": dtid << 8 | node, "can_mask": 0x00FFFFFF, "extended": True}
                for dtid in self.frame_ids
                for node in sorted(self.source_node_ids)
            ]
        return [{"can_id": dtid << 8, "can_mask": 0x00FFFF80, "extended": True} for dtid in self.frame_ids]

    @staticmethod
    def _new_reassembly() -> _Reassembly:
        return _Reassembly({}, {})

    def decode(
        self, arbitration_id: int, is_extended: bool, data: bytes | bytearray, time_s: float
    ) -> list[tuple[int, float]] | None:
        """One frame: [(value index, value)] when it completes a transfer, else None. ``time_s`` (s)
        times the transfers out; NaN: no timeout. Never raises for any frame content."""
        self.counters["frames"] += 1
        return self._take(self._live, self.counters, int(arbitration_id), bool(is_extended), bytes(data), time_s)

    def _take(
        self, state: _Reassembly, counts: dict[str, int], can_id: int, extended: bool, payload: bytes, time_s: float
    ) -> list[tuple[int, float]] | None:
        fields = self._plans.get((can_id >> 8) & 0xFFFF) if extended and not can_id & 0x80 else None
        source = can_id & 0x7F
        if fields is None or source == 0:  # not a mapped broadcast (anonymous frames carry 2-bit type ids)
            counts["unknown_id"] += 1
            return None
        if self.source_node_ids and source not in self.source_node_ids:
            counts["filtered_node"] += 1
            return None
        if not payload:
            _malformed(counts, "bad_dlc")
            return None
        tail = payload[-1]
        key = (can_id & _CAN_ID_MASK, tail & 0x1F)
        active = state.active
        if tail & 0x80:  # start of transfer
            if key in active:  # a new start replaces the unfinished transfer
                _malformed(counts, "transfer_timeout", len(active.pop(key)))
            state.started[key] = time_s
            if len(active) >= MAX_PENDING_TRANSFERS:
                oldest = min(state.started, key=lambda k: state.started[k] if k in active else math.inf)
                if oldest in active:
                    _malformed(counts, "transfer_timeout", len(active.pop(oldest)))
                    state.started.pop(oldest, None)
            if not tail & 0x40:
                active[key] = [payload]
                return None
            frames = [payload]
        elif key not in active:
            _malformed(counts, "orphan_frame")
            return None
        elif time_s - state.started.get(key, time_s) > TRANSFER_TIMEOUT_S:
            _malformed(counts, "transfer_timeout", len(active.pop(key)) + 1)
            state.started.pop(key, None)
            return None
        else:
            frames = active[key]
            frames.append(payload)
            if not tail & 0x40:
                return None
            del active[key]
        state.started.pop(key, None)
        # a start frame restarts and an end frame ends the transfer, so only the toggle bits can be out of order
        for i, frame in enumerate(frames):
            if (frame[-1] & 0x20) != (i & 1) << 5:
                _malformed(counts, "bad_toggle", len(frames))
                return None
        type_id = key[0] >> 8 & 0xFFFF
        codec = self._codecs[type_id]
        if len(frames) == 1:
            body = payload[:-1]
        else:
            body = b"".join([frame[:-1] for frame in frames])
            if len(body) < 2:
                _malformed(counts, "decode_error", len(frames))
                return None
            if transfer_crc(body[2:], codec.base_crc or 0) != body[0] | body[1] << 8:
                _malformed(counts, "bad_crc", len(frames))
                return None
            body = body[2:]
        readers = self._readers.get((type_id, len(body)))
        if readers is None:
            readers = self._prepare_readers(type_id, codec, len(body))
        if readers:  # the mapped fields read where this payload length puts them
            raws = [read(body) for read in readers]
        else:  # a layout that depends on the content, or a length that does not unpack
            try:
                message = codec.decode(body)
            except PayloadError:
                _malformed(counts, "decode_error", len(frames))
                return None
            raws = []
            for f in fields:
                try:
                    raws.append(_value(message, f.steps))
                except (ValueError, IndexError, KeyError, TypeError, OverflowError):
                    raws.append(math.nan)
        counts["ok"] += len(frames)
        out: list[tuple[int, float]] = []
        for f, raw in zip(fields, raws, strict=True):
            if math.isnan(raw):
                counts["unknown_value"] += 1
                continue
            value = raw * f.unit.scale + f.unit.offset
            if f.to_altitude:
                value = pressure_altitude_m(value)
            if math.isfinite(value):
                out.append((f.output, value))
            else:
                counts["unknown_value"] += 1
        return out

    def _prepare_readers(self, type_id: int, codec: MessageCodec, size: int) -> tuple[Callable[[bytes], float], ...]:
        """The readers of the mapped fields of ``type_id`` in a payload of ``size`` bytes, built once per length
        from :meth:`MessageCodec.layout` (each gives what :func:`_value` gives on the decoded payload: the raw
        number, NaN if absent or not finite); () when the layout depends on the content or no payload of that
        length unpacks. At most :data:`_MAX_READER_SIZES` lengths are kept (garbage cannot grow the cache)."""
        try:
            layout = codec.layout(size)
        except PayloadError:
            layout = None
        readers: tuple[Callable[[bytes], float], ...] = ()
        if layout is not None:
            made = [_reader(layout, f.steps) for f in self._plans[type_id]]
            if all(r is not None for r in made):
                readers = tuple(r for r in made if r is not None)
        if len(self._readers) < _MAX_READER_SIZES:
            self._readers[(type_id, size)] = readers
        return readers

    def decode_batch(
        self,
        arbitration_ids: np.ndarray,
        is_extended: np.ndarray,
        dlc: np.ndarray,
        data: np.ndarray,
        times_s: np.ndarray,
        ignored: np.ndarray | None = None,
    ) -> BatchDecoded:
        """:meth:`decode` over a whole log (frames in log order), with its own reassembly state and counts
        (the live ones untouched): the same values and counts. Frames of other types are counted with
        numpy. A clean log (see :meth:`_clean_log`) is reassembled, checked and unpacked with numpy,
        transfers of one type and length at once; any other goes frame by frame through the code of
        :meth:`decode`."""
        n = len(arbitration_ids)
        ids = np.asarray(arbitration_ids, dtype=np.int64)
        ext = np.asarray(is_extended, dtype=bool)
        lengths = np.minimum(np.asarray(dlc, dtype=np.int64), 8)
        payloads = np.ascontiguousarray(data, dtype=np.uint8).reshape(n, 8)
        times = np.asarray(times_s, dtype=np.float64)
        skip = np.zeros(n, dtype=bool) if ignored is None else np.asarray(ignored, dtype=bool)
        counts = _new_counts()
        counts["frames"] = n
        counts["ignored"] = int(np.count_nonzero(skip))
        wanted = ext & ~skip & ((ids & 0x80) == 0) & ((ids & 0x7F) != 0)
        wanted &= np.isin((ids >> 8) & 0xFFFF, np.asarray(self.frame_ids, dtype=np.int64))
        counts["unknown_id"] = int(np.count_nonzero(~wanted & ~skip))
        found: list[list[tuple[int, float]]] = [[] for _ in self.names]
        fast = self._clean_log(ids, lengths, payloads, times, wanted, counts)
        if fast is not None:
            return BatchDecoded(fast, counts)
        state = self._new_reassembly()
        rows = np.flatnonzero(wanted)
        id_list = ids[rows].tolist()
        len_list = lengths[rows].tolist()
        time_list = times[rows].tolist()
        for row, can_id, length, stamp in zip(rows.tolist(), id_list, len_list, time_list, strict=True):
            decoded = self._take(state, counts, can_id, True, payloads[row, :length].tobytes(), stamp)
            if decoded:
                for slot, value in decoded:
                    found[slot].append((row, value))
        values: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for index, name in enumerate(self.names):
            pairs = found[index]
            values[name] = (
                np.fromiter((p[0] for p in pairs), dtype=np.int64, count=len(pairs)),
                np.fromiter((p[1] for p in pairs), dtype=np.float64, count=len(pairs)),
            )
        return BatchDecoded(values, counts)

    def _clean_log(
        self,
        ids: np.ndarray,
        lengths: np.ndarray,
        payloads: np.ndarray,
        times: np.ndarray,
        wanted: np.ndarray,
        counts: dict[str, int],
    ) -> dict[str, tuple[np.ndarray, np.ndarray]] | None:
        """The values of a log whose transfers the per-frame reassembly would all complete, or None.

        Clean: every frame has a tail byte and a finite time; per transfer key (CAN id, transfer id) the
        frames run start ... end, transfer after transfer, toggles alternating from 0, no frame later
        than :data:`TRANSFER_TIMEOUT_S` after its transfer's first, never :data:`MAX_PENDING_TRANSFERS`
        in progress at once. Then no frame is orphaned, timed out or out of toggle, and each transfer
        is checked (CRC) and unpacked (:meth:`MessageCodec.layout`, :func:`column_values`) with numpy,
        those whose layout depends on their content one by one through :meth:`MessageCodec.decode`.
        ``counts`` is filled only when the log is clean."""
        rows = np.flatnonzero(wanted)
        source = ids[rows] & 0x7F
        if self.source_node_ids:
            keep = np.isin(source, np.asarray(sorted(self.source_node_ids), dtype=np.int64))
            filtered = int(np.count_nonzero(~keep))
            rows = rows[keep]
        else:
            filtered = 0
        n_rows = len(rows)
        length = lengths[rows]
        if n_rows == 0 or np.any(length < 1) or not np.all(np.isfinite(times[rows])):
            return None
        tail = payloads[rows, length - 1].astype(np.int64)
        key = (ids[rows] & _CAN_ID_MASK) << 5 | (tail & 0x1F)
        order = np.argsort(key, kind="stable")  # frames of one key together, in log order
        key_s, tail_s = key[order], tail[order]
        start, end = (tail_s & 0x80) != 0, (tail_s & 0x40) != 0
        first = np.ones(n_rows, dtype=bool)
        first[1:] = key_s[1:] != key_s[:-1]
        last = np.ones(n_rows, dtype=bool)
        last[:-1] = first[1:]
        after_end = np.ones(n_rows, dtype=bool)  # the key's previous frame ended a transfer (or there is none)
        after_end[1:] = end[:-1]
        after_end |= first
        if not (np.array_equal(start, after_end) and np.all(end[last])):
            return None
        starts = np.flatnonzero(start)
        ends = np.flatnonzero(end)
        transfer = np.cumsum(start) - 1
        position = np.arange(n_rows) - starts[transfer]
        if np.any(((tail_s & 0x20) != 0) != ((position & 1) == 1)):
            return None
        time_s = times[rows][order]
        if np.any(time_s - time_s[starts][transfer] > TRANSFER_TIMEOUT_S):
            return None
        frames_per = ends - starts + 1
        multi = frames_per > 1
        pending = np.zeros(n_rows, dtype=np.int64)  # transfers in progress, in log order
        pending[order[starts[multi]]] += 1
        pending[order[ends[multi]]] -= 1
        if len(pending) and int(np.cumsum(pending).max()) >= MAX_PENDING_TRANSFERS:
            return None
        # clean: assemble each transfer's bytes (the frames' data without tail bytes, in order)
        counts["filtered_node"] += filtered
        data_s = payloads[rows[order]]
        body_len = length[order] - 1
        flat = data_s[np.arange(8) < body_len[:, None]]
        byte_end = np.cumsum(np.add.reduceat(body_len, starts))
        sizes = np.add.reduceat(body_len, starts)
        offset = byte_end - sizes
        done_row = rows[order[ends]]  # the log row of the frame that completes each transfer
        dtid = (key_s[starts] >> 13) & 0xFFFF
        found: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in self.names]
        too_short = multi & (sizes < 2)
        _malformed(counts, "decode_error", int(frames_per[too_short].sum()))
        body_start = offset + np.where(multi, 2, 0)
        body_size = sizes - np.where(multi, 2, 0)
        groups = np.flatnonzero(~too_short)
        group_key = (dtid[groups] << 32) | (multi[groups].astype(np.int64) << 31) | body_size[groups]  # size < 2**31
        group_order = np.argsort(group_key, kind="stable")
        bounds = np.flatnonzero(np.diff(group_key[group_order])) + 1
        for part in np.split(group_order, bounds) if len(groups) else []:
            sel = groups[part]
            head = int(sel[0])
            type_id, is_multi, size = int(dtid[head]), bool(multi[head]), int(body_size[head])
            codec = self._codecs[type_id]
            body = flat[body_start[sel][:, None] + np.arange(size)] if size else np.zeros((len(sel), 0), np.uint8)
            if is_multi:
                sent_crc = flat[offset[sel]].astype(np.uint32) | flat[offset[sel] + 1].astype(np.uint32) << 8
                good = transfer_crc_rows(body, codec.base_crc or 0) == sent_crc
                _malformed(counts, "bad_crc", int(frames_per[sel[~good]].sum()))
                sel, body = sel[good], body[good]
            self._columns(codec, type_id, sel, body, size, frames_per, done_row, counts, found)
        values: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for index, name in enumerate(self.names):
            parts = found[index]
            at = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, dtype=np.int64)
            value = np.concatenate([p[1] for p in parts]) if parts else np.zeros(0, dtype=np.float64)
            sort = np.argsort(at, kind="stable")
            values[name] = (at[sort].astype(np.int64), value[sort].astype(np.float64))
        return values

    def _columns(
        self,
        codec: MessageCodec,
        type_id: int,
        sel: np.ndarray,
        body: np.ndarray,
        size: int,
        frames_per: np.ndarray,
        done_row: np.ndarray,
        counts: dict[str, int],
        found: list[list[tuple[np.ndarray, np.ndarray]]],
    ) -> None:
        """The mapped values of the transfers ``sel`` of one data type whose payloads (``body`` rows)
        all have ``size`` bytes, appended to ``found`` as (log rows, values); counts as :meth:`_take`."""
        try:
            layout = codec.layout(size)
        except PayloadError:
            _malformed(counts, "decode_error", int(frames_per[sel].sum()))
            return
        fields = self._plans[type_id]
        raws: list[np.ndarray | None] = [None] * len(fields)
        if layout is not None:
            raws = [_column(layout, f.steps, body) for f in fields]
        if layout is None or any(r is None for r in raws):  # by content: one transfer at a time
            raws = [np.empty(len(sel)) for _ in fields]
            keep = np.ones(len(sel), dtype=bool)
            for i, payload in enumerate(body):
                try:
                    message = codec.decode(payload.tobytes())
                except PayloadError:
                    keep[i] = False
                    continue
                for raw, f in zip(raws, fields, strict=True):
                    try:
                        raw[i] = _value(message, f.steps)  # type: ignore[index]
                    except (ValueError, IndexError, KeyError, TypeError, OverflowError):
                        raw[i] = math.nan  # type: ignore[index]
            _malformed(counts, "decode_error", int(frames_per[sel[~keep]].sum()))
            sel = sel[keep]
            raws = [r[keep] for r in raws]  # type: ignore[index]
        counts["ok"] += int(frames_per[sel].sum())
        for f, raw in zip(fields, raws, strict=True):
            assert raw is not None
            value = raw * f.unit.scale + f.unit.offset
            if f.to_altitude:
                value = np.array([pressure_altitude_m(v) if not math.isnan(v) else math.nan for v in value.tolist()])
            ok = np.isfinite(value)
            counts["unknown_value"] += int(np.count_nonzero(~ok))
            found[f.output].append((done_row[sel[ok]], value[ok]))


def _new_counts() -> dict[str, int]:
    counts = dict.fromkeys(("frames", "ok", "unknown_id", "ignored", "malformed", "filtered_node", "unknown_value"), 0)
    counts.update(dict.fromkeys((*MALFORMED_REASONS, *DRONECAN_REASONS), 0))
    return counts


def _column(layout: Any, steps: tuple[str | int, ...], body: np.ndarray) -> np.ndarray | None:
    """The raw number at ``steps`` of every payload row of one layout, NaN where absent or not finite
    (:func:`_value` on each row); None where :func:`column_values` cannot read it (then row by row)."""
    node = layout
    for i, step in enumerate(steps):
        if isinstance(step, int):
            if step >= len(node):
                return np.full(len(body), math.nan)
            node = node[step]
        elif step in _REDUCTIONS:
            rest = steps[i + 1 :]
            if not node:
                return np.full(len(body), math.nan)
            items = [_column(item, rest, body) for item in node]
            if any(item is None for item in items):
                return None
            leaf = _leaf(node[0], rest)
            table = np.stack(items, axis=1)  # type: ignore[arg-type]
            finite = np.isfinite(table)
            with np.errstate(invalid="ignore", divide="ignore"):
                if step == "max":
                    out = np.where(finite, table, -np.inf).max(axis=1)
                elif step == "min":
                    out = np.where(finite, table, np.inf).min(axis=1)
                elif len(node) == 1 or _exact_sum(leaf, len(node)):
                    out = np.where(finite, table, 0.0).sum(axis=1) / finite.sum(axis=1)
                else:  # math.fsum row by row, as _value
                    out = np.array([math.fsum(r[np.isfinite(r)]) / max(np.isfinite(r).sum(), 1) for r in table])
            out[~finite.any(axis=1)] = math.nan
            return out
        else:
            node = node[step]
    values = column_values(body, node)
    if values is not None:
        values[~np.isfinite(values)] = math.nan
    return values


def _reader(layout: Any, steps: tuple[str | int, ...]) -> Callable[[bytes], float] | None:
    """A function of a payload (of the layout's length) -> the raw number at ``steps``, as :func:`_value` gives it
    on the decoded payload; None when a step cannot be followed in the layout (then the payload is decoded)."""
    node = layout
    for i, step in enumerate(steps):
        if isinstance(step, int):
            if not isinstance(node, list):
                return None
            if step >= len(node):
                return _absent
            node = node[step]
        elif step in _REDUCTIONS:
            if not isinstance(node, list):
                return None
            items = [_reader(item, steps[i + 1 :]) for item in node]
            if any(item is None for item in items):
                return None
            return _reduction(step, tuple(item for item in items if item is not None))
        elif isinstance(node, dict) and step in node:
            node = node[step]
        else:
            return None
    if not (isinstance(node, tuple) and len(node) == 2):
        return None
    pos, prim = node
    if prim.code is not None and not pos & 7:  # byte-aligned: one struct unpack
        unpack_from, offset = struct.Struct("<" + prim.code).unpack_from, pos >> 3

        def aligned(body: bytes) -> float:
            value = float(unpack_from(body, offset)[0])
            return value if math.isfinite(value) else math.nan

        return aligned
    bits, (full_bytes, rest) = prim.bits, divmod(prim.bits, 8)

    def unaligned(body: bytes) -> float:
        total = 8 * len(body)
        raw = take_bits(int.from_bytes(body, "big"), total, pos, bits, full_bytes, rest)
        value = float(prim.value(raw))
        return value if math.isfinite(value) else math.nan

    return unaligned


def _absent(body: bytes) -> float:
    """The reader of an array element the payload does not carry."""
    return math.nan


def _reduction(step: str | int, items: tuple[Callable[[bytes], float], ...]) -> Callable[[bytes], float]:
    """The reader of ``name[mean|max|min]`` over the elements' readers, as :func:`_value` reduces (one element:
    its own reader, NaN when not finite; an empty array: NaN)."""
    if len(items) == 1:
        return items[0]
    if not items:
        return _absent

    def reduce(body: bytes) -> float:
        values = [v for v in (read(body) for read in items) if math.isfinite(v)]
        if not values:
            return math.nan
        if step == "mean":
            return math.fsum(values) / len(values)
        return max(values) if step == "max" else min(values)

    return reduce


def _leaf(node: Any, steps: tuple[str | int, ...]) -> Any:
    """The primitive node at ``steps`` below a layout (any element of an array; None if one is empty)."""
    for step in steps:
        if isinstance(node, list):
            if not node:
                return None
            node = node[0]
        else:
            node = node[step]
    return node[1]


def _exact_sum(leaf: Any, count: int) -> bool:
    """True when any sum of ``count`` values of this primitive is exact in float64 (so numpy's sum is
    math.fsum's): float16 (multiples of 2**-24 below 2**16) and integers of up to 32 bits."""
    if leaf is None:
        return False
    kind, bits = leaf.kind, leaf.bits
    if kind == 3:
        return bits == 16 and count <= 1 << 12
    return bits <= 32 and count <= 1 << 20


def _malformed(counts: dict[str, int], reason: str, frames: int = 1) -> None:
    counts[reason] += frames
    counts["malformed"] += frames


def looks_like_dronecan(
    arbitration_ids: np.ndarray, is_extended: np.ndarray, dlc: np.ndarray, data: np.ndarray
) -> bool:
    """True when most frames of a log look like DroneCAN broadcasts: 29-bit ids of a non-anonymous
    message and a tail byte whose start/end/toggle bits are consistent with a single frame or the first
    of a transfer. A guess for choosing a default config, never for decoding."""
    n = len(arbitration_ids)
    if n == 0:
        return False
    ids = np.asarray(arbitration_ids, dtype=np.int64)
    ext = np.asarray(is_extended, dtype=bool)
    lengths = np.clip(np.asarray(dlc, dtype=np.int64), 0, 8)
    rows = np.flatnonzero(ext & (lengths > 0) & ((ids & 0x7F) != 0))
    if rows.size < 0.5 * n:
        return False
    tails = np.asarray(data, dtype=np.uint8).reshape(n, 8)[rows, lengths[rows] - 1]
    start = (tails & 0x80) != 0
    # the first frame of every transfer has its toggle bit clear
    consistent = ~start | ((tails & 0x20) == 0)
    return bool(np.count_nonzero(start) >= 0.1 * rows.size and np.all(consistent[start]) and np.mean(consistent) > 0.9)


class DroneCanEncoder:
    """Values -> the frames of one broadcast transfer, through the DSDL definitions (prepared once per type,
    :class:`~ecu_monitor.bus.dronecan_codec.MessageCodec`).

    ``node_id``: the sending node (1..127). :meth:`frames` keeps one transfer id per data type
    (+1 modulo 32 per transfer). Values are given as a mapping of field name -> number, string (byte
    arrays: text, cut to the array's capacity), nested mapping (a compound field) or list of mappings
    (an array of compounds). A float field not given is NaN (DSDL: unknown); an integer field not
    given is 0; numbers beyond a field's range are cast as DSDL says (saturated: clamped).
    """

    def __init__(self, node_id: int) -> None:
        if not (isinstance(node_id, int) and 1 <= node_id <= 127):
            raise ConfigError(f"DroneCAN node id {node_id!r}: expected 1..127")
        self.node_id = node_id
        self._transfer_ids: dict[str, int] = {}

    def payload(self, type_name: str, values: Mapping[str, Any]) -> bytes:
        """The payload bytes of the message ``type_name`` filled from ``values`` (without the transfer CRC)."""
        return message_codec(type_name).encode(values)

    def frames(self, type_name: str, values: Mapping[str, Any], time_s: float, priority: int = 24) -> list[Any]:
        """The ``can.Message`` frames of one transfer of ``type_name`` stamped ``time_s`` (s)."""
        import can

        codec = message_codec(type_name)
        if codec.data_type_id is None or codec.base_crc is None:
            raise ValueError(f"{type_name}: not a broadcast message with a data type id")
        transfer_id = self._transfer_ids.get(type_name, 0)
        self._transfer_ids[type_name] = (transfer_id + 1) % 32
        can_id = (priority & 0x1F) << 24 | codec.data_type_id << 8 | self.node_id
        return [
            can.Message(timestamp=time_s, arbitration_id=can_id, is_extended_id=True, data=data)
            for data in transfer_frames(codec.encode(values), transfer_id, codec.base_crc)
        ]

    def response_frames(
        self, type_name: str, values: Mapping[str, Any], time_s: float, request_id: int, transfer_id: int
    ) -> list[Any]:
        """The frames of the response of service ``type_name`` to the request whose CAN id is ``request_id``
        (from its source node, at its priority) and transfer id ``transfer_id``, stamped ``time_s`` (s)."""
        import can

        codec = service_codec(type_name, "response")
        if codec.data_type_id is None or codec.base_crc is None:
            raise ValueError(f"{type_name}: not a service with a data type id")
        requester = request_id & 0x7F
        can_id = (request_id >> 24 & 0x1F) << 24 | codec.data_type_id << 16 | requester << 8 | 0x80 | self.node_id
        return [
            can.Message(timestamp=time_s, arbitration_id=can_id, is_extended_id=True, data=data)
            for data in transfer_frames(codec.encode(values), transfer_id, codec.base_crc)
        ]
