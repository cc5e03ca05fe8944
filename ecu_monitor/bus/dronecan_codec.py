"""DroneCAN (UAVCAN v0) payloads and transfers with integer arithmetic, prepared from the ``dronecan`` package's DSDL.

The ``dronecan`` package decodes and encodes through strings of '0'/'1' characters and builds a Python object per
field (0.3-0.6 ms for a 7-frame ICE status). Here each data type is prepared once, at start-up, from the package's
own parsed type definition (:class:`dronecan.dsdl.CompoundType`: field names, kinds, bit lengths, cast modes, value
ranges, array modes and capacities, union tags, the data type's CRC seed ``base_crc``): no message layout is written
by hand. A payload then unpacks with ``int``/``struct`` arithmetic into plain values and packs back the same way:

* a compound is a ``dict`` (field name -> value; a union holds only its active field), an array a ``list``,
  a number an ``int``, ``float`` or ``bool`` (void fields are skipped);
* the bit order is the package's (``be_from_le_bits``): the payload is a bit stream, most significant bit of each
  byte first; a field of ``n`` bits is its value's little-endian bytes, the last one holding the top ``n mod 8``
  bits. Runs of byte-aligned fields of 8/16/32/64 bits are one :class:`struct.Struct` (float16 is struct's ``e``);
* tail-array optimisation as the package applies it (classic CAN): the last field of the message, and recursively
  the last field or element of it, takes ``tao``; a dynamic array under ``tao`` whose element is at least 8 bits
  long has no length prefix and runs to the end of the payload (while 8 bits or more remain);
* length prefix and union tag widths are the package's (``array_len_bits_from_max_size``,
  ``union_tag_bits_from_num_elements``); values are cast on the way out as the package casts them (saturated:
  clamped to the type's range; truncated: integers masked, floats beyond the range infinite); float16 is rounded as
  the package's ``f16_from_f32`` (libuavcan's conversion).

Stricter than the package on bad input, never looser: a payload too short for its fields, an array longer than its
DSDL capacity or a union tag beyond its fields raises :class:`PayloadError` (the package would take an over-long
array). tests/bus/test_dronecan_codec.py checks both directions bit for bit against the package itself.

:func:`transfer_frames` splits a payload into the frames of one transfer (transfer CRC seeded by the data type's
``base_crc`` for a multi-frame transfer, tail bytes: start, end, toggle, transfer id) as
``dronecan.transport.Transfer.to_frames`` does; :func:`transfer_crc` is the CRC the receiver checks.
"""

from __future__ import annotations

import binascii
import functools
import logging
import math
import struct
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = [
    "MessageCodec",
    "PayloadError",
    "column_values",
    "dronecan_module",
    "message_codec",
    "service_codec",
    "take_bits",
    "transfer_crc",
    "transfer_crc_rows",
    "transfer_frames",
]

_F16 = struct.Struct("<e")
_F32 = struct.Struct("<f")
_F64 = struct.Struct("<d")
_U32 = struct.Struct("<I")
#: struct codes of byte-aligned primitives: (kind, bits) -> code; kinds as dronecan.dsdl.PrimitiveType.KIND_*
_STRUCT_CODES = {
    (1, 8): "B", (1, 16): "H", (1, 32): "I", (1, 64): "Q",
    (2, 8): "b", (2, 16): "h", (2, 32): "i", (2, 64): "q",
    (3, 16): "e", (3, 32): "f", (3, 64): "d",
}  # fmt: skip
_BOOLEAN, _UNSIGNED, _SIGNED, _FLOAT = 0, 1, 2, 3
_SATURATED = 0


class PayloadError(ValueError):
    """A payload that does not unpack as its data type (too short, an array over capacity, a bad union tag)."""


@functools.cache
def dronecan_module() -> Any:
    """The ``dronecan`` package, imported on first use (it parses its DSDL tree on import, ~0.3 s)."""
    quiet = logging.Filter("-")  # drops every record: the import's note that its SLCAN driver lacks pyserial
    driver_log = logging.getLogger("dronecan.driver.slcan")
    driver_log.addFilter(quiet)
    try:
        import dronecan
    finally:
        driver_log.removeFilter(quiet)
    return dronecan


# Every prepared node has read(payload bytes, payload as a big-endian int, payload bit count, bit position,
# tail-array flag) -> (value, next bit position) and write(accumulator int, bit count, value, tail-array flag)
# -> (accumulator, bit count).


