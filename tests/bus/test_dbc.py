"""The DBC contract: engine.dbc (frames in) and health.dbc (frames out), and the frame checksum."""

from __future__ import annotations

import random
from pathlib import Path
from typing import Any

import cantools
import pytest

from ecu_monitor.bus.checksum import crc8_sae_j1850, frame_checksum
from tests.helpers import REPO

DBC_DIR = REPO / "ecu_monitor" / "data" / "dbc"

#: file -> message -> (frame id, cycle time ms, sender, signal names). Other engineers code against these.
CONTRACT: dict[str, dict[str, tuple[int, int, str, tuple[str, ...]]]] = {
    "engine.dbc": {
        "ECU_Fast": (0x100, 20, "ECU", ("EngineSpeed", "ThrottlePos", "FuelFlow", "FastCounter", "FastChecksum")),
        "ECU_Slow": (0x101, 100, "ECU", ("CHT", "OAT", "EcuStatus", "ManifoldPressure", "SlowCounter", "SlowChecksum")),
        "AirData": (
            0x200,
            100,
            "Autopilot",
            ("PressureAltitude", "CalibratedAirspeed", "VerticalSpeed", "AirDataCounter", "AirDataChecksum"),
        ),
    },
    "health.dbc": {
        "Health_Status": (
            0x300,
            100,
            "EcuMonitor",
            (
                "ChtEstimate",
                "ModelDeviation",
                "DegradationState",
                "ChtRate",
                "HealthCounter",
                "HealthChecksum",
            ),
        ),
        "Health_Isolation": (
            0x301,
            500,
            "EcuMonitor",
            (
                "GammaQEstimate",
                "GammaDEstimate",
                "ThermalHeadroom",
                "ChtLimitMargin",
                "IsolationCounter",
                "IsolationChecksum",
            ),
        ),
        "Health_Diag": (
            0x302,
            1000,
            "EcuMonitor",
            (
                "StaleInputs",
                "MalformedFrames",
                "BusErrors",
                "StaleInputsHigh",
                "MaintenanceAlert",
                "DetectorArmed",
                "NotIsolable",
                "HistoryDown",
                "DiagCounter",
                "DiagChecksum",
            ),
        ),
        "Health_Spread": (
            0x303,
            500,
            "EcuMonitor",
            (
                "ChtSpread",
                "HottestCylinder",
                "SpreadAlarm",
                "CylinderCount",
                "FaultyCylinders",
                "SpreadCounter",
                "SpreadChecksum",
            ),
        ),
        "Health_Cylinder": (
            0x304,
            500,
            "EcuMonitor",
            (
                "CylinderNumber",
                "CylChtEstimate",
                "CylState",
                "CylGammaQ",
                "CylGammaD",
                "CylNotIsolable",
                "CylCounter",
                "CylChecksum",
            ),
        ),
        "Health_Event": (
            0x305,
            None,  # sent when an engine event starts
            "EcuMonitor",
            ("EventKind", "EventCylinder", "EventValue", "EventLimit", "EventCounter", "EventChecksum"),
        ),
    },
    "cylinders.dbc": {
        "ECU_Cht1to4": (0x102, 100, "ECU", ("CHT1", "CHT2", "CHT3", "CHT4", "Cht1to4Counter", "Cht1to4Checksum")),
        "ECU_Cht5to8": (0x103, 100, "ECU", ("CHT5", "CHT6", "CHT7", "CHT8", "Cht5to8Counter", "Cht5to8Checksum")),
        "ECU_Egt1to4": (0x104, 100, "ECU", ("EGT1", "EGT2", "EGT3", "EGT4", "Egt1to4Counter", "Egt1to4Checksum")),
        "ECU_Oil": (0x105, 1000, "ECU", ("OilTemp", "OilCounter", "OilChecksum")),
    },
}

