"""Replay of a flight that has no throttle (a light aircraft's engine monitor) on a fuel-flow model."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np

from ecu_monitor.flightlog import FlightLog, write_csv
from ecu_monitor.model import HeatMap, paper_table_a1, save_model


def test_replay_csv_without_throttle_on_a_fuel_flow_heat_map(tmp_path: Path):
    n = 900  # 15 min at 1 Hz
    t = np.arange(n, dtype=float)
    fuel = 1.0 + 0.5 * (t > 120)
    log = FlightLog(
        {
            "time_s": t,
            "rpm": np.where(t > 120, 6000.0, 3000.0),
            "fuel_flow_lph": fuel,
            "altitude_m": np.clip((t - 150) * 2.0, 0.0, 600.0),
            "airspeed_mps": np.where(t > 130, 23.0, 0.0),
            "oat_c": np.full(n, 15.0),
            "cht_c": np.round(60 + 40 * (1 - np.exp(-np.clip(t - 120, 0, None) / 80))),
        },
        source="no-throttle",
    )
    flight = tmp_path / "flight.csv"
    write_csv(log, flight)
    heat = HeatMap(
        "fuel_flow_lph", "rpm", (0.5, 1.0, 2.0), (2000.0, 5000.0, 9000.0), ((100.0,) * 3, (300.0,) * 3, (900.0,) * 3)
    )
    model = tmp_path / "model.yaml"
    save_model(paper_table_a1().replace(heat_map=heat), model)
    out = tmp_path / "health.csv"
    result = subprocess.run(
        [sys.executable, "-m", "ecu_monitor.cli", "replay", str(flight), "--model", str(model), "--out", str(out)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    with out.open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) > 8000  # one row per 100 ms
    assert {row["state"] for row in rows} <= {"NOMINAL", "SUSPECT", "DEGRADED"}  # never INPUT_STALE
    assert all("throttle" not in row["stale_inputs"] for row in rows[100:])
