"""The virtual ECU on a DroneCAN bus: the truth plant's measurements as DroneCAN messages.

:class:`DroneCanFrameEncoder` is the DroneCAN twin of :class:`virtual_bus.emitter.FrameEncoder` (the same
``frames(block)``, so :class:`~virtual_bus.emitter.FrameEmitter` and the recorder take either). Two
nodes publish, as on an aircraft with an EFI and an air-data computer:

* the engine node (:data:`ENGINE_NODE_ID`): ``uavcan.equipment.ice.reciprocating.Status`` every
  :data:`PERIOD_S`: engine speed, throttle (integer percent, the DSDL field), fuel flow (cm3/min),
  atmospheric pressure (the standard pressure at the pressure altitude), state RUNNING or STOPPED,
  the temperature flags (above nominal at or over the CHT limit, as the DBC ECU's EcuStatus) and one
  ``CylinderStatus`` per measured cylinder with its head temperature in kelvin; every other float
  field NaN (DSDL: unknown);
* the air-data node (:data:`AIR_DATA_NODE_ID`): ``uavcan.equipment.air_data.IndicatedAirspeed``,
  ``StaticPressure`` (Pa, the standard pressure at the pressure altitude) and ``StaticTemperature``
  (kelvin) every :data:`PERIOD_S`.

Every transfer is built by the service's one DroneCAN encoder (:class:`ecu_monitor.bus.dronecan.DroneCanEncoder`:
the ``dronecan`` package's DSDL serialisation, multi-frame split, toggle and transfer CRC; transfer id
+1 mod 32 per message type). The frames of one transfer carry its time stamp; messages due at the same
instant go in the order above, the engine status first.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from typing import Any

import can
import numpy as np

from ecu_monitor.bus.dronecan import DroneCanEncoder
from ecu_monitor.units import UNITS, standard_pressure_kpa
from virtual_bus.plant import StepBlock

__all__ = ["AIR_DATA_NODE_ID", "ENGINE_NODE_ID", "PERIOD_S", "DroneCanFrameEncoder"]

#: Node ids of the virtual engine ECU and of the virtual air-data computer.
ENGINE_NODE_ID = 20
AIR_DATA_NODE_ID = 21
#: Broadcast period of every message, s (10 Hz, a usual EFI and air-data rate).
PERIOD_S = 0.1

_STATUS = "uavcan.equipment.ice.reciprocating.Status"
_KELVIN = -UNITS["K"].offset  # 273.15
_CC_PER_MIN = UNITS["cc_per_min"].scale  # L/h per cm3/min
#: Status.flags: temperature flags supported, above nominal (DSDL constants of the Status type)
_FLAG_TEMPERATURE_SUPPORTED = 8
_FLAG_TEMPERATURE_ABOVE_NOMINAL = 32
_STATE_STOPPED, _STATE_RUNNING = 0, 2


class DroneCanFrameEncoder:
    """Encodes StepBlocks into timestamped DroneCAN frames, keeping transfer ids across blocks.

    ``cht_limit_c`` sets the over-temperature flag; ``start_time_s`` is added to every timestamp.
    """

    def __init__(self, *, cht_limit_c: float = 150.0, start_time_s: float = 0.0) -> None:
        self.cht_limit_c = cht_limit_c
        self.start_time_s = start_time_s
        self.engine = DroneCanEncoder(ENGINE_NODE_ID)
        self.air_data = DroneCanEncoder(AIR_DATA_NODE_ID)
        self._next_index = 0

    def frames(self, block: StepBlock) -> list[can.Message]:
        """The frames due during ``block`` (times in [first step, first step + block length)), in time order."""
        t = block.time_s
        dt = float(t[1] - t[0]) if t.size > 1 else 0.02
        end = float(t[-1]) + dt - 1e-9
        index = np.arange(self._next_index, math.ceil(end / PERIOD_S) + 1)
        stamps = index * PERIOD_S
        index, stamps = index[stamps < end], stamps[stamps < end]
        if index.size == 0:
            return []
        self._next_index = int(index[-1]) + 1
        k = np.maximum(np.searchsorted(t, stamps + 1e-9, side="right") - 1, 0)
        m = block.measured
        out: list[can.Message] = []
        for j, stamp in zip(k.tolist(), stamps.tolist(), strict=True):
            out.extend(self._transfers(m, j, self.start_time_s + stamp))
        return out

    def _transfers(self, m: Any, j: int, stamp: float) -> list[can.Message]:
        rpm = float(m.rpm[j])
        pressure_kpa = float(standard_pressure_kpa(float(m.altitude_m[j])))
        heads = m.cht_cylinders_c  # an engine flown with cylinders: one CylinderStatus each
        chts = [float(m.cht_c[j])] if heads is None else [float(v) for v in heads[:, j]]
        flags = _FLAG_TEMPERATURE_SUPPORTED
        if max(chts) >= self.cht_limit_c:
            flags |= _FLAG_TEMPERATURE_ABOVE_NOMINAL
        status = {
            "state": _STATE_RUNNING if rpm > 0.0 else _STATE_STOPPED,
            "flags": flags,
            "engine_speed_rpm": rpm,
            "throttle_position_percent": float(m.throttle_pct[j]),
            "fuel_consumption_rate_cm3pm": float(m.fuel_flow_lph[j]) / _CC_PER_MIN,
            "atmospheric_pressure_kpa": pressure_kpa,
            "cylinder_status": [{"cylinder_head_temperature": c + _KELVIN} for c in chts],
        }
        frames = self.engine.frames(_STATUS, status, stamp)
        air = self.air_data
        frames += air.frames(
            "uavcan.equipment.air_data.IndicatedAirspeed", {"indicated_airspeed": float(m.airspeed_mps[j])}, stamp
        )
        frames += air.frames(
            "uavcan.equipment.air_data.StaticPressure", {"static_pressure": pressure_kpa * 1000.0}, stamp
        )
        frames += air.frames(
            "uavcan.equipment.air_data.StaticTemperature", {"static_temperature": float(m.oat_c[j]) + _KELVIN}, stamp
        )
        return frames

    def iter_frames(self, blocks: Iterable[StepBlock]) -> Iterator[can.Message]:
        """Every frame of a flight, streamed block by block."""
        for block in blocks:
            yield from self.frames(block)
