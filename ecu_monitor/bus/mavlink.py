"""MAVLink in: message fields of an autopilot's telemetry -> named values in canonical units.

Every message layout comes from pymavlink (``mavutil.mavlink``, the generated dialect: field names,
types, units, CRC extras); nothing here knows a byte offset. pymavlink is imported on first use
(:func:`mavlink_module`), so the DBC and DroneCAN paths of the service never pay for it. The dialect
is MAVLink 2 (``MAVLINK20=1`` is set before pymavlink is imported unless the process set it): its
parser reads MAVLink 1 and 2 frames alike, signed or not (a signature is not checked: the decoder
holds no key; a link that signs is read as it is).

* :func:`parse_field`: ``MESSAGE.field`` (or ``MESSAGE.field[i]`` for an array element) checked
  against the dialect: the message exists, the field is a number (not text), and its unit in the
  message definition (:data:`DEFINITION_UNITS`) is one the config's unit must agree with.

* :func:`parse_connection` / :func:`open_connection`: a connection string as MAVProxy takes it
  (``udpin:0.0.0.0:14550``, ``udpout:127.0.0.1:14550``, ``tcp:host:5760``, ``tcpin:0.0.0.0:5760``,
  ``udpbcast:192.168.1.255:14550``, ``/dev/ttyACM0,115200``) checked, then opened with
  ``mavutil.mavlink_connection`` (the serial baud rate after the comma, as MAVProxy splits it).

* :class:`MavlinkDecoder` (the counterpart of :class:`ecu_monitor.bus.dronecan.DroneCanDecoder`): specs
  like the DroneCAN decoder's (:class:`~ecu_monitor.bus.codec.SignalSpec`: input name, message name
  e.g. ``EFI_STATUS``, field e.g. ``cylinder_head_temperature``, unit). :meth:`MavlinkDecoder.decode`
  takes a pymavlink message object (from a ``mavutil`` connection, a log, or :meth:`parse_bytes`) and
  gives ``[(slot, value)]`` (slot: the index of the spec in :attr:`names`) converted once to the
  canonical unit; None for a message it does not read. :meth:`MavlinkDecoder.parse_bytes` feeds raw
  bytes (a UDP datagram, a serial read) to a pymavlink parser and decodes every message completed;
  no exception escapes for any input, and garbage is counted.

  Messages, in order of the checks (keys of :attr:`MavlinkDecoder.counters`, every message counted
  once in ``frames``): a piece of the byte stream that is not a message (bytes between frames, a bad
  CRC, a length that does not add up, bad incompatibility flags) is ``malformed`` under one of
  :data:`MAVLINK_REASONS` (``garbage``, ``bad_crc``, ``bad_length``, ``decode_error``); a message of a
  type no spec reads (including ids the dialect does not know) is ``unknown_id``; from the service's
  own system and component (an echo of its output on a shared link) ``ignored``; from a system or
  component other than ``source_system`` / ``source_component`` ``filtered_source``; otherwise ``ok``.
  A field that is NaN or infinite, or holds its definition's "not available" value
  (:data:`NOT_AVAILABLE`: ``SCALED_PRESSURE.temperature_press_diff`` 0), gives no value (counted
  ``unknown_value``), so that input goes stale rather than take a made-up number.

  A value whose quantity is a length given in a pressure unit is a pressure altitude
  (:func:`ecu_monitor.units.pressure_altitude_m`, standard atmosphere): ``SCALED_PRESSURE.press_abs``
  in hPa mapped to ``altitude_m``.

Kelvin in degC fields. Some senders put kelvin into fields the definition says are degC (issue 27:
PX4's EFI_STATUS stream; ArduPilot's own EFI_STATUS sent its EGT in kelvin before it was fixed). The
decoder checks every degC field it reads (:func:`kelvin_like`): an engine temperature (CHT, EGT) of
250 "degC" or more while the same message says the engine is stopped (``rpm`` below 1), a CHT of 400
"degC" or more at any time (no head runs that hot; a warm head in kelvin reads 400-520), or any other
temperature (an air or intake temperature) of 150 "degC" or more, reads like kelvin. The first such
value of an input is logged as one warning line naming the field and the fix, and kept in
:attr:`MavlinkDecoder.warnings`; the value is passed on as the definition says (no guess). The fix is
the input's unit: ``unit: K`` on a degC field declares that this sender puts kelvin there, and the
value is converted from kelvin (the one case where the config's unit may differ from the definition's).
Such an input whose value reads like Celsius (below 150 "K") is warned about the same way. The check
does not convert by itself: a hot engine's CHT of 260-300 degC is a real reading, and no rule tells it
from a cold engine's CHT in kelvin without the engine's state, which not every message carries.
"""

