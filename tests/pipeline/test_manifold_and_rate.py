"""The two changes that prove the tables: manifold pressure as a model input (a heat-map axis read from a
DBC signal, a DroneCAN field and the flight CSV) and the CHT rate of change as a health output."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from ecu_monitor.bus.codec import Encoder
from ecu_monitor.config import load_config
from ecu_monitor.errors import ConfigError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.inputs import INPUT_NAMES, stale_bit
from ecu_monitor.model import HeatMap, paper_table_a1
from ecu_monitor.offline.replay import frames_from_flight, replay_frames, replay_live
from ecu_monitor.runtime.publishers import LiveMonitor
from ecu_monitor.shipped import shipped_file


def _flight(n: int = 1500, map_until_s: float = np.inf) -> FlightLog:
    """A 1 Hz flight of an engine set by manifold pressure: MAP steps up at 200 s, the CHT follows."""
    t = np.arange(n, dtype=float)
    manifold = np.where(t > 200, 85.0, 45.0)
    return FlightLog(
        {
            "time_s": t,
            "rpm": np.where(t > 200, 2500.0, 1200.0),
            "throttle_pct": np.where(t > 200, 80.0, 20.0),
            "fuel_flow_lph": np.where(t > 200, 40.0, 10.0),
            "manifold_pressure_kpa": np.where(t <= map_until_s, manifold, np.nan),
            "altitude_m": np.clip((t - 250) * 3.0, 0.0, 1500.0),
            "airspeed_mps": np.where(t > 220, 50.0, 0.0),
            "oat_c": np.full(n, 15.0),
            "cht_c": np.round(90 + 80 * (1 - np.exp(-np.clip(t - 200, 0, None) / 120))),
        },
        source="manifold",
    )


def _model() -> object:
    heat = HeatMap(
        "manifold_pressure_kpa", "rpm", (30.0, 60.0, 100.0), (1000.0, 2000.0, 2800.0),
        ((300.0, 500.0, 700.0), (600.0, 1000.0, 1400.0), (900.0, 1500.0, 2100.0)),
    )  # fmt: skip
    return paper_table_a1().replace(heat_map=heat, cht_limit_c=260.0)


def test_manifold_pressure_is_an_input_with_its_own_stale_bit() -> None:
    assert "manifold_pressure_kpa" in INPUT_NAMES
    assert stale_bit("manifold_pressure_kpa") == 1 << 8  # past StaleInputs' 8 bits: StaleInputsHigh bit 0


def test_a_manifold_pressure_model_replays_live_and_batch_alike() -> None:
    config = load_config(shipped_file("config", "manifold.yaml"))
    params = _model()
    frames = frames_from_flight(_flight(), config, ("manifold_pressure_kpa", "rpm", "altitude_m", "airspeed_mps",
                                                     "oat_c", "cht_c"))  # fmt: skip
    batch = replay_frames(config, params, frames)
    live = replay_live(config, params, frames.messages())
    assert len(batch) == len(live) > 10_000
    for name in ("cht_est_c", "gamma_q", "headroom_s", "cht_rate_c_per_min"):
        assert np.array_equal(batch.columns[name], live.columns[name], equal_nan=True), name
    states = set(batch.columns["state"][200:].tolist())
    assert not states & {3, 5}  # never INPUT_STALE nor UNAVAILABLE once started: the model's inputs all come


def test_a_model_on_manifold_pressure_needs_a_config_that_maps_it() -> None:
    config = load_config(shipped_file("config", "example.yaml"))
    with pytest.raises(ConfigError, match=r"manifold_pressure_kpa.*manifold\.yaml"):
        LiveMonitor(config, _model())


def test_manifold_pressure_from_a_dronecan_field(tmp_path: Path) -> None:
    data = yaml.safe_load(shipped_file("config", "dronecan.yaml").read_text(encoding="utf-8"))
    data["inputs"]["manifold_pressure_kpa"] = {
        "field": "uavcan.equipment.ice.reciprocating.Status.intake_manifold_pressure_kpa",
        "unit": "kPa",
        "stale_after_s": 1.0,
    }
    path = tmp_path / "dronecan_map.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    config = load_config(path)
    frames = frames_from_flight(_flight(600), config, ("manifold_pressure_kpa", "rpm", "altitude_m", "cht_c"))
    result = replay_frames(config, _model(), frames)
    assert result.counters["ok"] > 0
    assert np.isfinite(result.columns["cht_est_c"][-1])


def test_a_silent_manifold_pressure_is_reported_in_stale_inputs_high() -> None:
    config = load_config(shipped_file("config", "manifold.yaml"))
    frames = frames_from_flight(_flight(900), config, ("rpm", "altitude_m", "cht_c"))
    kept = frames.take(~((frames.arbitration_id == 257) & (frames.time_s > 600.0)))  # ECU_Slow (CHT, MAP) stops
    monitor = LiveMonitor(config, _model())
    sent = []
    for msg in kept.messages():
        sent += monitor.advance_to(msg.timestamp)
        monitor.feed(msg)
    diag = Encoder([config.health_dbc])
    high = [diag.message("Health_Diag").decode(bytes(f.data))["StaleInputsHigh"] for f in sent
            if f.arbitration_id == diag.message("Health_Diag").frame_id and f.timestamp > 700.0]  # fmt: skip
    assert high and all(v == 1 for v in high)


def test_the_cht_rate_follows_the_estimate_and_goes_out_in_health_status() -> None:
    config = load_config(shipped_file("config", "example.yaml"))
    params = paper_table_a1()
    log = _flight()
    log = log.with_columns(cht_c=np.round(60 + 60 * (1 - np.exp(-np.clip(log.time_s - 200, 0, None) / 120))))
    frames = frames_from_flight(log, config, ("throttle_pct", "rpm", "altitude_m", "cht_c"))
    result = replay_frames(config, params, frames)
    t = result.columns["time_s"]
    est = result.columns["cht_est_c"]
    rate = result.columns["cht_rate_c_per_min"]
    ok = np.isfinite(rate) & np.isfinite(est)
    assert ok.mean() > 0.9
    # against the estimate's own slope over 20 s windows (an independent reading of the same thing)
    step = round(20.0 / float(np.median(np.diff(t))))
    slope = (est[step:] - est[:-step]) / (t[step:] - t[:-step]) * 60.0
    middle = 0.5 * (rate[step:] + rate[:-step])
    both = np.isfinite(slope) & np.isfinite(middle)
    assert np.corrcoef(slope[both], middle[both])[0, 1] > 0.9
    monitor = LiveMonitor(config, params)
    sent = []
    for msg in frames.messages():
        sent += monitor.advance_to(msg.timestamp)
        monitor.feed(msg)
    status = Encoder([config.health_dbc]).message("Health_Status")
    decoded = [status.decode(bytes(f.data))["ChtRate"] for f in sent if f.arbitration_id == status.frame_id]
    assert min(decoded) >= -128 and max(decoded) <= 127 and max(decoded) > 5  # the climb heats at several degC/min
