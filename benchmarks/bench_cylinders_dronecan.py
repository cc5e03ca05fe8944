"""bench_cylinders.py over DroneCAN: the issue 14 cylinder targets with the engine on a DroneCAN bus.

    nice -n 10 .venv/bin/python benchmarks/bench_cylinders_dronecan.py [--flights 8] [--hours 1]
                                                                       [--models truth|identified]

The flights, degradations and figures of benchmarks/bench_cylinders.py (its ``main``, unchanged), with
two differences: the virtual ECU records DroneCAN (``record(..., protocol="dronecan")``: the ICE status
with one CylinderStatus per cylinder from node 20, the air data from node 21), and the replay reads
them through the shipped dronecan.yaml with ``cht1_c .. cht4_c`` mapped to
``cylinder_status[0..3].cylinder_head_temperature`` and four_cylinders.yaml's ``cylinders`` and
``health`` sections (instead of four_cylinders.yaml's DBC). The recordings go to their own folder
(``.../cylinders-dronecan``), so the DBC flights of bench_cylinders.py are not reused. Same seeds, so
each row compares with the same row of bench_cylinders.py (docs/results/cylinders.md).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import bench_cylinders  # this folder's module (run as a script)
import yaml

from ecu_monitor.runtime import config as service_config
from ecu_monitor.shipped import shipped_file

_FIELD = "uavcan.equipment.ice.reciprocating.Status.cylinder_status[{}].cylinder_head_temperature"


def dronecan_four_cylinders() -> Any:
    """The shipped dronecan.yaml with four cylinder inputs and four_cylinders.yaml's cylinders and health."""
    shipped = shipped_file("config", "dronecan.yaml")
    four = shipped_file("config", "four_cylinders.yaml")
    assert shipped is not None and four is not None
    data = yaml.safe_load(shipped.read_text(encoding="utf-8"))
    four_data = yaml.safe_load(four.read_text(encoding="utf-8"))
    inputs = {name: spec for name, spec in data["inputs"].items() if not name.startswith("cht")}
    for n in range(1, bench_cylinders.CYLINDERS + 1):
        inputs[f"cht{n}_c"] = {"field": _FIELD.format(n - 1), "unit": "K", "stale_after_s": 1.0}
    data["inputs"] = inputs
    data["cylinders"] = four_data["cylinders"]
    data["health"] = four_data["health"]
    return service_config.parse_config(data, shipped.with_name("dronecan_four_cylinders.yaml"))


def main() -> None:
    record_dbc = bench_cylinders._record
    where = bench_cylinders.bench_dir()

    def record_dronecan(
        path: Path, seed: int, hours: float, models: tuple, degradation: list, protocol: str = "dronecan"
    ) -> None:
        from ecu_monitor.model import paper_table_a1
        from virtual_bus.random_missions import random_mission
        from virtual_bus.recorder import record

        if path.with_suffix(".csv").exists():
            return
        path.parent.mkdir(parents=True, exist_ok=True)
        record(random_mission(seed, duration_s=hours * 3600.0), [path.with_suffix(".blf"), path.with_suffix(".csv")],
               paper_table_a1(), degradation=degradation, seed=seed, cylinders=models, protocol="dronecan")  # fmt: skip

    load_config = service_config.load_config
    bench_cylinders._record = record_dronecan
    bench_cylinders.bench_dir = lambda: where.with_name(where.name + "-dronecan")
    service_config.load_config = lambda path: (
        dronecan_four_cylinders() if path == "four_cylinders.yaml" else load_config(path)
    )
    try:
        bench_cylinders.main()
    finally:
        bench_cylinders._record = record_dbc
        service_config.load_config = load_config


if __name__ == "__main__":
    main()
