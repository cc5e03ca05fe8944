"""Frame emitter of the virtual ECU: the truth plant's measurements as CAN frames of engine.dbc.

:class:`FrameEncoder` turns :class:`~virtual_bus.plant.StepBlock` objects into ``can.Message`` frames:
ECU_Fast (0x100) every 20 ms, ECU_Slow (0x101) and AirData (0x200) every 100 ms (the DBC's
GenMsgCycleTime). Frame ``n`` of a message is stamped ``start_time_s + n * cycle`` (mission time) and
carries the latest measurement at or before that time (sample and hold of the integration steps).
Each frame is built by the service's one encoder (:class:`ecu_monitor.bus.codec.Encoder`): values
clamped to the signal's DBC range (a real ECU saturates its outputs the same way), rolling counter
(+1 mod 16 per frame of that id) and CRC-8 checksum in byte 7. The DBC is read by the one loader,
:func:`ecu_monitor.bus.dbc.load_dbc`.

:class:`FrameEmitter` sends those frames onto any python-can ``BusABC`` passed in (it never opens a
bus itself): as fast as possible by default, or paced to the wall clock (``realtime=True``, ``speed``
times real time). A failed send (``can.CanError``) is counted and logged, never fatal.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can
import numpy as np

from ecu_monitor.bus.codec import Encoder
from ecu_monitor.bus.dbc import load_dbc, shipped_dbc
from ecu_monitor.errors import ConfigError
from virtual_bus.plant import StepBlock

if TYPE_CHECKING:
    from virtual_bus.dronecan_emitter import DroneCanFrameEncoder

__all__ = [
    "ENGINE_DBC",
    "MESSAGE_SIGNALS",
    "EmitStats",
    "FrameEmitter",
    "FrameEncoder",
    "load_engine_dbc",
]

_log = logging.getLogger(__name__)

#: The engine DBC the emitter encodes with.
ENGINE_DBC = shipped_dbc("engine.dbc")
#: The per-cylinder CHT frames an engine flown with cylinders also sends (ECU_Cht1to4, ECU_Cht5to8).
CYLINDERS_DBC = shipped_dbc("cylinders.dbc")
#: Per-cylinder CHT messages of cylinders.dbc, four cylinders each, in cylinder order.
CYLINDER_MESSAGES: tuple[str, ...] = ("ECU_Cht1to4", "ECU_Cht5to8")

#: Message -> (signal -> field of :class:`~virtual_bus.sensors.Measurements`), counter, checksum.
MESSAGE_SIGNALS: dict[str, tuple[dict[str, str], str, str]] = {
    "ECU_Fast": (
        {"EngineSpeed": "rpm", "ThrottlePos": "throttle_pct", "FuelFlow": "fuel_flow_lph"},
        "FastCounter",
        "FastChecksum",
    ),
    "ECU_Slow": ({"CHT": "cht_c", "OAT": "oat_c"}, "SlowCounter", "SlowChecksum"),
    "AirData": (
        {"PressureAltitude": "altitude_m", "CalibratedAirspeed": "airspeed_mps", "VerticalSpeed": "vspeed_mps"},
        "AirDataCounter",
        "AirDataChecksum",
    ),
}
#: EcuStatus values (engine.dbc VAL_): OK below the CHT limit, WARNING at or above it.
_STATUS_OK, _STATUS_WARNING = 0, 1


def load_engine_dbc(path: Path = ENGINE_DBC) -> Any:
    """The engine DBC as a cantools database (through the one loader, parsed once per file)."""
    return load_dbc(path).database


@dataclass
class _MessageSpec:
    """One message to send: its cantools definition, signal sources, cycle and running counter."""

    definition: Any
    sources: dict[str, str]
    cycle_ms: int
    next_index: int = 0
    counter: int = 0
    first_cylinder: int = -1  # a per-cylinder CHT message: index of its first cylinder (-1: not one)


class FrameEncoder:
    """Encodes StepBlocks into timestamped frames of engine.dbc, keeping the counters across blocks.

    ``cht_limit_c`` sets EcuStatus (WARNING at or above it); ``start_time_s`` is added to every
    timestamp (mission time 0 -> start_time_s). ``cylinders`` >= 2: an engine flown with cylinders
    also sends the per-cylinder CHT frames of cylinders.dbc (ECU_Cht1to4, ECU_Cht5to8 from five
    cylinders on; a signal past the last cylinder carries the range minimum) and ECU_Slow.CHT carries
    the cylinders' mean.
    """

    def __init__(
        self,
        dbc_path: Path = ENGINE_DBC,
        *,
        cht_limit_c: float = 150.0,
        start_time_s: float = 0.0,
        cylinders: int = 1,
    ) -> None:
        db = load_engine_dbc(Path(dbc_path))
        self.cylinders = cylinders
        self.encoder = Encoder([dbc_path, CYLINDERS_DBC] if cylinders > 1 else [dbc_path])
        self.cht_limit_c = cht_limit_c
        self.start_time_s = start_time_s
        self.specs: list[_MessageSpec] = []
        for name, (sources, _, _) in MESSAGE_SIGNALS.items():
            try:
                definition = db.get_message_by_name(name)
            except KeyError:
                raise ConfigError(f"{dbc_path}: no message {name!r}") from None
            if not definition.cycle_time:
                raise ConfigError(f"{dbc_path}: message {name!r} has no GenMsgCycleTime")
            if not self.encoder.has_counter(name):
                raise ConfigError(f"{dbc_path}: message {name!r} lacks the rolling counter and checksum of docs/dbc.md")
            self.specs.append(_MessageSpec(definition, sources, int(definition.cycle_time)))
        if cylinders > 1:
            for index, name in enumerate(CYLINDER_MESSAGES[: math.ceil(cylinders / 4)]):
                definition = self.encoder.message(name)
                self.specs.append(_MessageSpec(definition, {}, int(definition.cycle_time), first_cylinder=4 * index))

    def frames(self, block: StepBlock) -> list[can.Message]:
        """The frames due during ``block`` (times in [first step, first step + block length)), in time
        order; messages due at the same instant go in MESSAGE_SIGNALS order."""
        t = block.time_s
        dt = float(t[1] - t[0]) if t.size > 1 else 0.02
        end = float(t[-1]) + dt - 1e-9
        due: list[tuple[float, int, can.Message]] = []
        for order, spec in enumerate(self.specs):
            index = np.arange(spec.next_index, math.ceil(end * 1000.0 / spec.cycle_ms) + 1)
            stamps = index * spec.cycle_ms / 1000.0
            index, stamps = index[stamps < end], stamps[stamps < end]
            if index.size == 0:
                continue
            encoded = self._encode(spec, block, stamps)
            due.extend((stamp, order, msg) for stamp, msg in zip(stamps.tolist(), encoded, strict=True))
            spec.next_index = int(index[-1]) + 1
        due.sort(key=lambda item: (item[0], item[1]))
        return [msg for _, _, msg in due]

    def _encode(self, spec: _MessageSpec, block: StepBlock, stamps: np.ndarray) -> list[can.Message]:
        """Frames of one message at ``stamps`` (mission time, s), sampling the latest step at or before each."""
        k = np.maximum(np.searchsorted(block.time_s, stamps + 1e-9, side="right") - 1, 0)
        columns: dict[str, np.ndarray] = {
            signal: getattr(block.measured, source)[k] for signal, source in spec.sources.items()
        }
        if spec.definition.name == "ECU_Slow":
            hottest = (
                block.measured.cht_c
                if block.measured.cht_cylinders_c is None
                else block.measured.cht_cylinders_c.max(axis=0)
            )
            warning = hottest[k] >= self.cht_limit_c
            columns["EcuStatus"] = np.where(warning, _STATUS_WARNING, _STATUS_OK)
            columns["ManifoldPressure"] = np.zeros(k.size)  # not in the plant (fixed-pitch): 0, "not measured"
        if spec.first_cylinder >= 0:
            heads = block.measured.cht_cylinders_c
            if heads is None:
                raise ConfigError(f"{spec.definition.name}: the flight was not flown with cylinders")
            for i, signal in enumerate(s for s in spec.definition.signals if s.name.startswith("CHT")):
                c = spec.first_cylinder + i
                columns[signal.name] = heads[c, k] if c < heads.shape[0] else np.full(k.size, float(signal.minimum))
        payloads = self.encoder.encode_rows(spec.definition.name, columns, spec.counter)
        spec.counter = (spec.counter + len(payloads)) % 16
        frame_id, extended = spec.definition.frame_id, bool(spec.definition.is_extended_frame)
        start = self.start_time_s
        return [
            can.Message(timestamp=start + stamp, arbitration_id=frame_id, is_extended_id=extended, data=data)
            for stamp, data in zip(stamps.tolist(), payloads, strict=True)
        ]

    def iter_frames(self, blocks: Iterable[StepBlock]) -> Iterator[can.Message]:
        """Every frame of a flight, streamed block by block."""
        for block in blocks:
            yield from self.frames(block)


@dataclass
class EmitStats:
    """What an emission did: frames sent, failed sends, last mission time (s) and wall time (s)."""

    frames_sent: int = 0
    send_errors: int = 0
    mission_time_s: float = 0.0
    wall_time_s: float = 0.0


class FrameEmitter:
    """Sends a flight's frames onto ``bus`` (any python-can ``BusABC``; the caller owns and shuts it down).

    ``realtime=False`` sends as fast as possible; ``realtime=True`` paces the frames to the wall clock
    at ``speed`` times real time. ``progress`` is called with the EmitStats after each block.
    :meth:`stop` (from another thread) ends :meth:`emit` at the next frame.
    """

    def __init__(
        self,
        bus: can.BusABC,
        encoder: FrameEncoder | DroneCanFrameEncoder | None = None,
        *,
        realtime: bool = False,
        speed: float = 1.0,
        send_timeout_s: float = 0.1,
        progress: Callable[[EmitStats], None] | None = None,
    ) -> None:
        if not speed > 0.0:
            raise ConfigError(f"--speed: expected a positive factor, got {speed!r}")
        self.bus = bus
        self.encoder: FrameEncoder | DroneCanFrameEncoder = encoder or FrameEncoder()
        self.realtime = realtime
        self.speed = float(speed)
        self.send_timeout_s = send_timeout_s
        self.progress = progress
        self._stop = threading.Event()

    def stop(self) -> None:
        """Ask a running :meth:`emit` to return (idempotent, thread safe)."""
        self._stop.set()

    def emit(self, blocks: Iterable[StepBlock]) -> EmitStats:
        """Send every frame of ``blocks``; returns the counts. Send failures are counted and logged."""
        stats = EmitStats()
        wall0 = time.perf_counter()
        first_stamp: float | None = None
        for block in blocks:
            for msg in self.encoder.frames(block):
                if self._stop.is_set():
                    stats.wall_time_s = time.perf_counter() - wall0
                    return stats
                if first_stamp is None:
                    first_stamp = msg.timestamp
                if self.realtime:
                    ahead = (msg.timestamp - first_stamp) / self.speed - (time.perf_counter() - wall0)
                    if ahead > 0.0005:
                        self._stop.wait(ahead)
                try:
                    self.bus.send(msg, timeout=self.send_timeout_s)
                    stats.frames_sent += 1
                except can.CanError as exc:
                    stats.send_errors += 1
                    if stats.send_errors <= 5 or stats.send_errors % 1000 == 0:
                        _log.warning("send failed (%d so far) at t=%.3f s: %s", stats.send_errors, msg.timestamp, exc)
                stats.mission_time_s = msg.timestamp
            if self.progress is not None:
                stats.wall_time_s = time.perf_counter() - wall0
                self.progress(stats)
        stats.wall_time_s = time.perf_counter() - wall0
        return stats
