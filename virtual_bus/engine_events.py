"""The virtual engine's exhaust-gas and oil temperatures, and engine events injected into a virtual flight
(docs/service.md, "Engine events"; scored by benchmarks/bench_events_virtual.py).

The truth plant flies the cylinders' heads (virtual_bus/plant.py); :func:`with_exhaust_and_oil` adds, simply,
what the engine events also read to the flown log:

* each cylinder's EGT: a first-order lag (EGT_LAG_S) of OAT + EGT_RISE_C + EGT_PER_PCT_C x throttle (%)
  plus the cylinder's own offset (drawn within +-EGT_SPREAD_C from the seed: the cylinders of one engine
  burn differently), probe noise (EGT_NOISE_C) and 1-degC steps; truth ``egtN_true_c``, measured ``egtN_c``;
* the oil: a first-order lag (OIL_LAG_S) of OAT + OIL_RISE_C x (1 + throttle / 100) / 2 (it warms with the
  power), noise and 1-degC steps; truth ``oil_true_c``, measured ``oil_temp_c``.

The injections (:class:`Injections`): an exhaust valve's EGT swinging (one cylinder's EGT plus a sine of the
given peak-to-peak amplitude and period from its onset to its end), an oil excursion (the oil's target up
to ``oil_to_c`` for a while: a blocked oil cooler), a CHT divergence (a
:class:`~virtual_bus.faults.Degradation` of one cylinder's gamma_Q, flown by the plant) and a power-off dive
(a segment of the mission: throttle closed at high speed). :func:`event_mission` draws a mission with all
four from a seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ecu_monitor.flightlog import FlightLog
from virtual_bus.faults import Degradation
from virtual_bus.missions import Atmosphere, Climb, Cruise, Descent, GroundRun, Landing, Mission, Takeoff, Variation

__all__ = ["EGT_LAG_S", "Injections", "event_mission", "with_exhaust_and_oil"]

#: The EGT model (module docstring): degC above OAT at zero throttle, degC per % throttle, the cylinders'
#: offsets' half range, degC, the probe's lag, s, its noise, degC (1 sigma).
EGT_RISE_C = 300.0
EGT_PER_PCT_C = 5.0
EGT_SPREAD_C = 20.0
EGT_LAG_S = 10.0
EGT_NOISE_C = 2.0
#: The oil model: its rise above OAT at full throttle, degC, its lag, s, its noise, degC.
OIL_RISE_C = 75.0
OIL_LAG_S = 120.0
OIL_NOISE_C = 0.3


@dataclass(frozen=True)
class Injections:
    """What is injected into one flight (times in s of flight time; cylinders 1-based; 0: none).

    valve_cylinder: the cylinder whose EGT swings, ``valve_pp_c`` peak to peak with ``valve_period_s``,
    from ``valve_start_s`` to ``valve_end_s``; oil_to_c: the oil's target, degC, from ``oil_start_s`` for
    ``oil_s`` (0: no excursion); divergence: the CHT divergence's degradation (None: none); dive: whether
    the mission has a power-off dive."""

    valve_cylinder: int = 0
    valve_pp_c: float = 0.0
    valve_period_s: float = 60.0
    valve_start_s: float = 0.0
    valve_end_s: float = 0.0
    oil_to_c: float = 0.0
    oil_start_s: float = 0.0
    oil_s: float = 0.0
    divergence: Degradation | None = None
    dive: bool = False


def _lag(target: np.ndarray, time_s: np.ndarray, tau_s: float, start: float) -> np.ndarray:
    """First-order lag of ``target`` with time constant ``tau_s`` (s), from ``start``."""
    out = np.empty_like(target)
    value = start
    dt = np.diff(time_s, prepend=time_s[0]).tolist()
    for k, (x, d) in enumerate(zip(target.tolist(), dt, strict=True)):
        value += (x - value) * min(d / tau_s, 1.0)
        out[k] = value
    return out


def with_exhaust_and_oil(log: FlightLog, cylinders: int, seed: int, injections: Injections = Injections()) -> FlightLog:
    """``log`` (a flight of the plant with ``cylinders`` heads) with each cylinder's EGT
    and the oil temperature, truth and measured (module docstring), and the ``injections``' valve swinging
    and oil excursion."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 29]))
    t = np.asarray(log.time_s, dtype=float)
    oat = np.asarray(log["oat_c"], dtype=float)
    throttle = np.clip(np.asarray(log["throttle_pct"], dtype=float), 0.0, 100.0)
    offsets = rng.uniform(-EGT_SPREAD_C, EGT_SPREAD_C, cylinders)
    columns: dict[str, np.ndarray] = {}
    target = oat + EGT_RISE_C + EGT_PER_PCT_C * throttle
    burning = _lag(target, t, EGT_LAG_S, float(target[0]))  # lit at once (a cold probe's reading below 0 degC
    # would not fit the ECU's EGT signal)
    for n in range(1, cylinders + 1):
        egt = burning + offsets[n - 1]
        if n == injections.valve_cylinder:
            swinging = (t >= injections.valve_start_s) & (t < injections.valve_end_s)
            phase = 2.0 * np.pi * (t - injections.valve_start_s) / injections.valve_period_s
            egt = egt + np.where(swinging, 0.5 * injections.valve_pp_c * np.sin(phase), 0.0)
        columns[f"egt{n}_true_c"] = egt
        columns[f"egt{n}_c"] = np.round(egt + rng.normal(0.0, EGT_NOISE_C, t.size))
    target = oat + OIL_RISE_C * (1.0 + throttle / 100.0) / 2.0
    excursion = (t >= injections.oil_start_s) & (t < injections.oil_start_s + injections.oil_s)
    if injections.oil_to_c > 0.0:
        target = np.where(excursion, injections.oil_to_c, target)
    oil = _lag(target, t, OIL_LAG_S, float(oat[0]))
    columns["oil_true_c"] = oil
    columns["oil_temp_c"] = np.round(oil + rng.normal(0.0, OIL_NOISE_C, t.size))
    return log.with_columns(**columns)