#: message.signal -> (unit, at least this min, at least this max, resolution at most)
RANGES: dict[str, tuple[str, float, float, float]] = {
    "ECU_Fast.EngineSpeed": ("rpm", 0, 16000, 0.5),
    "ECU_Fast.ThrottlePos": ("%", 0, 100, 0.01),
    "ECU_Fast.FuelFlow": ("L/h", 0, 50, 0.01),
    "ECU_Slow.CHT": ("degC", -40, 400, 0.1),
    "ECU_Slow.OAT": ("degC", -60, 80, 0.1),
    "AirData.PressureAltitude": ("m", -500, 10000, 0.5),
    "AirData.CalibratedAirspeed": ("m/s", 0, 100, 0.01),
    "AirData.VerticalSpeed": ("m/s", -30, 30, 0.01),
    "Health_Status.ChtEstimate": ("degC", -40, 400, 0.1),
    "Health_Status.ModelDeviation": ("degC/s", -10, 10, 0.001),
    "Health_Isolation.GammaQEstimate": ("", 0.5, 2.5, 0.001),
    "Health_Isolation.GammaDEstimate": ("", 0.5, 2.5, 0.001),
    "Health_Isolation.ThermalHeadroom": ("s", 0, 6000, 1),
    "Health_Isolation.ChtLimitMargin": ("degC", -200, 300, 0.1),
    "Health_Diag.MalformedFrames": ("", 0, 65535, 1),
    "Health_Diag.BusErrors": ("", 0, 255, 1),
    "ECU_Cht1to4.CHT1": ("degC", -40, 350, 0.1),
    "ECU_Cht5to8.CHT8": ("degC", -40, 350, 0.1),
    "ECU_Egt1to4.EGT4": ("degC", 0, 1000, 0.25),
    "ECU_Oil.OilTemp": ("degC", -40, 200, 0.1),
    "Health_Spread.ChtSpread": ("degC", 0, 400, 0.1),
    "Health_Spread.HottestCylinder": ("", 0, 16, 1),
    "Health_Spread.FaultyCylinders": ("", 0, 65535, 1),
    "Health_Cylinder.CylinderNumber": ("", 1, 16, 1),
    "Health_Cylinder.CylChtEstimate": ("degC", -40, 400, 0.1),
    "Health_Cylinder.CylGammaQ": ("", 0.5, 2.5, 0.001),
    "Health_Cylinder.CylGammaD": ("", 0.5, 2.5, 0.001),
    "Health_Event.EventValue": ("", -3276.8, 3276.7, 0.1),
    "Health_Event.EventLimit": ("", -3276.8, 3276.7, 0.1),
}

CHOICES: dict[str, dict[int, str]] = {
    "ECU_Slow.EcuStatus": {0: "OK", 1: "WARNING", 2: "FAULT", 3: "CHT_SENSOR_OPEN"},
    "Health_Status.DegradationState": {
        0: "NOMINAL",
        1: "SUSPECT",
        2: "DEGRADED",
        3: "INPUT_STALE",
        4: "SENSOR_FAULT",
        5: "UNAVAILABLE",
    },
    "Health_Cylinder.CylState": {
        0: "NOMINAL",
        1: "SUSPECT",
        2: "DEGRADED",
        3: "INPUT_STALE",
        4: "SENSOR_FAULT",
        5: "UNAVAILABLE",
    },
}


def _load(name: str) -> Any:
    return cantools.database.load_file(str(DBC_DIR / name), strict=True)


def _find(dbs: list[Any], ref: str) -> Any:
    msg_name, sig_name = ref.split(".")
    msg = next(db.get_message_by_name(msg_name) for db in dbs if msg_name in {m.name for m in db.messages})
    return msg.get_signal_by_name(sig_name)


@pytest.fixture(scope="module", params=sorted(CONTRACT))
def dbc(request: pytest.FixtureRequest) -> tuple[str, Any]:
    return request.param, _load(request.param)


def _messages() -> list[tuple[str, str]]:
    return [(f, m) for f, msgs in CONTRACT.items() for m in msgs]


def test_contract_names_ids_rates_and_senders(dbc: tuple[str, Any]) -> None:
    name, db = dbc
    assert sorted(m.name for m in db.messages) == sorted(CONTRACT[name])
    for msg_name, (frame_id, cycle_ms, sender, signals) in CONTRACT[name].items():
        msg = db.get_message_by_name(msg_name)
        assert msg.frame_id == frame_id
        assert not msg.is_extended_frame
        assert msg.length == 8
        assert msg.cycle_time == cycle_ms
        assert msg.senders == [sender]
        assert tuple(s.name for s in msg.signals) == signals


def test_counter_and_checksum_positions(dbc: tuple[str, Any]) -> None:
    _, db = dbc
    for msg in db.messages:
        counter, checksum = msg.signals[-2], msg.signals[-1]
        assert counter.name.endswith("Counter") and (counter.start, counter.length) == (48, 4)
        assert checksum.name.endswith("Checksum") and (checksum.start, checksum.length) == (56, 8)
        assert counter.byte_order == checksum.byte_order == "little_endian"
        for sig in msg.signals[:-2]:  # payload stays in bytes 0..5 (+ reserved high nibble of byte 6)
            assert sig.start + sig.length <= 48, sig.name


