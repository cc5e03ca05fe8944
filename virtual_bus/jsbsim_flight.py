"""Fly one of JSBSim's piston aircraft through a mission and log what its engine monitor shows.

The engine here is JSBSim's (FGPiston: its CHT, EGT, oil temperature, fuel flow and manifold pressure),
physics nobody in this project wrote: a check that identification carries to an engine it was not built
around (docs/jsbsim.md). Needs the optional ``jsbsim`` package (``pip install 'ecu-monitor[jsbsim]'``).

A mission is a list of :class:`Leg` drawn from a seed (:func:`make_mission`): a ground run with the brakes
on, take-off and a climb at the aircraft's climb speed, cruise legs at set power, mixture (leaned to an
air-fuel ratio, as a pilot leans by EGT) and altitude, a descent at part power and a power-off glide. A small
controller written here flies it (wings level, pitch for airspeed or altitude, rudder for the runway); the
aircraft's own autopilot is not used, so every shipped piston aircraft in :data:`AIRCRAFT` flies the same
way. The log is decimated to ``record_dt_s`` (1 s) in canonical units (docs/contracts.md).
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ecu_monitor.errors import ConfigError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.units import UNITS

__all__ = ["AIRCRAFT", "MISSIONS", "Aircraft", "Leg", "fly", "make_mission"]

_FT = UNITS["ft"].scale  # m per foot


@dataclass(frozen=True)
class Aircraft:
    """A JSBSim piston aircraft and the speeds its pilot flies (knots, calibrated)."""

    name: str
    rotate_kts: float
    climb_kts: float
    descent_kts: float
    glide_kts: float
    ceiling_m: float


#: The piston aircraft of the jsbsim package this flies (name as the package's ``aircraft/`` folder): the c172x
#: and c172p (O-320), the c172r and pa28 (IO-360), the c182 (IO-540, constant-speed propeller) and the c310 twin
#: (IO-470, both engines flown alike, engine 1 logged). Not the J3Cub: its tail wheel ground-loops on take-off.
AIRCRAFT: dict[str, Aircraft] = {
    a.name: a
    for a in (
        Aircraft("c172x", 55.0, 75.0, 95.0, 68.0, 3500.0),
        Aircraft("c172p", 55.0, 75.0, 95.0, 68.0, 3500.0),
        Aircraft("c172r", 55.0, 75.0, 95.0, 68.0, 3500.0),
        Aircraft("c182", 60.0, 85.0, 105.0, 75.0, 4500.0),
        Aircraft("pa28", 60.0, 80.0, 100.0, 75.0, 3500.0),
        Aircraft("c310", 90.0, 110.0, 140.0, 100.0, 5000.0),
    )
}


@dataclass(frozen=True)
class Leg:
    """One part of a mission.

    kind: "ground" (brakes on, engine at ``throttle``), "climb" (take-off if on the ground, then pitch for
        ``speed_kts`` to ``altitude_m``), "cruise" (hold ``altitude_m`` at ``throttle``) or "descent" (pitch
        for ``speed_kts`` at ``throttle`` down to ``altitude_m``).
    duration_s: the leg's length (s); a climb or descent also ends at its altitude.
    throttle: throttle lever, 0-1. afr: the air-fuel ratio the pilot leans to (None: full rich).
    altitude_m: target altitude above the field (m). speed_kts: target calibrated airspeed (knots).
    """

    kind: str
    duration_s: float
    throttle: float
    afr: float | None = None
    altitude_m: float = 0.0
    speed_kts: float = 0.0


#: Mission kinds :func:`make_mission` draws, with what they fly.
MISSIONS: dict[str, str] = {
    "pattern": "a short flight: ground run, climb to 300-600 m, two power settings, descent (~15 min)",
    "cross_country": "ground run, climb to 1200-3000 m, three or four cruise legs leaned, descent (~45 min)",
    "step_climb": "ground run, climbs and descents between cruise levels at changing power and mixture (~35 min)",
}


def make_mission(kind: str, aircraft: Aircraft, seed: int) -> tuple[tuple[Leg, ...], float, float]:
    """The legs of mission ``kind`` for ``aircraft`` from ``seed``, the field elevation (m) and the day's
    temperature offset from ISA (K)."""
    if kind not in MISSIONS:
        raise ConfigError(f"--mission: expected one of {', '.join(MISSIONS)}, got {kind!r}")
    rng = np.random.default_rng(seed)
    field_m = float(rng.uniform(0.0, 1200.0))
    delta_t_k = float(rng.uniform(-15.0, 15.0))
    top = aircraft.ceiling_m - field_m
    legs = [Leg("ground", float(rng.uniform(120.0, 420.0)), float(rng.uniform(0.15, 0.45)))]
    climb = aircraft.climb_kts
    cruise_speed = aircraft.descent_kts
    if kind == "pattern":
        level = float(rng.uniform(300.0, 600.0))
        legs.append(Leg("climb", 900.0, 1.0, altitude_m=level, speed_kts=climb))
        for _ in range(2):
            legs.append(
                Leg("cruise", float(rng.uniform(180.0, 360.0)), float(rng.uniform(0.5, 0.85)), altitude_m=level)
            )
    elif kind == "cross_country":
        level = float(rng.uniform(1200.0, max(1300.0, min(3000.0, top))))
        legs.append(Leg("climb", 1800.0, 1.0, altitude_m=level, speed_kts=climb))
        for _ in range(int(rng.integers(3, 5))):
            legs.append(
                Leg(
                    "cruise",
                    float(rng.uniform(360.0, 720.0)),
                    float(rng.uniform(0.55, 0.9)),
                    afr=float(rng.uniform(11.0, 13.5)),
                    altitude_m=level,
                )
            )
    else:  # step_climb
        level = 0.0
        for _ in range(int(rng.integers(3, 5))):
            new = float(rng.uniform(400.0, max(500.0, min(2800.0, top))))
            if new > level:
                legs.append(Leg("climb", 1200.0, float(rng.uniform(0.85, 1.0)), altitude_m=new, speed_kts=climb))
            else:
                speed = float(rng.uniform(climb, cruise_speed))
                legs.append(Leg("descent", 900.0, float(rng.uniform(0.3, 0.6)), altitude_m=new, speed_kts=speed))
            level = new
            afr = None if rng.random() < 0.3 else float(rng.uniform(11.0, 13.5))
            legs.append(
                Leg("cruise", float(rng.uniform(240.0, 540.0)), float(rng.uniform(0.5, 0.9)), afr=afr, altitude_m=level)
            )
    legs.append(Leg("descent", 1200.0, float(rng.uniform(0.25, 0.5)), altitude_m=250.0, speed_kts=cruise_speed))
    legs.append(Leg("descent", 300.0, 0.0, altitude_m=60.0, speed_kts=aircraft.glide_kts))
    return tuple(legs), field_m, delta_t_k


class _Pid:
    """A PI(D) loop on an error with a clamped output and integrator (anti-windup)."""

    def __init__(self, kp: float, ki: float, low: float, high: float) -> None:
        self.kp, self.ki, self.low, self.high = kp, ki, low, high
        self.integral = 0.0

    def __call__(self, error: float, rate: float, kd: float, dt: float) -> float:
        unclamped = self.kp * error + self.integral - kd * rate
        if self.low < unclamped < self.high:
            self.integral += self.ki * error * dt
        return min(self.high, max(self.low, unclamped))


#: Property -> canonical column and unit conversion of the engine monitor's log.
_ENGINE = "propulsion/engine"
#: The aircraft is dropped from this height onto its gear (ft) and left this long (s) before the log, engine off:
#: it settles on its gear and the engine, which JSBSim starts at 15 degC, soaks to the day's temperature.
_DROP_FT = 5.0
_SETTLE_S = 400.0


def _load(aircraft: Aircraft, scratch: str) -> Any:
    try:
        import jsbsim
    except ImportError:
        raise ConfigError("virtual-ecu jsbsim needs the jsbsim package: pip install 'ecu-monitor[jsbsim]'") from None
    jsbsim.FGJSBBase().debug_lvl = 0  # no start-up banner on stdout
    fdm = jsbsim.FGFDMExec(None)
    fdm.set_output_path(scratch)
    if not fdm.load_model(aircraft.name):
        raise ConfigError(f"--aircraft {aircraft.name}: the jsbsim package could not load it")
    fdm.disable_output()
    return fdm


def fly(
    aircraft_name: str,
    mission: str,
    seed: int = 0,
    *,
    record_dt_s: float = 1.0,
    progress: Callable[[float], None] | None = None,
) -> FlightLog:
    """Fly ``mission`` (a kind of :data:`MISSIONS`, drawn from ``seed``) in ``aircraft_name`` and return the
    engine monitor's log at ``record_dt_s``: the canonical columns, fuel flow, EGT, oil temperature,
    manifold pressure, the mixture lever (``mixture_pct``) and the height above the field (``agl_m``).
    ``cht_c`` is rounded to 1 degC as an ECU's sensor is; ``cht_true_c`` is JSBSim's own value."""
    aircraft = AIRCRAFT.get(aircraft_name)
    if aircraft is None:
        raise ConfigError(f"--aircraft: expected one of {', '.join(AIRCRAFT)}, got {aircraft_name!r}")
    legs, field_m, delta_t_k = make_mission(mission, aircraft, seed)
    # the aircraft's own output files (JSBout172B.csv ...) go to a scratch folder, then away
    with tempfile.TemporaryDirectory(prefix="jsbsim-") as scratch:
        fdm = _load(aircraft, scratch)
        rows, t0 = _fly_legs(fdm, aircraft, legs, field_m, delta_t_k, record_dt_s, progress)
    return _log(rows, t0, f"jsbsim {aircraft.name} {mission} seed {seed}")


def _fly_legs(
    fdm: Any,
    aircraft: Aircraft,
    legs: tuple[Leg, ...],
    field_m: float,
    delta_t_k: float,
    record_dt_s: float,
    progress: Callable[[float], None] | None,
) -> tuple[list[list[float]], float]:
    """Fly ``legs`` from a cold start on a field at ``field_m`` on a day ``delta_t_k`` off ISA: the logged
    rows every ``record_dt_s`` and the simulation time of the log's start (s)."""
    catalog = {p.split()[0] for p in fdm.get_property_catalog()}
    engines = sum(1 for p in catalog if p.endswith("/cht-degF"))
    fdm["atmosphere/delta-T"] = delta_t_k * 1.8  # Rankine
    fdm["ic/terrain-elevation-ft"] = field_m / _FT
    fdm["ic/h-agl-ft"] = _DROP_FT
    fdm["ic/vc-kts"] = 0.0
    fdm["ic/psi-true-deg"] = 0.0
    fdm["ic/lat-geod-deg"] = 45.0
    fdm["ic/long-gc-deg"] = 7.0
    fdm.run_ic()
    for name in ("fcs/left-brake-cmd-norm", "fcs/right-brake-cmd-norm", "fcs/center-brake-cmd-norm"):
        fdm[name] = 1.0
    while fdm.get_sim_time() < _SETTLE_S:
        fdm.run()
    t0 = float(fdm.get_sim_time())
    fdm["propulsion/magneto_cmd"] = 3  # both magnetos, then the starter until the engine runs: a cold start
    fdm["propulsion/starter_cmd"] = 1
    for i in range(engines):
        fdm[f"fcs/mixture-cmd-norm[{i}]"] = 1.0
        if f"fcs/advance-cmd-norm[{i}]" in catalog or (i == 0 and "fcs/advance-cmd-norm" in catalog):
            fdm[f"fcs/advance-cmd-norm[{i}]"] = 1.0  # a constant-speed propeller at its highest rpm
    dt = fdm.get_delta_t()
    control_every = max(1, round(0.05 / dt))  # the controller at 20 Hz
    control_dt = control_every * dt
    record_every = max(1, round(record_dt_s / dt))

    roll = _Pid(2.0, 0.2, -1.0, 1.0)
    pitch = _Pid(3.0, 1.5, -1.0, 1.0)
    target = _Pid(0.6, 0.08, math.radians(-12.0), math.radians(15.0))  # outer loop -> pitch (rad)
    mixture = 1.0
    rows: list[list[float]] = []
    step = 0
    airborne = False
    for leg in legs:
        leg_start = fdm.get_sim_time()
        while fdm.get_sim_time() - leg_start < leg.duration_s:
            if step % control_every == 0:
                if fdm["propulsion/starter_cmd"] and all(
                    fdm[f"propulsion/engine[{i}]/set-running"] for i in range(engines)
                ):
                    fdm["propulsion/starter_cmd"] = 0
                agl = fdm["position/h-agl-ft"] * _FT
                kts = fdm["velocities/vc-kts"]
                vs = -fdm["velocities/v-down-fps"] * _FT
                if leg.kind in ("climb", "descent") and (
                    (leg.kind == "climb" and agl >= leg.altitude_m) or (leg.kind == "descent" and agl <= leg.altitude_m)
                ):
                    break
                on_ground = leg.kind == "ground"
                brakes = 1.0 if on_ground else 0.0
                fdm["fcs/left-brake-cmd-norm"] = brakes
                fdm["fcs/right-brake-cmd-norm"] = brakes
                fdm["fcs/center-brake-cmd-norm"] = brakes
                throttle = leg.throttle
                if leg.kind == "cruise":  # sinking below the level at this power: the pilot adds some
                    throttle = min(1.0, max(throttle, throttle + 0.01 * (leg.altitude_m - 30.0 - agl)))
                for i in range(engines):
                    fdm[f"fcs/throttle-cmd-norm[{i}]"] = throttle
                # the pilot leans towards the leg's air-fuel ratio (as by EGT), the lever never below half
                # (an aircraft with automatic mixture control, the c172x, overrides the lever)
                if leg.afr is None:
                    mixture = 1.0
                else:
                    afr = fdm[f"{_ENGINE}/AFR"]
                    mixture = min(1.0, max(0.5, mixture + 0.005 * control_dt * (afr - leg.afr)))
                for i in range(engines):
                    fdm[f"fcs/mixture-cmd-norm[{i}]"] = mixture
                rolling = leg.kind == "ground" or (not airborne and kts < aircraft.rotate_kts)
                if not airborne:  # rudder and nose wheel hold the runway heading (north; + turns right)
                    psi = fdm["attitude/psi-rad"]
                    yaw = 1.5 * math.atan2(math.sin(psi), math.cos(psi)) + 1.0 * fdm["velocities/r-rad_sec"]
                    fdm["fcs/rudder-cmd-norm"] = fdm["fcs/steer-cmd-norm"] = max(-1.0, min(1.0, -yaw))
                    airborne = agl > 15.0
                    if airborne and "gear/gear-cmd-norm" in catalog:
                        fdm["gear/gear-cmd-norm"] = 0.0  # a retractable gear up after lift-off
                else:  # the ball centred
                    fdm["fcs/rudder-cmd-norm"] = max(-1.0, min(1.0, 2.0 * fdm["aero/beta-rad"]))
                if rolling:  # controls neutral until the rotation speed
                    roll.integral = pitch.integral = 0.0
                    target.integral = math.radians(6.0)
                    fdm["fcs/aileron-cmd-norm"] = fdm["fcs/elevator-cmd-norm"] = 0.0
                else:
                    # wings level; pitch for the leg's airspeed (climb, descent) or its altitude (cruise)
                    phi = fdm["attitude/phi-rad"]
                    fdm["fcs/aileron-cmd-norm"] = roll(-phi, fdm["velocities/p-rad_sec"], 0.3, control_dt)
                    if not airborne:
                        theta_cmd = math.radians(8.0)
                    elif leg.kind == "cruise" and kts > aircraft.glide_kts:  # slower: pitch for the glide speed
                        vs_cmd = max(-3.0, min(3.0, 0.05 * (leg.altitude_m - agl)))
                        theta_cmd = target(0.05 * (vs_cmd - vs), 0.0, 0.0, control_dt)
                    else:
                        speed = leg.speed_kts if leg.kind != "cruise" else aircraft.glide_kts + 2.0
                        theta_cmd = target(0.02 * (kts - speed), 0.0, 0.0, control_dt)
                        if leg.kind == "climb" and agl < 150.0:  # never nose down to gain speed near the ground
                            theta_cmd = max(theta_cmd, math.radians(5.0))
                    theta = fdm["attitude/theta-rad"]
                    q = fdm["velocities/q-rad_sec"]
                    fdm["fcs/elevator-cmd-norm"] = -pitch(theta_cmd - theta, q, 0.8, control_dt)
            if step % record_every == 0:
                rows.append([fdm[prop] for prop, _ in _CHANNELS.values()])
                if progress is not None:
                    progress(fdm.get_sim_time())
            fdm.run()
            step += 1
    return rows, t0


