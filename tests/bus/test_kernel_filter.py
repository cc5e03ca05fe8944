"""The udp_multicast kernel receive filter (bus/kernel_filter.py) keeps exactly what python-can's filter keeps.

The BPF program is attached to a UDP socket on 127.0.0.1 (no multicast, no privilege needed) and fed
datagrams packed by python-can's own ``pack_message``; what the kernel lets through is compared with
``BusABC._matches_filters`` on the same frames.
"""

from __future__ import annotations

import random
import socket
import sys

import can
import pytest

from ecu_monitor.bus.kernel_filter import attach_kernel_filter, attach_program, udp_filter_program

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="SO_ATTACH_FILTER is Linux's")
pack_message = pytest.importorskip("can.interfaces.udp_multicast.utils").pack_message
pytest.importorskip("msgpack")

SENTINEL_ID = 0x5A5  # matched by every filter set below: marks the end of a batch


def _python_can_keeps(filters: list[dict[str, int]], frames: list[can.Message]) -> list[bool]:
    """python-can's own matching (``BusABC._matches_filters``, what ``recv`` applies) of each frame."""
    bus = can.Bus(interface="virtual", channel="kernel-filter-reference", receive_own_messages=False)
    try:
        bus.set_filters(filters)
        return [bool(bus._matches_filters(frame)) for frame in frames]
    finally:
        bus.shutdown()


def _kernel_keeps(filters: list[dict[str, int]], datagrams: list[bytes]) -> list[bytes]:
    """The datagrams (in order) that a socket with the filter of ``filters`` receives."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        rx.bind(("127.0.0.1", 0))
        rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        rx.settimeout(10.0)
        attach_program(rx, udp_filter_program(filters))
        sentinel = pack_message(can.Message(timestamp=1.0, arbitration_id=SENTINEL_ID, is_extended_id=False))
        kept = []
        for start in range(0, len(datagrams), 200):  # batches well inside the receive buffer
            for data in datagrams[start : start + 200]:
                tx.sendto(data, rx.getsockname())
            tx.sendto(sentinel, rx.getsockname())
            while (got := rx.recv(4096)) != sentinel:
                kept.append(got)
        return kept
    finally:
        rx.close()
        tx.close()


def _frames(rng: random.Random, ids: list[int]) -> list[can.Message]:
    return [
        can.Message(
            timestamp=rng.uniform(0.0, 2e9),
            arbitration_id=frame_id,
            is_extended_id=frame_id > 0x7FF or rng.random() < 0.1,
            data=rng.randbytes(rng.randrange(9)),
        )
        for frame_id in ids
    ]


def test_kernel_keeps_exactly_what_python_can_keeps() -> None:
    rng = random.Random(13)
    filters = [{"can_id": i, "can_mask": 0x1FFFFFFF} for i in (0x7F, 0x80, 0x100, 0x101, 0x200, 0xFF, SENTINEL_ID)]
    filters.append({"can_id": 0x1234500, "can_mask": 0x00FFFF80})  # a DroneCAN-style masked id
    filters.append({"can_id": 0x18FEEE00, "can_mask": 0x1FFFFF00})
    edges = [0, 1, 0x7E, 0x7F, 0x80, 0x81, 0xFF, 0x100, 0x101, 0x1FF, 0x200, 0xFFFF, 0x10000, 0x1234500, 0x123457F,
             0x1234580, 0x18FEEE00, 0x18FEEEFF, 0x18FEEF00, 0x1FFFFFFF]  # fmt: skip
    ids = edges + [rng.choice((0x7F, 0xFF, 0x7FF, 0xFFFF, 0x1FFFFFFF)) & rng.getrandbits(29) for _ in range(3000)]
    ids += [rng.choice(edges) for _ in range(1000)]
    frames = _frames(rng, ids)
    datagrams = [pack_message(f) for f in frames]
    expected = [d for keep, d in zip(_python_can_keeps(filters, frames), datagrams, strict=True) if keep]
    kept = _kernel_keeps(filters, datagrams)
    assert kept == expected
    assert 0 < len(kept) < len(datagrams) // 2  # the test feeds both kinds


def test_what_the_program_cannot_read_is_left_to_python_can() -> None:
    filters = [{"can_id": 0x100, "can_mask": 0x7FF}, {"can_id": SENTINEL_ID, "can_mask": 0x7FF}]
    other = pack_message(can.Message(timestamp=1.5, arbitration_id=0x400))
    odd = [
        b"",
        b"short",
        b"\x8b" + b"\x00" * 60,  # a map of other keys
        other.replace(b"\xcb", b"\xca", 1),  # a float32 timestamp: another layout
        other.replace(b"\xa9timestamp", b"\xa9timeStamp", 1),
        other[:36],  # cut inside the id
        bytes(range(256)),
    ]
    assert _kernel_keeps(filters, [other, *odd]) == odd  # the packed other id is dropped, the rest kept


def test_only_udp_multicast_buses_get_the_filter() -> None:
    bus = can.Bus(interface="virtual", channel="kernel-filter-test", receive_own_messages=False)
    try:
        assert not attach_kernel_filter(bus, [{"can_id": 0x100, "can_mask": 0x7FF}])
    finally:
        bus.shutdown()
