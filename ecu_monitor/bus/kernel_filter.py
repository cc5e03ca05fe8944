"""Receive filters in the kernel for python-can's ``udp_multicast`` interface (Linux).

On socketcan the kernel applies a bus's receive filters: frames of other ids never reach the process.
``udp_multicast`` has no such filter: every process on the group receives every datagram, and
python-can unpacks each one (msgpack, a checked ``can.Message``) before ``BusABC.recv`` drops it on
its id, ~20 us of Python per frame: at 4,000 frames/s of other traffic that alone is 8-9 % of a core.

:func:`attach_kernel_filter` attaches a classic BPF socket filter (``SO_ATTACH_FILTER``) to the bus's
UDP socket that drops, in the kernel, the datagrams whose CAN id matches none of the filters. It reads
the id where python-can's ``pack_message`` puts it: the datagram is a msgpack map whose first two keys
are ``timestamp`` (a float64) and ``arbitration_id`` (a positive integer in 1, 2, 3 or 5 bytes), so the
id starts at byte 35 of the UDP payload. A datagram that does not have exactly this layout (shorter,
another key order, another encoding of the timestamp) is accepted and left to python-can, so the
kernel only ever drops datagrams that provably carry another id; python-can's own filter still runs
on everything that passes (the ``extended`` flag of a filter is checked there only). A datagram is
never changed, only kept or dropped.

The layout is checked once against python-can's own ``pack_message`` before the filter is attached
(a python-can that packs differently gets no kernel filter, and a warning, never a wrong one).
"""

from __future__ import annotations

import ctypes
import logging
import os
import socket
import struct
from collections.abc import Sequence

import can
from can.typechecking import CanFilter

__all__ = ["PAYLOAD_ID_OFFSET", "attach_kernel_filter", "attach_program", "udp_filter_program"]

_log = logging.getLogger(__name__)

#: SO_ATTACH_FILTER (asm-generic/socket.h; not exported by Python's socket module).
SO_ATTACH_FILTER = 26
#: Offset of the UDP payload in the packet a socket filter sees (it starts at the UDP header), bytes.
_UDP_HEADER = 8
#: Byte of the UDP payload where the encoded CAN id starts (module docstring).
PAYLOAD_ID_OFFSET = 35
#: The payload before the id: msgpack map header (any fixmap), key "timestamp", float64 marker,
#: the 8 timestamp bytes (any), key "arbitration_id".
_TIMESTAMP_KEY = b"\xa9timestamp"
_ID_KEY = b"\xaearbitration_id"
#: Classic BPF opcodes (linux/filter.h).
_LD_W_ABS, _LD_H_ABS, _LD_B_ABS, _LD_W_LEN = 0x20, 0x28, 0x30, 0x80
_JEQ_K, _JGE_K, _AND_K, _RET_K, _TAX, _TXA = 0x15, 0x35, 0x54, 0x06, 0x07, 0x87
_ACCEPT, _DROP = 0xFFFFFFFF, 0
_MAX_FILTERS = 100  # jump offsets are 8 bits: more filters than this are left to python-can


