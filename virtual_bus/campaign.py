"""A campaign: many flights of one engine, each a random mission, with a per-flight degradation schedule.

``WearSchedule`` says how a degradation factor grows from flight to flight (``gamma_q+0.005``: gamma_Q is
1.0 on the first flight, 1.005 on the second, ...), present from engine start in each flight: slow wear
(a fouling fin, a cowling seal that gives) as the across-flight detector must see it. Flight ``i`` flies
:func:`~virtual_bus.random_missions.random_mission` of its own seed and starts ``every_s`` after the
previous one on the log's clock (UNIX time), so a history of the campaign reads as days of operation.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass

from ecu_monitor.errors import ConfigError
from virtual_bus.faults import DEGRADATION_FACTORS, Degradation
from virtual_bus.missions import Mission
from virtual_bus.random_missions import random_mission

__all__ = ["CampaignFlight", "WearSchedule", "campaign_flights"]

_SCHEDULE_RE = re.compile(r"^(?P<factor>gamma_[qd])\+(?P<step>[0-9.eE+-]+)$")


@dataclass(frozen=True)
class WearSchedule:
    """``factor`` (gamma_q or gamma_d) = 1 + ``step`` x (flight number - 1), from engine start of each flight."""

    factor: str = "gamma_q"
    step: float = 0.0

    def __post_init__(self) -> None:
        if self.factor not in DEGRADATION_FACTORS:
            raise ConfigError(f"--wear: expected gamma_q or gamma_d, got {self.factor!r}")
        if not math.isfinite(self.step) or not -0.1 <= self.step <= 0.1:
            raise ConfigError(f"--wear: expected a step per flight in [-0.1, 0.1], got {self.step!r}")

    @classmethod
    def parse(cls, text: str) -> WearSchedule:
        """``gamma_q+0.005`` (gamma_Q grows 0.005 a flight); ConfigError on bad syntax."""
        match = _SCHEDULE_RE.match(text.strip())
        if match is None:
            raise ConfigError(f"--wear {text!r}: expected gamma_q|gamma_d+STEP, e.g. gamma_q+0.005")
        try:
            step = float(match["step"])
        except ValueError:
            raise ConfigError(f"--wear {text!r}: STEP is not a number") from None
        return cls(match["factor"], step)

    def value(self, number: int) -> float:
        """The factor on flight ``number`` (1-based)."""
        return 1.0 + self.step * (number - 1)

    def degradation(self, number: int) -> tuple[Degradation, ...]:
        """The degradation of flight ``number``: none while the factor is 1."""
        value = self.value(number)
        return () if value == 1.0 else (Degradation(self.factor, value, 0.0),)


@dataclass(frozen=True)
class CampaignFlight:
    """One flight of a campaign: its number (1-based), mission, seed, degradation and start time (UNIX s)."""

    number: int
    mission: Mission
    seed: int
    degradation: tuple[Degradation, ...]
    start_time_s: float


def campaign_flights(
    flights: int,
    schedule: WearSchedule,
    *,
    seed: int = 0,
    duration_s: float = 3600.0,
    start_time_s: float = 1.7e9,
    every_s: float = 86400.0,
    climb_m: tuple[float, float] | None = None,
) -> Iterator[CampaignFlight]:
    """The campaign's flights in order (module docstring); each mission drawn from its own seed
    (``climb_m``: as :func:`~virtual_bus.random_missions.random_mission`'s, for short flights)."""
    if flights < 1:
        raise ConfigError(f"--flights: expected at least 1, got {flights!r}")
    for number in range(1, flights + 1):
        flight_seed = seed * 100_003 + number
        yield CampaignFlight(
            number,
            random_mission(flight_seed, duration_s, climb_m=climb_m),
            flight_seed,
            schedule.degradation(number),
            start_time_s + (number - 1) * every_s,
        )
