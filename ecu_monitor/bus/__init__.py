"""CAN bus layer: DBC-driven decoding to model inputs, health-frame encoding, unit conversion.

``codec`` builds a :class:`Decoder` (frames -> named values in canonical units, every malformed frame
counted by reason and dropped; a numpy batch path for replay) and an :class:`Encoder` (values ->
payloads with rolling counter and checksum) once from DBC files. ``checksum`` holds the frame
checksum (CRC-8/SAE-J1850 over bytes 0..6) shared by every frame of the shipped engine.dbc
and health.dbc; see docs/dbc.md.
"""

from ecu_monitor.bus.checksum import frame_checksum
from ecu_monitor.bus.codec import INPUT_NAMES, UNITS, Decoder, Encoder, SignalSpec, load_dbc, unit_conversion

__all__ = [
    "INPUT_NAMES",
    "UNITS",
    "Decoder",
    "Encoder",
    "SignalSpec",
    "frame_checksum",
    "load_dbc",
    "unit_conversion",
]
