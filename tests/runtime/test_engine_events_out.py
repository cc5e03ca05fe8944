"""Engine events out of the service: counted per flight in the history (and listed by ``history``), the
engine's hours since overhaul and the overhaul due, and each event published when it starts on the DBC
event frame, a DroneCAN LogMessage and a MAVLink STATUSTEXT (pipeline/events.py, runtime/publishers.py)."""

from __future__ import annotations

import pytest

from ecu_monitor.bus.mavlink_settings import MavlinkSettings
from ecu_monitor.cli import main
from ecu_monitor.config import DroneCanSettings, load_config
from ecu_monitor.pipeline.events import EVENT_KINDS, Event
from ecu_monitor.pipeline.outputs import HealthSnapshot
from ecu_monitor.runtime.dronecan_node import DroneCanNode
from ecu_monitor.runtime.flight_recorder import FlightRecorder
from ecu_monitor.runtime.mavlink_publisher import MavlinkPublisher
from ecu_monitor.runtime.persistence import DATABASE_NAME, FlightRules, FlightSample, StateStore
from ecu_monitor.runtime.publishers import DbcHealthFrames, LiveMonitor
from tests.helpers.dronecan_logs import log_messages
from tests.helpers.history import write_old_flight_database

SERIAL = "UAV-ENG-EVENTS"
RULES = FlightRules(running_rpm=1000.0, min_flight_s=60.0, end_after_s=10.0, checkpoint_every_s=30.0)
SHOCK = Event(100.0, "shock_cooling", 3, -41.2, -33.0, 5.0, ongoing=True)
OIL = Event(150.0, "oil_exceedance", 0, 121.0, 118.0, 2.0, ongoing=True)


def _sample(t: float, rpm: float) -> FlightSample:
    return FlightSample(time_s=t, wall_time_s=1.7e9 + t, rpm=rpm, cht_c=150.0, trends={"gamma_q": 1.0, "gamma_d": 1.0},
                        state="NOMINAL")  # fmt: skip


def _fly(recorder: FlightRecorder, t0: float, seconds: float, events: dict[float, list[Event]]) -> float:
    """A flight of ``seconds`` at 1 Hz from t0 (then the engine stopped for 20 s); ``events`` by flight time."""
    t = t0
    for k in range(round(seconds)):
        t = t0 + k
        recorder.add(_sample(t, 2400.0))
        recorder.add_events(events.get(float(k), []))
    for k in range(20):
        recorder.add(_sample(t + 1.0 + k, 0.0))
    return t + 21.0


