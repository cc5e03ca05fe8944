"""replay --history: a log's flights recorded in a flight history as the daemon would, with its wear index."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ecu_monitor.cli import main
from ecu_monitor.runtime.persistence import StateStore


def _flight_csv(path: Path, seconds: float = 180.0) -> None:
    t = np.arange(0.0, seconds, 0.1)
    cht = 80.0 + 70.0 * (1.0 - np.exp(-t / 120.0))
    rows = ["time_s,throttle_pct,rpm,altitude_m,airspeed_mps,oat_c,cht_c"]
    rows += [f"{x:.1f},70,5500,300,25,15,{round(c)}" for x, c in zip(t, cht, strict=True)]
    path.write_text("\n".join(rows) + "\n")


def test_replay_into_a_history_records_the_flight(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "flight.csv"
    _flight_csv(log)
    state = tmp_path / "state"
    code = main(["replay", str(log), "--history", str(state), "--out", str(tmp_path / "health.csv")])
    out = capsys.readouterr().out
    assert code == 0 and f"history {state}" in out and "flights recorded: 1" in out
    with StateStore(state, readonly=True) as store:
        (flight,) = store.flights()
    assert flight.status == "finished" and flight.duration_s > 150.0
    assert flight.wear_index is not None and flight.wear_samples >= 60
    phase_s = sum(p["seconds"] for p in flight.phases.values())
    assert phase_s == pytest.approx(flight.duration_s, abs=1.0)
    assert (tmp_path / "health.csv").stat().st_size > 0
