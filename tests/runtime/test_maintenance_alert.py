"""Across flights in the service: the wear index in the history, the alert raised, kept across restarts, printed
by ``history`` and told on every output at the next start; an older database migrated without loss."""

from __future__ import annotations

from pathlib import Path

import can
import pytest

from ecu_monitor.bus.canlog import load_flight
from ecu_monitor.cli import main
from ecu_monitor.config import DroneCanSettings, load_config
from ecu_monitor.estimation.wear import WearReference, WearSettings
from ecu_monitor.offline.flight_frames import frames_from_flight
from ecu_monitor.pipeline.engine import model_input_names
from ecu_monitor.pipeline.outputs import HealthSnapshot
from ecu_monitor.runtime.dronecan_node import DroneCanNode
from ecu_monitor.runtime.flight_recorder import FlightRecorder, engine_wear
from ecu_monitor.runtime.persistence import DATABASE_NAME, FlightRules, FlightSample, StateStore
from ecu_monitor.runtime.publishers import LiveMonitor
from tests.helpers.dronecan_logs import log_messages
from tests.helpers.history import write_old_flight_database

SERIAL = "UAV-ENG-WEAR"
RULES = FlightRules(running_rpm=1000.0, min_flight_s=60.0, end_after_s=10.0, checkpoint_every_s=30.0)
REFERENCE = WearReference(mean=0.0, sd=0.005, flights=10)
OAT_C = 15.0


def _fly(recorder: FlightRecorder, start_utc: float, excess: float, seconds: float = 600.0) -> None:
    """One flight at 10 Hz whose head runs ``excess`` (a fraction of the model's rise over OAT) above the model;
    airborne, at power fraction 0.8 (high power) from 300 s to 400 s, 0.5 (cruise) otherwise."""
    n = round(seconds * 10)
    for i in range(n + 200):  # then 20 s stopped: the flight ends
        t = i * 0.1
        running = i < n
        model = 150.0 if running else 60.0
        recorder.add(FlightSample(
            time_s=t, wall_time_s=start_utc + t, rpm=5000.0 if running else 0.0,
            cht_c=model + excess * (model - OAT_C), trends={"gamma_q": 1.0, "gamma_d": 1.0}, state="NOMINAL",
            model_c=model, oat_c=OAT_C, airspeed_mps=30.0, power=0.8 if 3000 <= i < 4000 else 0.5, deviation=0.01,
        ))  # fmt: skip


def test_flights_keep_their_wear_index_and_a_drift_raises_one_alert_kept_across_restarts(tmp_path: Path) -> None:
    excess = [0.0, 0.002, -0.001] + [0.004 * n for n in range(1, 12)]
    with StateStore(tmp_path) as store:
        recorder = FlightRecorder(store, SERIAL, 200.0, RULES, wear=WearSettings(), reference=REFERENCE)
        for n, x in enumerate(excess):
            _fly(recorder, 1.7e9 + 86400.0 * n, x)
        flights = store.flights(SERIAL)
        assert [round(f.wear_index or 0.0, 6) for f in flights] == [round(x, 6) for x in excess]
        assert all(f.wear_samples == 6000 and f.high_power_s == pytest.approx(100.0, abs=0.2) for f in flights)
        phases = flights[-1].phases  # the regions of estimation/regions.py: the first 300 s are the start
        assert {k: round(v["seconds"]) for k, v in phases.items()} == {"start": 300, "high power": 100,
                                                                        "cruise power": 200}  # fmt: skip
        assert phases["high power"]["wear_index"] == pytest.approx(excess[-1])
        assert phases["cruise power"]["deviation_mean"] == pytest.approx(0.01)
        (alert,) = recorder.alerts
        # z = x / (0.005 x 1.4695, the sd's 90 % bound from 10 flights), S += z - 0.5: 0.04, 0.63, 1.76, 3.44, 5.66
        # after flights 4-8 (h 5.75), 8.42 after flight 9 (x = 0.024)
        assert alert.flight_id == flights[8].id
        assert alert.threshold == pytest.approx(WearSettings().threshold) and alert.statistic >= alert.threshold
        assert alert.text.startswith(f"MAINTENANCE {SERIAL}: head +2.4% hotter")
    with StateStore(tmp_path) as store:  # a restart: the alert is there, open, and not raised twice
        recorder = FlightRecorder(store, SERIAL, 200.0, RULES, wear=WearSettings(), reference=REFERENCE)
        _fly(recorder, 1.7e9 + 86400.0 * 20, 0.06)
        assert recorder.alerts == [] and [a.id for a in store.alerts(SERIAL, open_only=True)] == [alert.id]
        assert store.clear_alerts(SERIAL, 1.7e9 + 86400.0 * 21) == 1
        assert engine_wear(store, SERIAL, WearSettings(), REFERENCE).flights == ()  # restarts after maintenance


