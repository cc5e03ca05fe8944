"""Decoding of input frames to model inputs and encoding of frames, built once from DBC files.

One place turns CAN frames into numbers and back (docs/architecture.md, docs/dbc.md):

* :class:`Decoder` maps ``Message.Signal`` of the input DBCs to named values (model inputs in their
  canonical units, plus any extra signal the caller asks for, such as the ECU status). It checks
  every frame in a fixed order and counts each failure under one reason; a bad frame is dropped,
  never raised:

  1. ``unknown_id``: no mapped message has this id (ignored, not malformed);
  2. ``bad_dlc``: the payload length differs from the DBC message length;
  3. ``bad_checksum``: byte 7 is not the CRC-8/SAE-J1850 of bytes 0..6 (messages that follow the
     docs/dbc.md layout: a ``...Counter`` signal at 48|4 and a ``...Checksum`` signal at 56|8);
  4. ``bad_counter``: the rolling counter neither advanced by 1 nor by 2 (one lost frame) since the
     last frame of that id that passed checks 2-3 (the first frame, and the first after a silence
     longer than ``COUNTER_RESYNC_S``, are accepted);
  5. ``decode_error``: cantools refused the payload;
  6. ``out_of_range``: a used signal is outside its DBC ``[min|max]`` (checked on the raw integer);
  7. ``not_finite``: a used float signal is NaN or infinite.

  :meth:`Decoder.decode` is the live per-frame path (cantools, strict database). :meth:`Decoder.decode_batch`
  runs the same checks on whole arrays with numpy (little- and big-endian integer signals by bit
  extraction; float signals through cantools per frame), for replay of long logs; both scale with
  the same float arithmetic (``raw * factor + offset``, then the unit conversion), so they give equal
  values.

* :class:`Encoder` builds frames from values: clamps each signal into its DBC range (docs/dbc.md:
  the sender clamps), sets the rolling counter and writes the checksum into byte 7. Each message is
  prepared once into a :class:`FrameLayout` (bit positions, masks, the signal's own scaled-to-raw
  conversion) that packs a frame with integer arithmetic, without cantools' per-call checks and
  dictionaries; messages it cannot pack exactly (float or multiplexed signals, a DBC range wider than
  the signal's bits) keep cantools' encoder. Both give the same bytes (tests/bus/test_codec.py checks
  them against cantools over random and clipped values).

Units: the one table is :data:`ecu_monitor.units.UNITS` (a signal's unit is a name of it or a custom
``Unit`` with its scale and offset); :data:`INPUT_QUANTITIES` says which quantity each model input is.
DBC files are read by the one loader, :func:`ecu_monitor.bus.dbc.load_dbc`.
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from can.typechecking import CanFilter

from ecu_monitor.bus.checksum import CHECKSUM_BYTE, crc8_sae_j1850, frame_checksum
from ecu_monitor.bus.dbc import Dbc, load_dbc
from ecu_monitor.errors import ConfigError
from ecu_monitor.inputs import INPUT_NAMES, INPUT_QUANTITIES
from ecu_monitor.units import Unit, unit_conversion

__all__ = [
    "COUNTER_RESYNC_S",
    "INPUT_NAMES",
    "INPUT_QUANTITIES",
    "MALFORMED_REASONS",
    "BatchDecoded",
    "Decoder",
    "Encoder",
    "FrameLayout",
    "SignalSpec",
]

#: A silence longer than this (s) resynchronises the rolling-counter check of a message.
COUNTER_RESYNC_S = 1.0

#: Reasons a frame is counted as malformed and dropped (keys of :attr:`Decoder.counters`).
MALFORMED_REASONS: tuple[str, ...] = (
    "bad_dlc",
    "bad_checksum",
    "bad_counter",
    "decode_error",
    "out_of_range",
    "not_finite",
)

_RANGE_SLACK = 1e-6  # raw units: absorbs rounding of (min - offset) / factor


@dataclass(frozen=True)
class SignalSpec:
    """One value wanted from the bus: ``name`` <- ``message.signal`` converted by ``unit`` (a name of
    :data:`ecu_monitor.units.UNITS` or a custom :class:`~ecu_monitor.units.Unit`)."""

    name: str
    message: str
    signal: str
    unit: str | Unit = "raw"

    def conversion(self) -> Unit:
        """The unit's conversion to the canonical unit; ValueError if the name is unknown."""
        return self.unit if isinstance(self.unit, Unit) else unit_conversion(self.unit)


