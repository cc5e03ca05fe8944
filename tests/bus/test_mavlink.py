"""MAVLink (bus/mavlink.py, bus/mavlink_log.py, runtime/mavlink_publisher.py, virtual_bus/mavlink_emitter.py):
messages built by pymavlink itself decode to canonical units, from the accepted sender only; kelvin in a degC
field is told once and converted when declared; random bytes never raise and are counted; the publisher's
STATUSTEXT chunks, severities, rate limit and NAMED_VALUE_FLOAT names; a virtual flight recorded to a .tlog
reads back to the virtual ECU's own CSV; the emitter's stream crosses UDP on 127.0.0.1 to a pymavlink reader."""

from __future__ import annotations

import itertools
import math
import re
import socket
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ecu_monitor.bus.codec import SignalSpec
from ecu_monitor.bus.mavlink import (
    MavlinkDecoder,
    default_specs,
    kelvin_like,
    mavlink_module,
    parse_connection,
    parse_field,
)
from ecu_monitor.bus.mavlink_log import read_tlog
from ecu_monitor.bus.mavlink_settings import MavlinkSettings
from ecu_monitor.cli import main as ecu_monitor_main
from ecu_monitor.config import load_config, parse_config
from ecu_monitor.errors import ConfigError, FlightLogError
from ecu_monitor.flightlog import read_csv
from ecu_monitor.model import paper_table_a1
from ecu_monitor.pipeline.output_table import HEALTH_VALUES, STATES
from ecu_monitor.pipeline.outputs import CylinderSnapshot, HealthSnapshot
from ecu_monitor.runtime.mavlink_publisher import (
    MAX_NAME,
    MAX_TEXT,
    SEVERITY,
    MavlinkPublisher,
    named_values,
    state_text,
    text_chunks,
)
from ecu_monitor.units import pressure_altitude_m
from tests.helpers import REPO
from virtual_bus.cli import main as virtual_ecu_main
from virtual_bus.mavlink_emitter import MavlinkEmitter, MavlinkFrameEncoder, TlogWriter, emitter_connection
from virtual_bus.missions import load_mission
from virtual_bus.plant import iter_steps

SHIPPED = REPO / "ecu_monitor" / "data" / "configs" / "mavlink.yaml"
ML = mavlink_module()
NAN = math.nan
#: A ~2.5-minute mission: ground run, take-off, climb, cruise: every message, the engine warming.
MISSION = {
    "name": "mavlink_test",
    "segments": [
        {"kind": "ground_run", "duration_s": 30, "throttle_pct": 40},
        {
            "kind": "takeoff",
            "duration_s": 20,
            "ground_roll_s": 10,
            "throttle_pct": 100,
            "airspeed_mps": 20,
            "climb_rate_mps": 3,
        },
        {"kind": "climb", "target_altitude_m": 250, "climb_rate_mps": 3, "throttle_pct": 85, "airspeed_mps": 21},
        {"kind": "cruise", "duration_s": 30, "airspeed_mps": 23, "throttle_pct": 60},
    ],
}


class _Sink:
    def __init__(self) -> None:
        self.data = bytearray()

    def write(self, buf: bytes) -> None:
        self.data += buf


def _efi(rpm: float = 5500.0, cht: float = 180.0, flow: float = 250.0, throttle: float = 63.0, egt: float = NAN) -> Any:
    """EFI_STATUS built with pymavlink's own message class (not our emitter)."""
    return ML.MAVLink_efi_status_message(
        1, 0, rpm, 100.0, flow, NAN, throttle, NAN, 95.0, 80.0, 25.0, cht, NAN, NAN, egt, NAN, NAN, 0.0, 0.0
    )


def _pack(*msgs: Any, system: int = 1, component: int = 1, mavlink1: bool = False) -> bytes:
    sink = _Sink()
    mav = ML.MAVLink(sink, srcSystem=system, srcComponent=component)
    for msg in msgs:
        mav.send(msg, force_mavlink1=mavlink1)
    return bytes(sink.data)


def _values(decoder: MavlinkDecoder, data: bytes) -> dict[str, list[float]]:
    got: dict[str, list[float]] = {}
    for slot, value in decoder.parse_bytes(data):
        got.setdefault(decoder.names[slot], []).append(value)
    return got


# --- the decoder --------------------------------------------------------------------------------


