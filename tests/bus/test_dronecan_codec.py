"""The prepared DSDL codec (bus/dronecan_codec.py) against the ``dronecan`` package itself, bit for bit.

Every message type of the package's DSDL tree (broadcasts and the nested types), filled with random values and
edge values (integer limits, float16/float32 limits, NaN, infinities, empty and full arrays, every union
field): payloads packed by the package unpack to the package's own values through the prepared decoder, and
the prepared encoder packs the same values to the same bytes. Truncated payloads fail or decode exactly as
the package does; the transfer framing (CRC, tail bytes) equals ``Transfer.to_frames``; the float16 conversions
equal the package's over every half-precision value."""

from __future__ import annotations

import math
import random
import struct
from typing import Any

import numpy as np
import pytest

from ecu_monitor.bus.dronecan_codec import (
    PayloadError,
    column_values,
    message_codec,
    service_codec,
    transfer_crc,
    transfer_crc_rows,
    transfer_frames,
)

dronecan = pytest.importorskip("dronecan")
T = dronecan.transport
MESSAGE_TYPES = sorted((t for t in dronecan.TYPENAMES.values() if t.kind == t.KIND_MESSAGE), key=lambda t: t.full_name)


def _float(rng: random.Random, bits: int) -> float:
    roll = rng.random()
    if roll < 0.1:
        return rng.choice([math.nan, math.inf, -math.inf, 0.0, -0.0])
    if roll < 0.2:  # at and beyond the type's range: the cast saturates or goes infinite as the package does
        limit = {16: 65504.0, 32: 3.4028234663852886e38, 64: 1.7976931348623157e308}[bits]
        return rng.choice([limit, -limit, 65520.0, -7e4, 1e-8, -6e-8, 2.0**-24, 2.0**-14])
    if roll < 0.5 and bits == 16:
        return float(struct.unpack("<e", rng.getrandbits(16).to_bytes(2, "little"))[0])
    return rng.uniform(-1e5, 1e5) * rng.choice([1.0, 1e-6, 1e-3])


def _random(dtype: Any, rng: random.Random) -> Any:
    """A random plain value of ``dtype`` (dict, list, number), edge values often."""
    category = dtype.category
    if category == dtype.CATEGORY_PRIMITIVE:
        if dtype.kind == dtype.KIND_BOOLEAN:
            return rng.random() < 0.5
        if dtype.kind == dtype.KIND_FLOAT:
            return _float(rng, dtype.bitlen)
        low, high = dtype.value_range
        return rng.choice([low, high, rng.randint(low, high), rng.randint(low, high)])
    if category == dtype.CATEGORY_ARRAY:
        if dtype.mode == dtype.MODE_STATIC:
            size = dtype.max_size
        else:
            size = rng.choice(
                [0, dtype.max_size, rng.randint(0, dtype.max_size), rng.randint(0, min(3, dtype.max_size))]
            )
        return [_random(dtype.value_type, rng) for _ in range(size)]
    fields = [f for f in dtype.fields if f.name]
    if dtype.union:
        chosen = rng.choice(fields)
        return {chosen.name: _random(chosen.type, rng)}
    return {f.name: _random(f.type, rng) for f in fields}


def _package_value(dtype: Any, plain: dict[str, Any]) -> Any:
    """The package's CompoundValue holding ``plain``."""
    out = T.CompoundValue(dtype)
    _fill(out, dtype.fields, plain)
    return out


def _fill(out: Any, fields: Any, plain: dict[str, Any]) -> None:
    """Set the fields of the package's value ``out`` (of DSDL ``fields``) from ``plain``."""
    types = {f.name: f.type for f in fields if f.name}
    for name, value in plain.items():
        ftype = types[name]
        if ftype.category == ftype.CATEGORY_ARRAY:
            array = getattr(out, name)
            item_type = ftype.value_type
            for i, item in enumerate(value):
                item = _package_value(item_type, item) if item_type.category == item_type.CATEGORY_COMPOUND else item
                if ftype.mode == ftype.MODE_STATIC:
                    array[i] = item
                else:
                    array.append(item)
        elif ftype.category == ftype.CATEGORY_COMPOUND:
            setattr(out, name, _package_value(ftype, value))
        else:
            setattr(out, name, value)