def udp_filter_program(filters: Sequence[CanFilter]) -> list[tuple[int, int, int, int]]:
    """The BPF program (code, jt, jf, k) keeping datagrams whose id matches one of ``filters``.

    ``filters`` are python-can filters (``can_id``, ``can_mask``); ``extended`` is not looked at here.
    """
    base = _UDP_HEADER
    # (code, true-label or offset, false-label or offset, k): labels "accept"/"drop"/"match" resolved below
    prog: list[tuple[int, int | str, int | str, int]] = [
        (_LD_W_LEN, 0, 0, 0),
        (_JGE_K, 0, "accept", base + PAYLOAD_ID_OFFSET + 5),  # shorter than the layout: python-can decides
        (_LD_B_ABS, 0, 0, base),
        (_AND_K, 0, 0, 0xF0),
        (_JEQ_K, 0, "accept", 0x80),  # a fixmap
    ]
    prefix = _TIMESTAMP_KEY  # bytes 1..10
    for offset in range(0, 8, 4):
        prog += [(_LD_W_ABS, 0, 0, base + 1 + offset), (_JEQ_K, 0, "accept", _word(prefix[offset : offset + 4]))]
    prog += [(_LD_H_ABS, 0, 0, base + 9), (_JEQ_K, 0, "accept", _word(prefix[8:10]))]
    prog += [(_LD_B_ABS, 0, 0, base + 11), (_JEQ_K, 0, "accept", 0xCB)]  # float64 timestamp
    key_at = base + 20  # bytes 20..34: the key "arbitration_id" (15 bytes: 3 words and the last word overlapping)
    for offset in (0, 4, 8, 11):
        prog += [(_LD_W_ABS, 0, 0, key_at + offset), (_JEQ_K, 0, "accept", _word(_ID_KEY[offset : offset + 4]))]
    id_at = base + PAYLOAD_ID_OFFSET
    prog += [
        (_LD_B_ABS, 0, 0, id_at),
        (_JGE_K, 0, "match", 0x80),  # positive fixint: the byte is the id
        (_JEQ_K, 0, 2, 0xCC),
        (_LD_B_ABS, 0, 0, id_at + 1),
        (_JEQ_K, "match", "match", 0),  # unconditional jump (jt = jf)
        (_JEQ_K, 0, 2, 0xCD),
        (_LD_H_ABS, 0, 0, id_at + 1),
        (_JEQ_K, "match", "match", 0),
        (_JEQ_K, 0, "accept", 0xCE),
        (_LD_W_ABS, 0, 0, id_at + 1),
    ]
    labels = {"match": len(prog)}
    prog.append((_TAX, 0, 0, 0))
    for flt in filters:
        mask = int(flt["can_mask"]) & 0x1FFFFFFF
        prog += [(_TXA, 0, 0, 0), (_AND_K, 0, 0, mask), (_JEQ_K, "accept", 0, int(flt["can_id"]) & mask)]
    labels["drop"] = len(prog)
    prog.append((_RET_K, 0, 0, _DROP))
    labels["accept"] = len(prog)
    prog.append((_RET_K, 0, 0, _ACCEPT))
    resolved = []
    for index, (code, jt, jf, k) in enumerate(prog):
        jt_off = labels[jt] - index - 1 if isinstance(jt, str) else jt
        jf_off = labels[jf] - index - 1 if isinstance(jf, str) else jf
        resolved.append((code, jt_off, jf_off, k))
    return resolved


def _word(chunk: bytes) -> int:
    return int.from_bytes(chunk, "big")  # BPF loads are big-endian (network order)


def _layout_ok() -> bool:
    """python-can packs a frame as the program expects (module docstring); False otherwise."""
    from can.interfaces.udp_multicast.utils import pack_message

    for frame_id in (0x7F, 0x80, 0x1FF, 0x1FFFFFFF):
        data = pack_message(can.Message(timestamp=1.5, arbitration_id=frame_id, is_extended_id=frame_id > 0x7FF))
        if not (
            data[0] & 0xF0 == 0x80
            and data[1:11] == _TIMESTAMP_KEY
            and data[11] == 0xCB
            and data[20:PAYLOAD_ID_OFFSET] == _ID_KEY
        ):
            return False
    return True


def attach_kernel_filter(bus: can.BusABC, filters: Sequence[CanFilter]) -> bool:
    """Attach the kernel filter of ``filters`` to a ``udp_multicast`` bus; True when attached.

    Any other interface, no filters, more than 100 filters or a python-can that packs frames otherwise:
    nothing is attached (False) and python-can filters in Python as before. Linux only.
    """
    try:
        from can.interfaces.udp_multicast import UdpMulticastBus
    except ImportError:  # pragma: no cover - python-can always ships it
        return False
    if not isinstance(bus, UdpMulticastBus) or not filters or len(filters) > _MAX_FILTERS:
        return False
    if not hasattr(socket, "SO_REUSEPORT") or not _layout_ok():  # SO_REUSEPORT: a Linux-like socket API
        _log.warning("udp_multicast: frames not packed as expected: no kernel filter (python-can filters them)")
        return False
    sock = socket.socket(fileno=os.dup(bus.fileno()))  # the same socket: a filter belongs to the socket, not the fd
    try:
        attach_program(sock, udp_filter_program(filters))
    except OSError as exc:
        _log.warning("udp_multicast: kernel filter not attached (%s): python-can filters the frames", exc)
        return False
    finally:
        sock.close()
    return True


def attach_program(sock: socket.socket, program: Sequence[tuple[int, int, int, int]]) -> None:
    """Attach a classic BPF ``program`` to ``sock`` (SO_ATTACH_FILTER; the kernel copies it)."""
    code = b"".join(struct.pack("HBBI", c, jt, jf, k) for c, jt, jf, k in program)
    buffer = ctypes.create_string_buffer(code, len(code))
    fprog = struct.pack("HL", len(program), ctypes.addressof(buffer))  # struct sock_fprog (native alignment)
    sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, fprog)