def test_messages_built_by_pymavlink_decode_to_canonical_units_over_mavlink_1_and_2() -> None:
    scaled = ML.MAVLink_scaled_pressure_message(1000, 950.0, 3.2, 1810, 1523)
    hud = ML.MAVLink_vfr_hud_message(24.5, 25.0, 90, 64, 812.0, 1.5)
    for mavlink1 in (False, True):
        decoder = MavlinkDecoder(default_specs())
        got = _values(decoder, _pack(_efi(), scaled, hud, mavlink1=mavlink1))
        assert got["rpm"] == [5500.0]
        assert got["throttle_pct"] == [63.0]
        assert got["cht_c"] == [180.0]
        assert got["fuel_flow_lph"] == [pytest.approx(250.0 * 0.06)]  # cm^3/min -> L/h
        assert got["manifold_pressure_kpa"] == [80.0]
        assert got["intake_temp_c"] == [25.0]
        assert got["oat_c"] == [pytest.approx(15.23)]  # cdegC -> degC
        assert got["altitude_m"] == [pytest.approx(pressure_altitude_m(95.0))]  # 950 hPa -> pressure altitude
        assert got["airspeed_mps"] == [24.5]
        assert "egt_c" not in got  # NaN: unknown, the input goes stale
        counts = decoder.counters
        assert (counts["frames"], counts["ok"], counts["malformed"], counts["unknown_value"]) == (3, 3, 0, 1)
    other = MavlinkDecoder([SignalSpec("throttle_pct", "VFR_HUD", "throttle", "pct")])
    assert _values(other, _pack(hud)) == {"throttle_pct": [64.0]}


def test_the_airspeed_sensor_temperature_of_zero_means_none() -> None:
    decoder = MavlinkDecoder(default_specs(["oat_c"]))
    assert _values(decoder, _pack(ML.MAVLink_scaled_pressure_message(0, 1000.0, 0.0, 0, 0))) == {}
    assert decoder.counters["unknown_value"] == 1


def test_an_array_element_is_read_and_text_fields_are_refused() -> None:
    decoder = MavlinkDecoder([SignalSpec("egt_c", "ESC_TELEMETRY_1_TO_4", "temperature[2]", "degC")])
    esc = ML.MAVLink_esc_telemetry_1_to_4_message([1, 2, 77, 4], [0] * 4, [0] * 4, [0] * 4, [0] * 4, [0] * 4)
    assert _values(decoder, _pack(esc)) == {"egt_c": [77.0]}
    for bad, word in (
        ("STATUSTEXT.text", "text"),
        ("EFI_STATUS.nope", "no field"),
        ("NO_SUCH_MESSAGE.x", "no MAVLink message"),
        ("ESC_TELEMETRY_1_TO_4.temperature", "array"),
        ("ESC_TELEMETRY_1_TO_4.temperature[4]", "elements"),
        ("EFI_STATUS.rpm[0]", "not an array"),
        ("efi_status.rpm", "MESSAGE.field"),
    ):
        with pytest.raises(ConfigError, match=word):
            parse_field(bad)


def test_a_unit_that_disagrees_with_the_message_definition_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"fuel_flow is in cm\^3/min .* give unit cc_per_min, got lph"):
        MavlinkDecoder([SignalSpec("fuel_flow_lph", "EFI_STATUS", "fuel_flow", "lph")])
    with pytest.raises(ConfigError, match="give unit cdegC"):
        MavlinkDecoder([SignalSpec("oat_c", "SCALED_PRESSURE", "temperature_press_diff", "degC")])
    MavlinkDecoder([SignalSpec("cht_c", "EFI_STATUS", "cylinder_head_temperature", "K")])  # declared kelvin


def test_only_the_accepted_sender_is_read_and_the_services_own_messages_are_ignored() -> None:
    decoder = MavlinkDecoder(default_specs(["rpm"]), source_system=1, source_component=1, own=(1, 191))
    data = _pack(_efi(rpm=1000.0), system=1, component=1)
    data += _pack(_efi(rpm=2000.0), system=2, component=1)
    data += _pack(_efi(rpm=3000.0), system=1, component=42)
    data += _pack(_efi(rpm=4000.0), system=1, component=191)
    data += _pack(ML.MAVLink_heartbeat_message(1, 3, 0, 0, 4, 3))
    assert _values(decoder, data) == {"rpm": [1000.0]}
    counts = decoder.counters
    assert (counts["ok"], counts["filtered_source"], counts["ignored"], counts["unknown_id"]) == (1, 2, 1, 1)
    anyone = MavlinkDecoder(default_specs(["rpm"]))
    assert _values(anyone, data) == {"rpm": [1000.0, 2000.0, 3000.0, 4000.0]}