def _integrity_signals(message: Any) -> tuple[Any, Any] | None:
    """(counter, checksum) signals if the message follows the docs/dbc.md layout, else None."""
    counter = checksum = None
    for sig in message.signals:
        little = sig.byte_order == "little_endian"
        if sig.name.lower().endswith("counter") and little and sig.start == 48 and sig.length == 4:
            counter = sig
        if sig.name.lower().endswith("checksum") and little and sig.start == 56 and sig.length == 8:
            checksum = sig
    if counter is None or checksum is None or message.length != 8:
        return None
    return counter, checksum


class _Field(NamedTuple):
    """A used signal of a message: where its value goes and how it is scaled and checked."""

    output: int  # index into Decoder.names
    signal: Any  # cantools Signal
    factor: float
    offset: float
    unit_scale: float
    unit_offset: float
    raw_low: float  # -inf when the DBC gives no minimum
    raw_high: float


class _Plan(NamedTuple):
    """How to decode one frame id."""

    message: Any
    fields: tuple[_Field, ...]
    counter_name: str | None  # None: no counter/checksum in this message
    length: int  # the message's DBC length, bytes
    # per field (output, shift, mask, sign bit or 0, big-endian, raw_low, raw_high, factor, offset, unit_scale,
    # unit_offset): the raw integer read straight from the payload as one integer, checked and scaled; or None
    # when cantools decodes the message (a float or multiplexed signal)
    extract: tuple[tuple[Any, ...], ...] | None


