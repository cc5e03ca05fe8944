"""The virtual ECU behind an autopilot: the truth plant's measurements as the MAVLink stream an autopilot sends.

:class:`MavlinkFrameEncoder` is the MAVLink twin of :class:`virtual_bus.emitter.FrameEncoder` (the same
``frames(block)``, each frame a :class:`MavlinkFrame`: its time stamp and the bytes of one MAVLink
message). One system (:data:`SYSTEM_ID`, component :data:`COMPONENT_ID`, MAV_COMP_ID_AUTOPILOT1)
sends, at :data:`DEFAULT_RATES`:

* ``HEARTBEAT`` 1 Hz: a fixed wing flown by ArduPilot, armed while the engine turns;
* ``EFI_STATUS`` 10 Hz (ArduPilot's SRx_EXTRA1 stream set to 10; its default is 1 Hz): rpm, throttle
  position, fuel flow (cm^3/min) and the fuel consumed since start, the standard pressure at the
  pressure altitude as barometric pressure, the CHT (degC; an engine flown with cylinders: their mean,
  EFI_STATUS has one CHT); the fields the plant does not model NaN (unknown);
* ``VFR_HUD`` 5 Hz (SRx_EXTRA2): airspeed (and as ground speed), throttle (integer percent), the
  pressure altitude as altitude, vertical speed;
* ``SCALED_PRESSURE`` 5 Hz (SRx_RAW_SENS): the static pressure (hPa), the dynamic pressure of the
  airspeed, the OAT as the barometer's temperature and as the airspeed sensor's
  (``temperature_press_diff``, cdegC, where ArduPilot puts it; a reading of 0 is sent as 1 cdegC, 0
  meaning "not available").

ArduPilot's own defaults for those streams are 1 Hz each (SRx_EXTRA1, SRx_EXTRA2, SRx_RAW_SENS); a
ground station usually asks for more (MAVProxy 4 Hz). The rates above are those docs/service.md
recommends for the service. ``kelvin_in_celsius=True`` sends the CHT in kelvin in its degC field, as
some autopilots have (issue 27), to exercise the service's plausibility check.

Every message is a pymavlink message object packed by one ``MAVLink`` instance (its sequence number
runs across the stream), MAVLink 2 unless ``mavlink1``. Frame ``n`` of a message is stamped
``start_time_s + n * period`` and carries the latest measurement at or before that time; messages due
at the same instant go in the order above.

:class:`MavlinkEmitter` sends the frames over a MAVLink connection (``udpout:127.0.0.1:14550``, a serial
port), as fast as possible or paced to the wall clock, as :class:`~virtual_bus.emitter.FrameEmitter`
does on a CAN bus; :class:`TlogWriter` writes them to a ``.tlog`` as MAVProxy and ground stations record
one (each message preceded by its time, microseconds since 1970 as a big-endian 64-bit integer).
"""

from __future__ import annotations

import logging
import math
import struct
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from types import MappingProxyType
from typing import Any, BinaryIO, NamedTuple

import numpy as np

from ecu_monitor.bus.mavlink import mavlink_module, open_connection, parse_connection
from ecu_monitor.errors import ConfigError
from ecu_monitor.units import UNITS, standard_pressure_kpa
from virtual_bus.emitter import EmitStats
from virtual_bus.plant import StepBlock

__all__ = [
    "COMPONENT_ID",
    "DEFAULT_RATES",
    "SYSTEM_ID",
    "MavlinkEmitter",
    "MavlinkFrame",
    "MavlinkFrameEncoder",
    "TlogWriter",
    "emitter_connection",
]

_log = logging.getLogger(__name__)

#: The autopilot's system id and component id (MAV_COMP_ID_AUTOPILOT1).
SYSTEM_ID = 1
COMPONENT_ID = 1
#: Message -> rate, Hz, in the order messages due at one instant are sent.
DEFAULT_RATES: Mapping[str, float] = MappingProxyType(
    {"HEARTBEAT": 1.0, "EFI_STATUS": 10.0, "VFR_HUD": 5.0, "SCALED_PRESSURE": 5.0}
)

_KELVIN = -UNITS["K"].offset  # 273.15
_CC_PER_MIN = UNITS["cc_per_min"].scale  # L/h per cm^3/min
_GAS_CONSTANT = 287.05  # J/(kg K), dry air
_MAV_TYPE_FIXED_WING, _MAV_AUTOPILOT_ARDUPILOTMEGA, _MAV_STATE_ACTIVE = 1, 3, 4
_MODE_FLAG_CUSTOM, _MODE_FLAG_ARMED = 1, 128
_PLANE_MODE_AUTO = 10
_US = 1_000_000


class MavlinkFrame(NamedTuple):
    """One MAVLink message on the wire: its time stamp (s), the message name and its bytes."""

    timestamp: float
    name: str
    data: bytes


class _Sink:
    def __init__(self) -> None:
        self.data = bytearray()

    def write(self, buf: bytes) -> None:
        self.data += buf