def test_kelvin_in_a_degc_field_is_told_once_and_converted_when_declared(caplog: pytest.LogCaptureFixture) -> None:
    decoder = MavlinkDecoder(default_specs(["cht_c", "intake_temp_c"]))
    with caplog.at_level("WARNING"):
        got = _values(decoder, _pack(_efi(rpm=0.0, cht=293.0), _efi(rpm=0.0, cht=294.0)))
    assert got["cht_c"] == [293.0, 294.0]  # passed on as the definition says: no guess
    assert len(decoder.warnings) == 1 and "EFI_STATUS.cylinder_head_temperature reads 293.0 degC" in decoder.warnings[0]
    assert "unit: K" in decoder.warnings[0] and len(caplog.records) == 1
    # a hot engine running at 260 degC is a real reading, not kelvin
    hot = MavlinkDecoder(default_specs(["cht_c"]))
    _values(hot, _pack(_efi(rpm=5000.0, cht=260.0)))
    assert hot.warnings == []
    declared = MavlinkDecoder([SignalSpec("cht_c", "EFI_STATUS", "cylinder_head_temperature", "K")])
    assert _values(declared, _pack(_efi(rpm=0.0, cht=293.15))) == {"cht_c": [pytest.approx(20.0)]}
    assert declared.warnings == []
    _values(declared, _pack(_efi(rpm=5000.0, cht=120.0)))  # declared kelvin, reads like degC
    assert len(declared.warnings) == 1 and "mapped with unit K" in declared.warnings[0]
    assert kelvin_like("intake_manifold_temperature", 290.0, None) and not kelvin_like("x", 40.0, None)
    assert not kelvin_like("cylinder_head_temperature", 300.0, None)  # no rpm: no verdict on a hot engine
    assert kelvin_like("cylinder_head_temperature", 430.0, 5000.0)  # no head runs at 430 degC: a warm one in kelvin
    assert not kelvin_like("exhaust_gas_temperature", 700.0, 5000.0)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.binary(max_size=300), max_size=8), st.binary(max_size=40))
def test_random_bytes_never_raise_and_every_piece_is_counted(chunks: list[bytes], prefix: bytes) -> None:
    decoder = MavlinkDecoder(default_specs())
    valid = _pack(_efi())
    for chunk in chunks:
        # bytes that start like a frame reach deeper into the parser than plain noise
        for data in (chunk, b"\xfd" + chunk, b"\xfe" + chunk, prefix + valid + chunk):
            decoder.parse_bytes(data)
    c = decoder.counters
    assert c["frames"] == c["ok"] + c["unknown_id"] + c["malformed"] + c["filtered_source"] + c["ignored"]
    assert c["malformed"] == c["garbage"] + c["bad_crc"] + c["bad_length"] + c["decode_error"]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(width=32), min_size=4, max_size=4), st.integers(0, 255), st.integers(0, 65535))
def test_any_field_values_decode_to_finite_numbers_or_none(floats: list[float], seq: int, throttle: int) -> None:
    rpm, cht, flow, alt = floats
    decoder = MavlinkDecoder(default_specs())
    msgs = [
        _efi(rpm=rpm, cht=cht, flow=flow),
        ML.MAVLink_vfr_hud_message(flow, 0.0, 0, throttle, alt, 0.0),
        ML.MAVLink_scaled_pressure_message(0, alt, 0.0, 0, throttle - 32768),
    ]
    for slot, value in decoder.parse_bytes(_pack(*msgs)):
        assert math.isfinite(value), decoder.names[slot]


def test_connection_strings_as_mavproxy_takes_them() -> None:
    assert parse_connection("udpin:0.0.0.0:14550")[:3] == ("udpin", "0.0.0.0", 14550)
    assert parse_connection("tcp:192.168.1.2:5760")[:3] == ("tcp", "192.168.1.2", 5760)
    serial = parse_connection("/dev/ttyACM0,57600")
    assert (serial.kind, serial.device, serial.baud, serial.device_string) == (
        "serial",
        "/dev/ttyACM0",
        57600,
        "/dev/ttyACM0",
    )
    assert parse_connection("/dev/ttyUSB0").baud == 115200
    for bad in ("udpin:0.0.0.0", "udpin:host:99999", "ftp:host:21", "/dev/ttyACM0,fast", ""):
        with pytest.raises(ConfigError):
            parse_connection(bad)
    assert emitter_connection("udpin:0.0.0.0:14550") == "udpout:127.0.0.1:14550"
    assert emitter_connection("tcp:127.0.0.1:5760") == "tcpin:0.0.0.0:5760"
    with pytest.raises(ConfigError, match="--connection"):
        emitter_connection("/dev/ttyACM0,115200")


# --- the config ---------------------------------------------------------------------------------