def _extraction(message: Any, fields: Sequence[_Field]) -> tuple[tuple[Any, ...], ...] | None:
    """How :meth:`Decoder.decode` reads each used signal's raw integer without cantools (the bits cantools
    reads: little-endian from the start bit up, big-endian from the sawtooth MSB down), or None."""
    if message.length > 8 or message.is_multiplexed():
        return None
    out = []
    for f in fields:
        sig = f.signal
        if sig.is_float or sig.multiplexer_ids:
            return None
        if sig.byte_order == "little_endian":
            shift = sig.start
        else:
            shift = (message.length - 1 - sig.start // 8) * 8 + sig.start % 8 - sig.length + 1
        if shift < 0 or shift + sig.length > 8 * message.length:
            return None
        sign = 1 << (sig.length - 1) if sig.is_signed else 0
        out.append((f.output, shift, (1 << sig.length) - 1, sign, sig.byte_order != "little_endian", f.raw_low,
                    f.raw_high, f.factor, f.offset, f.unit_scale, f.unit_offset))  # fmt: skip
    return tuple(out)


class BatchDecoded(NamedTuple):
    """Result of :meth:`Decoder.decode_batch`.

    values[name] = (frame indices of the valid frames carrying it, ascending; values, canonical unit).
    counts: frames per reason ("ok", "unknown_id", "ignored" and each of MALFORMED_REASONS).
    """

    values: dict[str, tuple[np.ndarray, np.ndarray]]
    counts: dict[str, int]


def _raw_bounds(sig: Any) -> tuple[float, float]:
    """Raw-integer range of a signal from its physical DBC [min|max] (inf when absent)."""
    factor = float(sig.scale)
    offset = float(sig.offset)
    low = -math.inf if sig.minimum is None else (float(sig.minimum) - offset) / factor
    high = math.inf if sig.maximum is None else (float(sig.maximum) - offset) / factor
    if factor < 0.0:
        low, high = high, low
    return low - _RANGE_SLACK, high + _RANGE_SLACK


def _extract_values(plan: _Plan, payload: bytes) -> list[tuple[int, float]] | None:
    """Integer signals of a prepared plan: raw integers by shift and mask (the values cantools' decode
    gives), the range check and the scaling: [(value index, value)], or None when a raw value is out of its
    range. No state."""
    little = int.from_bytes(payload, "little")
    big = int.from_bytes(payload, "big")
    out: list[tuple[int, float]] = []
    for output, shift, mask, sign, big_endian, low, high, factor, offset, unit_scale, unit_offset in plan.extract or ():
        raw = ((big if big_endian else little) >> shift) & mask
        if raw & sign:
            raw -= mask + 1
        if not low <= raw <= high:
            return None
        out.append((output, (raw * factor + offset) * unit_scale + unit_offset))
    return out


class Decoder:
    """Frames -> named values through DBC files, with the checks of the module docstring.

    ``dbc_paths``: input DBC files (loaded once, strict). ``specs``: the values wanted. A frame id
    defined in several DBCs is decoded as the message the specs use; two used messages on one id
    is a ConfigError. :attr:`counters` counts frames per reason since construction (``frames``,
    ``ok``, ``unknown_id``, ``ignored`` for error/remote frames, ``malformed`` and each reason).
    """

    def __init__(self, dbc_paths: Sequence[str | os.PathLike[str]], specs: Sequence[SignalSpec]) -> None:
        if not dbc_paths:
            raise ConfigError("no input DBC file given")
        self.databases: tuple[tuple[str, Dbc], ...] = tuple((str(p), load_dbc(p)) for p in dbc_paths)
        self.names: tuple[str, ...] = tuple(s.name for s in specs)
        if len(set(self.names)) != len(self.names):
            raise ConfigError(f"duplicate value names in {self.names}")
        fields: dict[tuple[int, bool], list[_Field]] = {}
        messages: dict[tuple[int, bool], Any] = {}
        for index, spec in enumerate(specs):
            message = self.find_message(spec.message)
            sig = next((s for s in message.signals if s.name == spec.signal), None)
            if sig is None:
                raise ConfigError(f"{spec.name}: message '{spec.message}' has no signal '{spec.signal}'")
            try:
                unit = spec.conversion()
            except ValueError as exc:
                raise ConfigError(f"{spec.name}: {exc}") from None
            key = (int(message.frame_id), bool(message.is_extended_frame))
            if key in messages and messages[key] is not message:
                raise ConfigError(
                    f"{spec.name}: messages '{messages[key].name}' and '{message.name}' share frame id "
                    f"0x{key[0]:X}; one bus cannot carry both"
                )
            messages[key] = message
            low, high = _raw_bounds(sig)
            fields.setdefault(key, []).append(
                _Field(index, sig, float(sig.scale), float(sig.offset), unit.scale, unit.offset, low, high)
            )
        self._plans: dict[tuple[int, bool], _Plan] = {}
        for key, message in messages.items():
            integrity = _integrity_signals(message)
            counter = integrity[0].name if integrity else None
            self._plans[key] = _Plan(
                message, tuple(fields[key]), counter, int(message.length), _extraction(message, fields[key])
            )
        self._last_counter: dict[tuple[int, bool], tuple[int, float]] = {}
        self.counters: dict[str, int] = dict.fromkeys(("frames", "ok", "unknown_id", "ignored", "malformed"), 0)
        self.counters.update(dict.fromkeys(MALFORMED_REASONS, 0))

    def find_message(self, name: str) -> Any:
        """The message called ``name`` in the input DBCs (the first that has it); ConfigError if none
        or if it failed the DBC's strict checks (see :mod:`ecu_monitor.bus.dbc`)."""
        for _, db in self.databases:
            message = db.find(name)
            if message is not None:
                db.check_usable(name)
                return message
        files = ", ".join(path for path, _ in self.databases)
        raise ConfigError(f"no message '{name}' in {files}")

    @property
    def frame_ids(self) -> tuple[int, ...]:
        """The frame ids this decoder reads (for a bus filter)."""
        return tuple(sorted(key[0] for key in self._plans))

    def can_filters(self) -> list[CanFilter]:
        """python-can receive filters of exactly the frame ids this decoder reads."""
        return [{"can_id": frame_id, "can_mask": 0x1FFFFFFF} for frame_id in self.frame_ids]

    def _malformed(self, reason: str) -> None:
        self.counters[reason] += 1
        self.counters["malformed"] += 1

    def decode(
        self, arbitration_id: int, is_extended: bool, data: bytes | bytearray, time_s: float
    ) -> list[tuple[int, float]] | None:
        """Decode one frame: [(value index, value)] or None when the frame is unknown or malformed.

        ``time_s`` (s) is used only for the counter resynchronisation after a silence. Never raises
        for any frame content.
        """
        self.counters["frames"] += 1
        key = (arbitration_id, is_extended)
        plan = self._plans.get(key)
        if plan is None:
            self.counters["unknown_id"] += 1
            return None
        payload = bytes(data)
        if len(payload) != plan.length:
            self._malformed("bad_dlc")
            return None
        if plan.counter_name is not None:  # 8 bytes (checked when the plan was made)
            if payload[CHECKSUM_BYTE] != crc8_sae_j1850(payload[:CHECKSUM_BYTE]):
                self._malformed("bad_checksum")
                return None
            counter = payload[6] & 0x0F
            last = self._last_counter.get(key)
            self._last_counter[key] = (counter, time_s)
            if last is not None and time_s - last[1] <= COUNTER_RESYNC_S and (counter - last[0]) % 16 not in (1, 2):
                self._malformed("bad_counter")
                return None
        if plan.extract is not None:
            return self._decode_prepared(plan, payload)
        import cantools  # here, not above: the prepared path above is the live hot path

        try:
            raw = plan.message.decode(payload, decode_choices=False, scaling=False)
        except (cantools.database.DecodeError, ValueError, KeyError, IndexError, TypeError, OverflowError):
            self._malformed("decode_error")
            return None
        out: list[tuple[int, float]] = []
        for f in plan.fields:
            value = raw[f.signal.name]
            if not isinstance(value, int | float):  # a multiplexed / named value cantools could not give
                self._malformed("decode_error")
                return None
            if not math.isfinite(value):
                self._malformed("not_finite")
                return None
            if not f.raw_low <= value <= f.raw_high:
                self._malformed("out_of_range")
                return None
            out.append((f.output, (value * f.factor + f.offset) * f.unit_scale + f.unit_offset))
        self.counters["ok"] += 1
        return out

    def _decode_prepared(self, plan: _Plan, payload: bytes) -> list[tuple[int, float]] | None:
        """The end of :meth:`decode` for integer signals (:func:`_extract_values`), counted."""
        out = _extract_values(plan, payload)
        if out is None:
            self._malformed("out_of_range")
            return None
        self.counters["ok"] += 1
        return out

    def decode_batch(
        self,
        arbitration_ids: np.ndarray,
        is_extended: np.ndarray,
        dlc: np.ndarray,
        data: np.ndarray,
        times_s: np.ndarray,
        ignored: np.ndarray | None = None,
    ) -> BatchDecoded:
        """The checks and decode of :meth:`decode` on whole arrays (frames in log order).

        ``data``: (N, 8) uint8, payload bytes beyond ``dlc`` zero. ``ignored``: error/remote frames.
        Does not touch :attr:`counters` or the live counter state.
        """
        n = len(arbitration_ids)
        ids = np.asarray(arbitration_ids, dtype=np.int64)
        ext = np.asarray(is_extended, dtype=bool)
        dlc = np.asarray(dlc, dtype=np.int64)
        data = np.ascontiguousarray(data, dtype=np.uint8).reshape(n, 8)
        words = data.view(np.uint64).reshape(n)  # a frame's 8 bytes as one word: gathered in one move
        times_s = np.asarray(times_s, dtype=np.float64)
        skip = np.zeros(n, dtype=bool) if ignored is None else np.asarray(ignored, dtype=bool)
        counts = dict.fromkeys(("frames", "ok", "unknown_id", "ignored", "malformed", *MALFORMED_REASONS), 0)
        counts["frames"] = n
        counts["ignored"] = int(np.count_nonzero(skip))
        known = np.zeros(n, dtype=bool)
        found: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {i: [] for i in range(len(self.names))}
        usable = ~skip
        for key, plan in self._plans.items():
            match = ids == key[0]
            match &= ext == key[1]
            match &= usable
            rows = np.flatnonzero(match)
            known[rows] = True
            payload = words[rows].view(np.uint8).reshape(rows.size, 8)
            ok = dlc[rows] == plan.length
            counts["bad_dlc"] += int(np.count_nonzero(~ok))
            if plan.counter_name is not None:
                good_sum = _crc8_rows(payload) == payload[:, CHECKSUM_BYTE]
                counts["bad_checksum"] += int(np.count_nonzero(ok & ~good_sum))
                ok &= good_sum
                checked = np.flatnonzero(ok)
                counter = payload[:, 6][checked] & 0x0F  # uint8: the difference wraps mod 256, a multiple of 16
                stamp = times_s[rows[checked]]
                step = (counter[1:] - counter[:-1]) & 0x0F  # (c - c_prev) mod 16
                fresh = stamp[1:] - stamp[:-1] > COUNTER_RESYNC_S
                good_counter = np.ones(len(checked), dtype=bool)
                good_counter[1:] = fresh | (step == 1) | (step == 2)
                counts["bad_counter"] += int(np.count_nonzero(~good_counter))
                ok[checked[~good_counter]] = False
            raws = [_extract(payload, f.signal, plan.message) for f in plan.fields]
            for f, raw in zip(plan.fields, raws, strict=True):  # the order of decode(): field by field
                finite = np.isfinite(raw)
                counts["not_finite"] += int(np.count_nonzero(ok & ~finite))
                ok &= finite
                with np.errstate(invalid="ignore"):
                    in_range = (raw >= f.raw_low) & (raw <= f.raw_high)
                counts["out_of_range"] += int(np.count_nonzero(ok & ~in_range))
                ok &= in_range
            keep = rows[ok]
            for f, raw in zip(plan.fields, raws, strict=True):
                found[f.output].append((keep, (raw[ok] * f.factor + f.offset) * f.unit_scale + f.unit_offset))
            counts["ok"] += len(keep)
        counts["unknown_id"] = int(np.count_nonzero(~known & ~skip))
        counts["malformed"] = sum(counts[r] for r in MALFORMED_REASONS)
        values: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for index, name in enumerate(self.names):
            parts = found[index]
            if len(parts) == 1:  # one message: its rows are in log order already (shared, not copied)
                values[name] = (parts[0][0], parts[0][1].astype(np.float64, copy=False))
                continue
            rows_all = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, dtype=np.int64)
            vals_all = np.concatenate([p[1] for p in parts]) if parts else np.zeros(0)
            order = np.argsort(rows_all, kind="stable")
            values[name] = (rows_all[order], vals_all[order].astype(np.float64))
        return BatchDecoded(values, counts)