from __future__ import annotations

import logging
import math
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from types import MappingProxyType, ModuleType
from typing import Any, NamedTuple

from ecu_monitor.bus.codec import SignalSpec
from ecu_monitor.errors import ConfigError
from ecu_monitor.units import QUANTITY_OF_COLUMN, UNITS, Unit, pressure_altitude_m

__all__ = [
    "DEFAULT_FIELDS",
    "DEFINITION_UNITS",
    "MAVLINK_REASONS",
    "NOT_AVAILABLE",
    "MavlinkConnection",
    "MavlinkDecoder",
    "MavlinkField",
    "default_specs",
    "kelvin_like",
    "mavlink_module",
    "open_connection",
    "parse_connection",
    "parse_field",
]

_log = logging.getLogger(__name__)

#: Reasons a piece of the byte stream is counted as malformed (keys of :attr:`MavlinkDecoder.counters`).
MAVLINK_REASONS: tuple[str, ...] = ("garbage", "bad_crc", "bad_length", "decode_error")
#: Unit names of MAVLink message definitions -> the unit table's name for the same unit. A field whose
#: definition gives one of these must be mapped with that unit (kelvin on a degC field aside).
DEFINITION_UNITS: Mapping[str, str] = MappingProxyType(
    {
        "degC": "degC",
        "cdegC": "cdegC",
        "%": "pct",
        "rpm": "rpm",
        "cm^3/min": "cc_per_min",
        "kPa": "kPa",
        "hPa": "hPa",
        "mbar": "mbar",
        "Pa": "Pa",
        "m": "m",
        "cm": "cm",
        "mm": "mm",
        "m/s": "mps",
        "cm/s": "cm/s",
        "s": "s",
        "ms": "ms",
    }
)
#: (message, field) -> the raw value its definition reserves for "not available" (no value, not a reading).
NOT_AVAILABLE: Mapping[tuple[str, str], float] = MappingProxyType(
    {
        ("SCALED_PRESSURE", "temperature_press_diff"): 0.0,
        ("SCALED_PRESSURE2", "temperature_press_diff"): 0.0,
        ("SCALED_PRESSURE3", "temperature_press_diff"): 0.0,
        ("EFI_STATUS", "ignition_voltage"): 0.0,
        ("EFI_STATUS", "fuel_pressure"): 0.0,
    }
)
#: The default mapping of an autopilot's telemetry (the shipped mavlink.yaml, and ``import`` of a .tlog):
#: column -> candidate ``MESSAGE.field`` and unit, in order of preference (a log import takes the first
#: the log carries). ``altitude_m`` is the pressure altitude of the static pressure (the model's air
#: density), VFR_HUD's altitude (the autopilot's AMSL estimate) only when the log has no SCALED_PRESSURE;
#: ``oat_c`` is the airspeed sensor's temperature as ArduPilot sends it.
DEFAULT_FIELDS: Mapping[str, tuple[tuple[str, str], ...]] = MappingProxyType(
    {
        "rpm": (("EFI_STATUS.rpm", "rpm"),),
        "throttle_pct": (("EFI_STATUS.throttle_position", "pct"), ("VFR_HUD.throttle", "pct")),
        "cht_c": (("EFI_STATUS.cylinder_head_temperature", "degC"),),
        "egt_c": (("EFI_STATUS.exhaust_gas_temperature", "degC"),),
        "fuel_flow_lph": (("EFI_STATUS.fuel_flow", "cc_per_min"),),
        "manifold_pressure_kpa": (("EFI_STATUS.intake_manifold_pressure", "kPa"),),
        "baro_pressure_kpa": (("EFI_STATUS.barometric_pressure", "kPa"),),
        "intake_temp_c": (("EFI_STATUS.intake_manifold_temperature", "degC"),),
        "airspeed_mps": (("VFR_HUD.airspeed", "mps"),),
        "altitude_m": (("SCALED_PRESSURE.press_abs", "hPa"), ("VFR_HUD.alt", "m")),
        "oat_c": (("SCALED_PRESSURE.temperature_press_diff", "cdegC"),),
    }
)
#: Fields holding an engine's own temperatures (kelvin check against the message's rpm).
_ENGINE_TEMPERATURES = frozenset({"cylinder_head_temperature", "exhaust_gas_temperature"})
_ENGINE_KELVIN_C = 250.0  # a stopped engine's CHT/EGT at or above this many "degC" reads like kelvin
_CHT_KELVIN_C = 400.0  # a CHT at or above this many "degC" reads like kelvin, engine running or not
_AIR_KELVIN_C = 150.0  # any other temperature at or above this reads like kelvin; a "K" value below, like degC
_FIELD = re.compile(r"^([A-Z][A-Z0-9_]*)\.([a-z_][a-z0-9_]*)(?:\[(\d+)\])?$")
_NUMERIC = frozenset(
    {"float", "double", "int8_t", "uint8_t", "int16_t", "uint16_t", "int32_t", "uint32_t", "int64_t", "uint64_t"}
)
_REASON_OF_ERROR = (("prefix", "garbage"), ("crc", "bad_crc"), ("length", "bad_length"))


