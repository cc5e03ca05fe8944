"""The virtual ECU: missions, truth plant, sensors, frame emitter and recorder (virtual_bus)."""

from __future__ import annotations

import itertools
import uuid
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

from ecu_monitor.bus.canlog import load_flight
from ecu_monitor.bus.checksum import frame_checksum
from ecu_monitor.errors import ConfigError, ParameterError
from ecu_monitor.flightlog import read_csv, write_csv
from ecu_monitor.model import (
    InputSeries,
    SensorLag,
    coefficients,
    compute_drive,
    paper_table_a1,
    steady_state_cht,
)
from virtual_bus.emitter import FrameEmitter, FrameEncoder, load_engine_dbc
from virtual_bus.missions import (
    Climb,
    Cruise,
    GroundRun,
    Mission,
    StepClimb,
    Variation,
    list_missions,
    load_mission,
    mission_from_dict,
)
from virtual_bus.pilot import propeller_rpm
from virtual_bus.plant import Degradation, fly, gamma_schedule, iter_steps, parse_effects, random_effects
from virtual_bus.random_missions import random_mission
from virtual_bus.recorder import record

# A short mission (~110 s): warm-up, take-off, a short climb. Fast to fly in every test.
SHORT = mission_from_dict(
    {
        "name": "short",
        "segments": [
            {"kind": "ground_run", "duration_s": 20, "throttle_pct": 30},
            {"kind": "takeoff"},
            {"kind": "climb", "target_altitude_m": 200},
        ],
    }
)


def _channel() -> str:
    return f"vecu-test-{uuid.uuid4().hex[:8]}"


# --------------------------------------------------------------------------------------------------
# Missions
# --------------------------------------------------------------------------------------------------


def test_every_shipped_mission_loads_and_default_matches_the_reference_uav():
    names = list_missions()
    assert {"default", "short_hop", "survey_lowalt", "endurance_hot_day"} <= set(names)
    for name in names:
        assert load_mission(name).segments
    default = load_mission("default")
    kinds = [seg.kind for seg in default.segments]
    assert kinds[0] == "ground_run" and "climb" in kinds and kinds[-1] == "landing"
    climb = next(seg for seg in default.segments if isinstance(seg, Climb))
    cruise = next(seg for seg in default.segments if isinstance(seg, Cruise))
    assert climb.climb_rate_mps == 3.0 and climb.target_altitude_m == 4000.0 and climb.step_climb is not None
    assert cruise.airspeed_mps == 23.0


def test_mission_round_trips_through_its_dict():
    mission = load_mission("survey_lowalt")
    assert mission_from_dict(mission.to_dict()) == mission


def test_isa_oat_with_day_offset():
    atmosphere = load_mission("endurance_hot_day").atmosphere
    assert atmosphere.oat_c(0.0) == pytest.approx(35.0)
    assert atmosphere.oat_c(2000.0) == pytest.approx(35.0 - 13.0)


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ("segments: []", "segments"),
        ("segments: [{kind: hover, duration_s: 3}]", "segments[0].kind"),
        ("segments: [{kind: ground_run}]", "segments[0].duration_s"),
        ("segments: [{kind: ground_run, duration_s: 10, throttle_pct: 120}]", "segments[0].throttle_pct"),
        ("segments: [{kind: climb, target_altitude_m: 100, step_climb: {margin: 3}}]", "segments[0].step_climb.margin"),
        (
            "segments: [{kind: cruise, duration_s: 9, throttle_variation: {kind: square}}]",
            "segments[0].throttle_variation.kind",
        ),
        ("atmosphere: {oat_offset_c: hot}\nsegments: [{kind: ground_run, duration_s: 1}]", "atmosphere.oat_offset_c"),
        ("wind: 3\nsegments: [{kind: ground_run, duration_s: 1}]", "wind"),
        ("segments: [{kind: ground_run, duration_s: 1}", "not valid YAML"),
    ],
)
def test_bad_mission_raises_config_error_naming_file_and_key(tmp_path: Path, text: str, key: str):
    path = tmp_path / "bad.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_mission(path)
    message = str(info.value)
    assert str(path) in message and key in message and "\n" not in message