def _crc8_rows(payload: np.ndarray) -> np.ndarray:
    """CRC-8/SAE-J1850 of bytes 0..6 of every row of an (N, 8) uint8 array (frame_checksum of each row),
    compiled (numba, loaded on the first batch decode)."""
    out = np.empty(len(payload), dtype=np.uint8)
    _compiled_crc8()(np.ascontiguousarray(payload, dtype=np.uint8), out)
    return out


def _crc8_loop(payload: np.ndarray, out: np.ndarray) -> None:
    for r in range(payload.shape[0]):
        out[r] = crc8_sae_j1850(payload[r, :CHECKSUM_BYTE])


@functools.cache
def _compiled_crc8() -> Any:
    import numba  # the batch path only: the live decoder and the CLI's start do not load it

    return numba.njit(cache=True, nogil=True)(_crc8_loop)


def _extract(payload: np.ndarray, sig: Any, message: Any) -> np.ndarray:
    """Raw values (float64) of one signal from (N, 8) payload rows; cantools for float signals."""
    import cantools

    n = len(payload)
    if n == 0:
        return np.zeros(0)
    if sig.is_float:
        out = np.empty(n)
        cache: dict[bytes, float] = {}
        length = message.length
        for i in range(n):
            row = payload[i, :length].tobytes()
            value = cache.get(row)
            if value is None:
                try:
                    value = float(message.decode(row, decode_choices=False, scaling=False)[sig.name])
                except (cantools.database.DecodeError, ValueError, KeyError, IndexError, TypeError, OverflowError):
                    value = math.nan  # counted as not finite
                cache[row] = value
            out[i] = value
        return out
    mask = np.uint64((1 << sig.length) - 1) if sig.length < 64 else np.uint64(0xFFFFFFFFFFFFFFFF)
    if sig.byte_order == "little_endian":
        word = payload.view("<u8").reshape(n)
        shift = np.uint64(sig.start)
    else:  # Motorola: DBC start bit is the MSB in sawtooth numbering
        word = payload.view(">u8").reshape(n)
        msb = (sig.start // 8) * 8 + (7 - sig.start % 8)
        shift = np.uint64(64 - (msb + sig.length))
    raw = (word >> shift) & mask
    if sig.is_signed:
        signed = raw.astype(np.int64)
        top = 1 << (sig.length - 1)
        if sig.length < 64:
            signed = np.where(signed >= top, signed - (1 << sig.length), signed)
        return signed.astype(np.float64)
    return raw.astype(np.float64)


def _linear(to_raw: Any) -> tuple[float, float] | None:
    """(offset, scale) when ``to_raw`` (a signal's ``numeric_scaled_to_raw``) is one of cantools' integer
    conversions, whose raw value is ``round((value - offset) / scale)`` with these very operands (for an
    integer scale cantools divides only when the remainder is not 0: when it is 0 the quotient is exact, so
    the division gives it too); None for any other (a layout is not made then)."""
    from cantools.database.conversion import IdentityConversion, LinearConversion, LinearIntegerConversion

    owner = getattr(to_raw, "__self__", None)  # a signal with a value table delegates to its inner conversion
    function = getattr(to_raw, "__func__", None)
    if owner is None or owner.is_float:
        return None
    if function is IdentityConversion.numeric_scaled_to_raw:
        return 0.0, 1.0  # round((v - 0.0) / 1.0) is round(v), bit for bit
    if function in (LinearConversion.numeric_scaled_to_raw, LinearIntegerConversion.numeric_scaled_to_raw):
        return owner.offset, owner.scale
    return None


class _Packed(NamedTuple):
    """One signal of a :class:`FrameLayout`: its clamp range, raw conversion and bit placement."""

    low: float  # physical clamp range (-inf/inf: none)
    high: float
    offset: float  # raw = round((value - offset) / scale): cantools' own arithmetic (:func:`_linear`)
    scale: float
    mask: int
    shift: int  # bit of the raw value's LSB in the message read as one little- (or big-) endian integer
    big_endian: bool


def _bits(fields: Sequence[_Packed], values: Sequence[float]) -> tuple[int, int]:
    """The raw values of ``fields`` from physical ``values`` (clamped), placed: (little-endian bits, big-endian
    bits) of the message read as one integer each."""
    little = 0
    big = 0
    for (low, high, offset, scale, mask, shift, big_endian), value in zip(fields, values, strict=False):
        v = float(value)
        raw = round(((low if v < low else high if v > high else v) - offset) / scale) & mask
        if big_endian:
            big |= raw << shift
        else:
            little |= raw << shift
    return little, big


class FrameLayout:
    """A message's encoding prepared once: :meth:`pack` gives the bytes of cantools' non-strict
    encode of the clamped values (plus counter and checksum), with integer arithmetic only.

    ``signal_names``: the data signals, in the order :meth:`pack` takes their values (DBC order,
    counter and checksum excluded). Build one with :meth:`Encoder.layout`.
    """

    def __init__(self, message: Any, integrity: tuple[Any, Any] | None, fields: tuple[_Packed, ...],
                 names: tuple[str, ...], counter: _Packed | None) -> None:  # fmt: skip
        self.name: str = message.name
        self.frame_id = int(message.frame_id)
        self.is_extended = bool(message.is_extended_frame)
        self.length = int(message.length)
        self.signal_names = names
        self._fields = fields
        self._checksum = integrity is not None
        # the counter's bits (little-, big-endian part) for each value 0..15, or None: no counter
        self._counter_bits = None if counter is None else tuple(_bits((counter,), (float(c),)) for c in range(16))
        self._any_big = any(f.big_endian for f in fields) or (counter is not None and counter.big_endian)

    @staticmethod
    def prepare(message: Any, integrity: tuple[Any, Any] | None) -> FrameLayout | None:
        """The layout of ``message``, or None when it cannot be packed exactly this way (a float or
        multiplexed signal, a message longer than 8 bytes, a clamp range whose raw values do not fit
        the signal's bits: cantools' encoder handles those)."""
        if message.length > 8 or message.is_multiplexed() or not message.signals:
            return None
        skip = {s.name for s in integrity} if integrity else set()
        fields: list[_Packed] = []
        names: list[str] = []
        counter: _Packed | None = None
        for sig in message.signals:
            if sig.is_float or sig.multiplexer_ids or sig.is_multiplexer:
                return None
            if sig.name in skip:
                low, high = (0.0, 15.0) if sig is integrity[0] else (0.0, 0.0)  # type: ignore[index]
            else:
                low = -math.inf if sig.minimum is None else float(sig.minimum)
                high = math.inf if sig.maximum is None else float(sig.maximum)
            to_raw = sig.conversion.numeric_scaled_to_raw
            linear = _linear(to_raw)
            if linear is None or not (math.isfinite(low) and math.isfinite(high)):
                return None
            first, second = to_raw(low), to_raw(high)
            lowest = -(1 << (sig.length - 1)) if sig.is_signed else 0
            highest = (1 << (sig.length - 1)) - 1 if sig.is_signed else (1 << sig.length) - 1
            if not all(isinstance(r, int) and lowest <= r <= highest for r in (first, second)):
                return None
            big = sig.byte_order != "little_endian"
            if big:  # Motorola: DBC start bit is the MSB in sawtooth numbering
                shift = (message.length - 1 - sig.start // 8) * 8 + sig.start % 8 - sig.length + 1
            else:
                shift = sig.start
            if shift < 0 or shift + sig.length > 8 * message.length:
                return None
            packed = _Packed(low, high, *linear, (1 << sig.length) - 1, shift, big)
            if sig.name in skip:
                if sig is integrity[0]:  # type: ignore[index]
                    counter = packed
                continue  # the checksum's bits stay 0 until byte 7 is written
            fields.append(packed)
            names.append(sig.name)
        return FrameLayout(message, integrity, tuple(fields), tuple(names), counter)

    def pack(self, values: Sequence[float], counter: int = 0) -> bytes:
        """Payload from physical ``values`` in :attr:`signal_names` order (clamped into the DBC
        range; NaN is a ValueError), the rolling counter modulo 16 and the checksum in byte 7."""
        if len(values) != len(self._fields):
            raise ValueError(f"{self.name}: expected {len(self._fields)} values, got {len(values)}")
        for value in values:
            if value != value:
                raise ValueError(f"{self.name}.{self.signal_names[list(values).index(value)]}: cannot encode NaN")
        little, big = _bits(self._fields, values)
        if self._counter_bits is not None:
            counter_little, counter_big = self._counter_bits[counter % 16]
            little |= counter_little
            big |= counter_big
        n = self.length
        if self._any_big:
            little |= int.from_bytes(big.to_bytes(n, "big"), "little")
        if not self._checksum:
            return little.to_bytes(n, "little")
        head = (little & 0xFFFFFFFFFFFFFF).to_bytes(CHECKSUM_BYTE, "little")
        return head + bytes((crc8_sae_j1850(head),))


class Encoder:
    """Values -> frame payloads through DBC files, with clamping, counter and checksum: the one
    encoder of the service's health frames, the virtual ECU's engine frames and replayed CSV rows.

    ``encode(name, values, counter)``: every data signal of the message must be given (physical
    units); values outside the DBC range are clamped to it (a real ECU saturates its outputs the same
    way); NaN is a ValueError. Once clamped, every value is inside the range cantools' strict mode
    checks, so the encoding skips that re-check; a message with a :class:`FrameLayout` (every
    integer-signal message of the shipped DBCs) is packed by it, the others by cantools' non-strict
    encode (the same bytes). For messages with the docs/dbc.md layout the counter is written modulo
    16 and byte 7 gets the checksum. Messages that fail the DBC's strict checks are not encodable
    (KeyError).
    """

    def __init__(self, dbc_paths: Sequence[str | os.PathLike[str]]) -> None:
        self.databases: tuple[tuple[str, Dbc], ...] = tuple((str(p), load_dbc(p)) for p in dbc_paths)
        self._messages: dict[str, tuple[Any, tuple[Any, Any] | None, tuple[tuple[str, float, float], ...]]] = {}
        self._layouts: dict[str, FrameLayout | None] = {}
        for _, db in self.databases:
            for message in db.messages:
                if message.name in self._messages or message.name in db.broken:
                    continue
                integrity = _integrity_signals(message)
                skip = {s.name for s in integrity} if integrity else set()
                limits = tuple(
                    (
                        s.name,
                        -math.inf if s.minimum is None else float(s.minimum),
                        math.inf if s.maximum is None else float(s.maximum),
                    )
                    for s in message.signals
                    if s.name not in skip
                )
                self._messages[message.name] = (message, integrity, limits)
                self._layouts[message.name] = FrameLayout.prepare(message, integrity)

    def message(self, name: str) -> Any:
        """The cantools message called ``name``; KeyError if none."""
        return self._messages[name][0]

    def layout(self, name: str) -> FrameLayout | None:
        """The prepared layout of message ``name`` (None: cantools encodes it); KeyError if no such message."""
        return self._layouts[name]

    def data_signals(self, name: str) -> tuple[str, ...]:
        """The data signals of message ``name`` in DBC order (counter and checksum excluded); KeyError if none."""
        return tuple(signal for signal, _, _ in self._messages[name][2])

    def has_counter(self, name: str) -> bool:
        """True if message ``name`` carries the rolling counter and checksum of docs/dbc.md."""
        return self._messages[name][1] is not None

    def encode(self, name: str, values: Mapping[str, float], counter: int = 0) -> bytes:
        """Payload of message ``name`` from physical ``values`` (clamped into range)."""
        layout = self._layouts.get(name)
        if layout is not None:
            return layout.pack([values[signal] for signal in layout.signal_names], counter)
        return self.encode_cantools(name, values, counter)

    def packer(self, name: str, signals: Sequence[str]) -> Callable[[Sequence[float], int], bytes]:
        """``pack(values, counter)``: the payload of message ``name`` from ``values`` given in ``signals`` order,
        the bytes of :meth:`encode`; the message's :meth:`FrameLayout.pack` itself when ``signals`` is its
        order (no mapping built per frame). KeyError if there is no such message."""
        layout = self._layouts[name]
        if layout is not None and tuple(signals) == layout.signal_names:
            return layout.pack
        names = tuple(signals)

        def pack(values: Sequence[float], counter: int = 0) -> bytes:
            return self.encode(name, dict(zip(names, values, strict=True)), counter)

        return pack

    def encode_cantools(self, name: str, values: Mapping[str, float], counter: int = 0) -> bytes:
        """:meth:`encode` through cantools' non-strict encode (the reference of :class:`FrameLayout`)."""
        message, integrity, limits = self._messages[name]
        clean: dict[str, float] = {}
        for signal, low, high in limits:
            value = float(values[signal])
            if math.isnan(value):
                raise ValueError(f"{name}.{signal}: cannot encode NaN")
            clean[signal] = min(max(value, low), high)
        if integrity is not None:
            clean[integrity[0].name] = counter % 16
            clean[integrity[1].name] = 0
        data = bytearray(message.encode(clean, strict=False, scaling=True))
        if integrity is not None:
            data[CHECKSUM_BYTE] = frame_checksum(data)
        return bytes(data)

    def encode_rows(self, name: str, columns: Mapping[str, Any], first_counter: int = 0) -> list[bytes]:
        """Payloads of message ``name`` for rows of physical values (one array per data signal): the
        same bytes as :meth:`encode` row by row with counters ``first_counter, first_counter + 1, ...``,
        the clamping and the NaN check done on whole arrays."""
        message, integrity, limits = self._messages[name]
        names = [signal for signal, _, _ in limits]
        clipped = []
        for signal, low, high in limits:
            column = np.asarray(columns[signal], dtype=np.float64)
            if np.isnan(column).any():
                raise ValueError(f"{name}.{signal}: cannot encode NaN")
            clipped.append(np.clip(column, low, high).tolist())
        encode = message.encode
        out: list[bytes] = []
        counter_name = checksum_name = ""
        if integrity is not None:
            counter_name, checksum_name = integrity[0].name, integrity[1].name
        for k, row in enumerate(zip(*clipped, strict=True)):
            clean = dict(zip(names, row, strict=True))
            if integrity is None:
                out.append(bytes(encode(clean, strict=False, scaling=True)))
                continue
            clean[counter_name] = (first_counter + k) % 16
            clean[checksum_name] = 0
            data = bytearray(encode(clean, strict=False, scaling=True))
            data[CHECKSUM_BYTE] = frame_checksum(data)
            out.append(bytes(data))
        return out
