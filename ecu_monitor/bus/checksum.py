"""Frame checksum of every ecu-monitor CAN frame (engine.dbc and health.dbc).

Layout (the same in every frame of both DBC files, see docs/dbc.md):

* byte 6, low nibble: rolling counter, +1 modulo 16 per transmitted frame of that id;
* byte 6, high nibble: reserved, sent as 0;
* byte 7: checksum = CRC-8/SAE-J1850 over bytes 0..6 (counter included).

CRC-8/SAE-J1850 (the AUTOSAR ``Crc_CalculateCRC8`` and E2E profile 1 polynomial): width 8,
polynomial 0x1D (x^8 + x^4 + x^3 + x^2 + 1), initial value 0xFF, no input/output reflection,
final XOR 0xFF. Check value: CRC of ASCII ``"123456789"`` is 0x4B. Unlike a byte sum it detects every
burst error up to 8 bits and every odd number of flipped bits, and a frame of all zeros does not
check (seven zero bytes give 0x0A, not 0).
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable
from numpy.typing import NDArray

__all__ = ["CHECKSUM_BYTE", "COUNTER_BYTE", "crc8_sae_j1850", "frame_checksum"]

#: Index of the byte holding the checksum.
CHECKSUM_BYTE = 7
#: Index of the byte whose low nibble holds the rolling counter.
COUNTER_BYTE = 6

_POLY = 0x1D
_INIT = 0xFF
_XOR_OUT = 0xFF


def _make_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ _POLY) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


#: The CRC state after byte b from state s is _TABLE[s ^ b].
_TABLE = _make_table()


@register_jitable
def crc8_sae_j1850(data: bytes | bytearray | memoryview | NDArray[np.uint8]) -> int:
    """CRC-8/SAE-J1850 of every byte of ``data`` (table driven, one lookup per byte): plain Python on
    bytes (the live decoder and encoders), compiled into the batch decoder's loop over uint8 rows."""
    crc = _INIT
    for byte in data:
        crc = _TABLE[crc ^ byte]
    return crc ^ _XOR_OUT


def frame_checksum(data: bytes | bytearray | memoryview) -> int:
    """Checksum of a CAN frame: CRC-8/SAE-J1850 over bytes 0..6.

    ``data`` is the 8-byte payload (byte 7, the checksum itself, is ignored) or just its first 7 bytes.
    Raises ``ValueError`` if fewer than 7 bytes are given.
    """
    if len(data) < CHECKSUM_BYTE:
        raise ValueError(f"frame_checksum needs at least 7 bytes, got {len(data)}")
    return crc8_sae_j1850(data[:CHECKSUM_BYTE])
