"""One CHT channel's detector calibrated on nominal flights: the procedure ``ecu-monitor calibrate`` runs on
each channel, and the fleet demo's commissioning of its engine type.

Two steps, so a caller can show what each found before the next: :func:`replay_and_choose` replays every
flight through the service (:func:`~ecu_monitor.offline.calibration_replays.flight_feeds`), takes the
nominal wear reference of the across-flight detector from them, and chooses the adaptive baseline by
cross-validation (:func:`~ecu_monitor.offline.calibration.choose_settings`, the flights replayed again with
overlays) unless the settings are given; :func:`calibrate_channel` then sets the threshold
(:func:`~ecu_monitor.offline.calibration.calibrate_flights`) and learns the engine's reference per operating
region (:func:`~ecu_monitor.offline.calibration_reference.calibrate_reference`). Nothing here prints: the
replays go through ``replay_map``, which may show progress or run them on a cluster.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from ecu_monitor.config import ServiceConfig
from ecu_monitor.errors import ParameterError
from ecu_monitor.estimation.wear import WearReference
from ecu_monitor.model import ThermalParams
from ecu_monitor.offline.calibration import (
    CalibrationResult,
    FlightFeeds,
    FlightStatistic,
    SettingsChoice,
    calibrate_flights,
    choose_settings,
    cross_validation_blocker,
    flight_feeds,
    wear_reference,
)
from ecu_monitor.offline.calibration_reference import ReferenceCalibration, calibrate_reference, with_reference

__all__ = [
    "DEFAULT_RATE_PER_100H",
    "ChannelCalibration",
    "ChannelFlights",
    "FlightPath",
    "ReplayMap",
    "calibrate_channel",
    "replay_and_choose",
    "replay_in_turn",
]

#: The false-alarm rate a detector is calibrated for unless asked otherwise, per 100 flight hours.
DEFAULT_RATE_PER_100H = 1.0

FlightPath = str | os.PathLike[str]
#: How the flights are replayed: ``replay_map(replay, flights, what)`` -> ``replay(flight)`` for each flight, in
#: order; ``what`` names the pass for a progress display ("flights": nominal, "overlays": with the overlays).
ReplayMap = Callable[[Callable[[FlightPath], FlightFeeds], Sequence[FlightPath], str], list[FlightFeeds]]


def replay_in_turn(
    replay: Callable[[FlightPath], FlightFeeds], flights: Sequence[FlightPath], what: str
) -> list[FlightFeeds]:
    """Each flight replayed in turn in this process (a :data:`ReplayMap` with no display)."""
    return [replay(flight) for flight in flights]


@dataclass(frozen=True)
class ChannelFlights:
    """The nominal flights replayed and the detector's settings chosen: each flight's feeds (overlays included
    when the settings were cross-validated), the choice, each flight's statistic with the chosen settings,
    each flight's wear index (None: too few samples) and their wear reference (None: fewer than 3)."""

    feeds: tuple[FlightFeeds, ...]
    choice: SettingsChoice
    statistics: tuple[FlightStatistic, ...]
    wear_indices: tuple[float | None, ...]
    wear: WearReference | None


@dataclass(frozen=True)
class ChannelCalibration:
    """The threshold calibrated, its settings carrying the engine's reference (``result.current``), the
    reference learned (None: none could be, ``no_reference`` says why; the detector then tests against its
    in-flight baseline only)."""

    result: CalibrationResult
    reference: ReferenceCalibration | None
    no_reference: str = ""


def replay_and_choose(
    flights: Sequence[FlightPath],
    config: ServiceConfig,
    params: ThermalParams,
    rate_per_100h: float,
    candidates: Sequence[float],
    *,
    given: SettingsChoice | None = None,
    cylinder: int | None = None,
    replay_map: ReplayMap = replay_in_turn,
) -> ChannelFlights:
    """Replay the nominal ``flights`` with ``config`` and ``params``, take their wear reference, and choose the
    adaptive baseline among the lengths ``candidates`` (s) for ``rate_per_100h`` false alarms per 100 flight
    hours; ``given``: settings chosen by the caller instead (no cross-validation, no overlays replayed).
    ``cylinder``: the flights' ``cht<cylinder>_c`` is the channel (``config`` maps it as ``cht_c``)."""
    nominal = functools.partial(flight_feeds, config=config, params=params, overlays=False, cylinder=cylinder,
                                keep_reference=True)  # fmt: skip
    feeds = replay_map(nominal, flights, "flights")
    indices, wear = wear_reference(feeds, config.wear)
    feeds = [dataclasses.replace(f, reference=()) for f in feeds]  # the per-step reference is not needed further
    if given is None:
        if cross_validation_blocker(feeds, config.detector) is None:  # replay again with the overlays
            with_overlays = functools.partial(flight_feeds, config=config, params=params, cylinder=cylinder)
            feeds = replay_map(with_overlays, flights, "overlays")
        choice = choose_settings(feeds, config.detector, rate_per_100h, candidates)
    else:
        choice = given
    statistics = tuple(f.statistic_for(choice.settings) for f in feeds)
    return ChannelFlights(tuple(feeds), choice, statistics, tuple(indices), wear)


def calibrate_channel(flights: ChannelFlights, rate_per_100h: float) -> ChannelCalibration:
    """The threshold for ``rate_per_100h`` false alarms per 100 flight hours on the flights' statistics, and the
    engine's reference learned on their feeds (never the config's, which is another engine's: the shipped one
    is the virtual ECU's). ParameterError (one line) when the flights give too few whole hours."""
    settings = flights.choice.settings
    result = calibrate_flights(flights.statistics, rate_per_100h, settings, flights.choice)
    try:
        reference = calibrate_reference(flights.feeds, settings, rate_per_100h)
    except ParameterError as exc:
        without = dataclasses.replace(result, current=with_reference(result.current, (), (), 0.0))
        return ChannelCalibration(without, None, str(exc))
    return ChannelCalibration(dataclasses.replace(result, current=reference.settings(result.current)), reference)