def mavlink_module() -> ModuleType:
    """pymavlink's MAVLink 2 dialect module (``mavutil.mavlink``), imported on first use.

    ``MAVLINK20=1`` is set before ``pymavlink.mavutil`` is imported (unless the process already set
    it), so mavutil's connections and this module share the MAVLink 2 dialect, which parses MAVLink 1
    frames too. ConfigError (one line) when pymavlink is not installed."""
    os.environ.setdefault("MAVLINK20", "1")
    try:
        from pymavlink import mavutil
    except ImportError:
        raise ConfigError("protocol mavlink needs pymavlink (pip install pymavlink)") from None
    if getattr(mavutil.mavlink, "WIRE_PROTOCOL_VERSION", "2.0") != "2.0":  # imported before, as MAVLink 1
        os.environ["MAVLINK20"] = "1"
        mavutil.set_dialect(mavutil.current_dialect)
    return mavutil.mavlink


class MavlinkField(NamedTuple):
    """A checked ``MESSAGE.field[i]``: the message name, its id, the field, the array element (-1: a
    scalar field), the unit its definition gives ("" if none) and the table's name for it ("" if the
    table has none)."""

    message: str
    message_id: int
    field: str
    element: int
    definition_unit: str
    unit_name: str

    @property
    def text(self) -> str:
        element = f"[{self.element}]" if self.element >= 0 else ""
        return f"{self.message}.{self.field}{element}"


def _message_classes() -> dict[str, Any]:
    mavlink = mavlink_module()
    return {cls.msgname: cls for cls in mavlink.mavlink_map.values()}


def parse_field(ref: str) -> MavlinkField:
    """``MESSAGE.field`` or ``MESSAGE.field[i]`` checked against the MAVLink dialect; ConfigError (one
    line) if it is not a number field of a known message."""
    if not isinstance(ref, str):
        raise ConfigError(f"expected 'MESSAGE.field' (e.g. EFI_STATUS.cylinder_head_temperature), got {ref!r}")
    match = _FIELD.match(ref.strip())
    if match is None:
        raise ConfigError(
            f"{ref}: expected 'MESSAGE.field' or 'MESSAGE.field[i]' (e.g. EFI_STATUS.cylinder_head_temperature)"
        )
    message, name, index = match.groups()
    cls = _message_classes().get(message)
    if cls is None:
        raise ConfigError(f"{ref}: no MAVLink message {message} in pymavlink's dialect")
    if name not in cls.fieldnames:
        raise ConfigError(f"{ref}: {message} has no field '{name}' (fields: {', '.join(cls.fieldnames)})")
    position = cls.fieldnames.index(name)
    kind, length = cls.fieldtypes[position], cls.array_lengths[position]
    if kind not in _NUMERIC:
        raise ConfigError(f"{ref}: {message}.{name} is {kind} text, not a number")
    if length and index is None:
        raise ConfigError(f"{ref}: {message}.{name} is an array of {length}: give an element, {name}[i]")
    if not length and index is not None:
        raise ConfigError(f"{ref}: {message}.{name} is not an array")
    element = -1 if index is None else int(index)
    if element >= max(length, 1):
        raise ConfigError(f"{ref}: {message}.{name} has {length} elements (0 .. {length - 1})")
    unit = cls.fieldunits_by_name.get(name, "")
    return MavlinkField(message, int(cls.id), name, element, unit, DEFINITION_UNITS.get(unit, ""))