def test_random_missions_are_deterministic_and_varied():
    assert random_mission(3, 3600.0) == random_mission(3, 3600.0)
    fields = {random_mission(seed, 3600.0).field_elevation_m for seed in range(5)}
    assert len(fields) == 5
    log = fly(random_mission(7, 1200.0), seed=7)
    assert 600.0 < log.duration_s < 3000.0
    assert np.ptp(log["altitude_m"]) > 300.0


def test_propeller_law_gives_about_6000_rpm_at_the_cruise_point():
    assert float(propeller_rpm(50.0, 23.0)) == pytest.approx(6000.0, rel=0.02)
    assert float(propeller_rpm(0.0, 0.0)) == pytest.approx(1800.0)
    assert 8800.0 <= float(propeller_rpm(100.0, 20.0)) <= 9200.0


# --------------------------------------------------------------------------------------------------
# Truth plant
# --------------------------------------------------------------------------------------------------


def test_same_seed_gives_identical_csv_and_another_seed_differs(tmp_path: Path):
    paths = [tmp_path / f"{name}.csv" for name in ("a", "b", "c")]
    for path, seed in zip(paths, (5, 5, 6), strict=True):
        write_csv(fly(SHORT, seed=seed), path)
    assert paths[0].read_bytes() == paths[1].read_bytes()
    assert paths[0].read_bytes() != paths[2].read_bytes()
    a, c = read_csv(paths[0]), read_csv(paths[2])
    # the truth is the same (no random pilot variation in SHORT), only the sensor noise differs
    np.testing.assert_array_equal(a["cht_true_c"], c["cht_true_c"])
    assert not np.array_equal(a["rpm"], c["rpm"])


def test_log_has_canonical_and_truth_columns_on_the_record_grid():
    log = fly(SHORT, record_dt_s=0.5)
    for name in (*("time_s", "throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c", "cht_c"),):
        assert log.has(name)
    for name in ("cht_true_c", "fuel_flow_lph", "vspeed_mps", "gamma_q", "gamma_d"):
        assert log.has(name)
    np.testing.assert_allclose(np.diff(log.time_s), 0.5, atol=1e-9)
    cht = log["cht_c"]
    np.testing.assert_array_equal(cht, np.round(cht))  # 1 degC quantiser
    assert np.max(np.abs(cht - log["cht_true_c"])) < 2.5  # 0.5 quantisation + ~4 sigma of 0.3 noise


def test_cht_rises_1_to_2_degc_per_s_over_the_first_30_s_of_full_power():
    """Measured on the truth CHT of the default mission: from the end of the 120 s warm-up at 30 %
    (take-off at 100 % starts) to 30 s later; the paper: 'CHT can rise about 1 degC/s in a climb'."""
    mission = load_mission("default")
    warmup = mission.segments[0]
    assert isinstance(warmup, GroundRun)
    log = fly(mission, max_duration_s=warmup.duration_s + 40.0)
    t, cht = log.time_s, log["cht_true_c"]
    start = int(np.searchsorted(t, warmup.duration_s))
    stop = int(np.searchsorted(t, warmup.duration_s + 30.0))
    rate = (cht[stop] - cht[start]) / (t[stop] - t[start])
    assert 0.8 <= rate <= 2.5


def test_step_climb_keeps_cht_below_the_limit_and_a_plain_climb_does_not():
    params = paper_table_a1()
    mission = load_mission("default")
    blocks = list(iter_steps(mission, params, max_duration_s=1500.0))
    cht_true = np.concatenate([b.cht_true_c for b in blocks])
    in_climb = np.concatenate([np.full(b.time_s.size, b.segment_index == 2) for b in blocks])
    throttle = np.concatenate([b.throttle_pct for b in blocks])
    assert cht_true.max() < params.cht_limit_c
    assert np.any(in_climb & (throttle < 55.0)), "no level-off seen in the climb"
    # the same climb without the step-climb overheats: the test above can fail
    plain = tuple(
        Climb(seg.target_altitude_m, seg.climb_rate_mps, seg.throttle_pct, seg.airspeed_mps, None)
        if isinstance(seg, Climb)
        else seg
        for seg in mission.segments
    )
    log = fly(Mission(mission.name, plain, atmosphere=mission.atmosphere), max_duration_s=1500.0)
    assert log["cht_true_c"].max() > params.cht_limit_c