def test_the_shipped_config_loads_and_bad_mavlink_keys_name_file_and_key(tmp_path: Path) -> None:
    config = load_config("mavlink.yaml")
    assert config.protocol == "mavlink" and config.bus == {}
    assert config.mavlink == MavlinkSettings()
    assert config.input("cht_c").message == "EFI_STATUS" and config.input("altitude_m").unit == "hPa"
    base = yaml.safe_load(SHIPPED.read_text(encoding="utf-8"))

    def bad(change: dict[str, Any], where: str) -> None:
        data = {**base, **change}
        with pytest.raises(ConfigError) as err:
            parse_config(data, tmp_path / "m.yaml")
        text = str(err.value)
        assert text.startswith(f"{tmp_path / 'm.yaml'}: {where}"), text
        assert "\n" not in text

    bad({"bus": {"interface": "virtual", "channel": "x"}}, "bus")
    bad({"mavlink": {"connection": "ftp:x:1"}}, "mavlink.connection")
    bad({"mavlink": {"colour": 1}}, "mavlink.colour")
    bad({"mavlink": {"component_id": 300}}, "mavlink.component_id")
    bad({"mavlink": {"statustext_per_s": 0}}, "mavlink.statustext_per_s")
    bad({"mavlink": {"efi_status_out": True}}, "mavlink")  # inputs from EFI_STATUS: never echoed
    bad({"mavlink": {"system_id": 1, "component_id": 1}}, "mavlink.component_id")
    inputs = {**base["inputs"], "fuel_flow_lph": {"field": "EFI_STATUS.fuel_flow", "unit": "lph", "stale_after_s": 1}}
    bad({"inputs": inputs}, "inputs")
    inputs = {**base["inputs"], "rpm": {"field": "EFI_STATUS.rpmm", "unit": "rpm", "stale_after_s": 1}}
    bad({"inputs": inputs}, "inputs.rpm.field")
    example = yaml.safe_load((SHIPPED.parent / "example.yaml").read_text(encoding="utf-8"))
    with pytest.raises(ConfigError, match="mavlink: applies to protocol mavlink only"):
        parse_config({**example, "mavlink": {}}, tmp_path / "e.yaml")


# --- the publisher ------------------------------------------------------------------------------


def _snap(
    state: str, t: float = 0.0, gq: float = 1.0, gd: float = 1.0, cht: float = 150.0, **kw: Any
) -> HealthSnapshot:
    values = {"deviation": 0.02, "headroom_s": 900.0, **kw}
    return HealthSnapshot(
        time_s=t,
        cht_meas_c=cht,
        cht_est_c=cht,
        state=state,
        gamma_q=gq,
        gamma_d=gd,
        stale_inputs=values.pop("stale", ()),
        **values,
    )


def _cyl(n: int, cht: float, dev: float, state: str, gq: float, gd: float, headroom: float) -> CylinderSnapshot:
    return CylinderSnapshot(
        number=n, cht_meas_c=cht, cht_est_c=cht, deviation=dev, state=state, gamma_q=gq, gamma_d=gd, headroom_s=headroom
    )


def _parse(data: bytes) -> list[Any]:
    parser = ML.MAVLink(None)
    parser.robust_parsing = True
    return parser.parse_buffer(data) or []


def test_publisher_heartbeat_names_the_component_and_its_state() -> None:
    pub = MavlinkPublisher(MavlinkSettings(), 180.0)
    got = _parse(pub.encode(pub.messages(0.0, _snap("NOMINAL"))))
    beat = next(m for m in got if m.get_type() == "HEARTBEAT")
    assert (beat.get_srcSystem(), beat.get_srcComponent()) == (1, 191)
    assert (beat.type, beat.autopilot, beat.system_status) == (
        ML.MAV_TYPE_ONBOARD_CONTROLLER,
        ML.MAV_AUTOPILOT_INVALID,
        ML.MAV_STATE_ACTIVE,
    )
    statuses = {}
    for k, state in enumerate(("DEGRADED", "UNAVAILABLE", "SUSPECT")):
        msgs = pub.messages(10.0 * (k + 1), _snap(state))
        statuses[state] = next(m for m in msgs if m.get_type() == "HEARTBEAT").system_status
    assert statuses == {"DEGRADED": ML.MAV_STATE_CRITICAL, "UNAVAILABLE": ML.MAV_STATE_STANDBY, "SUSPECT": 4}
    hot = pub.messages(50.0, _snap("NOMINAL", cht=181.0))
    assert next(m for m in hot if m.get_type() == "HEARTBEAT").system_status == ML.MAV_STATE_EMERGENCY
    # 1 Hz while nothing changes
    beats = [
        t for t in np.arange(60.0, 70.0, 0.1) for m in pub.messages(float(t), _snap("NOMINAL", cht=181.0))
        if m.get_type() == "HEARTBEAT"
    ]  # fmt: skip
    assert len(beats) == 10


