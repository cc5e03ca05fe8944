"""Mission profiles of the virtual ECU: YAML files parsed into frozen, validated dataclasses.

A mission is a field elevation, an atmosphere (ISA lapse with a day offset) and an ordered list of
flight segments. The pilot (:mod:`virtual_bus.pilot`) flies the segments one after the other; the
truth plant (:mod:`virtual_bus.plant`) turns the resulting inputs into a cylinder-head temperature.

Schema (every key optional unless marked *required*; units in the key names)::

    name: default
    description: free text
    field_elevation_m: 0              # pressure altitude of the airfield, m
    initial_cht_c: null               # CHT at engine start; null = the OAT at the field (cold engine)
    atmosphere:
      oat_offset_c: 0.0               # ISA day offset: OAT = 15 + offset - lapse * altitude / 1000
      lapse_rate_c_per_km: 6.5
    segments:                         # *required*, at least one; each item has a *required* "kind"
      - kind: ground_run              # warm-up on the ground, airspeed 0
        duration_s: 180               # *required*
        throttle_pct: 30
      - kind: takeoff                 # full power, ground roll then initial climb
        duration_s: 30
        ground_roll_s: 12
        throttle_pct: 100
        airspeed_mps: 20
        climb_rate_mps: 3
      - kind: climb
        target_altitude_m: 4000       # *required*, pressure altitude
        climb_rate_mps: 3
        throttle_pct: 100
        airspeed_mps: 20
        step_climb:                   # optional: level off when CHT nears the limit
          cht_margin_c: 12            # level off when measured CHT >= cht_limit_c - margin
          hysteresis_c: 15            # resume once back below cht_limit_c - margin - hysteresis ...
          min_level_s: 90             # ... and levelled for at least this long
          level_throttle_pct: 50      # throttle while levelled off (cruise power)
          level_airspeed_mps: 23
      - kind: cruise
        duration_s: 1200              # *required*
        airspeed_mps: 23
        throttle_pct: 50
        altitude_m: null              # null = hold the altitude reached by the previous segment
        throttle_variation: {kind: sine, amplitude: 5, period_s: 300}      # or kind: random
        speed_variation: {kind: random, amplitude: 1.5, period_s: 60}      # period_s = correlation time
        altitude_changes:             # new altitude targets at times from the segment start
          - {at_s: 600, altitude_m: 3500, rate_mps: 2}
      - kind: descent
        target_altitude_m: 300        # *required*
        rate_mps: 4                   # descent rate, positive
        throttle_pct: 20
        airspeed_mps: 25
      - kind: landing                 # approach to the field, roll-out, idle on the ground
        approach_rate_mps: 2
        throttle_pct: 20
        airspeed_mps: 18
        rollout_s: 20
        idle_s: 60
        idle_throttle_pct: 10

Every problem raises :class:`~ecu_monitor.errors.ConfigError` naming the file and the key
(``segments[2].climb_rate_mps``). :func:`virtual_bus.random_missions.random_mission` builds a varied
mission from a seed for estimator and gap-diagnosis tests.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, dataclass, fields
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ecu_monitor.errors import ConfigError
from ecu_monitor.shipped import resolve_file, shipped_dir, shipped_files
from ecu_monitor.yamlfile import load_yaml_file

__all__ = [
    "MISSIONS_DIR",
    "SEGMENT_KINDS",
    "AltitudeChange",
    "Atmosphere",
    "Climb",
    "Cruise",
    "Descent",
    "GroundRun",
    "Landing",
    "Mission",
    "Segment",
    "StepClimb",
    "Takeoff",
    "Variation",
    "list_missions",
    "load_mission",
    "mission_from_dict",
    "resolve_mission",
]

#: Shipped missions; ``--mission NAME`` names one when no file NAME exists (:func:`resolve_mission`).
MISSIONS_DIR = shipped_dir("mission")


def _check(where: str, value: Any, low: float, high: float) -> float:
    """A finite number in [low, high] or a ValueError naming ``where``."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{where}: expected a number, got {value!r}")
    if not low <= value <= high:
        raise ValueError(f"{where}: expected a number in [{low:g}, {high:g}], got {value!r}")
    return float(value)


class _Validated:
    """Mixin: check every float field against ``_RANGES`` (name -> (low, high)) after init."""

    _RANGES: ClassVar[dict[str, tuple[float, float]]] = {}

    def __post_init__(self) -> None:
        for name, (low, high) in self._RANGES.items():
            value = getattr(self, name)
            if value is None:
                continue
            object.__setattr__(self, name, _check(name, value, low, high))