def test_history_prints_the_alert_and_clears_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with StateStore(tmp_path) as store:
        recorder = FlightRecorder(store, SERIAL, 200.0, RULES, wear=WearSettings(baseline_flights=4))
        for n, x in enumerate([0.0, 0.003, -0.002, 0.001, 0.0] + [0.01 * n for n in range(1, 8)]):
            _fly(recorder, 1.7e9 + 86400.0 * n, x)  # no stored reference: the first 4 flights give it
        assert len(recorder.alerts) == 1 and recorder.alerts[0].reference_learned
    assert main(["history", "--state-dir", str(tmp_path), "--plot", str(tmp_path / "trend.png")]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0].startswith(f"ALERT MAINTENANCE {SERIAL}: head +")
    assert "across flights: " in out and "wear %" in out
    assert (tmp_path / "trend.png").stat().st_size > 10_000
    assert main(["history", "--state-dir", str(tmp_path), "--engine", SERIAL, "--clear-alert"]) == 0
    out = capsys.readouterr().out
    assert "1 maintenance alert(s) cleared" in out and "\nALERT" not in out and not out.startswith("ALERT")


def test_an_older_database_gains_the_wear_columns_and_the_alert_table_and_loses_nothing(tmp_path: Path) -> None:
    write_old_flight_database(tmp_path / DATABASE_NAME, version=2)  # flights with cylinders_json, no wear
    with StateStore(tmp_path, readonly=True) as store:  # read-only (history while the old daemon runs): NULLs
        (old,) = store.flights("OLD")
        assert old.wear_index is None and old.wear_samples == 0 and store.alerts() == []
    with StateStore(tmp_path) as store:
        (kept,) = store.flights("OLD")
        assert (kept.gamma_q_mean, kept.max_cht_c, kept.cycles_total) == (1.02, 150.0, 3.0)
        assert kept.wear_index is None and kept.high_power_s is None
        version = store._conn.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()[0]
    assert version == "4"


def _snap(t: float = 0.0) -> HealthSnapshot:
    return HealthSnapshot(time_s=t, cht_meas_c=150.0, cht_est_c=150.0, deviation=0.0, state="NOMINAL", gamma_q=1.0,
                          gamma_d=1.0, headroom_s=900.0, stale_inputs=())  # fmt: skip


def test_an_open_alert_is_told_on_every_output() -> None:
    text = f"MAINTENANCE {SERIAL}: head +4.2% hotter than nominal (ref +0.1%) after flight 17"
    # DBC health frames: Health_Diag.MaintenanceAlert from the tell on
    config = load_config("example.yaml")
    monitor = LiveMonitor(config, config.load_cylinder_params())
    diag = monitor.publishers[0].encoder.message("Health_Diag")

    def alert_bits(frames: list[can.Message]) -> list[int]:
        return [diag.decode(bytes(f.data))["MaintenanceAlert"] for f in frames if f.arbitration_id == diag.frame_id]

    flight = load_flight(Path(__file__).parent.parent / "data" / "flight_small.csv")
    frames = list(frames_from_flight(flight, config, model_input_names(monitor.params, config.input_names)).messages())
    start = frames[0].timestamp

    def run(until_s: float) -> list[can.Message]:
        out: list[can.Message] = []
        while frames and frames[0].timestamp < start + until_s:
            msg = frames.pop(0)
            out += monitor.advance_to(msg.timestamp)
            monitor.feed(msg)
        return out

    assert set(alert_bits(run(3.0))) == {0}
    monitor.tell(text)
    assert set(alert_bits(run(6.0))) == {1}
    # DroneCAN: one LogMessage, level WARNING
    node = DroneCanNode(DroneCanSettings(), 200.0, 0.1, 5)
    node.tell(text)
    logs = log_messages(msg for t in (0.1, 0.2) for msg in node.frames(t, _snap(t)))
    assert (2, text) in logs and sum(1 for _, t in logs if t == text) == 1
    # MAVLink: one STATUSTEXT, severity WARNING
    from ecu_monitor.bus.mavlink_settings import MavlinkSettings
    from ecu_monitor.runtime.mavlink_publisher import MavlinkPublisher

    pub = MavlinkPublisher(MavlinkSettings(statustext_per_s=10.0), 200.0)
    pub.tell(text)
    for t in (0.0, 1.0, 2.0):
        pub.messages(t, _snap(t))
    assert [s for s in pub.sent_texts if s[0] == text] == [(text, 4)]