def test_statustext_wording_severity_and_chunks_of_at_most_50() -> None:
    assert state_text(_snap("DEGRADED", gq=1.18)) == "ENGINE: heat-in +18 %, DEGRADED"
    assert state_text(_snap("SUSPECT", gq=1.02, gd=0.88)) == "ENGINE: cooling -12 %, SUSPECT"
    assert state_text(_snap("SUSPECT", gq=1.03, gd=1.01)) == "ENGINE: CHT +0.02 C/s off model, SUSPECT"
    cyl = _cyl(3, 190.0, 0.1, "DEGRADED", 1.18, 0.9, 300.0)
    other = _cyl(1, 150.0, 0.0, "NOMINAL", 1.0, 1.0, 900.0)
    multi = _snap(
        "DEGRADED",
        gq=1.18,
        gd=0.9,
        cht=190.0,
        deviation=0.1,
        headroom_s=300.0,
        cylinders=(other, cyl),
        cht_spread_c=40.0,
        hottest_cylinder=3,
        lead_cylinder=3,
    )
    assert state_text(multi) == "ENGINE cyl 3: heat-in +18 %, cooling -10 %, DEGRADED"
    assert state_text(_snap("INPUT_STALE", stale=("cht_c", "airspeed_mps"))) == (
        "ENGINE monitor: CHT+airspeed lost, INPUT_STALE"
    )
    for state in STATES:
        assert len(state_text(_snap(state, gq=1.5, gd=0.5))) <= MAX_TEXT, state
    long = "x" * 120
    assert text_chunks(long) == ["x" * 50, "x" * 50, "x" * 20]
    assert text_chunks("y" * 100) == ["y" * 50, "y" * 50, ""]  # the last chunk is the shorter one (MAVProxy)
    assert text_chunks(long, mavlink1=True) == ["x" * 47 + "..."]
    assert SEVERITY["NOMINAL"] == ML.MAV_SEVERITY_INFO and SEVERITY["SUSPECT"] == ML.MAV_SEVERITY_WARNING
    assert SEVERITY["DEGRADED"] == SEVERITY["SENSOR_FAULT"] == ML.MAV_SEVERITY_CRITICAL
    # a long text goes in chunks that a receiver joins by id and chunk_seq
    pub = MavlinkPublisher(MavlinkSettings(statustext_per_s=10), 180.0)
    pub.messages(0.0, _snap("NOMINAL"))
    texts = [m for m in _parse(pub.encode(pub.messages(0.1, _snap("INPUT_STALE", stale=tuple(STALE_ALL)))))
             if m.get_type() == "STATUSTEXT"]  # fmt: skip
    assert len(texts) > 1 and all(len(m.text) <= MAX_TEXT for m in texts)
    assert (
        len({m.id for m in texts}) == 1 and texts[0].id != 0 and [m.chunk_seq for m in texts] == list(range(len(texts)))
    )
    assert "".join(m.text for m in texts) == pub.sent_texts[-1][0]
    assert all(m.severity == ML.MAV_SEVERITY_WARNING for m in texts)


STALE_ALL = ("rpm", "throttle_pct", "cht_c", "oat_c", "altitude_m", "airspeed_mps", "fuel_flow_lph")


def test_statustext_rate_limit_delays_and_merges_but_never_drops_a_state() -> None:
    pub = MavlinkPublisher(MavlinkSettings(statustext_per_s=1.0), 180.0)
    sent: list[tuple[float, str, int]] = []
    states = ["NOMINAL"] * 5 + ["SUSPECT", "DEGRADED", "SUSPECT", "NOMINAL", "SENSOR_FAULT"] + ["SENSOR_FAULT"] * 40
    for k, state in enumerate(states):
        t = 0.1 * k
        for m in pub.messages(t, _snap(state, t=t, gq=1.2)):
            if m.get_type() == "STATUSTEXT" and m.chunk_seq == 0:
                sent.append((t, m.text, m.severity))
    times = [t for t, _, _ in sent]
    assert all(b - a >= 1.0 - 1e-9 for a, b in itertools.pairwise(times))  # at most one a second
    told = " ".join(text for text, _ in pub.sent_texts)
    for state in ("SUSPECT", "DEGRADED", "NOMINAL", "SENSOR_FAULT"):
        assert state in told, state  # each state is in some text: delayed, merged, never dropped
    merged = pub.sent_texts[-1]
    assert merged[0].startswith("ENGINE: CHT probe fault, SENSOR_FAULT (via ") and merged[1] == ML.MAV_SEVERITY_CRITICAL
    assert pub.sent_texts[-1][0].endswith("(via SUSPECT, DEGRADED, SUSPECT, NOMINAL)")


def test_inputs_lost_after_the_input_stale_text_are_told_again_with_the_whole_set() -> None:
    """A dropped link: the inputs of the 5 Hz messages go stale first, EFI_STATUS's 0.1 s later; the pilot is
    told the first, then all (and nothing more while the set does not grow)."""
    pub = MavlinkPublisher(MavlinkSettings(), 180.0)
    slow, fast = ("oat_c", "altitude_m", "airspeed_mps"), ("rpm", "throttle_pct", "cht_c", "fuel_flow_lph")
    snaps = [_snap("NOMINAL")] * 3 + [_snap("INPUT_STALE", stale=slow)] + [_snap("INPUT_STALE", stale=slow + fast)] * 3
    snaps += [_snap("INPUT_STALE", stale=fast)] * 2 + [_snap("NOMINAL")] * 5
    for k, snap in enumerate(snaps):
        pub.messages(0.1 * k, snap)
    texts = [text for text, _ in pub.sent_texts]
    assert texts[1:] == [
        "ENGINE monitor: OAT+altitude+airspeed lost, INPUT_STALE",
        "ENGINE monitor: OAT+altitude+airspeed+rpm+throttle+CHT+fuel flow lost, INPUT_STALE",
        "ENGINE: normal, NOMINAL, CHT 150 C",
    ], texts
    assert [sev for _, sev in pub.sent_texts[1:3]] == [ML.MAV_SEVERITY_WARNING] * 2
    # a text still waiting for the rate takes the whole set: one text, no "(via INPUT_STALE)"
    pub = MavlinkPublisher(MavlinkSettings(statustext_per_s=1.0), 180.0)
    for k, snap in enumerate([_snap("NOMINAL"), _snap("INPUT_STALE", stale=slow), _snap("INPUT_STALE", stale=fast)]):
        pub.messages(0.1 * k, snap)
    for k in range(3, 20):
        pub.messages(0.1 * k, _snap("INPUT_STALE", stale=slow + fast))
    assert [text for text, _ in pub.sent_texts][1:] == [
        "ENGINE monitor: OAT+altitude+airspeed+rpm+throttle+CHT+fuel flow lost, INPUT_STALE"
    ]