def test_units_ranges_and_resolution() -> None:
    dbs = [_load(n) for n in CONTRACT]
    for ref, (unit, lo, hi, res) in RANGES.items():
        sig = _find(dbs, ref)
        assert (sig.unit or "") == unit, ref
        assert sig.minimum <= lo and sig.maximum >= hi, ref
        assert sig.scale <= res + 1e-12, ref
        raw_lo = (sig.minimum - sig.offset) / sig.scale
        raw_hi = (sig.maximum - sig.offset) / sig.scale
        span = (-(2 ** (sig.length - 1)), 2 ** (sig.length - 1) - 1) if sig.is_signed else (0, 2**sig.length - 1)
        assert span[0] <= round(raw_lo) and round(raw_hi) <= span[1], f"{ref}: range does not fit the bits"


def test_enumerations() -> None:
    dbs = [_load(n) for n in CONTRACT]
    for ref, choices in CHOICES.items():
        sig = _find(dbs, ref)
        assert {int(k): str(v) for k, v in sig.choices.items()} == choices
        assert (sig.minimum, sig.maximum) == (min(choices), max(choices))


@pytest.mark.parametrize(("dbc_name", "msg_name"), _messages())
def test_round_trip_min_mid_max(dbc_name: str, msg_name: str) -> None:
    msg: Any = _load(dbc_name).get_message_by_name(msg_name)
    mids = {s.name: (s.minimum + s.maximum) / 2 for s in msg.signals}
    for sig in msg.signals:
        for value in (sig.minimum, mids[sig.name], sig.maximum):
            values = dict(mids, **{sig.name: value})
            data = msg.encode(values, strict=True)
            assert len(data) == 8
            decoded = msg.decode(data, decode_choices=False)
            for name, expected in values.items():
                tol = msg.get_signal_by_name(name).scale / 2 + 1e-9
                assert decoded[name] == pytest.approx(expected, abs=tol), (name, value)


def test_out_of_range_is_refused_strict() -> None:
    msg = _load("engine.dbc").get_message_by_name("ECU_Fast")
    values = {"EngineSpeed": 16000.25, "ThrottlePos": 0, "FuelFlow": 0, "FastCounter": 0, "FastChecksum": 0}
    with pytest.raises(cantools.database.EncodeError, match="EngineSpeed"):
        msg.encode(values, strict=True)


# Frames pinned byte for byte (independently checked by hand: little-endian raw = (value - offset) / scale).
GOLDEN_FRAMES = [
    (
        "engine.dbc",
        "ECU_Fast",
        {"EngineSpeed": 5200.25, "ThrottlePos": 63.5, "FuelFlow": 21.37, "FastCounter": 9},
        "4151ce18590809cc",
    ),
    (
        "engine.dbc",
        "ECU_Slow",
        {"CHT": 187.0, "OAT": -12.3, "EcuStatus": 1, "ManifoldPressure": 0.0, "SlowCounter": 15},
        "de0885ff01000fa9",
    ),
    (
        "health.dbc",
        "Health_Isolation",
        {
            "GammaQEstimate": 1.0,
            "GammaDEstimate": 0.8,
            "ThermalHeadroom": 6000,
            "ChtLimitMargin": -12.5,
            "IsolationCounter": 3,
        },
        "f46109dc1dfc0390",
    ),
]


@pytest.mark.parametrize(("dbc_name", "msg_name", "values", "hex_frame"), GOLDEN_FRAMES)
def test_golden_frames(dbc_name: str, msg_name: str, values: dict[str, float], hex_frame: str) -> None:
    msg = _load(dbc_name).get_message_by_name(msg_name)
    checksum_name = msg.signals[-1].name
    data = bytearray(msg.encode({**values, checksum_name: 0}, strict=True))
    data[7] = frame_checksum(data)
    assert data.hex() == hex_frame
    assert frame_checksum(bytes.fromhex(hex_frame)) == bytes.fromhex(hex_frame)[7]


def test_golden_bit_layout_of_packed_frame() -> None:
    # Health_Isolation packs 11+11+13+13 bits; check against integer arithmetic, not cantools.
    raw = int.from_bytes(bytes.fromhex(GOLDEN_FRAMES[2][3])[:6], "little")
    assert raw == 500 | 300 << 11 | 6000 << 22 | (8192 - 125) << 35


