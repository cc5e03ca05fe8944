"""Random missions for campaigns and tests: a varied, deterministic mission drawn from a seed."""

from __future__ import annotations

import math

import numpy as np

from virtual_bus.missions import (
    AltitudeChange,
    Atmosphere,
    Climb,
    Cruise,
    Descent,
    GroundRun,
    Landing,
    Mission,
    Segment,
    StepClimb,
    Takeoff,
    Variation,
)

__all__ = ["random_mission"]


def random_mission(seed: int, duration_s: float = 3600.0, *, climb_m: tuple[float, float] | None = None) -> Mission:
    """A varied mission of about ``duration_s`` seconds drawn from ``seed`` (deterministic).

    Ground run, take-off, a (step-)climb to 600-3800 m, cruise legs with random throttle/speed
    variations and altitude changes, a descent and a landing; day offset -15..+20 degC, field
    elevation 0-1200 m. The flown duration differs from ``duration_s`` by the step-climb plateaus.
    ``climb_m`` (low, high): climb this far above the field instead (short flights: (300, 900) m with
    ``duration_s`` 600 flies 10-20 minutes); the other draws are those of the same seed without it.
    """
    if not math.isfinite(duration_s) or duration_s < 600.0:
        raise ValueError(f"duration_s: expected at least 600 s, got {duration_s!r}")
    rng = np.random.default_rng(seed)
    field = float(rng.uniform(0.0, 1200.0))
    low, high = (600.0, 3800.0 - min(field, 600.0)) if climb_m is None else climb_m
    cruise_alt = float(field + rng.uniform(low, high))
    climb_rate = float(rng.uniform(2.0, 4.0))
    descent_rate = float(rng.uniform(2.5, 5.0))
    ground_s = float(rng.uniform(60.0, 300.0))
    climb_s = (cruise_alt - field) / climb_rate
    descent_s = (cruise_alt - field - 150.0) / descent_rate
    fixed = ground_s + 30.0 + climb_s + descent_s + 120.0
    cruise_total = max(120.0, duration_s - fixed)
    legs = int(rng.integers(1, 4))
    leg_s = cruise_total / legs
    segments: list[Segment] = [
        GroundRun(duration_s=ground_s, throttle_pct=float(rng.uniform(20.0, 40.0))),
        Takeoff(throttle_pct=float(rng.uniform(90.0, 100.0)), airspeed_mps=float(rng.uniform(18.0, 22.0))),
        Climb(
            target_altitude_m=cruise_alt,
            climb_rate_mps=climb_rate,
            throttle_pct=float(rng.uniform(80.0, 100.0)),
            airspeed_mps=float(rng.uniform(18.0, 22.0)),
            step_climb=StepClimb(
                cht_margin_c=float(rng.uniform(10.0, 18.0)),
                hysteresis_c=float(rng.uniform(8.0, 20.0)),
                min_level_s=float(rng.uniform(30.0, 150.0)),
            )
            if rng.random() < 0.7
            else None,
        ),
    ]
    altitude = cruise_alt
    for _ in range(legs):
        changes: list[AltitudeChange] = []
        if rng.random() < 0.6:
            new_alt = float(np.clip(altitude + rng.uniform(-800.0, 600.0), field + 300.0, 4000.0))
            changes.append(AltitudeChange(float(rng.uniform(0.2, 0.6) * leg_s), new_alt, float(rng.uniform(1.0, 3.0))))
            altitude = new_alt
        segments.append(
            Cruise(
                duration_s=leg_s,
                airspeed_mps=float(rng.uniform(20.0, 28.0)),
                throttle_pct=float(rng.uniform(40.0, 65.0)),
                throttle_variation=Variation(
                    kind=str(rng.choice(["sine", "random"])),
                    amplitude=float(rng.uniform(2.0, 10.0)),
                    period_s=float(rng.uniform(60.0, 600.0)),
                ),
                speed_variation=Variation(
                    kind=str(rng.choice(["sine", "random"])),
                    amplitude=float(rng.uniform(0.5, 3.0)),
                    period_s=float(rng.uniform(30.0, 300.0)),
                ),
                altitude_changes=tuple(changes),
            )
        )
    segments.append(
        Descent(
            target_altitude_m=field + 150.0,
            rate_mps=descent_rate,
            throttle_pct=float(rng.uniform(12.0, 30.0)),
            airspeed_mps=float(rng.uniform(22.0, 28.0)),
        )
    )
    segments.append(Landing(idle_s=float(rng.uniform(30.0, 120.0))))
    return Mission(
        name=f"random-{seed}",
        description=f"random mission from seed {seed}, about {duration_s:.0f} s",
        segments=tuple(segments),
        field_elevation_m=field,
        atmosphere=Atmosphere(oat_offset_c=float(rng.uniform(-15.0, 20.0))),
    )