def test_named_value_float_names_rate_and_values() -> None:
    pub = MavlinkPublisher(MavlinkSettings(named_value_hz=2.0), 180.0)
    names: list[str] = []
    for k in range(20):  # 2 s of health-status periods
        for m in _parse(pub.encode(pub.messages(0.1 * k, _snap("DEGRADED", gq=1.18)))):
            if m.get_type() == "NAMED_VALUE_FLOAT":
                names.append(m.name)
                if m.name == "GAMMA_Q":
                    assert m.value == pytest.approx(1.18)
    # one channel: the output table's per-cylinder names for cylinder 1, then the engine's, in table order
    rows = [v.mavlink for v in HEALTH_VALUES if v.mavlink and v.scope != "cylinders"]
    one = [m.format(n=1) for m in rows if "{n}" in m] + [m for m in rows if "{n}" not in m]
    assert {"CHT1_EST", "HDRM1", "ENG_DEV", "ENG_ST", "GAMMA_Q", "GAMMA_D"} <= set(one)
    assert names == one * 4
    cyls = tuple(_cyl(n, 150.0, 0.0, "NOMINAL", 1.0, 1.0, 900.0) for n in range(1, 17))
    snap = _snap("NOMINAL", deviation=0.0, cylinders=cyls, cht_spread_c=12.0, hottest_cylinder=16)
    multi = [name for name, _ in named_values(snap)]
    assert {"CHT16_EST", "HDRM16", "CHT_SPRD", "CHT_HOT", "GAMMA_Q"} <= set(multi)
    assert all(len(name) <= MAX_NAME for name in multi) and len(set(multi)) == len(multi)
    silent = MavlinkPublisher(MavlinkSettings(named_value_hz=0.0), 180.0)
    assert not [m for m in silent.messages(0.0, _snap("NOMINAL")) if m.get_type() == "NAMED_VALUE_FLOAT"]


def test_efi_status_out_only_when_configured_and_never_for_efi_status_inputs() -> None:
    with pytest.raises(ConfigError, match="must not echo"):
        MavlinkPublisher(MavlinkSettings(efi_status_out=True), 180.0, input_messages=("EFI_STATUS", "VFR_HUD"))
    inputs = {"rpm": 5200.0, "throttle_pct": 61.0, "fuel_flow_lph": 15.0, "altitude_m": 0.0}
    off = MavlinkPublisher(MavlinkSettings(), 180.0)
    assert not [m for m in off.messages(0.0, _snap("NOMINAL"), inputs) if m.get_type() == "EFI_STATUS"]
    pub = MavlinkPublisher(MavlinkSettings(efi_status_out=True), 180.0, input_messages=("SOME_CAN_ECU",))
    efi = [m for m in _parse(pub.encode(pub.messages(0.0, _snap("NOMINAL", cht=171.0), inputs)))
           if m.get_type() == "EFI_STATUS"]  # fmt: skip
    assert len(efi) == 1
    decoder = MavlinkDecoder(default_specs(["rpm", "throttle_pct", "cht_c", "fuel_flow_lph", "baro_pressure_kpa"]))
    got = dict(decoder.decode(efi[0]) or [])
    values = {decoder.names[slot]: value for slot, value in got.items()}
    assert values["rpm"] == 5200.0 and values["cht_c"] == 171.0
    assert values["fuel_flow_lph"] == pytest.approx(15.0, rel=1e-6)
    assert values["baro_pressure_kpa"] == pytest.approx(101.325, rel=1e-6)