@pytest.mark.parametrize("dbc_name", sorted(CONTRACT))
def test_dump_reload_round_trip(dbc_name: str, tmp_path: Path) -> None:
    db = _load(dbc_name)
    out = tmp_path / dbc_name
    cantools.database.dump_file(db, str(out))
    again: Any = cantools.database.load_file(str(out), strict=True)
    assert [m.name for m in again.messages] == [m.name for m in db.messages]
    for a, b in zip(db.messages, again.messages, strict=True):
        assert (a.frame_id, a.length, a.cycle_time, a.senders) == (b.frame_id, b.length, b.cycle_time, b.senders)
        for sa, sb in zip(a.signals, b.signals, strict=True):
            assert (sa.name, sa.start, sa.length, sa.byte_order, sa.is_signed) == (
                sb.name,
                sb.start,
                sb.length,
                sb.byte_order,
                sb.is_signed,
            )
            assert (sa.scale, sa.offset, sa.minimum, sa.maximum, sa.unit) == (
                sb.scale,
                sb.offset,
                sb.minimum,
                sb.maximum,
                sb.unit,
            )
            assert sa.choices == sb.choices
            assert sa.comment == sb.comment


# AUTOSAR SWS_CRC "8-bit SAE-J1850 CRC Calculation" reference results, plus the catalogue check value.
CRC_VECTORS = [
    ("00000000", 0x59),
    ("F20183", 0x37),
    ("0FAA0055", 0x79),
    ("00FF5511", 0xB8),
    ("332255AABBCCDDEEFF", 0xCB),
    ("926B55", 0x8C),
    ("FFFFFFFF", 0x74),
    ("313233343536373839", 0x4B),  # "123456789"
]


@pytest.mark.parametrize(("hex_data", "expected"), CRC_VECTORS)
def test_crc8_known_vectors(hex_data: str, expected: int) -> None:
    assert crc8_sae_j1850(bytes.fromhex(hex_data)) == expected


def test_frame_checksum_covers_bytes_0_to_6_only() -> None:
    frame = bytes.fromhex("4151ce18590809")
    assert frame_checksum(frame) == frame_checksum(frame + b"\x00") == frame_checksum(frame + b"\xff") == 0xCC
    assert frame_checksum(bytes(7)) != 0  # an all-zero frame does not check
    flipped = bytes([frame[0] ^ 0x01]) + frame[1:]
    assert frame_checksum(flipped) != 0xCC
    with pytest.raises(ValueError, match="7 bytes"):
        frame_checksum(b"\x00" * 6)


def test_the_batch_decoders_compiled_crc_is_the_per_frame_crc_on_random_heads() -> None:
    """One CRC routine: compiled into the batch decoder's loop over uint8 rows, it gives what it gives in
    plain Python on bytes (the live decoder and the encoders), byte for byte."""
    import numpy as np

    from ecu_monitor.bus.codec import _crc8_rows

    rng = random.Random(7)
    heads = [bytes(7), b"\xff" * 7, bytes.fromhex("4151ce18590809")]
    heads += [bytes(rng.randrange(256) for _ in range(7)) for _ in range(5000)]
    rows = np.array([[*head, 0] for head in heads], dtype=np.uint8)
    assert _crc8_rows(rows).tolist() == [crc8_sae_j1850(head) for head in heads] == [frame_checksum(h) for h in heads]
    assert crc8_sae_j1850(bytes.fromhex("4151ce18590809")) == 0xCC


# --------------------------------------------------------------------------------------------------
# The one loader (ecu_monitor.bus.dbc): a vendor's file by configuration only, a file that is not a DBC
# --------------------------------------------------------------------------------------------------

VENDOR_DBC = """VERSION ""

NS_ :

BS_:

BU_: ECU DASH
# Vendor dash protocol: these comment lines are not in Vector's format
// nor are these
BO_ 0x360 Engine1: 8 ECU
 SG_ RPM : 7|16@0+ (1,0) [0|30000] "rpm" DASH
 SG_ CHT : 23|16@0+ (0.1,-273.15) [-273.15|6280.35] "degC" DASH
 SG_ Throttle : 39|16@0+ (0.1,0) [0|100] "%" DASH

BO_ 0x361 Fuel: 8 ECU
 SG_ FuelFlow : 7|16@0+ (1,0) [0|65535] "cc/min" DASH

BO_ 866 Unused: 8 ECU
 SG_ A : 0|16@1+ (1,0) [0|65535] "" DASH
 SG_ B : 8|16@1+ (1,0) [0|65535] "" DASH

CM_ BO_ 0x360 "Engine data at 50 Hz";
"""