def test_a_step_climb_that_cannot_cool_is_abandoned_and_the_mission_ends(caplog: pytest.LogCaptureFixture):
    hot = Mission(
        "hot",
        (
            GroundRun(duration_s=10.0),
            Climb(target_altitude_m=300.0, step_climb=StepClimb(cht_margin_c=40.0, level_throttle_pct=90.0)),
            Cruise(duration_s=60.0),
        ),
    )
    log = fly(hot, record_dt_s=1.0)
    assert "abandoned" in caplog.text
    assert log.duration_s < 10.0 + 4.0 * 100.0 + 1800.0 + 120.0
    assert log["altitude_m"].max() < 290.0  # never got there: levelled off the whole time


def test_variations_apply_in_a_first_segment_cruise():
    sine = Mission(
        "sine",
        (Cruise(duration_s=200.0, throttle_pct=50.0, throttle_variation=Variation("sine", 10.0, 100.0)),),
    )
    throttle = fly(sine, record_dt_s=1.0)["throttle_pct"]
    assert throttle[30:].max() > 57.0 and throttle[30:].min() < 43.0


def _held_cruise(duration_s: float) -> Mission:
    return Mission(
        "held",
        (Cruise(duration_s=duration_s, airspeed_mps=23.0, throttle_pct=50.0),),
        field_elevation_m=1000.0,
    )


@pytest.mark.parametrize(("factor", "value"), [("gamma_q", 1.2), ("gamma_d", 1.1)])
def test_degradation_step_raises_cht_by_the_steady_state_amount(factor: str, value: float):
    params = paper_table_a1()
    log = fly(_held_cruise(900.0), params, degradation=[Degradation(factor, value, 450.0)])
    coeffs = coefficients(params)
    t = log.time_s
    before, after = int(np.searchsorted(t, 440.0)), int(np.searchsorted(t, 890.0))
    *_, last = iter_steps(_held_cruise(900.0), params, max_duration_s=440.0)
    # the truth inputs (not the noisy measured ones) once the airframe has settled
    inputs = InputSeries(
        last.throttle_pct[-1], last.rpm[-1], last.altitude_m[-1], last.airspeed_mps[-1], last.oat_c[-1]
    )
    drive = compute_drive(inputs, coeffs)
    gammas = {"gamma_q": 1.0, "gamma_d": 1.0}
    nominal = steady_state_cht(drive, coeffs)
    gammas[factor] = value
    degraded = steady_state_cht(drive, coeffs, gammas["gamma_q"], gammas["gamma_d"])
    assert degraded - nominal > 5.0
    cht = log["cht_true_c"]
    assert cht[before] == pytest.approx(nominal, abs=0.2)
    assert cht[after] - cht[before] == pytest.approx(degraded - nominal, abs=0.3)
    np.testing.assert_array_equal(log[factor][[before, after]], [1.0, value])


def test_degradation_syntax_and_schedule():
    step = Degradation.parse("gamma_q=1.2@1800")
    ramp = Degradation.parse("gamma_D=1.1@600:ramp=300")
    assert (step.factor, step.value, step.start_s, step.ramp_s) == ("gamma_q", 1.2, 1800.0, 0.0)
    assert (ramp.factor, ramp.value, ramp.start_s, ramp.ramp_s) == ("gamma_d", 1.1, 600.0, 300.0)
    assert str(Degradation.parse(str(ramp))) == str(ramp)
    t = np.array([0.0, 599.0, 750.0, 900.0, 2000.0])
    np.testing.assert_allclose(gamma_schedule([ramp], "gamma_d", t), [1.0, 1.0, 1.05, 1.1, 1.1])
    np.testing.assert_allclose(gamma_schedule([ramp], "gamma_q", t), 1.0)
    second = Degradation("gamma_d", 1.3, 1000.0, 1000.0)  # ramps on from the level reached (1.1)
    np.testing.assert_allclose(gamma_schedule([second, ramp], "gamma_d", [1500.0]), [1.2])
    for bad in ("gamma_q=1.2", "gamma_x=1@3", "gamma_q=abc@3", "gamma_q=1.2@10:ramp=-1", "gamma_q=9@1"):
        with pytest.raises(ConfigError):
            Degradation.parse(bad)