def kelvin_like(field: str, value: float, rpm: float | None) -> bool:
    """True when ``value``, read from the degC field ``field`` of a message whose ``rpm`` field says
    ``rpm`` (None: the message has none), reads like kelvin (module docstring)."""
    if field == "cylinder_head_temperature" and value >= _CHT_KELVIN_C:
        return True
    if field in _ENGINE_TEMPERATURES:
        return rpm is not None and rpm < 1.0 and value >= _ENGINE_KELVIN_C
    return value >= _AIR_KELVIN_C


class _Field(NamedTuple):
    output: int
    name: str  # the input's name
    field: str
    element: int
    unit: Unit
    to_altitude: bool  # a pressure (canonical kPa) turned into a pressure altitude, m
    not_available: float  # the raw "not available" value, NaN: none
    check: int  # 0: no kelvin check; 1: a degC field read as degC; 2: a degC field declared kelvin (unit K)


class MavlinkDecoder:
    """pymavlink messages (or raw bytes) -> named values through the MAVLink definitions (module docstring).

    ``specs``: the values wanted (``message`` = the MAVLink message name, ``signal`` = its field,
    ``field[i]`` for an array element). ``source_system`` / ``source_component``: accept only messages
    from this system / component (None: any). ``own``: the service's own (system id, component id),
    whose messages are ``ignored`` (None: none). :attr:`counters` counts messages per outcome since
    construction; :attr:`warnings` holds the one-line warnings given (kelvin in degC fields).
    """

    def __init__(
        self,
        specs: Sequence[SignalSpec],
        source_system: int | None = None,
        source_component: int | None = None,
        own: tuple[int, int] | None = None,
    ) -> None:
        self.names: tuple[str, ...] = tuple(s.name for s in specs)
        if len(set(self.names)) != len(self.names):
            raise ConfigError(f"duplicate value names in {self.names}")
        for label, value in (("source_system", source_system), ("source_component", source_component)):
            if value is not None and not (type(value) is int and 0 <= value <= 255):
                raise ConfigError(f"{label} {value!r}: expected 0..255")
        self.source_system = source_system
        self.source_component = source_component
        self.own = own
        plans: dict[str, list[_Field]] = {}
        for output, spec in enumerate(specs):
            try:
                ref = parse_field(f"{spec.message}.{spec.signal}")
                unit = spec.conversion()
            except (ConfigError, ValueError) as exc:
                raise ConfigError(f"{spec.name}: {exc}") from None
            check = _unit_check(spec, ref, unit)
            to_altitude = unit.quantity == "pressure" and QUANTITY_OF_COLUMN.get(spec.name) == "length"
            missing = NOT_AVAILABLE.get((ref.message, ref.field), math.nan)
            plans.setdefault(ref.message, []).append(
                _Field(output, spec.name, ref.field, ref.element, unit, to_altitude, missing, check)
            )
        self._plans: dict[str, tuple[_Field, ...]] = {name: tuple(fields) for name, fields in plans.items()}
        self.counters: dict[str, int] = _new_counts()
        self.warnings: list[str] = []
        self._warned: set[str] = set()
        self._parser: Any = None

    @property
    def message_types(self) -> tuple[str, ...]:
        """The MAVLink message names this decoder reads."""
        return tuple(sorted(self._plans))

    def decode(self, msg: Any) -> list[tuple[int, float]] | None:
        """One pymavlink message: [(value index, value)] when it is a mapped message from an accepted
        source (empty when every mapped field is unknown), else None. Never raises for any message."""
        counts = self.counters
        counts["frames"] += 1
        try:
            kind = msg.get_type()
        except AttributeError:
            _malformed(counts, "decode_error")
            return None
        if kind == "BAD_DATA":
            _malformed(counts, _bad_data_reason(getattr(msg, "reason", "")))
            return None
        fields = self._plans.get(kind)
        if fields is None:
            counts["unknown_id"] += 1
            return None
        system, component = msg.get_srcSystem(), msg.get_srcComponent()
        if self.own is not None and (system, component) == self.own:
            counts["ignored"] += 1
            return None
        if (self.source_system is not None and system != self.source_system) or (
            self.source_component is not None and component != self.source_component
        ):
            counts["filtered_source"] += 1
            return None
        counts["ok"] += 1
        out: list[tuple[int, float]] = []
        for f in fields:
            try:
                raw = getattr(msg, f.field)
                raw = float(raw[f.element] if f.element >= 0 else raw)
            except (AttributeError, IndexError, TypeError, ValueError, OverflowError):
                raw = math.nan
            if not math.isfinite(raw) or raw == f.not_available:
                counts["unknown_value"] += 1
                continue
            if f.check:
                self._check_kelvin(msg, kind, f, raw)
            value = raw * f.unit.scale + f.unit.offset
            if f.to_altitude:
                value = pressure_altitude_m(value)
            if math.isfinite(value):
                out.append((f.output, value))
            else:
                counts["unknown_value"] += 1
        return out

    def parse_messages(self, data: bytes | bytearray | memoryview) -> list[Any]:
        """The messages completed by ``data`` (raw bytes of a MAVLink stream, fed to one pymavlink parser
        kept across calls, so a frame split over two reads is joined). Pieces that are not messages are
        counted here (``frames`` and ``malformed`` by reason) and not returned; no exception escapes."""
        parser = self._parser
        if parser is None:
            parser = self._parser = mavlink_module().MAVLink(None)
            parser.robust_parsing = True
        try:
            found = parser.parse_buffer(bytes(data)) or []
        except Exception as exc:  # noqa: BLE001 - a parser fault on hostile bytes must not reach the daemon
            # robust parsing turns every error pymavlink knows of into BAD_DATA; anything else is counted and
            # the parser's state thrown away (the bytes it held are lost, the stream resynchronises at the next frame)
            _log.debug("pymavlink parser failed on %d bytes: %s", len(data), exc)
            self.counters["frames"] += 1
            _malformed(self.counters, "decode_error")
            self._parser = None
            return []
        out = []
        for msg in found:
            if msg.get_type() == "BAD_DATA":
                self.decode(msg)  # counted
            else:
                out.append(msg)
        return out

    def parse_bytes(self, data: bytes | bytearray | memoryview) -> list[tuple[int, float]]:
        """:meth:`decode` of every message completed by ``data`` (:meth:`parse_messages`), values in order."""
        out: list[tuple[int, float]] = []
        for msg in self.parse_messages(data):
            decoded = self.decode(msg)
            if decoded:
                out.extend(decoded)
        return out

    def _check_kelvin(self, msg: Any, kind: str, f: _Field, raw: float) -> None:
        """Warn once per input about a degC field that reads like kelvin, or a declared-kelvin one like degC."""
        if f.name in self._warned:
            return
        rpm = getattr(msg, "rpm", None)
        rpm = float(rpm) if isinstance(rpm, int | float) else None
        where = f"{kind}.{f.field}" + (f"[{f.element}]" if f.element >= 0 else "")
        if f.check == 1 and kelvin_like(f.field, raw, rpm):
            stopped = " with the engine stopped" if f.field in _ENGINE_TEMPERATURES and raw < _CHT_KELVIN_C else ""
            text = (
                f"input {f.name}: {where} reads {raw:.1f} degC{stopped}: kelvin in a degC field (as some autopilots"
                f" send it)? if so, map it with unit: K"
            )
        elif f.check == 2 and raw < _AIR_KELVIN_C:
            text = (
                f"input {f.name}: {where} is mapped with unit K but reads {raw:.1f} ({raw - 273.15:.1f} degC):"
                " degC as its definition says? if so, map it with unit: degC"
            )
        else:
            return
        self._warned.add(f.name)
        self.warnings.append(text)
        _log.warning("%s", text)


