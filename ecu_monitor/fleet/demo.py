"""A virtual fleet from nothing: ``ecu-monitor fleet demo DIR``.

``engines`` engines of one type (the paper's model, ``paper_table_a1``), ``flights`` flights shared among
them, each a short random mission of the virtual ECU (virtual_bus/campaign.py: its own seed, a day apart on
the log's clock; a climb of 300-900 m above the field, 15-25 minutes flown; CSVs at 1 Hz as an engine monitor
records them); ``degrading`` of the engines wear slowly from engine start, each at its own rate (gamma_Q
grows by the rate each flight: the campaign's WearSchedule), the others stay nominal. Every flight's truth
plant carries unmodelled effects of residual size drawn from its seed (the detection campaigns'
``research.evaluation.residual_effects``): the model is never the truth.

The engine type is commissioned as a user commissions a real one (docs/commissioning.md): ``reference_flights``
nominal flights of a sister engine, flown apart (hour-long campaign missions, ``reference_duration_s``, with
residual effects of the same kind), and the detector calibrated on them by the procedure ``ecu-monitor
calibrate`` runs (offline/calibration_channel.py, the service config the fleet replays with): the per-flight
detector's baseline, threshold and engine reference, and the across-flight detector's nominal wear reference,
written as DIR/detector.yaml in the form ``ecu-monitor calibrate --out`` writes.

Writes DIR/FLEET.yaml, DIR/detector.yaml, DIR/logs/SERIAL/flight_NNN.EXT, DIR/reference/ (the sister engine's
flights), and DIR/truth.json (which engines degrade, at which rate: what the ranking must find). Flights are
recorded, and the reference flights replayed for the calibration, as Dask tasks on the same cluster the fleet
then runs on.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ecu_monitor.errors import ConfigError

__all__ = ["DEFAULT_RATES", "VirtualFleet", "make_virtual_fleet"]

#: gamma_Q growth per flight of the degrading engines (the first of them the fastest).
DEFAULT_RATES = (0.03, 0.02, 0.015)
#: Climb above the field of the short random missions, m (virtual_bus/random_missions.py).
SHORT_CLIMB_M = (300.0, 900.0)
#: Sample period of the CSVs, s (CAN logs carry every frame at its DBC rate).
_RECORD_DT_S = 1.0
#: The virtual engines' serials: VF-001, VF-002, ...
_SERIAL = "VF-{:03d}"
#: The service config the fleet is replayed with and its detector calibrated for (a shipped name).
_CONFIG = "example.yaml"
#: Dask priority of the reference flights' recordings and replays: ahead of the fleet's recordings.
_CALIBRATION_PRIORITY = 1


@dataclass(frozen=True)
class VirtualFleet:
    """The fleet made: its FLEET.yaml, the serials of the degrading engines and their rates."""

    fleet_file: Path
    degrading: dict[str, float]
    flights: int


def _record(path: Path, flight: Any) -> str:
    """Fly one campaign flight of the virtual ECU into ``path`` (a Dask task)."""
    from ecu_monitor.model import paper_table_a1
    from ecu_monitor.research.evaluation import residual_effects
    from virtual_bus.recorder import record

    effects = residual_effects(flight.seed)
    record(flight.mission, [path], paper_table_a1(), effects=effects, degradation=flight.degradation,
           seed=flight.seed, start_time_s=flight.start_time_s, record_dt_s=_RECORD_DT_S)  # fmt: skip
    return str(path)


def make_virtual_fleet(
    out_dir: str | os.PathLike[str],
    client: Any,
    *,
    engines: int = 20,
    flights: int = 200,
    rates: Sequence[float] = DEFAULT_RATES,
    reference_flights: int = 8,
    reference_duration_s: float = 4500.0,
    duration_s: float = 600.0,
    log_format: str = "csv",
    seed: int = 0,
    say: Callable[[str], None] = print,
) -> VirtualFleet:
    """Make the virtual fleet in ``out_dir`` (module docstring) on the Dask ``client``; ``duration_s`` and
    ``reference_duration_s``: the missions' length as the campaign draws them, s."""
    from dask.distributed import as_completed

    from ecu_monitor.offline.calibration_reference import MIN_REFERENCE_FLIGHTS
    from virtual_bus.campaign import WearSchedule, campaign_flights

    root = Path(out_dir)
    if engines < 1 or flights < engines:
        raise ConfigError(f"--engines {engines}, --flights {flights}: expected at least one flight per engine")
    if len(rates) > engines:
        raise ConfigError(f"--degrading: {len(rates)} degrading engines in a fleet of {engines}")
    if log_format not in ("csv", "blf", "asc"):
        raise ConfigError(f"--format {log_format}: expected csv, blf or asc")
    if reference_flights < MIN_REFERENCE_FLIGHTS:
        raise ConfigError(f"reference flights {reference_flights}: the detector's calibration needs at least"
                          f" {MIN_REFERENCE_FLIGHTS}")  # fmt: skip
    if (root / "FLEET.yaml").exists():
        raise ConfigError(f"{root}: already holds a FLEET.yaml: give a new folder")
    rng = np.random.default_rng(seed)
    chosen = sorted(rng.choice(engines, size=len(rates), replace=False).tolist())  # not the first ones by design
    degrading = {_SERIAL.format(i + 1): float(rate) for i, rate in zip(chosen, rates, strict=True)}
    per_engine = [flights // engines + (1 if i < flights % engines else 0) for i in range(engines)]
    work: list[tuple[Path, Any]] = []
    for i, count in enumerate(per_engine):
        serial = _SERIAL.format(i + 1)
        schedule = WearSchedule("gamma_q", degrading.get(serial, 0.0))
        flown = campaign_flights(
            count, schedule, seed=seed * 1000 + i + 1, duration_s=duration_s, climb_m=SHORT_CLIMB_M
        )
        for flight in flown:
            work.append((root / "logs" / serial / f"flight_{flight.number:03d}.{log_format}", flight))
    reference = [(root / "reference" / f"flight_{f.number:03d}.{log_format}", f)
                 for f in campaign_flights(reference_flights, WearSchedule(), seed=seed * 1000 + 999,
                                           duration_s=reference_duration_s)]  # fmt: skip
    for path, _ in [*work, *reference]:
        path.parent.mkdir(parents=True, exist_ok=True)
    say(f"fleet demo: flying {len(reference)} reference flights of a sister engine (hour-long missions, to"
        f" calibrate the detector on) and {len(work)} flights of {engines} engines (short random missions,"
        " 15-25 min)")  # fmt: skip
    # the reference flights first: the calibration replays them while the fleet's flights are still recorded
    first = [client.submit(_record, path, flight, pure=False, priority=_CALIBRATION_PRIORITY)
             for path, flight in reference]  # fmt: skip
    rest = [client.submit(_record, path, flight, pure=False) for path, flight in work]
    for done, _ in enumerate(as_completed(first), start=1):
        say(f"fleet demo: {done}/{len(first)} reference flights recorded")
    _commission(root, [path for path, _ in reference], client, say)
    for done, _ in enumerate(as_completed(rest), start=1):
        if done % 10 == 0 or done == len(rest):
            say(f"fleet demo: {done}/{len(rest)} flights recorded")
    fleet = {
        "defaults": {"config": _CONFIG, "detector": "detector.yaml", "tbo_hours": 2000},
        "engines": [{"serial": _SERIAL.format(i + 1), "logs": [f"logs/{_SERIAL.format(i + 1)}/*.{log_format}"],
                     "overhaul_hours": float(round(rng.uniform(0.0, 1500.0)))} for i in range(engines)],
    }  # fmt: skip
    fleet_file = root / "FLEET.yaml"
    fleet_file.write_text(
        "# a virtual fleet (ecu-monitor fleet demo): run it with ecu-monitor fleet run FLEET.yaml --out out\n"
        + yaml.safe_dump(fleet, sort_keys=False)
    )
    (root / "truth.json").write_text(json.dumps({"degrading": degrading, "rates": "gamma_Q growth per flight"}))
    return VirtualFleet(fleet_file, degrading, len(work))


def _commission(root: Path, flights: Sequence[Path], client: Any, say: Callable[[str], None]) -> None:
    """The engine type's detector calibrated on the reference ``flights`` as ``ecu-monitor calibrate`` does (its
    replays as Dask tasks on ``client``), written as ``root``/detector.yaml."""
    from ecu_monitor.config import load_config
    from ecu_monitor.offline.calibration import BASELINE_CANDIDATES_S, detector_fragment_yaml, model_fingerprint
    from ecu_monitor.offline.calibration_channel import DEFAULT_RATE_PER_100H, calibrate_channel, replay_and_choose
    from ecu_monitor.shipped import resolve_file

    config = load_config(resolve_file(_CONFIG, "config", root.resolve()))  # as FLEET.yaml names it
    params = config.load_params()
    say(f"fleet demo: calibrating the detector on the {len(flights)} reference flights (as ecu-monitor calibrate)")
    replayed = replay_and_choose(flights, config, params, DEFAULT_RATE_PER_100H, BASELINE_CANDIDATES_S,
                                 replay_map=_replay_on_cluster(client, say))  # fmt: skip
    calibrated = calibrate_channel(replayed, DEFAULT_RATE_PER_100H)
    if replayed.wear is None:
        raise ConfigError(f"{root}: fewer than 3 reference flights with a wear index: give more reference flights")
    sources = [str(path.relative_to(root)) for path in flights]
    text = detector_fragment_yaml(calibrated.result, config.detector_symptom, DEFAULT_RATE_PER_100H, sources,
                                  model_fingerprint(params), wear=replayed.wear)  # fmt: skip
    (root / "detector.yaml").write_text(text)
    settings = calibrated.result.current
    reference = (f"engine reference test h {settings.nominal_threshold:g}" if calibrated.reference is not None
                 else f"no engine reference ({calibrated.no_reference})")  # fmt: skip
    say(f"fleet demo: detector calibrated on {calibrated.result.hours:.1f} flight hours: baseline"
        f" {settings.baseline_s:g} s, threshold h {calibrated.result.calibration.threshold:.3f}, {reference};"
        f" wear reference {100.0 * replayed.wear.mean:+.1f} % (sd {100.0 * replayed.wear.sd:.1f} %)"
        f" -> {root / 'detector.yaml'}")  # fmt: skip


def _replay_on_cluster(client: Any, say: Callable[[str], None]) -> Callable[..., list[Any]]:
    """A calibration ReplayMap: each flight's replay one Dask task on ``client``, ahead of the queued recordings;
    says each one done."""
    from dask.distributed import as_completed

    passes = {"flights": "replayed", "overlays": "replayed with the degradations overlaid"}

    def replay_map(replay: Callable[[Any], Any], flights: Sequence[Any], what: str) -> list[Any]:
        futures = client.map(replay, flights, pure=False, priority=_CALIBRATION_PRIORITY)
        for done, _ in enumerate(as_completed(futures), start=1):
            say(f"fleet demo: calibration: {done}/{len(futures)} reference flights {passes.get(what, what)}")
        return list(client.gather(futures))

    return replay_map
