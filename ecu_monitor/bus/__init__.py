"""CAN bus layer: DBC-driven decoding to model inputs, health-frame encoding, config mapping.

``checksum`` holds the frame checksum (CRC-8/SAE-J1850 over bytes 0..6) shared by every frame of
dbc/engine.dbc and dbc/health.dbc; see docs/dbc.md.
"""

__all__: list[str] = []
