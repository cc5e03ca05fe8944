"""The bus section of a YAML config: which python-can bus ``virtual-ecu run`` emits onto.

Schema (other top-level sections of the file, such as a service config's, are ignored)::

    bus:
      interface: virtual        # virtual | udp_multicast | socketcan | any python-can interface
      channel: vcan0            # interface-specific channel name
      # any further keys are passed to can.Bus() unchanged, e.g.
      # receive_own_messages: false
      # preserve_timestamps: true   (virtual only: receivers see mission time, not wall time)

Problems raise :class:`~ecu_monitor.errors.ConfigError` naming the file and the key.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can

from ecu_monitor.errors import ConfigError
from ecu_monitor.shipped import resolve_file
from ecu_monitor.yamlfile import load_yaml_file

__all__ = ["BusConfig", "config_mavlink_connection", "config_protocol", "load_bus_config", "open_bus"]


@dataclass(frozen=True)
class BusConfig:
    """A python-can bus: interface name, channel and extra keyword options for ``can.Bus``."""

    interface: str
    channel: str
    options: dict[str, Any] = field(default_factory=dict)
    source: str = "<command line>"

    def __post_init__(self) -> None:
        if not isinstance(self.interface, str) or self.interface not in can.interfaces.VALID_INTERFACES:
            known = ", ".join(sorted(can.interfaces.VALID_INTERFACES))
            raise ConfigError(f"{self.source}: bus.interface: unknown interface {self.interface!r} (known: {known})")
        if not isinstance(self.channel, str | int) or isinstance(self.channel, bool) or str(self.channel) == "":
            raise ConfigError(f"{self.source}: bus.channel: expected a channel name, got {self.channel!r}")

    def replace(self, interface: str | None = None, channel: str | None = None) -> BusConfig:
        """A copy with the interface and/or channel overridden (command-line options)."""
        return BusConfig(interface or self.interface, channel or self.channel, dict(self.options), self.source)


def load_bus_config(path: str | Path) -> BusConfig:
    """Read the ``bus`` section of a YAML file (a path, or a shipped config's name: ``example.yaml``)."""
    path = resolve_file(path, "config")
    data = load_yaml_file(path, "config file", ConfigError)
    if not isinstance(data, dict) or not isinstance(data.get("bus"), dict):
        raise ConfigError(f"{path}: bus: expected a mapping with interface and channel")
    bus = dict(data["bus"])
    for key in ("interface", "channel"):
        if key not in bus:
            raise ConfigError(f"{path}: bus.{key}: missing")
    interface, channel = bus.pop("interface"), bus.pop("channel")
    return BusConfig(interface, str(channel) if isinstance(channel, int) else channel, bus, str(path))


def config_protocol(path: str | Path) -> str:
    """The ``protocol:`` of a YAML config (``dbc`` when absent): what a service config's bus speaks."""
    path = resolve_file(path, "config")
    try:
        data = load_yaml_file(path, "config file", ConfigError)
    except ConfigError:
        return "dbc"  # load_bus_config reports the file's problem
    protocol = data.get("protocol", "dbc") if isinstance(data, dict) else "dbc"
    if protocol not in ("dbc", "dronecan", "mavlink"):
        raise ConfigError(f"{path}: protocol: expected dbc, dronecan or mavlink, got {protocol!r}")
    return str(protocol)


def config_mavlink_connection(path: str | Path) -> str:
    """The ``mavlink.connection`` of a YAML config (the shipped default ``udpin:0.0.0.0:14550`` when absent)."""
    path = resolve_file(path, "config")
    data = load_yaml_file(path, "config file", ConfigError)
    section = data.get("mavlink") if isinstance(data, dict) else None
    connection = section.get("connection", "udpin:0.0.0.0:14550") if isinstance(section, dict) else None
    if not isinstance(connection, str):
        connection = "udpin:0.0.0.0:14550"
    return connection


def open_bus(config: BusConfig) -> can.BusABC:
    """Open the configured bus; failures raise ConfigError (one line, naming the bus)."""
    try:
        return can.Bus(interface=config.interface, channel=config.channel, **config.options)
    except (can.CanError, OSError, ValueError, TypeError, ImportError) as exc:
        raise ConfigError(f"{config.source}: bus {config.interface}:{config.channel}: cannot open: {exc}") from None