def test_events_are_counted_per_flight_and_history_lists_them_with_the_engine_hours(
    tmp_path: pytest.TempPathFactory, capsys: pytest.CaptureFixture[str]
) -> None:
    end = SHOCK._replace(ongoing=False, duration_s=12.0)  # an end record counts nothing: its start did
    with StateStore(tmp_path) as store:
        recorder = FlightRecorder(store, SERIAL, 200.0, RULES, hours=(1990.5, 2000.0))
        t = _fly(recorder, 0.0, 1800.0, {100.0: [SHOCK], 112.0: [end], 300.0: [SHOCK, OIL]})
        _fly(recorder, t + 3600.0, 900.0, {})
        recorder.add_events([SHOCK])  # no flight open (the engine stopped): not a flight's
        first, second = store.flights(SERIAL)
        assert first.events == {"shock_cooling": {"3": 2}, "oil_exceedance": {"0": 1}}
        assert second.events == {}
        hours = store.engine_hours(SERIAL)
    assert hours.running_h == pytest.approx(0.75, abs=0.01)
    assert hours.since_overhaul_h == pytest.approx(1991.25, abs=0.01) and not hours.due
    assert main(["history", "--state-dir", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "events: oil_exceedance 1 (engine: 1), shock_cooling 2 (cyl 3: 2)" in text
    assert "engine hours: 0.7 h running recorded, 1991.2 h since overhaul, TBO 2000 h (8.8 h left)" in text
    assert "ALERT" not in text
    # ten more hours: the overhaul is due, an ALERT line the maintainer reads first
    with StateStore(tmp_path) as store:
        recorder = FlightRecorder(store, SERIAL, 200.0, RULES, hours=(1990.5, 2000.0))
        _fly(recorder, 1e5, 10 * 3600.0 / 20, {})  # (flights at 1 Hz: a short proxy of 10 h is enough below)
        store._conn.execute("UPDATE flights SET duration_s = 36000 WHERE id = 3")
    assert main(["history", "--state-dir", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert text.startswith(f"ALERT OVERHAUL DUE engine {SERIAL}: 10.7 h running recorded, 2001.2 h since overhaul")
    # an overhaul: the maintainer sets overhaul_hours to 0, the count starts again from the running hours then
    with StateStore(tmp_path) as store:
        FlightRecorder(store, SERIAL, 200.0, RULES, hours=(0.0, 2000.0))
        hours = store.engine_hours(SERIAL)
    assert hours.since_overhaul_h == 0.0 and hours.running_h == pytest.approx(10.75, abs=0.01) and not hours.due


def test_an_older_database_gains_the_event_and_hours_columns(tmp_path: pytest.TempPathFactory) -> None:
    write_old_flight_database(tmp_path / DATABASE_NAME, version=2)
    with StateStore(tmp_path, readonly=True) as store:  # read-only before migration: nothing new, no error
        (old,) = store.flights("OLD")
        assert old.events == {} and store.engine_hours("OLD").since_overhaul_h is None
    with StateStore(tmp_path) as store:
        store.set_engine_hours("OLD", 100.0, None)
        (kept,) = store.flights("OLD")
        assert kept.events == {} and kept.gamma_q_mean == 1.02
        hours = store.engine_hours("OLD")
    assert hours.running_h == pytest.approx(600.0 / 3600.0) and hours.since_overhaul_h == 100.0


def _snap(t: float) -> HealthSnapshot:
    return HealthSnapshot(time_s=t, cht_meas_c=150.0, cht_est_c=150.0, deviation=0.0, state="NOMINAL", gamma_q=1.0,
                          gamma_d=1.0, headroom_s=900.0, stale_inputs=())  # fmt: skip


def test_an_event_that_starts_goes_out_on_every_output() -> None:
    text = SHOCK.start_text()
    assert text == "ENGINE cyl 3: shock cooling -41 C/min"
    # DBC: one Health_Event frame, decoded back to the record
    config = load_config("example.yaml")
    monitor = LiveMonitor(config, config.load_cylinder_params())
    dbc = next(p for p in monitor.publishers if isinstance(p, DbcHealthFrames))
    (frame,) = dbc.announce(SHOCK)
    message = dbc.encoder.message("Health_Event")
    assert frame.arbitration_id == message.frame_id == 0x305 and not frame.is_extended_id
    decoded = message.decode(bytes(frame.data), decode_choices=False)
    assert decoded["EventKind"] == EVENT_KINDS.index("shock_cooling") and decoded["EventCylinder"] == 3
    assert decoded["EventValue"] == pytest.approx(-41.2) and decoded["EventLimit"] == pytest.approx(-33.0)
    assert message.decode(bytes(frame.data))["EventKind"] == "shock_cooling"
    # DroneCAN: one LogMessage, WARNING (INFO for the advisory)
    node = DroneCanNode(DroneCanSettings(), 200.0, 0.1, 5)
    node.tell(text)
    node.tell("ENGINE cyl 2: valve advisory +40 C", advisory=True)
    logs = log_messages(msg for t in (0.1, 0.2, 0.3) for msg in node.frames(t, _snap(t)))
    assert (2, text) in logs and (1, "ENGINE cyl 2: valve advisory +40 C") in logs
    # MAVLink: one STATUSTEXT, WARNING
    pub = MavlinkPublisher(MavlinkSettings(statustext_per_s=10.0), 200.0)
    pub.announce(SHOCK)
    for t in (0.0, 1.0):
        pub.messages(t, _snap(t))
    assert [s for s in pub.sent_texts if s[0] == text] == [(text, 4)]