def _unit_check(spec: SignalSpec, ref: MavlinkField, unit: Unit) -> int:
    """ConfigError when the spec's unit disagrees with the field's definition; the kelvin check to run (0, 1, 2)."""
    if isinstance(spec.unit, Unit) or not ref.unit_name:  # a custom unit, or a definition without a known unit
        return 0
    defined = UNITS[ref.unit_name]
    if ref.definition_unit == "degC" and spec.unit == "K":
        return 2  # declared: this sender puts kelvin in the degC field
    if (unit.quantity, unit.scale, unit.offset) != tuple(defined):
        raise ConfigError(
            f"{spec.name}: {ref.text} is in {ref.definition_unit} by its MAVLink definition: give unit"
            f" {ref.unit_name}, got {spec.unit}"
            + (" (or K, for a sender that puts kelvin in this degC field)" if ref.definition_unit == "degC" else "")
        )
    return 1 if ref.definition_unit == "degC" else 0


def _bad_data_reason(reason: Any) -> str:
    text = str(reason).lower()
    for key, name in _REASON_OF_ERROR:
        if key in text:
            return name
    return "decode_error"


def _new_counts() -> dict[str, int]:
    counts = dict.fromkeys(
        ("frames", "ok", "unknown_id", "ignored", "malformed", "filtered_source", "unknown_value"), 0
    )
    counts.update(dict.fromkeys(MAVLINK_REASONS, 0))
    return counts