def event_mission(seed: int, cylinders: int) -> tuple[Mission, Injections]:
    """A mission of about 50 min with every event injected, drawn from ``seed``: climb, a steady cruise in
    which one cylinder's exhaust valve starts swinging, a cruise with throttle variations in which one
    cylinder's head starts running hot (gamma_Q up) and the oil cooler blocks for a while, a power-off dive
    at high speed, a short cruise, the descent and landing. The injections' times are set from the
    mission's planned timeline (the climb at its planned rate)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 2929]))
    field = float(rng.uniform(0.0, 800.0))
    cruise_alt = field + float(rng.uniform(1200.0, 2500.0))
    climb_rate = float(rng.uniform(2.5, 4.0))
    ground_s = float(rng.uniform(60.0, 180.0))
    steady_s = float(rng.uniform(900.0, 1100.0))
    varied_s = float(rng.uniform(700.0, 900.0))
    steady_from = ground_s + 30.0 + (cruise_alt - field) / climb_rate
    varied_from = steady_from + steady_s
    dive_speed = float(rng.uniform(40.0, 48.0))
    segments = (
        GroundRun(duration_s=ground_s, throttle_pct=float(rng.uniform(25.0, 35.0))),
        Takeoff(throttle_pct=float(rng.uniform(95.0, 100.0)), airspeed_mps=float(rng.uniform(18.0, 22.0))),
        Climb(
            target_altitude_m=cruise_alt,
            climb_rate_mps=climb_rate,
            throttle_pct=float(rng.uniform(85.0, 100.0)),
            airspeed_mps=float(rng.uniform(19.0, 22.0)),
        ),
        Cruise(
            duration_s=steady_s,
            airspeed_mps=float(rng.uniform(22.0, 27.0)),
            throttle_pct=float(rng.uniform(50.0, 65.0)),
            speed_variation=Variation(
                kind="sine", amplitude=float(rng.uniform(0.5, 2.0)), period_s=float(rng.uniform(60.0, 300.0))
            ),
        ),
        Cruise(
            duration_s=varied_s,
            airspeed_mps=float(rng.uniform(22.0, 27.0)),
            throttle_pct=float(rng.uniform(50.0, 65.0)),
            throttle_variation=Variation(
                kind="random", amplitude=float(rng.uniform(2.0, 5.0)), period_s=float(rng.uniform(60.0, 600.0))
            ),
        ),
        Descent(
            target_altitude_m=cruise_alt - 600.0,
            rate_mps=float(rng.uniform(7.0, 10.0)),
            throttle_pct=0.0,
            airspeed_mps=dive_speed,
        ),
        Cruise(duration_s=120.0, airspeed_mps=23.0, throttle_pct=50.0),
        Descent(target_altitude_m=field + 150.0, rate_mps=3.0, throttle_pct=20.0, airspeed_mps=24.0),
        Landing(idle_s=60.0),
    )
    mission = Mission(
        name=f"events-{seed}",
        description=f"engine events injected, seed {seed}",
        segments=segments,
        field_elevation_m=field,
        atmosphere=Atmosphere(oat_offset_c=float(rng.uniform(-10.0, 20.0))),
    )
    valve_start = steady_from + float(rng.uniform(60.0, 180.0))
    injections = Injections(
        valve_cylinder=int(rng.integers(1, cylinders + 1)),
        valve_pp_c=float(rng.uniform(25.0, 55.0)),  # 45-100 degF: a sticking exhaust valve's swing
        valve_period_s=float(rng.uniform(20.0, 120.0)),  # 0.5-3 cycles/min
        valve_start_s=valve_start,
        valve_end_s=steady_from + steady_s,
        oil_to_c=float(rng.uniform(128.0, 145.0)),  # 10-27 degC past the shipped 118 degC limit
        oil_start_s=varied_from + float(rng.uniform(60.0, 250.0)),
        oil_s=float(rng.uniform(240.0, 360.0)),
        divergence=Degradation(
            "gamma_q",
            float(rng.uniform(2.0, 2.5)),
            varied_from + float(rng.uniform(60.0, 300.0)),
            cylinder=int(rng.integers(1, cylinders + 1)),
        ),
        dive=True,
    )
    return mission, injections