@dataclass(frozen=True)
class Atmosphere(_Validated):
    """ISA troposphere temperature with a day offset: OAT = 15 + oat_offset_c - lapse * z / 1000 (degC)."""

    oat_offset_c: float = 0.0
    lapse_rate_c_per_km: float = 6.5
    _RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "oat_offset_c": (-50.0, 40.0),
        "lapse_rate_c_per_km": (0.0, 12.0),
    }

    def oat_c(self, altitude_m: Any) -> Any:
        """Outside air temperature (degC) at a pressure altitude (m); floats or arrays."""
        return 15.0 + self.oat_offset_c - self.lapse_rate_c_per_km * np.asarray(altitude_m, dtype=float) / 1000.0


@dataclass(frozen=True)
class Variation(_Validated):
    """A variation added to a commanded value: ``sine`` (amplitude * sin(2 pi t / period_s)) or
    ``random`` (Ornstein-Uhlenbeck process with standard deviation ``amplitude`` and correlation time
    ``period_s``). Amplitude is in the unit of the varied value (% throttle or m/s)."""

    kind: str = "sine"
    amplitude: float = 0.0
    period_s: float = 120.0
    _RANGES: ClassVar[dict[str, tuple[float, float]]] = {"amplitude": (0.0, 50.0), "period_s": (2.0, 1e5)}

    def __post_init__(self) -> None:
        if self.kind not in ("sine", "random"):
            raise ValueError(f"kind: expected 'sine' or 'random', got {self.kind!r}")
        super().__post_init__()


@dataclass(frozen=True)
class AltitudeChange(_Validated):
    """A new altitude target ``altitude_m`` from ``at_s`` seconds after the segment start, flown at
    up to ``rate_mps`` vertical speed."""

    at_s: float
    altitude_m: float
    rate_mps: float = 2.0
    _RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "at_s": (0.0, 1e6),
        "altitude_m": (-400.0, 6000.0),
        "rate_mps": (0.1, 10.0),
    }


@dataclass(frozen=True)
class StepClimb(_Validated):
    """Step-climb: level off at level_throttle_pct when the measured CHT reaches cht_limit_c -
    cht_margin_c (degC); resume the climb once levelled for at least min_level_s (s) and cooled by
    hysteresis_c (degC) more."""

    cht_margin_c: float = 12.0
    hysteresis_c: float = 15.0
    min_level_s: float = 90.0
    level_throttle_pct: float = 50.0
    level_airspeed_mps: float = 23.0
    _RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "cht_margin_c": (0.0, 100.0),
        "hysteresis_c": (0.5, 100.0),
        "min_level_s": (0.0, 3600.0),
        "level_throttle_pct": (0.0, 100.0),
        "level_airspeed_mps": (5.0, 80.0),
    }


@dataclass(frozen=True)
class GroundRun(_Validated):
    """Engine run on the ground (warm-up): airspeed 0 for duration_s at throttle_pct."""

    duration_s: float
    throttle_pct: float = 30.0
    kind = "ground_run"
    _RANGES: ClassVar[dict[str, tuple[float, float]]] = {"duration_s": (0.0, 1e5), "throttle_pct": (0.0, 100.0)}


@dataclass(frozen=True)
class Takeoff(_Validated):
    """Take-off at throttle_pct: ground roll for ground_roll_s accelerating to airspeed_mps, then an
    initial climb at climb_rate_mps until duration_s."""

    duration_s: float = 30.0
    ground_roll_s: float = 12.0
    throttle_pct: float = 100.0
    airspeed_mps: float = 20.0
    climb_rate_mps: float = 3.0
    kind = "takeoff"
    _RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "duration_s": (1.0, 600.0),
        "ground_roll_s": (0.0, 600.0),
        "throttle_pct": (0.0, 100.0),
        "airspeed_mps": (5.0, 80.0),
        "climb_rate_mps": (0.0, 10.0),
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.ground_roll_s > self.duration_s:
            raise ValueError(
                f"ground_roll_s: expected at most duration_s ({self.duration_s:g}), got {self.ground_roll_s}"
            )