def _f16_bits(value: float) -> int:
    """float -> float16 bits, rounded as the package's ``f16_from_f32`` (libuavcan's conversion)."""
    u = _U32.unpack(_F32.pack(value))[0]
    sign = u & 0x80000000
    u ^= sign
    if u >= 0x7F800000:  # inf or NaN
        out = 0x7FFF if u > 0x7F800000 else 0x7C00
    else:
        u &= 0xFFFFF000
        u = _U32.unpack(_F32.pack(_F32.unpack(_U32.pack(u))[0] * 2.0**-112))[0]
        u += 0x1000
        out = (min(u, 31 << 23) >> 13) & 0xFFFF
    return out | (sign >> 16)


class _Primitive:
    """A bool, integer or float field: its raw bits to and from the Python value, as the package does."""

    def __init__(self, dtype: Any) -> None:
        self.kind: int = dtype.kind
        self.bits: int = dtype.bitlen
        self.low, self.high = dtype.value_range
        self.saturated = dtype.cast_mode == _SATURATED
        self.code = _STRUCT_CODES.get((self.kind, self.bits))  # None: not a struct field
        self.full_bytes, self.rest = divmod(self.bits, 8)
        if self.kind == _FLOAT and self.bits not in (16, 32, 64):
            raise PayloadError(f"float{self.bits}: not a DSDL float")

    def value(self, raw: int) -> Any:
        """The raw bits (an unsigned int) as the field's value."""
        kind = self.kind
        if kind == _UNSIGNED:
            return raw
        if kind == _FLOAT:
            bits = self.bits
            if bits == 16:
                return _F16.unpack(raw.to_bytes(2, "little"))[0]
            return (_F32 if bits == 32 else _F64).unpack(raw.to_bytes(bits // 8, "little"))[0]
        if kind == _SIGNED:
            return raw - (1 << self.bits) if raw >> (self.bits - 1) else raw
        return bool(raw)

    def raw(self, value: Any) -> int:
        """The field's raw bits for ``value``, cast as the package casts it (``dronecan.transport.cast``).

        ``None`` (not given) is NaN for a float (DSDL: unknown), else 0; a non-integer number for an integer
        field is rounded (non-finite: 0)."""
        kind = self.kind
        if kind == _BOOLEAN:
            return 1 if value else 0
        if kind == _FLOAT:
            value = math.nan if value is None else float(value)
            if self.saturated:
                value = self.high if value > self.high else self.low if value < self.low else value
            elif value > self.high:
                value = math.inf
            elif value < self.low:
                value = -math.inf
            if self.bits == 16:
                return _f16_bits(value)
            if self.bits == 32:
                return int(_U32.unpack(_F32.pack(value))[0])
            return int.from_bytes(_F64.pack(value), "little")
        if value is None:
            value = 0
        elif hasattr(value, "__index__"):
            value = value.__index__()
        else:
            number = float(value)
            value = round(number) if math.isfinite(number) else 0
        if self.saturated:
            value = self.high if value > self.high else self.low if value < self.low else value
        else:
            value &= (1 << self.bits) - 1
        return value + (1 << self.bits) if value < 0 else value

    def read(self, data: bytes, big: int, total: int, pos: int, tao: bool) -> tuple[Any, int]:
        end = pos + self.bits
        if end > total:
            raise PayloadError("payload too short")
        if not pos & 7 and not self.rest:
            return self.value(int.from_bytes(data[pos >> 3 : end >> 3], "little")), end
        return self.value(_take(big, total, pos, self.bits, self.full_bytes, self.rest)), end

    def write(self, acc: int, nbits: int, value: Any, tao: bool) -> tuple[int, int]:
        return _put(acc, self.raw(value), self.bits, self.full_bytes, self.rest), nbits + self.bits

    def layout(self, total: int, pos: int, tao: bool) -> tuple[Any, int]:
        if pos + self.bits > total:
            raise PayloadError("payload too short")
        return (pos, self), pos + self.bits

    def fixed_bits(self) -> int | None:
        return self.bits


def _take(big: int, total: int, pos: int, bits: int, full_bytes: int, rest: int) -> int:
    """The unsigned value of the ``bits`` bits at ``pos`` of the stream ``big`` (``total`` bits), package bit order."""
    segment = (big >> (total - pos - bits)) & ((1 << bits) - 1)
    low = int.from_bytes((segment >> rest).to_bytes(full_bytes, "big"), "little") if full_bytes else 0
    return low | (segment & ((1 << rest) - 1)) << (8 * full_bytes)


#: the public name of :func:`_take` (the live decoder's field readers use it)
take_bits = _take


def _put(acc: int, raw: int, bits: int, full_bytes: int, rest: int) -> int:
    """``acc`` with the ``bits`` bits of ``raw`` appended in the package's bit order."""
    low = int.from_bytes((raw & ((1 << (8 * full_bytes)) - 1)).to_bytes(full_bytes, "little"), "big")
    return (acc << bits) | (low << rest) | (raw >> (8 * full_bytes))


class _Void:
    def __init__(self, bits: int) -> None:
        self.bits = bits

    def read(self, data: bytes, big: int, total: int, pos: int, tao: bool) -> tuple[Any, int]:
        return None, pos + self.bits  # the package skips void bits without looking

    def write(self, acc: int, nbits: int, value: Any, tao: bool) -> tuple[int, int]:
        return acc << self.bits, nbits + self.bits

    def layout(self, total: int, pos: int, tao: bool) -> tuple[Any, int]:
        return None, pos + self.bits

    def fixed_bits(self) -> int | None:
        return self.bits


class _Array:
    """A static or dynamic array; dynamic ones with a length prefix or, under tail-array optimisation, without."""

    def __init__(self, dtype: Any, transport: Any) -> None:
        self.item = _node(dtype.value_type, transport)
        self.static = dtype.mode == dtype.MODE_STATIC
        self.capacity: int = dtype.max_size
        self.tao_ok = dtype.value_type.get_min_bitlen() >= 8  # no length prefix under TAO
        self.count_bits = 0 if self.static else int(transport.array_len_bits_from_max_size(dtype.max_size))
        self.count_split = divmod(self.count_bits, 8)
        item = self.item
        self.byte_items = isinstance(item, _Primitive) and item.kind == _UNSIGNED and item.bits == 8

    def read(self, data: bytes, big: int, total: int, pos: int, tao: bool) -> tuple[Any, int]:
        item = self.item
        out: list[Any] = []
        if self.static:
            count = self.capacity
        elif tao and self.tao_ok:
            if self.byte_items and not pos & 7:
                out = list(data[pos >> 3 :])
                if len(out) > self.capacity:
                    raise PayloadError("array longer than its capacity")
                return out, max(pos, total)
            while total - pos >= 8:
                if len(out) == self.capacity:
                    raise PayloadError("array longer than its capacity")
                value, pos = item.read(data, big, total, pos, False)
                out.append(value)
            return out, max(pos, total)
        else:
            if pos + self.count_bits > total:
                raise PayloadError("payload too short")
            count = _take(big, total, pos, self.count_bits, *self.count_split)
            pos += self.count_bits
            if count > self.capacity:
                raise PayloadError("array longer than its capacity")
        if self.byte_items and not pos & 7:
            end = pos + 8 * count
            if end > total:
                raise PayloadError("payload too short")
            return list(data[pos >> 3 : end >> 3]), end
        last = count - 1
        for i in range(count):
            value, pos = item.read(data, big, total, pos, tao and i == last)
            out.append(value)
        return out, pos

    def layout(self, total: int, pos: int, tao: bool) -> tuple[Any, int]:
        """The elements' layouts, when the element count follows from the payload length alone."""
        item = self.item
        if self.static:
            out = []
            for i in range(self.capacity):
                node, pos = item.layout(total, pos, tao and i == self.capacity - 1)
                out.append(node)
            return out, pos
        if not (tao and self.tao_ok) or item.fixed_bits() is None:
            raise _ContentDependentError
        out = []
        while total - pos >= 8:
            if len(out) == self.capacity:
                raise PayloadError("array longer than its capacity")
            node, pos = item.layout(total, pos, False)
            out.append(node)
        return out, max(pos, total)

    def fixed_bits(self) -> int | None:
        bits = self.item.fixed_bits()
        return None if bits is None or not self.static else bits * self.capacity

    def write(self, acc: int, nbits: int, value: Any, tao: bool) -> tuple[int, int]:
        if value is None:
            items: list[Any] = []
        elif isinstance(value, str) and self.byte_items:
            items = list(value.encode("ascii", "replace"))
        else:
            items = list(value)
        items = items[: self.capacity]
        if self.static:
            items += [None] * (self.capacity - len(items))
        without_prefix = not self.static and tao and self.tao_ok
        if not self.static and not without_prefix:
            acc = _put(acc, len(items), self.count_bits, *self.count_split)
            nbits += self.count_bits
        item = self.item
        if self.byte_items and items:
            raws = bytes(item.raw(one) for one in items)
            return (acc << (8 * len(raws))) | int.from_bytes(raws, "big"), nbits + 8 * len(raws)
        last = len(items) - 1
        for i, one in enumerate(items):  # the package: TAO reaches the last item unless the array itself took it
            acc, nbits = item.write(acc, nbits, one, tao and not without_prefix and i == last)
        return acc, nbits


class _ContentDependentError(Exception):
    """A layout that depends on the payload's content (a length prefix, a union tag), not only its length."""


class _Compound:
    """A message or nested type: its fields in order (byte-aligned runs of struct fields at once), or a union."""

    def __init__(self, dtype: Any, transport: Any) -> None:
        self.full_name: str = dtype.full_name
        fields = list(dtype.fields)
        self.union = bool(dtype.union)
        self.names: tuple[str, ...] = tuple(f.name for f in fields if f.name)
        self.name_set = frozenset(self.names)
        self.nodes: dict[str, Any] = {}
        plan: list[tuple[Any, ...]] = []  # ("run", names, Struct, bits, [(name, node)]) or ("one", name, node)
        run: list[tuple[str | None, Any]] = []

        def close_run() -> None:
            if len(run) > 1:
                code = "<" + "".join(f"{n.bits // 8}x" if isinstance(n, _Void) else n.code for _, n in run)
                plan.append(("run", tuple(name for name, _ in run if name), struct.Struct(code),
                             sum(n.bits for _, n in run), tuple(run)))  # fmt: skip
            else:
                plan.extend(("one", name, n) for name, n in run)
            run.clear()

        self.all_nodes: list[Any] = []  # every field's node, voids included
        for field in fields:
            node = _node(field.type, transport)
            self.all_nodes.append(node)
            if field.name:
                self.nodes[field.name] = node
            structable = (isinstance(node, _Primitive) and node.code is not None) or (
                isinstance(node, _Void) and node.bits % 8 == 0
            )
            if structable and not self.union:
                run.append((field.name, node))
                continue
            close_run()
            plan.append(("one", field.name, node))
        close_run()
        self.plan = tuple(plan)
        self.last = len(plan) - 1
        if self.union:
            self.tag_bits = int(transport.union_tag_bits_from_num_elements(len(fields)))
            self.tag_split = divmod(self.tag_bits, 8)

    def read(self, data: bytes, big: int, total: int, pos: int, tao: bool) -> tuple[Any, int]:
        if self.union:
            if pos + self.tag_bits > total:
                raise PayloadError("payload too short")
            tag = (big >> (total - pos - self.tag_bits)) & ((1 << self.tag_bits) - 1)  # the package: MSB first
            if tag >= len(self.names):
                raise PayloadError("union tag beyond its fields")
            name = self.names[tag]
            value, pos = self.nodes[name].read(data, big, total, pos + self.tag_bits, tao)
            return {name: value}, pos
        out: dict[str, Any] = {}
        last = self.last
        for i, step in enumerate(self.plan):
            if step[0] == "run":
                _, names, layout, bits, parts = step
                if not pos & 7 and pos + bits <= total:
                    out.update(zip(names, layout.unpack_from(data, pos >> 3), strict=True))
                    pos += bits
                else:
                    for name, node in parts:
                        value, pos = node.read(data, big, total, pos, False)
                        if name:
                            out[name] = value
            else:
                _, name, node = step
                value, pos = node.read(data, big, total, pos, tao and i == last)
                if name:
                    out[name] = value
        return out, pos

    def layout(self, total: int, pos: int, tao: bool) -> tuple[Any, int]:
        if self.union:
            raise _ContentDependentError
        out: dict[str, Any] = {}
        last = self.last
        for i, step in enumerate(self.plan):
            parts = step[4] if step[0] == "run" else ((step[1], step[2]),)
            for name, node in parts:
                sub, pos = node.layout(total, pos, tao and i == last)
                if name:
                    out[name] = sub
        return out, pos

    def fixed_bits(self) -> int | None:
        if self.union:
            return None
        total = 0
        for node in self.all_nodes:
            bits = node.fixed_bits()
            if bits is None:
                return None
            total += bits
        return total

    def write(self, acc: int, nbits: int, value: Mapping[str, Any] | None, tao: bool) -> tuple[int, int]:
        if value is None:
            value = {}
        elif not self.name_set.issuperset(value):
            unknown = sorted(set(value) - self.name_set)
            raise KeyError(f"{self.full_name} has no field {unknown[0]!r}")
        if self.union:
            given = [name for name in self.names if name in value]
            name = given[0] if given else self.names[0]
            acc = (acc << self.tag_bits) | self.names.index(name)
            return self.nodes[name].write(acc, nbits + self.tag_bits, value.get(name), tao)
        last = self.last
        for i, step in enumerate(self.plan):
            parts = step[4] if step[0] == "run" else ((step[1], step[2]),)
            for name, node in parts:
                acc, nbits = node.write(acc, nbits, value.get(name) if name else None, tao and i == last)
        return acc, nbits


def _node(dtype: Any, transport: Any) -> Any:
    """The prepared node of a DSDL type (dronecan.dsdl.Type)."""
    category = dtype.category
    if category == dtype.CATEGORY_PRIMITIVE:
        return _Primitive(dtype)
    if category == dtype.CATEGORY_VOID:
        return _Void(dtype.bitlen)
    if category == dtype.CATEGORY_ARRAY:
        return _Array(dtype, transport)
    return _Compound(dtype, transport)


class _ServicePart:
    """The request or the response of a DSDL service type, shaped as a compound type for :class:`_Compound`."""

    def __init__(self, dtype: Any, part: str) -> None:
        self.full_name = f"{dtype.full_name}.{part.capitalize()}"
        self.fields = getattr(dtype, f"{part}_fields")
        self.union = getattr(dtype, f"{part}_union")


class MessageCodec:
    """One DSDL message type, or the request or response of a service type (``part``: "request" or
    "response"), prepared for :meth:`decode` and :meth:`encode` (module docstring).

    ``data_type_id`` (the message or service type id) and ``base_crc`` (the transfer CRC's seed, from the data
    type signature) are the package's (both None for a nested type).
    """

    def __init__(self, dtype: Any, part: str | None = None) -> None:
        if part is None and dtype.kind != dtype.KIND_MESSAGE:
            raise ValueError(f"{dtype.full_name}: not a message type")
        if part is not None and (dtype.kind != dtype.KIND_SERVICE or part not in ("request", "response")):
            raise ValueError(f"{dtype.full_name}: not a service type, or {part!r} not one of request, response")
        self.full_name: str = dtype.full_name
        self.data_type_id: int | None = dtype.default_dtid
        self.base_crc: int | None = getattr(dtype, "base_crc", None)  # None: a nested type, never sent alone
        self._root = _Compound(dtype if part is None else _ServicePart(dtype, part), dronecan_module().transport)

    def decode(self, payload: bytes) -> dict[str, Any]:
        """A transfer's payload (without the transfer CRC) -> field name -> value; PayloadError if it cannot be."""
        total = 8 * len(payload)
        value, _ = self._root.read(payload, int.from_bytes(payload, "big"), total, 0, True)
        result: dict[str, Any] = value
        return result

    def layout(self, nbytes: int) -> dict[str, Any] | None:
        """Where each field lies in every payload of ``nbytes`` bytes: the structure :meth:`decode` gives,
        with ``(bit offset, node)`` for each number (``None`` for a void) and one entry per array element;
        None when the layout depends on the content (a length-prefixed array, a union); PayloadError when
        no payload of that length unpacks (the same payloads :meth:`decode` refuses)."""
        try:
            out, _ = self._root.layout(8 * nbytes, 0, True)
        except _ContentDependentError:
            return None
        result: dict[str, Any] = out
        return result

    def encode(self, values: Mapping[str, Any]) -> bytes:
        """Field name -> value -> the payload bytes. A compound is a mapping, an array a sequence (a byte array
        may be a str: ASCII, '?' for other characters), cut to its capacity; a field not given is NaN if a
        float (DSDL: unknown), else 0 or empty; KeyError for a name the type does not have."""
        acc, nbits = self._root.write(0, 0, values, True)
        pad = -nbits % 8
        return (acc << pad).to_bytes((nbits + pad) // 8, "big")


def column_values(payloads: np.ndarray, leaf: tuple[int, Any]) -> np.ndarray | None:
    """The number at ``leaf`` (``(bit offset, node)`` of :meth:`MessageCodec.layout`) of every row of
    ``payloads`` (uint8, one payload per row, all of the layout's length), as float64: the value
    :meth:`MessageCodec.decode` gives, as a float. None for a field spread over more than 8 bytes."""
    pos, node = leaf
    bits = node.bits
    first, last = pos >> 3, (pos + bits - 1) >> 3
    if last - first >= 8:
        return None
    segment = np.zeros(len(payloads), dtype=np.uint64)
    for b in range(first, last + 1):
        segment = (segment << np.uint64(8)) | payloads[:, b].astype(np.uint64)
    segment >>= np.uint64(8 * (last + 1) - (pos + bits))
    if bits < 64:
        segment &= np.uint64((1 << bits) - 1)
    full_bytes, rest = divmod(bits, 8)
    raw = np.zeros(len(payloads), dtype=np.uint64)
    for i in range(full_bytes):  # the package's bit order: the value's little-endian bytes, the top bits last
        raw |= ((segment >> np.uint64(bits - 8 * (i + 1))) & np.uint64(0xFF)) << np.uint64(8 * i)
    if rest:
        raw |= (segment & np.uint64((1 << rest) - 1)) << np.uint64(8 * full_bytes)
    kind = node.kind
    if kind == _UNSIGNED:
        return raw.astype(np.float64)
    if kind == _BOOLEAN:
        return (raw != 0).astype(np.float64)
    if kind == _SIGNED:
        signed = raw.view(np.int64)
        if bits < 64:
            signed = np.where(raw >= np.uint64(1 << (bits - 1)), signed - (1 << bits), signed)
        return signed.astype(np.float64)
    if bits == 16:
        return raw.astype(np.uint16).view(np.float16).astype(np.float64)
    if bits == 32:
        return raw.astype(np.uint32).view(np.float32).astype(np.float64)
    return raw.view(np.float64).copy()


#: CRC-16-CCITT (polynomial 0x1021, unreflected) of each byte value, for :func:`transfer_crc_rows`
_CRC_TABLE = np.array([binascii.crc_hqx(bytes((b,)), 0) for b in range(256)], dtype=np.uint32)


def transfer_crc_rows(payloads: np.ndarray, base_crc: int) -> np.ndarray:
    """:func:`transfer_crc` of every row of ``payloads`` (uint8, equal lengths), vectorised over the rows."""
    crc = np.full(len(payloads), base_crc, dtype=np.uint32)
    for column in range(payloads.shape[1]):
        crc = ((crc << 8) & 0xFFFF) ^ _CRC_TABLE[((crc >> 8) ^ payloads[:, column]) & 0xFF]
    return crc


@functools.cache
def message_codec(type_name: str) -> MessageCodec:
    """The prepared codec of the message ``type_name`` (KeyError if the package has no such type)."""
    return MessageCodec(dronecan_module().TYPENAMES[type_name])


@functools.cache
def service_codec(type_name: str, part: str) -> MessageCodec:
    """The prepared codec of the ``part`` ("request" or "response") of the service ``type_name``."""
    return MessageCodec(dronecan_module().TYPENAMES[type_name], part)


def transfer_crc(payload: bytes, base_crc: int) -> int:
    """CRC-16-CCITT of a multi-frame transfer's payload seeded by the data type's ``base_crc`` (the package's
    ``crc16_from_bytes``; binascii's ``crc_hqx`` is the same polynomial, unreflected, computed in C)."""
    return binascii.crc_hqx(payload, base_crc)


def transfer_frames(payload: bytes, transfer_id: int, base_crc: int) -> list[bytes]:
    """The data of each frame of one classic-CAN transfer of ``payload`` (``Transfer.to_frames``)."""
    tid = transfer_id & 0x1F
    if len(payload) <= 7:
        return [payload + bytes((0xC0 | tid,))]
    crc = transfer_crc(payload, base_crc)
    stream = bytes((crc & 0xFF, crc >> 8)) + payload
    out: list[bytes] = []
    last = (len(stream) - 1) // 7
    for k in range(last + 1):
        tail = (0x80 if k == 0 else 0) | (0x40 if k == last else 0) | (0x20 if k & 1 else 0) | tid
        out.append(stream[7 * k : 7 * k + 7] + bytes((tail,)))
    return out