#: Canonical column -> the JSBSim property logged and its unit (:data:`ecu_monitor.units.UNITS`); time_s is the
#: simulation time from the start of the log, cht_c the probe's reading of cht_true_c.
_CHANNELS: dict[str, tuple[str, str]] = {
    "time_s": ("simulation/sim-time-sec", "s"),
    "throttle_pct": ("fcs/throttle-pos-norm", "ratio"),
    "rpm": (f"{_ENGINE}/engine-rpm", "rpm"),
    "altitude_m": ("atmosphere/pressure-altitude", "ft"),
    "airspeed_mps": ("velocities/vc-kts", "kt"),
    "oat_c": ("atmosphere/T-R", "degR"),
    "cht_true_c": (f"{_ENGINE}/cht-degF", "degF"),
    "fuel_flow_lph": (f"{_ENGINE}/fuel-flow-rate-gph", "gph"),
    "egt_c": (f"{_ENGINE}/egt-degF", "degF"),
    "oil_temp_c": (f"{_ENGINE}/oil-temperature-degF", "degF"),
    "manifold_pressure_kpa": (f"{_ENGINE}/map-inhg", "inHg"),
    "mixture_pct": ("fcs/mixture-pos-norm", "ratio"),
    "agl_m": ("position/h-agl-ft", "ft"),
}


def _log(rows: list[list[float]], t0: float, source: str) -> FlightLog:
    data = np.asarray(rows, dtype=float)
    columns = {name: UNITS[unit].to_canonical(data[:, i]) for i, (name, (_, unit)) in enumerate(_CHANNELS.items())}
    columns["time_s"] = np.round(columns["time_s"] - t0, 6)  # the step's binary fractions, not a clock
    columns["cht_c"] = np.round(columns["cht_true_c"])
    return FlightLog(columns, source=source)