class MavlinkFrameEncoder:
    """Encodes StepBlocks into timestamped MAVLink frames of an autopilot's stream (module docstring).

    ``start_time_s`` is added to every timestamp; ``rates``: message -> Hz (a subset of
    :data:`DEFAULT_RATES`' messages; 0 leaves one out).
    """

    def __init__(
        self,
        *,
        start_time_s: float = 0.0,
        rates: Mapping[str, float] = DEFAULT_RATES,
        kelvin_in_celsius: bool = False,
        mavlink1: bool = False,
        system_id: int = SYSTEM_ID,
        component_id: int = COMPONENT_ID,
    ) -> None:
        unknown = set(rates) - set(DEFAULT_RATES)
        if unknown:
            raise ConfigError(f"MAVLink rates: unknown message(s) {', '.join(sorted(unknown))}")
        self.start_time_s = start_time_s
        self.kelvin_in_celsius = kelvin_in_celsius
        self.mavlink1 = mavlink1
        self._ml = mavlink_module()
        self._sink = _Sink()
        self.mav = self._ml.MAVLink(self._sink, srcSystem=system_id, srcComponent=component_id)
        # message -> period in microseconds (whole, so stamps never drift), next frame index
        self._periods = {name: round(_US / rate) for name in DEFAULT_RATES if (rate := float(rates.get(name, 0.0))) > 0}
        self._next = dict.fromkeys(self._periods, 0)
        self._fuel_cm3 = 0.0
        self._fuel_s: float | None = None

    def frames(self, block: StepBlock) -> list[MavlinkFrame]:
        """The frames due during ``block`` (times in [first step, first step + block length)), in time order."""
        t = block.time_s
        dt = float(t[1] - t[0]) if t.size > 1 else 0.02
        end_us = round((float(t[-1]) + dt) * _US)
        due: list[tuple[int, int, str]] = []
        for order, (name, period) in enumerate(self._periods.items()):
            index = self._next[name]
            while index * period < end_us:
                due.append((index * period, order, name))
                index += 1
            self._next[name] = index
        due.sort()
        out: list[MavlinkFrame] = []
        for stamp_us, _, name in due:
            stamp = stamp_us / _US
            j = max(int(np.searchsorted(t, stamp + 1e-9, side="right")) - 1, 0)
            msg = self._message(name, block, j, stamp)
            self._sink.data.clear()
            self.mav.send(msg, force_mavlink1=self.mavlink1)
            out.append(MavlinkFrame(self.start_time_s + stamp, name, bytes(self._sink.data)))
        return out

    def iter_frames(self, blocks: Iterable[StepBlock]) -> Iterator[MavlinkFrame]:
        """Every frame of a flight, streamed block by block."""
        for block in blocks:
            yield from self.frames(block)

    def _message(self, name: str, block: StepBlock, j: int, stamp: float) -> Any:
        m = block.measured
        ml = self._ml
        rpm = float(m.rpm[j])
        altitude = float(m.altitude_m[j])
        oat = float(m.oat_c[j])
        if name == "HEARTBEAT":
            armed = _MODE_FLAG_ARMED if rpm > 0.0 else 0
            return ml.MAVLink_heartbeat_message(
                _MAV_TYPE_FIXED_WING,
                _MAV_AUTOPILOT_ARDUPILOTMEGA,
                _MODE_FLAG_CUSTOM | armed,
                _PLANE_MODE_AUTO,
                _MAV_STATE_ACTIVE,
                3,
            )
        if name == "EFI_STATUS":
            flow = float(m.fuel_flow_lph[j]) / _CC_PER_MIN
            if self._fuel_s is not None:
                self._fuel_cm3 += flow * max(0.0, stamp - self._fuel_s) / 60.0
            self._fuel_s = stamp
            cht = float(m.cht_c[j]) + (_KELVIN if self.kelvin_in_celsius else 0.0)
            nan = math.nan
            return ml.MAVLink_efi_status_message(
                1,  # health
                0,  # ecu_index
                rpm,
                self._fuel_cm3,
                flow,
                nan,  # engine_load
                float(m.throttle_pct[j]),
                nan,  # spark_dwell_time
                float(standard_pressure_kpa(altitude)),
                nan,  # intake_manifold_pressure
                nan,  # intake_manifold_temperature
                cht,
                nan,  # ignition_timing
                nan,  # injection_time
                nan,  # exhaust_gas_temperature
                nan,  # throttle_out
                nan,  # pt_compensation
                0.0,  # ignition_voltage: unknown
                0.0,  # fuel_pressure: unknown
            )
        airspeed = float(m.airspeed_mps[j])
        if name == "VFR_HUD":
            throttle = min(100, max(0, round(float(m.throttle_pct[j]))))
            return ml.MAVLink_vfr_hud_message(airspeed, airspeed, 0, throttle, altitude, float(m.vspeed_mps[j]))
        pressure_pa = float(standard_pressure_kpa(altitude)) * 1000.0
        density = pressure_pa / (_GAS_CONSTANT * (oat + _KELVIN))
        centi = round(oat * 100.0)
        return ml.MAVLink_scaled_pressure_message(
            round(stamp * 1000.0) & 0xFFFFFFFF,
            pressure_pa / 100.0,
            0.5 * density * airspeed * airspeed / 100.0,
            max(-32768, min(32767, centi)),
            max(-32768, min(32767, centi if centi != 0 else 1)),  # 0 means "not available"
        )