# --- logs and links -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def mavlink_flight(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One virtual flight recorded by `virtual-ecu record --protocol mavlink` to a .tlog and its own CSV."""
    tmp = tmp_path_factory.mktemp("mavlink_flight")
    mission = tmp / "mission.yaml"
    mission.write_text(yaml.safe_dump(MISSION), encoding="utf-8")
    tlog, csv = tmp / "flight.tlog", tmp / "flight.csv"
    argv = ["record", "--mission", str(mission), "--protocol", "mavlink", "--out", str(tlog), "--out", str(csv)]
    assert virtual_ecu_main([*argv, "--start-time", "1700000000"]) == 0
    return {"tlog": tlog, "csv": csv, "mission": mission, "dir": tmp}


def test_a_recorded_tlog_reads_back_to_the_virtual_ecus_own_csv(mavlink_flight: dict[str, Path]) -> None:
    log = read_tlog(mavlink_flight["tlog"])
    truth = read_csv(mavlink_flight["csv"])
    assert log.notes == () and len(log) == len(truth)
    assert np.allclose(log.time_s, truth.time_s)
    # EFI_STATUS at 10 Hz carries the ECU's CHT at the CSV's own instants: equal within the 1 degC quantum
    assert np.max(np.abs(log["cht_c"] - truth["cht_c"])) <= 1.0
    assert np.mean(log["cht_c"] == truth["cht_c"]) > 0.99
    assert np.allclose(log["rpm"], truth["rpm"], atol=0.01)  # float32 of the same sample
    assert np.allclose(log["fuel_flow_lph"], truth["fuel_flow_lph"], rtol=1e-5)
    # the 5 Hz air data is held for one CSV row in two: within the sensor noise of the row before
    assert np.max(np.abs(log["oat_c"] - truth["oat_c"])) < 1.0
    assert np.max(np.abs(log["altitude_m"] - truth["altitude_m"])) < 15.0


def test_import_of_a_tlog_writes_the_canonical_csv(mavlink_flight: dict[str, Path], capsys: Any) -> None:
    out = mavlink_flight["dir"] / "imported.csv"
    assert ecu_monitor_main(["import", str(mavlink_flight["tlog"]), "--out", str(out)]) == 0
    assert "rows" in capsys.readouterr().out
    imported = read_csv(out)
    assert np.array_equal(imported["cht_c"], read_tlog(mavlink_flight["tlog"])["cht_c"])
    empty = mavlink_flight["dir"] / "empty.tlog"
    empty.write_bytes(b"")
    assert ecu_monitor_main(["import", str(empty), "--out", str(out)]) == 2
    assert "no MAVLink message" in capsys.readouterr().err


def test_a_tlog_of_an_autopilot_without_efi_names_what_is_missing(tmp_path: Path) -> None:
    tlog = tmp_path / "no_efi.tlog"
    encoder = MavlinkFrameEncoder(rates={"HEARTBEAT": 1.0, "VFR_HUD": 5.0}, start_time_s=1.7e9)
    writer = TlogWriter(tlog)
    for frame in encoder.iter_frames(iter_steps(load_mission(str(_mission(tmp_path))), paper_table_a1())):
        writer.on_message_received(frame)
    writer.stop()
    with pytest.raises(FlightLogError, match=r"no rpm, oat_c, cht_c in the log .*EFI_STATUS.rpm"):
        read_tlog(tlog)


def _mission(tmp: Path) -> Path:
    path = tmp / "mission.yaml"
    path.write_text(yaml.safe_dump(MISSION), encoding="utf-8")
    return path


def test_a_sender_of_kelvin_is_told_in_the_import_notes(tmp_path: Path) -> None:
    tlog = tmp_path / "px4.tlog"
    writer = TlogWriter(tlog)
    encoder = MavlinkFrameEncoder(kelvin_in_celsius=True, start_time_s=1.7e9)
    for frame in encoder.iter_frames(iter_steps(load_mission(str(_mission(tmp_path))), paper_table_a1())):
        writer.on_message_received(frame)
    writer.stop()
    log = read_tlog(tlog)
    assert len(log.notes) == 1 and "kelvin in a degC field" in log.notes[0]