def test_vendor_dbc_loads_what_can_be_loaded(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    import logging

    from ecu_monitor.bus.codec import Decoder, SignalSpec
    from ecu_monitor.bus.dbc import load_dbc
    from ecu_monitor.errors import ConfigError
    from ecu_monitor.units import custom_unit

    path = tmp_path / "dash.dbc"
    path.write_text(VENDOR_DBC, encoding="utf-8")
    with caplog.at_level(logging.WARNING, logger="ecu_monitor.bus.dbc"):
        dbc = load_dbc(path)
    assert {m.name: m.frame_id for m in dbc.messages} == {"Engine1": 0x360, "Fuel": 0x361, "Unused": 866}
    assert set(dbc.broken) == {"Unused"} and "overlapping" in dbc.broken["Unused"]
    assert len(dbc.notes) == 3  # comment lines, hex ids, the broken message: each a warning
    assert "2 comment line(s) ignored (first at line 8)" in caplog.text
    assert "3 hexadecimal id(s)" in caplog.text and "Unused" in caplog.text
    # any unit with a scale and offset: fuel flow in cc/min -> L/h (0.06)
    cc_per_min = custom_unit({"scale": 0.06}, "fuel_flow")
    decoder = Decoder([path], [SignalSpec("rpm", "Engine1", "RPM", "rpm"),
                               SignalSpec("fuel_flow_lph", "Fuel", "FuelFlow", cc_per_min)])  # fmt: skip
    assert decoder.decode(0x361, False, bytes([0x03, 0xE8, 0, 0, 0, 0, 0, 0]), 0.0) == [(1, pytest.approx(60.0))]
    with pytest.raises(ConfigError, match=r"message 'Unused' cannot be used: .*overlapping"):
        Decoder([path], [SignalSpec("a", "Unused", "A")])


def test_real_vendor_file_with_vendor_quirks_loads_the_same(tmp_path: Path) -> None:
    """rusEFI's published DBC, written as vendors do (hex ids, a comment header): the same messages."""
    from ecu_monitor.bus.dbc import load_dbc

    original = DBC_DIR / "third_party" / "rusEFI_CAN_verbose.dbc"
    text = original.read_text(encoding="utf-8")
    quirky = "\n".join(
        f"BO_ 0x{int(line.split()[1]):X} {' '.join(line.split()[2:])}" if line.startswith("BO_ ") else line
        for line in text.splitlines()
    )
    path = tmp_path / "rusefi_vendor.dbc"
    path.write_text("# rusEFI CAN broadcast, verbose\n" + quirky, encoding="utf-8")
    ours, theirs = load_dbc(path), load_dbc(original)
    assert [(m.name, m.frame_id, [s.name for s in m.signals]) for m in ours.messages] == [
        (m.name, m.frame_id, [s.name for s in m.signals]) for m in theirs.messages
    ]
    assert not ours.broken and len(ours.notes) == 2


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (bytes(range(256)) * 20, r"not a DBC file \(line 1 holds the control byte 0x00\)"),
        (b'VERSION ""\n\nBO_ 256 M: 8 A\n SG_ X : 0|8@1+ (1,0) [0|255] "" A\n\x00\x01\x02garbage', r"line 5 holds"),
        (b"time_s,rpm\n0,1000\n", r"not a DBC file \(no BO_ message definition"),
        (
            b'VERSION ""\n\nBO_ 256 M: 8 A\n SG_ X : 0|8@1+ (1,0) [0|255] "" A\nWHAT is this\n',
            r"syntax error at line 5",
        ),
    ],
)
def test_a_file_that_is_not_a_dbc_is_one_line_with_the_line_number(
    tmp_path: Path, content: bytes, expected: str
) -> None:
    from ecu_monitor.bus.dbc import load_dbc
    from ecu_monitor.errors import ConfigError

    path = tmp_path / "x.dbc"
    path.write_bytes(content)
    with pytest.raises(ConfigError, match=expected) as info:
        load_dbc(path)
    assert len(str(info.value).splitlines()) == 1 and len(str(info.value)) < 300