@dataclass(frozen=True)
class Climb(_Validated):
    """Climb to target_altitude_m at climb_rate_mps with throttle_pct, optionally as a step-climb."""

    target_altitude_m: float
    climb_rate_mps: float = 3.0
    throttle_pct: float = 100.0
    airspeed_mps: float = 20.0
    step_climb: StepClimb | None = None
    kind = "climb"
    _RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "target_altitude_m": (-400.0, 6000.0),
        "climb_rate_mps": (0.2, 10.0),
        "throttle_pct": (0.0, 100.0),
        "airspeed_mps": (5.0, 80.0),
    }


@dataclass(frozen=True)
class Cruise(_Validated):
    """Cruise for duration_s at airspeed_mps and throttle_pct, with optional variations and altitude
    changes; altitude_m None holds the altitude reached by the previous segment."""

    duration_s: float
    airspeed_mps: float = 23.0
    throttle_pct: float = 50.0
    altitude_m: float | None = None
    throttle_variation: Variation | None = None
    speed_variation: Variation | None = None
    altitude_changes: tuple[AltitudeChange, ...] = ()
    kind = "cruise"
    _RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "duration_s": (0.0, 1e6),
        "airspeed_mps": (5.0, 80.0),
        "throttle_pct": (0.0, 100.0),
        "altitude_m": (-400.0, 6000.0),
    }


@dataclass(frozen=True)
class Descent(_Validated):
    """Descend to target_altitude_m at rate_mps (positive) with a low throttle."""

    target_altitude_m: float
    rate_mps: float = 4.0
    throttle_pct: float = 20.0
    airspeed_mps: float = 25.0
    kind = "descent"
    _RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "target_altitude_m": (-400.0, 6000.0),
        "rate_mps": (0.2, 15.0),
        "throttle_pct": (0.0, 100.0),
        "airspeed_mps": (5.0, 80.0),
    }


@dataclass(frozen=True)
class Landing(_Validated):
    """Approach to the field at approach_rate_mps, roll-out for rollout_s (airspeed to 0), then idle
    on the ground for idle_s."""

    approach_rate_mps: float = 2.0
    throttle_pct: float = 20.0
    airspeed_mps: float = 18.0
    rollout_s: float = 20.0
    idle_s: float = 60.0
    idle_throttle_pct: float = 10.0
    kind = "landing"
    _RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "approach_rate_mps": (0.2, 10.0),
        "throttle_pct": (0.0, 100.0),
        "airspeed_mps": (5.0, 80.0),
        "rollout_s": (0.0, 600.0),
        "idle_s": (0.0, 1e5),
        "idle_throttle_pct": (0.0, 100.0),
    }


Segment = GroundRun | Takeoff | Climb | Cruise | Descent | Landing
_SEGMENT_TYPES: dict[str, type] = {
    "ground_run": GroundRun,
    "takeoff": Takeoff,
    "climb": Climb,
    "cruise": Cruise,
    "descent": Descent,
    "landing": Landing,
}
SEGMENT_KINDS: tuple[str, ...] = tuple(_SEGMENT_TYPES)


@dataclass(frozen=True)
class Mission(_Validated):
    """A mission: airfield, atmosphere and the segments flown in order."""

    name: str
    segments: tuple[Segment, ...]
    description: str = ""
    field_elevation_m: float = 0.0
    atmosphere: Atmosphere = Atmosphere()
    initial_cht_c: float | None = None
    _RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "field_elevation_m": (-400.0, 5000.0),
        "initial_cht_c": (-40.0, 300.0),
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.segments:
            raise ValueError("segments: expected at least one segment")
        for i, seg in enumerate(self.segments):
            if not isinstance(seg, tuple(_SEGMENT_TYPES.values())):
                raise ValueError(f"segments[{i}]: expected a segment, got {type(seg).__name__}")

    def to_dict(self) -> dict[str, Any]:
        """Plain dict in the YAML schema (loads back to an equal Mission)."""
        return {
            "name": self.name,
            "description": self.description,
            "field_elevation_m": self.field_elevation_m,
            "initial_cht_c": self.initial_cht_c,
            "atmosphere": _plain(self.atmosphere),
            "segments": [{"kind": seg.kind, **_plain(seg)} for seg in self.segments],
        }


def _plain(obj: Any) -> Any:
    if isinstance(obj, tuple):
        return [_plain(v) for v in obj]
    if hasattr(obj, "__dataclass_fields__"):
        return {f.name: _plain(getattr(obj, f.name)) for f in fields(obj)}
    return obj