class TlogWriter:
    """A ``.tlog`` as MAVProxy and ground stations write one: each message's bytes after its time stamp,
    microseconds since 1970 as a big-endian unsigned 64-bit integer. Written through pymavlink's log file
    (``mavutil.mavlogfile(path, write=True)``, which writes the bytes it is given); :meth:`on_message_received`
    and :meth:`stop` as python-can's writers, so the recorder feeds it as it feeds them."""

    def __init__(self, path: str | Path, handle: BinaryIO | None = None) -> None:
        """``handle``: the binary file to write (the caller closes it), else ``path`` is opened."""
        mavlink_module()
        from pymavlink import mavutil

        self.path = Path(path)
        if self.path.suffix.lower() != ".tlog":
            raise ConfigError(f"{path}: a MAVLink telemetry log is written to a .tlog")
        if handle is not None:
            self._log: Any = handle
            self._owned = False
            return
        self._owned = True
        try:
            self._log = mavutil.mavlogfile(str(self.path), write=True)
        except OSError as exc:
            raise ConfigError(f"{path}: cannot write: {exc.strerror or exc}") from None

    def on_message_received(self, frame: MavlinkFrame) -> None:
        """Append one frame (its time must not be negative)."""
        self._log.write(struct.pack(">Q", max(0, round(frame.timestamp * _US))) + frame.data)

    def stop(self) -> None:
        if self._owned:
            self._log.close()


def emitter_connection(service_connection: str) -> str:
    """Where the virtual autopilot sends so that a service on ``service_connection`` on this machine hears
    it: ``udpin:H:P`` -> ``udpout:127.0.0.1:P``, ``udpout:H:P`` -> ``udpin:0.0.0.0:P``, ``tcp:H:P`` ->
    ``tcpin:0.0.0.0:P``; ConfigError for a serial port or another kind (give ``--connection``)."""
    link = parse_connection(service_connection)
    pairs = {"udpin": "udpout:127.0.0.1", "udp": "udpout:127.0.0.1", "udpout": "udpin:0.0.0.0", "tcp": "tcpin:0.0.0.0"}
    if link.kind not in pairs:
        raise ConfigError(
            f"mavlink.connection {service_connection}: no local counterpart for a {link.kind} link: give --connection"
        )
    return f"{pairs[link.kind]}:{link.port}"


class MavlinkEmitter:
    """Sends a flight's MAVLink frames over a connection string (:func:`ecu_monitor.bus.mavlink.open_connection`,
    opened here as the autopilot's system and component, closed by :meth:`close`).

    ``realtime=False`` sends as fast as possible; ``realtime=True`` paces the frames to the wall clock at
    ``speed`` times real time (as :class:`~virtual_bus.emitter.FrameEmitter`). ``progress`` is called with
    the EmitStats after each block; :meth:`stop` (from another thread) ends :meth:`emit` at the next frame.
    """

    def __init__(
        self,
        connection: str,
        encoder: MavlinkFrameEncoder | None = None,
        *,
        realtime: bool = False,
        speed: float = 1.0,
        progress: Callable[[EmitStats], None] | None = None,
    ) -> None:
        if not speed > 0.0:
            raise ConfigError(f"--speed: expected a positive factor, got {speed!r}")
        self.encoder = encoder or MavlinkFrameEncoder()
        self.link = open_connection(connection, source_system=SYSTEM_ID, source_component=COMPONENT_ID)
        self.connection = connection
        self.realtime = realtime
        self.speed = float(speed)
        self.progress = progress
        self._stop = threading.Event()

    def stop(self) -> None:
        """Ask a running :meth:`emit` to return (idempotent, thread safe)."""
        self._stop.set()

    def close(self) -> None:
        self.link.close()

    def emit(self, blocks: Iterable[StepBlock]) -> EmitStats:
        """Send every frame of ``blocks``; returns the counts. Send failures are counted and logged."""
        stats = EmitStats()
        wall0 = time.perf_counter()
        first_stamp: float | None = None
        for block in blocks:
            for frame in self.encoder.frames(block):
                if self._stop.is_set():
                    stats.wall_time_s = time.perf_counter() - wall0
                    return stats
                if first_stamp is None:
                    first_stamp = frame.timestamp
                if self.realtime:
                    ahead = (frame.timestamp - first_stamp) / self.speed - (time.perf_counter() - wall0)
                    if ahead > 0.0005:
                        self._stop.wait(ahead)
                try:
                    self.link.write(frame.data)
                    stats.frames_sent += 1
                except OSError as exc:
                    stats.send_errors += 1
                    if stats.send_errors <= 5 or stats.send_errors % 1000 == 0:
                        _log.warning("send failed (%d so far) at t=%.3f s: %s", stats.send_errors, frame.timestamp, exc)
                stats.mission_time_s = frame.timestamp
            if self.progress is not None:
                stats.wall_time_s = time.perf_counter() - wall0
                self.progress(stats)
        stats.wall_time_s = time.perf_counter() - wall0
        return stats
