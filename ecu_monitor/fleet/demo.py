"""A virtual fleet from nothing: ``ecu-monitor fleet demo DIR``.

``engines`` engines of one type (the paper's model, ``paper_table_a1``), ``flights`` flights shared among
them, each a short random mission of the virtual ECU (virtual_bus/campaign.py: its own seed, a day apart on
the log's clock; a climb of 300-900 m above the field, 15-25 minutes flown; CSVs at 1 Hz as an engine monitor
records them); ``degrading`` of the engines wear slowly from engine start, each at its own rate (gamma_Q
grows by the rate each flight: the campaign's WearSchedule), the others stay nominal. The engine type's
nominal wear reference is what ``ecu-monitor calibrate`` stores: the wear index over ``reference_flights``
nominal flights of the type (a sister engine's, flown apart), written as the engines' detector file. Every
flight's truth plant carries unmodelled effects of residual size drawn from its seed (the detection
campaigns' ``research.evaluation.residual_effects``): the model is never the truth.

Writes DIR/FLEET.yaml, DIR/detector.yaml, DIR/logs/SERIAL/flight_NNN.EXT, DIR/reference/, and
DIR/truth.json (which engines degrade, at which rate: what the ranking must find). Flights are recorded as
Dask tasks on the same cluster the fleet then runs on.
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
    reference_flights: int = 10,
    duration_s: float = 600.0,
    log_format: str = "csv",
    seed: int = 0,
    say: Callable[[str], None] = print,
) -> VirtualFleet:
    """Make the virtual fleet in ``out_dir`` (module docstring) on the Dask ``client``."""
    from dask.distributed import as_completed

    from ecu_monitor.estimation.wear import reference_from_flights
    from ecu_monitor.fleet.spec import EngineSettings, LogJob
    from ecu_monitor.fleet.summary import summarise_log
    from ecu_monitor.offline.calibration import wear_fragment
    from ecu_monitor.shipped import DEFAULT_CONFIG
    from virtual_bus.campaign import WearSchedule, campaign_flights

    root = Path(out_dir)
    if engines < 1 or flights < engines:
        raise ConfigError(f"--engines {engines}, --flights {flights}: expected at least one flight per engine")
    if len(rates) > engines:
        raise ConfigError(f"--degrading: {len(rates)} degrading engines in a fleet of {engines}")
    if log_format not in ("csv", "blf", "asc"):
        raise ConfigError(f"--format {log_format}: expected csv, blf or asc")
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
                                           duration_s=duration_s, climb_m=SHORT_CLIMB_M)]  # fmt: skip
    for path, _ in [*work, *reference]:
        path.parent.mkdir(parents=True, exist_ok=True)
    say(f"fleet demo: flying {len(work)} flights of {engines} engines and {len(reference)} reference flights"
        f" (short random missions, 15-25 min)")  # fmt: skip
    futures = [client.submit(_record, path, flight, pure=False) for path, flight in [*reference, *work]]
    for done, _ in enumerate(as_completed(futures), start=1):
        if done % 10 == 0 or done == len(futures):
            say(f"fleet demo: {done}/{len(futures)} flights recorded")
    # the type's nominal wear reference, as calibrate stores it: the wear index of each reference flight
    type_engine = EngineSettings("reference", Path(DEFAULT_CONFIG), None, None, None, None, None, 0.0)
    jobs = [LogJob("reference", path, path.name, n, f"ref{n}") for n, (path, _) in enumerate(reference)]
    summaries = client.gather([client.submit(summarise_log, job, type_engine, pure=False) for job in jobs])
    indices = [s.flights[0]["wear_index"] for s in summaries]
    wear = reference_from_flights(indices)
    if wear is None:
        raise ConfigError(f"{root}: fewer than 3 reference flights with a wear index: give more --reference-flights")
    header = (f"# the engine type's nominal wear index over {wear.flights} nominal flights (reference/):"
              " the across-flight detector's reference, as ecu-monitor calibrate stores it\n")  # fmt: skip
    (root / "detector.yaml").write_text(header + yaml.safe_dump(wear_fragment(wear), sort_keys=False))
    fleet = {
        "defaults": {"config": "example.yaml", "detector": "detector.yaml", "tbo_hours": 2000},
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