# --------------------------------------------------------------------------------------------------
# Parsing
# --------------------------------------------------------------------------------------------------


def _build(kind: type, data: Any, where: str, nested: dict[str, Any] | None = None) -> Any:
    """Construct dataclass ``kind`` from mapping ``data``; errors name ``where.key``."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a mapping")
    known = {f.name for f in fields(kind)}
    nested = nested or {}
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key not in known:
            raise ValueError(f"{where}.{key}: unknown key (known: {', '.join(sorted(known))})")
        kwargs[key] = nested[key](value, f"{where}.{key}") if key in nested and value is not None else value
    missing = [f.name for f in fields(kind) if f.name not in kwargs and _required(kind, f.name)]
    if missing:
        raise ValueError(f"{where}.{missing[0]}: missing (required)")
    try:
        return kind(**kwargs)
    except ValueError as exc:
        raise ValueError(f"{where}.{exc}") from None


def _required(kind: type, name: str) -> bool:
    field = next(f for f in fields(kind) if f.name == name)
    return field.default is MISSING and field.default_factory is MISSING


def _variation(value: Any, where: str) -> Variation:
    return _build(Variation, value, where)


def _altitude_changes(value: Any, where: str) -> tuple[AltitudeChange, ...]:
    if not isinstance(value, list):
        raise ValueError(f"{where}: expected a list of {{at_s, altitude_m, rate_mps}}")
    changes = tuple(_build(AltitudeChange, item, f"{where}[{i}]") for i, item in enumerate(value))
    times = [c.at_s for c in changes]
    if times != sorted(times):
        raise ValueError(f"{where}: expected at_s in increasing order")
    return changes


def _step_climb(value: Any, where: str) -> StepClimb:
    return _build(StepClimb, value, where)


_NESTED: dict[str, dict[str, Any]] = {
    "climb": {"step_climb": _step_climb},
    "cruise": {
        "throttle_variation": _variation,
        "speed_variation": _variation,
        "altitude_changes": _altitude_changes,
    },
}


def _segment(item: Any, where: str) -> Segment:
    if not isinstance(item, dict):
        raise ValueError(f"{where}: expected a mapping with a 'kind' key")
    kind = item.get("kind")
    if kind not in _SEGMENT_TYPES:
        raise ValueError(f"{where}.kind: expected one of {', '.join(SEGMENT_KINDS)}, got {kind!r}")
    body = {k: v for k, v in item.items() if k != "kind"}
    return _build(_SEGMENT_TYPES[kind], body, where, _NESTED.get(kind))


def mission_from_dict(data: Any, default_name: str = "mission") -> Mission:
    """Parse the mission schema; raises ValueError naming the key (see :func:`load_mission`)."""
    if not isinstance(data, dict):
        raise ValueError("expected a mapping at the top level")
    known = {f.name for f in fields(Mission)}
    for key in data:
        if key not in known:
            raise ValueError(f"{key}: unknown key (known: {', '.join(sorted(known))})")
    segments = data.get("segments")
    if not isinstance(segments, list) or not segments:
        raise ValueError("segments: expected a non-empty list")
    name = data.get("name", default_name)
    description = data.get("description", "")
    if not isinstance(name, str) or not isinstance(description, str):
        raise ValueError("name/description: expected text")
    return Mission(
        name=name,
        description=description,
        segments=tuple(_segment(item, f"segments[{i}]") for i, item in enumerate(segments)),
        field_elevation_m=data.get("field_elevation_m", 0.0),
        atmosphere=_build(Atmosphere, data.get("atmosphere"), "atmosphere"),
        initial_cht_c=data.get("initial_cht_c"),
    )


def resolve_mission(name_or_path: str | Path) -> Path:
    """A mission file: a path that exists, else the name of a shipped mission (``default``)."""
    return resolve_file(name_or_path, "mission")


def list_missions() -> tuple[str, ...]:
    """Names of the shipped missions."""
    return tuple(name.removesuffix(".yaml") for name in shipped_files("mission"))


def load_mission(name_or_path: str | Path) -> Mission:
    """Read a mission YAML (a path or a shipped mission's name); problems raise ConfigError naming
    the file and the key."""
    path = resolve_mission(name_or_path)
    data = load_yaml_file(path, "mission file", ConfigError)
    try:
        return mission_from_dict(data, default_name=path.stem)
    except ValueError as exc:
        raise ConfigError(f"{path}: {exc}") from None
