"""The pilot, airframe and engine of the virtual ECU: from a mission to the model's inputs over time.

The pilot decides once per control period (:data:`CONTROL_PERIOD_S`, 1 s) and holds three targets
over it: throttle (%), calibrated airspeed (m/s) and vertical speed (m/s). The airframe follows each
target with a first-order lag, integrated exactly (closed form) for every integration step of the
period, so a whole period is computed with a few numpy operations:

    throttle   tau = :data:`THROTTLE_TAU_S` (engine/servo response)
    airspeed   tau = :data:`AIRSPEED_TAU_S`
    vspeed     tau = :data:`VSPEED_TAU_S`;  altitude = field elevation + integral of vspeed (floored)

Engine speed follows the throttle and the airspeed through a fixed-pitch propeller law
(:func:`propeller_rpm`), fuel flow through a documented engine map (:func:`fuel_flow_lph`). The
step-climb decision uses the *measured* CHT, as an autopilot would.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ecu_monitor.model import isa_pressure_pa
from virtual_bus.missions import Climb, Cruise, Descent, GroundRun, Landing, Mission, Segment, Takeoff, Variation

__all__ = [
    "AIRSPEED_TAU_S",
    "ALTITUDE_GAIN_PER_S",
    "ARRIVAL_TOLERANCE_M",
    "CLIMB_THROTTLE_PER_MPS",
    "CLIMB_TIMEOUT_EXTRA_S",
    "CLIMB_TIMEOUT_FACTOR",
    "CONTROL_PERIOD_S",
    "THROTTLE_TAU_S",
    "VSPEED_TAU_S",
    "AircraftState",
    "Command",
    "Kinematics",
    "Pilot",
    "fly_period",
    "fuel_flow_lph",
    "propeller_rpm",
]

_log = logging.getLogger(__name__)

#: The pilot decides once per control period, s.
CONTROL_PERIOD_S = 1.0
THROTTLE_TAU_S = 1.0
AIRSPEED_TAU_S = 5.0
VSPEED_TAU_S = 2.0
#: Proportional gain of altitude hold / capture: commanded vspeed = gain * altitude error, 1/s.
ALTITUDE_GAIN_PER_S = 0.1
#: Extra throttle per m/s of commanded vertical speed in cruise (power to climb), %/(m/s).
CLIMB_THROTTLE_PER_MPS = 8.0
#: Altitude within which a climb or descent counts as arrived, m.
ARRIVAL_TOLERANCE_M = 2.0
#: A climb (step-climb plateaus included) is abandoned, with a warning, after
#: CLIMB_TIMEOUT_FACTOR x its nominal duration + CLIMB_TIMEOUT_EXTRA_S: a mission always ends.
CLIMB_TIMEOUT_FACTOR = 4.0
CLIMB_TIMEOUT_EXTRA_S = 1800.0


def propeller_rpm(throttle_pct: np.ndarray | float, airspeed_mps: np.ndarray | float) -> np.ndarray:
    """Engine speed of the fixed-pitch propeller, rpm.

    rpm = 1800 + 7000 (throttle/100)^0.8 + 10 * airspeed, clipped to [1500, 9200]: idle 1800 rpm on
    the ground, 6050 rpm at the 50 % / 23 m/s cruise point, ~9000 rpm at full power in the climb
    (the reference engine's 2000-9000 rpm band); the airspeed term is the propeller's windmilling
    unloading (+10 rpm per m/s).
    """
    th = np.clip(np.asarray(throttle_pct, dtype=float), 0.0, 100.0) / 100.0
    v = np.maximum(np.asarray(airspeed_mps, dtype=float), 0.0)
    return np.clip(1800.0 + 7000.0 * th**0.8 + 10.0 * v, 1500.0, 9200.0)


def fuel_flow_lph(
    throttle_pct: np.ndarray | float, rpm: np.ndarray | float, altitude_m: np.ndarray | float, oat_c: np.ndarray | float
) -> np.ndarray:
    """Fuel volume flow, L/h, from a documented engine map (not the thermal model's heat map).

    Shaft power P = 1.9 kW * (0.12 + 0.88 (throttle/100)^0.95) * (rpm/9000)^0.7 * sigma, with sigma
    the air density ratio (ISA pressure, measured OAT); fuel = 500 g/kWh * P / 0.74 kg/L. About
    0.55 L/h at the sea-level cruise point (0.82 kW), 1.3 L/h at full power (paper Table 2: 500 g/kWh).
    """
    th = np.clip(np.asarray(throttle_pct, dtype=float), 0.0, 100.0) / 100.0
    speed = np.clip(np.asarray(rpm, dtype=float), 0.0, None) / 9000.0
    pressure = np.asarray(isa_pressure_pa(altitude_m), dtype=float)
    sigma = (pressure / 101325.0) * (288.15 / (np.asarray(oat_c, dtype=float) + 273.15))
    power_kw = 1.9 * (0.12 + 0.88 * th**0.95) * speed**0.7 * sigma
    return 0.5 * power_kw / 0.74


class Command(NamedTuple):
    """Targets held over one control period."""

    throttle_pct: float
    airspeed_mps: float
    vspeed_mps: float
    on_ground: bool = False


@dataclass
class AircraftState:
    """Airframe state at the start of a control period (mutable; owned by the plant loop)."""

    time_s: float
    altitude_m: float
    vspeed_mps: float = 0.0
    airspeed_mps: float = 0.0
    throttle_pct: float = 0.0


class Kinematics(NamedTuple):
    """Inputs at each integration step of one control period (arrays of length n)."""

    throttle_pct: np.ndarray
    airspeed_mps: np.ndarray
    vspeed_mps: np.ndarray
    altitude_m: np.ndarray


def _lag(start: float, target: float, decay: np.ndarray) -> np.ndarray:
    return target + (start - target) * decay


def fly_period(
    state: AircraftState, command: Command, n_steps: int, dt_s: float, floor_m: float
) -> tuple[Kinematics, AircraftState]:
    """Airframe response over ``n_steps`` steps of ``dt_s`` to a held command (exact first-order lags).

    Returns the inputs at the start of each step and the state at the end of the period. The
    altitude never goes below ``floor_m`` (the field); on the ground the vertical speed is 0.
    """
    t = dt_s * np.arange(n_steps + 1, dtype=float)
    throttle = _lag(state.throttle_pct, command.throttle_pct, np.exp(-t / THROTTLE_TAU_S))
    airspeed = _lag(state.airspeed_mps, command.airspeed_mps, np.exp(-t / AIRSPEED_TAU_S))
    if command.on_ground:
        vspeed = np.zeros_like(t)
        altitude = np.full_like(t, floor_m)
    else:
        decay = np.exp(-t / VSPEED_TAU_S)
        vspeed = _lag(state.vspeed_mps, command.vspeed_mps, decay)
        altitude = (
            state.altitude_m
            + command.vspeed_mps * t
            + (state.vspeed_mps - command.vspeed_mps) * VSPEED_TAU_S * (1.0 - decay)
        )
        below = altitude < floor_m
        altitude = np.where(below, floor_m, altitude)
        vspeed = np.where(below, 0.0, vspeed)
    end = AircraftState(
        time_s=state.time_s + n_steps * dt_s,
        altitude_m=float(altitude[-1]),
        vspeed_mps=float(vspeed[-1]),
        airspeed_mps=float(airspeed[-1]),
        throttle_pct=float(throttle[-1]),
    )
    kin = Kinematics(throttle[:-1], airspeed[:-1], vspeed[:-1], altitude[:-1])
    return kin, end


class _VariationState:
    """A running variation: sine of segment time, or an Ornstein-Uhlenbeck process."""

    def __init__(self, spec: Variation | None, rng: np.random.Generator) -> None:
        self.spec = spec
        self.rng = rng
        self.value = 0.0

    def sample(self, t_seg: float, dt_s: float) -> float:
        spec = self.spec
        if spec is None or spec.amplitude == 0.0:
            return 0.0
        if spec.kind == "sine":
            return spec.amplitude * math.sin(2.0 * math.pi * t_seg / spec.period_s)
        decay = math.exp(-dt_s / spec.period_s)
        self.value = self.value * decay + spec.amplitude * math.sqrt(1.0 - decay * decay) * float(
            self.rng.standard_normal()
        )
        return self.value


def _capture(target_m: float, altitude_m: float, rate_mps: float) -> float:
    """Vertical speed command towards an altitude: proportional, limited to +-rate_mps."""
    return max(-rate_mps, min(rate_mps, ALTITUDE_GAIN_PER_S * (target_m - altitude_m)))


class Pilot:
    """Flies the mission's segments in order; :meth:`command` is called once per control period.

    ``cht_limit_c`` is the engine limit the step-climb keeps clear of; ``rng`` drives the random
    variations (a stream separate from the sensor noise).
    """

    def __init__(self, mission: Mission, cht_limit_c: float, rng: np.random.Generator) -> None:
        self.mission = mission
        self.cht_limit_c = cht_limit_c
        self.rng = rng
        self.index = 0
        self.segment_start_s = 0.0
        self.levelled = False
        self.level_altitude_m = 0.0
        self.level_offs = 0
        self.levelled_at_s = 0.0
        self._entry_altitude_m = mission.field_elevation_m
        self._touchdown_s: float | None = None
        self._throttle_var = _VariationState(None, rng)
        self._speed_var = _VariationState(None, rng)
        self._enter(0, AircraftState(time_s=0.0, altitude_m=mission.field_elevation_m))

    @property
    def segment(self) -> Segment | None:
        """The segment being flown (None once the mission is over)."""
        return self.mission.segments[self.index] if self.index < len(self.mission.segments) else None

    def _enter(self, index: int, state: AircraftState) -> None:
        self.index = index
        self.segment_start_s = state.time_s
        self._entry_altitude_m = state.altitude_m
        self.levelled = False
        self._touchdown_s = None
        seg = self.segment
        if isinstance(seg, Cruise):
            self._throttle_var = _VariationState(seg.throttle_variation, self.rng)
            self._speed_var = _VariationState(seg.speed_variation, self.rng)

    def command(self, state: AircraftState, cht_measured_c: float) -> Command | None:
        """Targets for the next control period, or None when the last segment is finished."""
        while (seg := self.segment) is not None:
            cmd = self._segment_command(seg, state, state.time_s - self.segment_start_s, cht_measured_c)
            if cmd is not None:
                return cmd
            self._enter(self.index + 1, state)
        return None

    def _segment_command(
        self, seg: Segment, state: AircraftState, t_seg: float, cht_c: float
    ) -> Command | None:  # one branch per segment kind; None = segment finished
        field = self.mission.field_elevation_m
        if isinstance(seg, GroundRun):
            return None if t_seg >= seg.duration_s else Command(seg.throttle_pct, 0.0, 0.0, on_ground=True)
        if isinstance(seg, Takeoff):
            if t_seg >= seg.duration_s:
                return None
            rolling = t_seg < seg.ground_roll_s
            return Command(seg.throttle_pct, seg.airspeed_mps, 0.0 if rolling else seg.climb_rate_mps, rolling)
        if isinstance(seg, Climb):
            return self._climb(seg, state, cht_c)
        if isinstance(seg, Cruise):
            return self._cruise(seg, state, t_seg)
        if isinstance(seg, Descent):
            if state.altitude_m <= seg.target_altitude_m + ARRIVAL_TOLERANCE_M:
                return None
            vs = _capture(seg.target_altitude_m, state.altitude_m, seg.rate_mps)
            return Command(seg.throttle_pct, seg.airspeed_mps, vs)
        if isinstance(seg, Landing):
            if self._touchdown_s is None and state.altitude_m <= field + 0.5:
                self._touchdown_s = t_seg
            if self._touchdown_s is None:
                vs = -min(seg.approach_rate_mps, max(0.3, ALTITUDE_GAIN_PER_S * (state.altitude_m - field)))
                return Command(seg.throttle_pct, seg.airspeed_mps, vs)
            since = t_seg - self._touchdown_s
            if since >= seg.rollout_s + seg.idle_s:
                return None
            return Command(seg.idle_throttle_pct, 0.0, 0.0, on_ground=True)
        raise TypeError(f"unknown segment {seg!r}")

    def _climb(self, seg: Climb, state: AircraftState, cht_c: float) -> Command | None:
        if abs(state.altitude_m - seg.target_altitude_m) <= ARRIVAL_TOLERANCE_M:
            return None
        nominal_s = abs(seg.target_altitude_m - self._entry_altitude_m) / seg.climb_rate_mps
        if state.time_s - self.segment_start_s > CLIMB_TIMEOUT_FACTOR * nominal_s + CLIMB_TIMEOUT_EXTRA_S:
            _log.warning(
                "climb to %.0f m abandoned at %.0f m after %.0f s (the step-climb could not cool the engine)",
                seg.target_altitude_m,
                state.altitude_m,
                state.time_s - self.segment_start_s,
            )
            return None
        step = seg.step_climb
        if step is not None:
            level_at = self.cht_limit_c - step.cht_margin_c
            if not self.levelled and cht_c >= level_at:
                self.levelled = True
                self.level_offs += 1
                self.level_altitude_m = state.altitude_m
                self.levelled_at_s = state.time_s
            elif (
                self.levelled
                and cht_c <= level_at - step.hysteresis_c
                and state.time_s - self.levelled_at_s >= step.min_level_s
            ):
                self.levelled = False
            if self.levelled:
                vs = _capture(self.level_altitude_m, state.altitude_m, seg.climb_rate_mps)
                return Command(step.level_throttle_pct, step.level_airspeed_mps, vs)
        vs = _capture(seg.target_altitude_m, state.altitude_m, seg.climb_rate_mps)
        return Command(seg.throttle_pct, seg.airspeed_mps, vs)

    def _cruise(self, seg: Cruise, state: AircraftState, t_seg: float) -> Command | None:
        if t_seg >= seg.duration_s:
            return None
        target = seg.altitude_m if seg.altitude_m is not None else self._entry_altitude_m
        rate = 2.0
        for change in seg.altitude_changes:
            if t_seg >= change.at_s:
                target, rate = change.altitude_m, change.rate_mps
        vs = _capture(target, state.altitude_m, rate)
        throttle = seg.throttle_pct + self._throttle_var.sample(t_seg, CONTROL_PERIOD_S) + CLIMB_THROTTLE_PER_MPS * vs
        airspeed = seg.airspeed_mps + self._speed_var.sample(t_seg, CONTROL_PERIOD_S)
        return Command(min(100.0, max(0.0, throttle)), max(5.0, airspeed), vs)