def test_effects_from_cli_specs_and_random_sizes():
    effects = parse_effects(["airspeed_cooling", "sensor_lag:time_constant_s=12"])
    assert effects.active == ("airspeed_cooling", "sensor_lag")
    assert effects.sensor_lag == SensorLag(12.0)
    for bad in (["warp"], ["sensor_lag:tau=3"], ["sensor_lag:time_constant_s=x"], ["sensor_lag:12"]):
        with pytest.raises(ParameterError):
            parse_effects(bad)
    drawn = random_effects(4)
    assert drawn == random_effects(4) and drawn != random_effects(5)
    assert set(drawn.active) == {"airspeed_cooling", "density_cooling", "sensor_lag", "mixture_cooling"}


def test_sensor_lag_effect_delays_the_probe_in_a_warm_up():
    lag = parse_effects(["sensor_lag:time_constant_s=15"])
    plain = fly(SHORT, max_duration_s=20.0)
    lagged = fly(SHORT, effects=lag, max_duration_s=20.0)
    np.testing.assert_array_equal(plain["cht_true_c"], lagged["cht_true_c"])  # the head is the same
    k = int(np.searchsorted(plain.time_s, 15.0))
    assert lagged["cht_c"][k] < plain["cht_true_c"][k] - 3.0  # the probe reads low while warming


def test_airspeed_cooling_effect_cools_the_head_in_a_fast_cruise():
    mission = Mission("fast", (Cruise(duration_s=400.0, airspeed_mps=30.0, throttle_pct=50.0),))
    plain = fly(mission, max_duration_s=400.0)
    cooled = fly(mission, effects=parse_effects(["airspeed_cooling"]), max_duration_s=400.0)
    assert cooled["cht_true_c"][-1] < plain["cht_true_c"][-1] - 3.0


def test_iter_steps_streams_blocks_of_the_integration_step():
    blocks = iter_steps(SHORT, dt_s=0.02)
    first, second = itertools.islice(blocks, 2)
    assert first.time_s.size == 50 and first.first_step == 0 and second.first_step == 50
    np.testing.assert_allclose(second.time_s[0], 1.0)
    with pytest.raises(ParameterError):
        next(iter_steps(SHORT, dt_s=0.0))
    with pytest.raises(ParameterError):
        fly(SHORT, dt_s=0.02, record_dt_s=0.03)


# --------------------------------------------------------------------------------------------------
# Frames: encoder, emitter on a virtual bus, recorder
# --------------------------------------------------------------------------------------------------


def _decode(msg: can.Message) -> tuple[str, dict[str, float]]:
    message = load_engine_dbc().get_message_by_frame_id(msg.arbitration_id)
    return message.name, message.decode(bytes(msg.data), decode_choices=False)


