"""The runtime: the daemon (receive, tick and supervisor threads), bus I/O, the publishers that turn the
pipeline's output table into messages (DBC health frames, the DroneCAN node, MAVLink to the autopilot and
ground station), and persistence (SQLite flights, trend, thermal cycles). It imports nothing offline."""

__all__: list[str] = []
