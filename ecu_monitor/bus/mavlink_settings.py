"""The ``mavlink:`` section of a service config (``protocol: mavlink``; docs/service.md, "MAVLink").

Kept beside :mod:`ecu_monitor.config` rather than in it: the config loader calls
:func:`parse_mavlink_settings` on the section's raw YAML data and stores the result, and the MAVLink
publisher (:mod:`ecu_monitor.runtime.mavlink_publisher`) and the daemon read :class:`MavlinkSettings`.
Every problem raises :class:`~ecu_monitor.errors.ConfigError` naming the file and ``mavlink.<key>``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ecu_monitor.bus.mavlink import parse_connection
from ecu_monitor.errors import ConfigError

__all__ = ["MAVLINK_KEYS", "MAV_COMP_ID_ONBOARD_COMPUTER", "MavlinkSettings", "parse_mavlink_settings"]

#: MAV_COMPONENT value of a companion computer (common.xml), the service's default component id.
MAV_COMP_ID_ONBOARD_COMPUTER = 191
#: The keys of the ``mavlink:`` section.
MAVLINK_KEYS: tuple[str, ...] = (
    "connection",
    "source_system",
    "source_component",
    "output",
    "system_id",
    "component_id",
    "named_value_hz",
    "statustext_per_s",
    "efi_status_out",
    "efi_status_hz",
    "mavlink1",
)


@dataclass(frozen=True)
class MavlinkSettings:
    """The service on a MAVLink link (docs/service.md, "MAVLink").

    connection: where the autopilot's telemetry comes from, a connection string as MAVProxy takes it
    (``udpin:0.0.0.0:14550``, ``tcp:HOST:5760``, ``/dev/ttyACM0,115200``). source_system,
    source_component: accept inputs only from this system / component (None: any). output: where the
    service's own messages go ("": back over ``connection``). system_id, component_id: the service's
    own ids (its HEARTBEAT, STATUSTEXT, NAMED_VALUE_FLOAT; by default the vehicle's system 1 and
    MAV_COMP_ID_ONBOARD_COMPUTER). named_value_hz: rate of the NAMED_VALUE_FLOAT set (0: none).
    statustext_per_s: at most this many STATUSTEXT a second (a state change is delayed or merged, never
    dropped). efi_status_out: send EFI_STATUS too, at efi_status_hz (for an engine only the service
    reads; refused when an input comes from EFI_STATUS). mavlink1: send MAVLink 1 frames (a link that
    only speaks MAVLink 1; long STATUSTEXT is then cut at 50 characters, MAVLink 1 has no chunks).
    """

    connection: str = "udpin:0.0.0.0:14550"
    source_system: int | None = 1
    source_component: int | None = 1
    output: str = ""
    system_id: int = 1
    component_id: int = MAV_COMP_ID_ONBOARD_COMPUTER
    named_value_hz: float = 2.0
    statustext_per_s: float = 2.0
    efi_status_out: bool = False
    efi_status_hz: float = 2.0
    mavlink1: bool = False


def parse_mavlink_settings(data: Any, src: str) -> MavlinkSettings:
    """The ``mavlink:`` section's YAML ``data`` (None: every default) checked; ``src`` names the file."""

    def error(key: str | None, message: str) -> ConfigError:
        return ConfigError(f"{src}: mavlink{'.' + key if key else ''}: {message}")

    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise error(None, f"expected a mapping, got {type(data).__name__}")
    for key in data:
        if key not in MAVLINK_KEYS:
            raise error(key, f"unknown key (known: {', '.join(MAVLINK_KEYS)})")
    defaults = MavlinkSettings()
    values: dict[str, Any] = {}
    for key in ("connection", "output"):
        value = data.get(key, getattr(defaults, key))
        if key == "output" and value in ("", None):
            values[key] = ""
            continue
        try:
            parse_connection(value)
        except ConfigError as exc:
            raise error(key, str(exc)) from None
        values[key] = value.strip()
    for key, low in (("source_system", 1), ("source_component", 1), ("system_id", 1), ("component_id", 1)):
        value = data.get(key, getattr(defaults, key))
        nullable = key.startswith("source_")
        if (value is None and nullable) or (type(value) is int and low <= value <= 255):
            values[key] = value
        else:
            raise error(key, f"expected an id 1..255{' or null (any)' if nullable else ''}, got {value!r}")
    for key, high in (("named_value_hz", 50.0), ("statustext_per_s", 50.0), ("efi_status_hz", 50.0)):
        value = data.get(key, getattr(defaults, key))
        ok = not isinstance(value, bool) and isinstance(value, int | float) and math.isfinite(value)
        if not ok or not 0.0 <= value <= high or (key == "statustext_per_s" and value <= 0.0):
            least = "> 0" if key == "statustext_per_s" else ">= 0"
            raise error(key, f"expected a number {least} and <= {high:g}, got {value!r}")
        values[key] = float(value)
    for key in ("efi_status_out", "mavlink1"):
        value = data.get(key, getattr(defaults, key))
        if not isinstance(value, bool):
            raise error(key, f"expected true or false, got {value!r}")
        values[key] = value
    settings = MavlinkSettings(**values)
    if (settings.system_id, settings.component_id) == (settings.source_system, settings.source_component):
        raise error("component_id", "the service's own ids equal the source's: give the service its own component id")
    return settings