def test_frames_on_a_virtual_bus_reach_a_second_bus_with_correct_values_and_counters(make_bus: Any):
    channel = _channel()
    receiver = make_bus(channel)
    sender = make_bus(channel, preserve_timestamps=True)
    stats = FrameEmitter(sender).emit(iter_steps(SHORT, seed=3, max_duration_s=4.0))
    received = []
    while (msg := receiver.recv(timeout=0.5)) is not None:
        received.append(msg)
    assert stats.frames_sent == len(received) == 4 * (50 + 10 + 10)
    assert stats.send_errors == 0
    steps = list(iter_steps(SHORT, seed=3, max_duration_s=4.0))
    measured = {name: np.concatenate([getattr(b.measured, name) for b in steps]) for name in ("rpm", "cht_c")}
    times = np.concatenate([b.time_s for b in steps])
    counters: dict[str, list[int]] = {}
    for msg in received:
        assert msg.data[7] == frame_checksum(msg.data)
        name, values = _decode(msg)
        strict = load_engine_dbc().get_message_by_name(name).encode(values, strict=True)
        assert strict == bytes(msg.data)  # every value in range: the non-strict encoding lost nothing
        k = int(np.searchsorted(times, msg.timestamp + 1e-9)) - 1
        if name == "ECU_Fast":
            assert values["EngineSpeed"] == pytest.approx(measured["rpm"][k], abs=0.125)
            counters.setdefault(name, []).append(int(values["FastCounter"]))
        elif name == "ECU_Slow":
            assert values["CHT"] == pytest.approx(measured["cht_c"][k], abs=0.05)
            counters.setdefault(name, []).append(int(values["SlowCounter"]))
        else:
            counters.setdefault(name, []).append(int(values["AirDataCounter"]))
    for name, seq in counters.items():
        assert seq == [i % 16 for i in range(len(seq))], name
    fast = [m.timestamp for m in received if m.arbitration_id == 0x100]
    np.testing.assert_allclose(np.diff(fast), 0.02, atol=1e-9)


class _FlakyBus(can.BusABC):
    """A bus whose every third send fails."""

    def __init__(self) -> None:
        super().__init__(channel="flaky")
        self.sent: list[can.Message] = []
        self.calls = 0

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.calls += 1
        if self.calls % 3 == 0:
            raise can.CanOperationError("bus off")
        self.sent.append(msg)

    def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
        return None, False


def test_send_failures_are_counted_not_fatal():
    bus = _FlakyBus()
    try:
        stats = FrameEmitter(bus).emit(iter_steps(SHORT, max_duration_s=2.0))
    finally:
        bus.shutdown()
    assert stats.frames_sent + stats.send_errors == 140
    assert stats.send_errors == 140 // 3 and len(bus.sent) == stats.frames_sent


def test_realtime_emission_is_paced_to_the_wall_clock(make_bus: Any):
    bus = make_bus(_channel())
    stats = FrameEmitter(bus, realtime=True, speed=10.0).emit(iter_steps(SHORT, max_duration_s=2.0))
    assert stats.frames_sent == 140
    assert stats.wall_time_s >= 0.9 * (2.0 - 0.02) / 10.0  # never faster than asked (a lower bound only)


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".log"])
def test_can_logs_read_back_frame_for_frame(tmp_path: Path, suffix: str):
    path = tmp_path / f"flight{suffix}"
    summary = record(SHORT, [path], seed=2)
    expected = list(FrameEncoder().iter_frames(iter_steps(SHORT, seed=2)))
    with can.LogReader(str(path)) as reader:
        got = list(reader)
    assert summary.frames == len(expected) == len(got) > 7000
    for want, have in zip(expected, got, strict=True):
        assert have.arbitration_id == want.arbitration_id
        assert bytes(have.data) == bytes(want.data)
        assert have.timestamp == pytest.approx(want.timestamp, abs=1e-6)


def test_recorder_writes_csv_and_logs_of_the_same_flight(tmp_path: Path):
    csv_path, blf_path = tmp_path / "f.csv", tmp_path / "f.blf"
    injection = [Degradation("gamma_q", 1.3, 60.0)]
    summary = record(SHORT, [csv_path, blf_path], seed=1, degradation=injection)
    log = read_csv(csv_path)
    assert summary.rows == len(log) and log.has("cht_true_c") and log["gamma_q"][-1] == 1.3
    np.testing.assert_array_equal(
        log["cht_c"], fly(SHORT, seed=1, degradation=[Degradation("gamma_q", 1.3, 60.0)])["cht_c"]
    )
    decoded = load_flight(blf_path)  # the flight-log importer decodes the frames through engine.dbc
    k = int(np.searchsorted(log.time_s, 50.0))
    j = int(np.searchsorted(decoded.time_s, 50.0))
    assert decoded["cht_c"][j] == pytest.approx(log["cht_c"][k], abs=0.05)
    assert summary.max_cht_c == log["cht_c"].max()
    with pytest.raises(ConfigError):
        record(SHORT, [tmp_path / "f.txt"])
