"""CAN bus layer: the one boundary between CAN frames and the rest of ecu-monitor.

* ``dbc``: the one DBC loader (vendor files: comment lines, hex ids, broken unused messages) and the
  place of the shipped DBC files;
* ``codec``: :class:`Decoder` (frames -> named values in canonical units, every malformed frame
  counted by reason and dropped; a numpy batch path equal to the per-frame one) and :class:`Encoder`
  (values -> payloads with rolling counter and checksum; health frames, the virtual ECU's frames and
  replayed CSV rows alike);
* ``checksum``: the frame checksum (CRC-8/SAE-J1850 over bytes 0..6), see docs/dbc.md;
* ``kernel_filter``: receive filters in the kernel for python-can's ``udp_multicast`` (a BPF socket
  filter on the CAN id; socketcan filters in the kernel by itself);
* ``canlog``: the one CAN-log reader (any python-can log -> arrays) and the import of a CAN log
  into a flight log; ``load_flight`` for any supported log.

Units come from the one table, :mod:`ecu_monitor.units`.
"""

from ecu_monitor.bus.canlog import (
    CAN_LOG_SUFFIXES,
    DEFAULT_SIGNAL_MAP,
    FrameArrays,
    import_can_log,
    load_flight,
    read_frames,
)
from ecu_monitor.bus.checksum import frame_checksum
from ecu_monitor.bus.codec import INPUT_NAMES, Decoder, Encoder, SignalSpec
from ecu_monitor.bus.dbc import Dbc, load_dbc, shipped_dbc

__all__ = [
    "CAN_LOG_SUFFIXES",
    "DEFAULT_SIGNAL_MAP",
    "INPUT_NAMES",
    "Dbc",
    "Decoder",
    "Encoder",
    "FrameArrays",
    "SignalSpec",
    "frame_checksum",
    "import_can_log",
    "load_dbc",
    "load_flight",
    "read_frames",
    "shipped_dbc",
]