def _package_bytes(value: Any) -> bytes:
    bits = value._pack(tao=True)  # what Transfer(payload=value) does for classic CAN
    return bytes(T.bytes_from_bits(bits + "0" * (-len(bits) % 8)))


def _package_decode(dtype: Any, payload: bytes) -> Any:
    value = T.CompoundValue(dtype)
    value._unpack(T.bits_from_bytes(payload), True)
    return _plain(value)


def _plain(value: Any) -> Any:
    if isinstance(value, T.CompoundValue):
        if T.is_union(value):
            name = T.get_active_union_field(value) or next(iter(T.get_fields(value)))
            return {name: _plain(getattr(value, name))}
        return {k: _plain(getattr(value, k)) for k in T.get_fields(value) if not k.startswith("_void_")}
    if isinstance(value, T.ArrayValue):
        return [_plain(item) for item in value]
    return value


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and math.isnan(a):
        return isinstance(b, float) and math.isnan(b)
    return type(a) is type(b) and a == b and (not isinstance(a, float) or math.copysign(1, a) == math.copysign(1, b))


@pytest.mark.parametrize("dtype", MESSAGE_TYPES, ids=lambda t: t.full_name)
def test_every_message_type_decodes_and_encodes_as_the_package(dtype: Any) -> None:
    codec = message_codec(dtype.full_name)
    rng = random.Random(dtype.full_name)
    for _ in range(6):
        plain = _random(dtype, rng)
        payload = _package_bytes(_package_value(dtype, plain))
        expected = _package_decode(dtype, payload)
        assert _same(codec.decode(payload), expected), (dtype.full_name, plain)
        assert codec.encode(plain) == payload, (dtype.full_name, plain)
        _check_columns(codec, payload, expected)
        for cut in sorted({0, len(payload) // 2, max(len(payload) - 1, 0)}):  # truncated: fails as the package fails
            try:
                short = _package_decode(dtype, payload[:cut])
            except (ValueError, IndexError):
                with pytest.raises(PayloadError):
                    codec.decode(payload[:cut])
                try:
                    codec.layout(cut)  # the batch path's layout refuses the same lengths (or cannot tell)
                except PayloadError:
                    pass
                else:
                    assert codec.layout(cut) is None
            else:
                assert _same(codec.decode(payload[:cut]), short)
                _check_columns(codec, payload[:cut], short)


def _check_columns(codec: Any, payload: bytes, expected: Any) -> None:
    """Every number of a layout known from the length, read for a whole column, equals the decoded one."""
    layout = codec.layout(len(payload))
    if layout is None:
        return
    rows = np.frombuffer(payload, dtype=np.uint8).reshape(1, -1).repeat(2, axis=0)

    def walk(node: Any, value: Any) -> None:
        if isinstance(node, dict):
            assert node.keys() == value.keys()
            for name in node:
                walk(node[name], value[name])
        elif isinstance(node, list):
            assert len(node) == len(value)
            for item, one in zip(node, value, strict=True):
                walk(item, one)
        elif node is not None:
            got = column_values(rows, node)
            if got is not None:
                want = float(value)
                assert all(g == want or (math.isnan(g) and math.isnan(want)) for g in got.tolist())

    walk(layout, expected)


def test_transfer_framing_and_crc_equal_the_package() -> None:
    rng = random.Random(14)
    for name in ("uavcan.equipment.ice.reciprocating.Status", "uavcan.protocol.debug.LogMessage",
                 "uavcan.protocol.NodeStatus", "uavcan.protocol.debug.KeyValue"):  # fmt: skip
        dtype = dronecan.TYPENAMES[name]
        codec = message_codec(name)
        for transfer_id in (0, 1, 30, 31):
            value = _package_value(dtype, _random(dtype, rng))
            transfer = T.Transfer(transfer_id=transfer_id, source_node_id=42, payload=value, transfer_priority=9)
            frames = [bytes(f.bytes) for f in transfer.to_frames()]
            assert transfer_frames(bytes(transfer.payload), transfer_id, codec.base_crc) == frames
            body = bytes(transfer.payload)
            assert transfer_crc(body, codec.base_crc) == dronecan.dsdl.crc16_from_bytes(body, initial=dtype.base_crc)
            rows = np.frombuffer(body, dtype=np.uint8).reshape(1, -1)
            assert transfer_crc_rows(rows, codec.base_crc).tolist() == [transfer_crc(body, codec.base_crc)]


def test_float16_over_every_half_value_equals_the_package() -> None:
    from ecu_monitor.bus.dronecan_codec import _f16_bits

    codec = message_codec("uavcan.equipment.air_data.Sideslip")  # two float16 fields
    for half in range(0, 65536, 1):
        payload = half.to_bytes(2, "little") * 2
        got = codec.decode(payload)["sideslip_angle"]
        want = T.f32_from_f16(half)
        assert got == want or (math.isnan(got) and math.isnan(want))
        if math.isfinite(want):
            assert _f16_bits(want) == T.f16_from_f32(want)
    rng = random.Random(16)
    for value in [rng.uniform(-65504, 65504) * rng.choice([1, 1e-3, 1e-6]) for _ in range(5000)]:
        assert _f16_bits(value) == T.f16_from_f32(value)


def test_over_capacity_arrays_and_bad_union_tags_are_payload_errors() -> None:
    status = message_codec("uavcan.equipment.ice.reciprocating.Status")
    one = status.encode({"cylinder_status": [{"cylinder_head_temperature": 400.0}]})
    assert len(status.decode(one + one[-10:] * 15)["cylinder_status"]) == 16
    with pytest.raises(PayloadError):
        status.decode(one + one[-10:] * 16)  # 17 cylinders: the DSDL allows 16
    log = message_codec("uavcan.protocol.debug.LogMessage")
    with pytest.raises(PayloadError):  # source: a 5-bit length 31 with 3 bytes behind it
        log.decode(bytes([0b00111111, 0xFF, 0, 0]))
    with pytest.raises(KeyError, match="has no field 'nope'"):
        status.encode({"nope": 1})


SERVICE_TYPES = sorted((t for t in dronecan.TYPENAMES.values() if t.kind == t.KIND_SERVICE), key=lambda t: t.full_name)


class _Part:
    """A service type's request or response fields, shaped for :func:`_random` (a compound of those fields)."""

    CATEGORY_PRIMITIVE, CATEGORY_ARRAY, category = "primitive", "array", "compound"

    def __init__(self, dtype: Any, part: str) -> None:
        self.fields, self.union = getattr(dtype, f"{part}_fields"), getattr(dtype, f"{part}_union")


@pytest.mark.parametrize("part", ["request", "response"])
@pytest.mark.parametrize("dtype", SERVICE_TYPES, ids=lambda t: t.full_name)
def test_every_service_request_and_response_decodes_and_encodes_as_the_package(dtype: Any, part: str) -> None:
    codec = service_codec(dtype.full_name, part)
    assert (codec.data_type_id, codec.base_crc) == (dtype.default_dtid, dtype.base_crc)
    rng = random.Random(f"{dtype.full_name}.{part}")
    for _ in range(4):
        plain = _random(_Part(dtype, part), rng)
        value = T.CompoundValue(dtype, _mode=part)
        _fill(value, getattr(dtype, f"{part}_fields"), plain)
        payload = _package_bytes(value)
        decoded = T.CompoundValue(dtype, _mode=part)
        decoded._unpack(T.bits_from_bytes(payload), True)
        assert _same(codec.decode(payload), _plain(decoded)), (dtype.full_name, part, plain)
        assert codec.encode(plain) == payload, (dtype.full_name, part, plain)