def test_record_refuses_a_tlog_without_mavlink_and_a_can_log_with_it(tmp_path: Path, capsys: Any) -> None:
    mission = str(_mission(tmp_path))
    assert virtual_ecu_main(["record", "--mission", mission, "--out", str(tmp_path / "x.tlog")]) == 2
    assert "give --protocol mavlink" in capsys.readouterr().err
    argv = ["record", "--mission", mission, "--protocol", "mavlink", "--out", str(tmp_path / "x.asc")]
    assert virtual_ecu_main(argv) == 2
    assert "MAVLink is not on CAN" in capsys.readouterr().err


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def test_the_emitters_stream_crosses_udp_to_a_pymavlink_reader(tmp_path: Path) -> None:
    from pymavlink import mavutil

    port = _free_udp_port()
    reader = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}")
    received: list[Any] = []
    done = threading.Event()

    def read() -> None:
        quiet_since = time.monotonic()
        while not done.is_set() or time.monotonic() - quiet_since < 0.5:
            msg = reader.recv_match(blocking=True, timeout=0.1)
            if msg is None:
                continue
            quiet_since = time.monotonic()
            received.append(msg)

    thread = threading.Thread(target=read, daemon=True)
    thread.start()
    emitter = MavlinkEmitter(f"udpout:127.0.0.1:{port}", MavlinkFrameEncoder(), realtime=True, speed=40.0)
    try:
        stats = emitter.emit(iter_steps(load_mission(str(_mission(tmp_path))), paper_table_a1()))
    finally:
        emitter.close()
        done.set()
        thread.join(timeout=10.0)
        reader.close()
    assert stats.frames_sent > 2500 and stats.send_errors == 0  # ~140 s at 21 messages a second
    kinds = {m.get_type() for m in received}
    assert {"HEARTBEAT", "EFI_STATUS", "VFR_HUD", "SCALED_PRESSURE"} <= kinds
    assert len(received) >= 0.95 * stats.frames_sent  # loopback UDP, paced: none or next to none lost
    assert all((m.get_srcSystem(), m.get_srcComponent()) == (1, 1) for m in received)
    decoder = MavlinkDecoder([spec.signal_spec() for spec in load_config("mavlink.yaml").inputs], 1, 1)
    got: dict[str, float] = {}
    for msg in received:
        for slot, value in decoder.decode(msg) or ():
            got[decoder.names[slot]] = value
    assert set(got) == {"rpm", "throttle_pct", "fuel_flow_lph", "cht_c", "oat_c", "airspeed_mps", "altitude_m"}
    assert decoder.counters["malformed"] == 0 and decoder.warnings == []
    assert 20.0 < got["airspeed_mps"] < 26.0 and 200.0 < got["altitude_m"] < 300.0


def test_the_publishers_bytes_reach_a_pymavlink_reader_over_udp() -> None:
    from pymavlink import mavutil

    port = _free_udp_port()
    reader = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}")
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        pub = MavlinkPublisher(MavlinkSettings(), 180.0)
        for k, state in enumerate(["UNAVAILABLE", "NOMINAL", "NOMINAL", "DEGRADED"]):
            sender.sendto(pub.encode(pub.messages(1.5 * k, _snap(state, gq=1.18))), ("127.0.0.1", port))
        texts = []
        deadline = time.monotonic() + 5.0
        while len(texts) < 3 and time.monotonic() < deadline:
            msg = reader.recv_match(type="STATUSTEXT", blocking=True, timeout=0.2)
            if msg is not None:
                texts.append((msg.severity, msg.text))
    finally:
        sender.close()
        reader.close()
    assert texts == [
        (ML.MAV_SEVERITY_NOTICE, "ENGINE monitor: started, UNAVAILABLE"),
        (ML.MAV_SEVERITY_INFO, "ENGINE: normal, NOMINAL, CHT 150 C"),
        (ML.MAV_SEVERITY_CRITICAL, "ENGINE: heat-in +18 %, DEGRADED"),
    ]


@pytest.mark.slow
def test_demo_over_mavlink_tells_the_pilot_nominal_then_degraded(tmp_path: Path, capsys: Any) -> None:
    """``ecu-monitor demo --protocol mavlink``: the virtual autopilot's messages into the service, its STATUSTEXT
    printed and written; gamma_Q 1.2 after the detector's warm-up gives SUSPECT then DEGRADED, critical."""
    from ecu_monitor.cli import main

    out = tmp_path / "d"
    args = ["demo", "--protocol", "mavlink", "--mission", "short_hop", "--inject-at", "650", "--out", str(out)]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "MAVLink messages from the virtual autopilot" in printed and " 0 malformed" in printed
    lines = (out / "statustext.csv").read_text(encoding="utf-8").splitlines()
    texts = [t for t in lines if '"ENGINE cyl ' not in t]  # the engine events' texts (shock cooling) aside
    assert lines[0] == "time_s,severity,text"
    assert all(re.search(r',WARNING,"ENGINE cyl \d: [a-z ]+ [-+]\d+ ', t) for t in lines if t not in texts)
    assert texts[1].startswith('0.1,INFO,"ENGINE: monitoring, NOMINAL, CHT ')
    # the cause as the isolation tells it once the split is identifiable, "not isolable" until then
    cause = r"(heat-in \+\d+ %|CHT \+\d\.\d\d C/s off model, cause not isolable)"
    assert re.fullmatch(rf'\d+\.\d,CRITICAL,"ENGINE: {cause}, DEGRADED"', texts[-1]), texts
    assert float(texts[-1].split(",")[0]) > 650.0 and "DEGRADED at t = " in printed
    assert re.search(rf"CRITICAL  ENGINE: {cause}", printed)
    assert (out / "health.csv").stat().st_size > 1000
    assert main(["demo", "--protocol", "mavlink", "--cylinders", "2", "--out", str(out)]) == 2
    assert "EFI_STATUS carries one CHT" in capsys.readouterr().err
