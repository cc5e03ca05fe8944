"""The virtual engine ECU: mission profiles, truth plant, sensor model, frame emitter and recorder.

Start with :func:`virtual_bus.missions.load_mission` and :func:`virtual_bus.plant.fly` (a mission to a
FlightLog with the truth beside the measurements), :class:`virtual_bus.emitter.FrameEmitter` (frames
onto a python-can bus) and :func:`virtual_bus.recorder.record` (CSV and CAN logs). The ``virtual-ecu``
command is :mod:`virtual_bus.cli`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from virtual_bus.emitter import EmitStats, FrameEmitter, FrameEncoder
    from virtual_bus.missions import Mission, list_missions, load_mission
    from virtual_bus.plant import Degradation, StepBlock, fly, iter_steps, parse_effects, random_effects
    from virtual_bus.random_missions import random_mission
    from virtual_bus.recorder import RecordSummary, record
    from virtual_bus.sensors import SensorModel

#: Public name -> its module: imported on first use (PEP 562), so ``virtual-ecu --help`` and
#: ``import virtual_bus.cli`` do not pay for numpy, python-can and the plant's kernels.
_HOME: dict[str, str] = {
    **dict.fromkeys(("EmitStats", "FrameEmitter", "FrameEncoder"), "emitter"),
    **dict.fromkeys(("Mission", "list_missions", "load_mission"), "missions"),
    **dict.fromkeys(("Degradation", "StepBlock", "fly", "iter_steps", "parse_effects", "random_effects"), "plant"),
    "random_mission": "random_missions",
    **dict.fromkeys(("RecordSummary", "record"), "recorder"),
    "SensorModel": "sensors",
}


def __getattr__(name: str) -> Any:
    module = _HOME.get(name)
    if module is None:
        raise AttributeError(f"module 'virtual_bus' has no attribute {name!r}")
    return getattr(importlib.import_module(f"virtual_bus.{module}"), name)


__all__ = [
    "Degradation",
    "EmitStats",
    "FrameEmitter",
    "FrameEncoder",
    "Mission",
    "RecordSummary",
    "SensorModel",
    "StepBlock",
    "fly",
    "iter_steps",
    "list_missions",
    "load_mission",
    "parse_effects",
    "random_effects",
    "random_mission",
    "record",
]