def _malformed(counts: dict[str, int], reason: str) -> None:
    counts[reason] += 1
    counts["malformed"] += 1


def default_specs(columns: Iterable[str] | None = None, choice: int = 0) -> list[SignalSpec]:
    """The specs of :data:`DEFAULT_FIELDS` (``columns``: those columns only; ``choice``: which candidate of
    each, the first by default; a column with fewer candidates is left out)."""
    out: list[SignalSpec] = []
    for column, candidates in DEFAULT_FIELDS.items():
        if (columns is not None and column not in columns) or choice >= len(candidates):
            continue
        ref, unit = candidates[choice]
        message, field = ref.split(".", 1)
        out.append(SignalSpec(column, message, field, unit))
    return out


#: Connection kinds (the prefix of a connection string) -> the part after it is HOST:PORT.
_NETWORK_KINDS = ("udpin", "udpout", "udpbcast", "udp", "tcpin", "tcp")


class MavlinkConnection(NamedTuple):
    """A checked connection string: ``kind`` (one of udpin, udpout, udpbcast, udp, tcpin, tcp, serial),
    ``host`` and ``port`` for a network link, ``device`` and ``baud`` for a serial one; ``text`` as given."""

    kind: str
    host: str
    port: int
    device: str
    baud: int
    text: str

    @property
    def device_string(self) -> str:
        """The string ``mavutil.mavlink_connection`` takes (a serial link without its baud rate)."""
        return self.device if self.kind == "serial" else f"{self.kind}:{self.host}:{self.port}"


def parse_connection(text: str) -> MavlinkConnection:
    """A connection string as MAVProxy takes it (module docstring); ConfigError (one line) otherwise.
    ``udp:`` is mavutil's listening UDP (``udpin:``); a serial device is a path (``/dev/ttyACM0``,
    ``COM3``) with an optional ``,BAUD`` (default 115200)."""
    if not isinstance(text, str) or not text.strip():
        raise ConfigError(
            f"expected a connection string (udpin:0.0.0.0:14550, tcp:HOST:5760, /dev/ttyACM0,115200), got {text!r}"
        )
    text = text.strip()
    kind, sep, rest = text.partition(":")
    if sep and kind in _NETWORK_KINDS:
        host, sep, port = rest.rpartition(":")
        if not (sep and host and port.isdigit() and 0 < int(port) < 65536):
            raise ConfigError(f"{text}: expected {kind}:HOST:PORT with a port 1..65535")
        return MavlinkConnection(kind, host, int(port), "", 0, text)
    device, sep, baud = text.partition(",")
    if sep and not (baud.isdigit() and int(baud) > 0):
        raise ConfigError(f"{text}: expected DEVICE,BAUD with a baud rate in bits/s, e.g. /dev/ttyACM0,115200")
    if ":" in device and not re.match(r"^[A-Za-z]:[\\/]", device):
        known = ", ".join(f"{k}:" for k in _NETWORK_KINDS)
        raise ConfigError(f"{text}: unknown link '{kind}:' (known: {known} HOST:PORT, or a serial device path)")
    return MavlinkConnection("serial", "", 0, device, int(baud) if sep else 115200, text)


def open_connection(text: str, *, source_system: int = 255, source_component: int = 0) -> Any:
    """Open a connection string (:func:`parse_connection`) with ``mavutil.mavlink_connection``, sending as
    ``source_system`` / ``source_component``; ConfigError (one line) when it cannot be opened."""
    link = parse_connection(text)
    mavlink_module()
    from pymavlink import mavutil

    try:
        return mavutil.mavlink_connection(
            link.device_string, baud=link.baud or 115200, source_system=source_system, source_component=source_component
        )
    except (OSError, ValueError, mavutil.mavlink.MAVError) as exc:
        raise ConfigError(f"MAVLink connection {text}: cannot open: {exc}") from None
