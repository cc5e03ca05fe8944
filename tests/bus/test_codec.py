"""bus/codec.py: decode/encode round trips, golden frames, every malformed reason counted, batch == live."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cantools
import numpy as np
import pytest

from ecu_monitor.bus.checksum import frame_checksum
from ecu_monitor.bus.codec import MALFORMED_REASONS, Decoder, Encoder, SignalSpec
from ecu_monitor.errors import ConfigError
from ecu_monitor.units import GASOLINE_DENSITY_KG_PER_L, unit_conversion
from tests.helpers import REPO

ENGINE_DBC = REPO / "ecu_monitor" / "data" / "dbc" / "engine.dbc"
HEALTH_DBC = REPO / "ecu_monitor" / "data" / "dbc" / "health.dbc"
RUSEFI_DBC = REPO / "ecu_monitor" / "data" / "dbc" / "third_party" / "rusEFI_CAN_verbose.dbc"

SPECS = [
    SignalSpec("rpm", "ECU_Fast", "EngineSpeed", "rpm"),
    SignalSpec("throttle_pct", "ECU_Fast", "ThrottlePos", "pct"),
    SignalSpec("cht_c", "ECU_Slow", "CHT", "degC"),
    SignalSpec("oat_c", "ECU_Slow", "OAT", "degC"),
    SignalSpec("status", "ECU_Slow", "EcuStatus", "raw"),
    SignalSpec("altitude_m", "AirData", "PressureAltitude", "m"),
    SignalSpec("airspeed_mps", "AirData", "CalibratedAirspeed", "mps"),
]


def _decoder() -> Decoder:
    return Decoder([ENGINE_DBC], SPECS)


def _named(decoder: Decoder, result: list[tuple[int, float]] | None) -> dict[str, float]:
    assert result is not None
    return {decoder.names[i]: v for i, v in result}


def _fast(counter: int, rpm: float = 5200.25, throttle: float = 63.5) -> bytes:
    return Encoder([ENGINE_DBC]).encode("ECU_Fast", {"EngineSpeed": rpm, "ThrottlePos": throttle, "FuelFlow": 21.37},
                                        counter)  # fmt: skip


def test_golden_frames_of_docs_dbc_md_decode() -> None:
    dec = _decoder()
    fast = _named(dec, dec.decode(0x100, False, bytes.fromhex("4151ce18590809cc"), 0.0))
    assert fast == {"rpm": 5200.25, "throttle_pct": pytest.approx(63.5)}
    slow = _named(dec, dec.decode(0x101, False, bytes.fromhex("de0885ff01000fa9"), 0.1))
    assert slow["cht_c"] == pytest.approx(187.0) and slow["oat_c"] == pytest.approx(-12.3) and slow["status"] == 1
    assert dec.counters["ok"] == 2 and dec.counters["malformed"] == 0


def test_encoder_reproduces_golden_frame_and_round_trips() -> None:
    enc = Encoder([ENGINE_DBC])
    assert _fast(9).hex() == "4151ce18590809cc"
    data = enc.encode("AirData", {"PressureAltitude": 812.5, "CalibratedAirspeed": 23.45, "VerticalSpeed": -1.5}, 20)
    assert data[6] == 20 % 16 and data[7] == frame_checksum(data)
    dec = _decoder()
    values = _named(dec, dec.decode(0x200, False, data, 0.0))
    assert values["altitude_m"] == 812.5 and values["airspeed_mps"] == pytest.approx(23.45)


def test_encoder_clamps_to_dbc_range_and_refuses_nan() -> None:
    enc = Encoder([HEALTH_DBC])
    data = enc.encode(
        "Health_Status", {"ChtEstimate": 999.0, "ModelDeviation": -99.0, "DegradationState": 2, "ChtRate": 0.0}, 3
    )
    db: Any = cantools.database.load_file(str(HEALTH_DBC))
    decoded = db.decode_message(0x300, data)
    assert decoded["ChtEstimate"] == pytest.approx(400.0) and decoded["ModelDeviation"] == pytest.approx(-32.768)
    with pytest.raises(ValueError, match="NaN"):
        enc.encode(
            "Health_Status", {"ChtEstimate": math.nan, "ModelDeviation": 0.0, "DegradationState": 0, "ChtRate": 0}, 0
        )


def test_every_malformed_reason_is_counted_and_dropped() -> None:
    dec = _decoder()
    assert dec.decode(0x100, False, _fast(0), 0.00) is not None
    assert dec.decode(0x7FF, False, bytes(8), 0.01) is None  # unknown id
    assert dec.decode(0x100, False, _fast(1)[:7], 0.02) is None  # bad DLC
    corrupt = bytearray(_fast(1))
    corrupt[0] ^= 0x01
    assert dec.decode(0x100, False, bytes(corrupt), 0.03) is None  # bad checksum
    assert dec.decode(0x100, False, _fast(7), 0.04) is None  # counter jumped 0 -> 7
    assert dec.decode(0x100, False, _fast(8), 0.05) is not None  # back in step after the jump
    assert dec.decode(0x100, False, _fast(8), 0.06) is None  # frozen counter
    assert dec.decode(0x100, False, _fast(10), 0.07) is not None  # one lost frame is tolerated
    raw = bytearray(_fast(11))
    raw[2:4] = (10001).to_bytes(2, "little")  # throttle 100.01 % > DBC max 100
    raw[7] = frame_checksum(raw)
    assert dec.decode(0x100, False, bytes(raw), 0.08) is None
    c = dec.counters
    assert (c["unknown_id"], c["bad_dlc"], c["bad_checksum"], c["bad_counter"], c["out_of_range"]) == (1, 1, 1, 2, 1)
    assert c["malformed"] == sum(c[r] for r in MALFORMED_REASONS) == 5
    assert c["ok"] == 3 and c["frames"] == 9


def test_counter_resynchronises_after_a_silence() -> None:
    dec = _decoder()
    assert dec.decode(0x100, False, _fast(3), 0.0) is not None
    assert dec.decode(0x100, False, _fast(9), 0.5) is None  # jump within the window
    assert dec.decode(0x100, False, _fast(2), 2.0) is not None  # after > 1 s of silence any counter is taken


def test_not_finite_float_signal_is_malformed(tmp_path: Path) -> None:
    dbc = tmp_path / "float.dbc"
    dbc.write_text(
        'VERSION ""\n\nNS_ :\n\nBS_:\n\nBU_: A\n\n'
        'BO_ 16 F: 8 A\n SG_ Temp : 0|32@1- (1,0) [-100|400] "degC" A\n SIG_VALTYPE_ 16 Temp : 1;\n',
        encoding="utf-8",
    )
    dec = Decoder([dbc], [SignalSpec("cht_c", "F", "Temp", "degC")])
    nan = np.array([math.nan], dtype="<f4").tobytes() + bytes(4)
    ok = np.array([123.5], dtype="<f4").tobytes() + bytes(4)
    assert dec.decode(16, False, nan, 0.0) is None and dec.counters["not_finite"] == 1
    assert _named(dec, dec.decode(16, False, ok, 0.1)) == {"cht_c": 123.5}
    batch = dec.decode_batch(np.array([16, 16]), np.zeros(2, bool), np.array([8, 8]),
                             np.frombuffer(nan + ok, np.uint8).reshape(2, 8), np.array([0.0, 0.1]))  # fmt: skip
    assert batch.counts["not_finite"] == 1 and batch.values["cht_c"][1].tolist() == [123.5]


def test_units_convert_once_rusefi_fuel_flow_in_grams_per_second() -> None:
    dec = Decoder([RUSEFI_DBC], [SignalSpec("fuel_flow_lph", "BASE6", "FuelFlow", "g_per_s_gasoline")])
    db: Any = cantools.database.load_file(str(RUSEFI_DBC))
    data = db.encode_message("BASE6", {"FuelUsed": 0, "FuelFlow": 1.0, "FuelTrim1": 0, "FuelTrim2": 0})
    (value,) = _named(dec, dec.decode(518, False, data, 0.0)).values()
    assert value == pytest.approx(3.6 / GASOLINE_DENSITY_KG_PER_L)  # 1 g/s = 3.6 kg/h = 4.86 L/h
    assert unit_conversion("degF").scale * 212 + unit_conversion("degF").offset == pytest.approx(100.0)
    with pytest.raises(ValueError, match="temperature"):
        unit_conversion("rpm", "temperature")


def test_two_used_messages_on_one_id_is_a_config_error() -> None:
    specs = [SignalSpec("x", "BASE0", "WarningCounter"), SignalSpec("altitude_m", "AirData", "PressureAltitude", "m")]
    with pytest.raises(ConfigError, match="share frame id 0x200"):
        Decoder([RUSEFI_DBC, ENGINE_DBC], specs)
    with pytest.raises(ConfigError, match="no message 'Nope'"):
        Decoder([ENGINE_DBC], [SignalSpec("x", "Nope", "Y")])


def _random_frames(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    """A mix of good frames and every kind of bad one, in time order."""
    enc = Encoder([ENGINE_DBC])
    ids, dlcs, rows, times = [], [], [], []
    counters = {0x100: 0, 0x101: 0, 0x200: 0}
    t = 0.0
    for _ in range(n):
        t += float(rng.uniform(0.0, 0.05)) if rng.random() > 0.01 else 1.5
        kind = rng.integers(0, 10)
        fid = int(rng.choice([0x100, 0x101, 0x200, 0x123]))
        if fid == 0x100:
            values = {"EngineSpeed": rng.uniform(0, 9000), "ThrottlePos": rng.uniform(0, 100), "FuelFlow": 3.0}
            data = bytearray(enc.encode("ECU_Fast", values, counters[fid]))
        elif fid == 0x101:
            values = {"CHT": rng.uniform(-40, 400), "OAT": rng.uniform(-60, 80), "EcuStatus": int(rng.integers(0, 4)),
                      "ManifoldPressure": rng.uniform(0, 120)}  # fmt: skip
            data = bytearray(enc.encode("ECU_Slow", values, counters[fid]))
        elif fid == 0x200:
            values = {"PressureAltitude": rng.uniform(-500, 5000), "CalibratedAirspeed": rng.uniform(0, 60),
                      "VerticalSpeed": 0.0}  # fmt: skip
            data = bytearray(enc.encode("AirData", values, counters[fid]))
        else:
            data = bytearray(rng.integers(0, 256, 8, dtype=np.uint8).tobytes())
        if fid in counters:
            counters[fid] += 1 if kind != 1 else int(rng.integers(3, 14))
        dlc = 8
        if kind == 2:
            dlc = int(rng.integers(0, 8))
        elif kind == 3:
            data[int(rng.integers(0, 7))] ^= 0x10
        elif kind == 4:  # out of range with a valid checksum
            data[0:2] = b"\xff\xff"
            data[7] = frame_checksum(data)
        ids.append(fid)
        dlcs.append(dlc)
        rows.append(bytes(data[:dlc]).ljust(8, b"\0"))
        times.append(t)
    payload = np.frombuffer(b"".join(rows), dtype=np.uint8).reshape(n, 8)
    return np.array(ids), np.zeros(n, bool), np.array(dlcs), payload, np.array(times)


def test_batch_decode_equals_frame_by_frame() -> None:
    rng = np.random.default_rng(7)
    ids, ext, dlc, data, times = _random_frames(rng, 3000)
    live = _decoder()
    per_frame: dict[str, list[tuple[int, float]]] = {name: [] for name in live.names}
    for i in range(ids.size):
        result = live.decode(int(ids[i]), False, data[i, : dlc[i]].tobytes(), float(times[i]))
        for slot, value in result or []:
            per_frame[live.names[slot]].append((i, value))
    batch = _decoder().decode_batch(ids, ext, dlc, data, times)
    for name in live.names:
        rows, values = batch.values[name]
        assert rows.tolist() == [i for i, _ in per_frame[name]]
        assert values.tolist() == [v for _, v in per_frame[name]]  # the same float arithmetic: exactly equal
    for key in ("ok", "unknown_id", "malformed", *MALFORMED_REASONS):
        assert batch.counts[key] == live.counters[key], key
    assert live.counters["malformed"] > 300 and all(live.counters[r] for r in MALFORMED_REASONS if r != "decode_error"
                                                    and r != "not_finite")  # fmt: skip


def test_batch_bit_extraction_matches_cantools_for_big_endian_and_signed(tmp_path: Path) -> None:
    dbc = tmp_path / "mixed.dbc"
    dbc.write_text(
        'VERSION ""\n\nNS_ :\n\nBS_:\n\nBU_: A\n\nBO_ 32 M: 8 A\n'
        ' SG_ Be16 : 7|16@0+ (0.5,-10) [-10|32757] "" A\n'
        ' SG_ BeS12 : 27|12@0- (1,0) [-2048|2047] "" A\n'
        ' SG_ LeS7 : 41|7@1- (2,1) [-127|127] "" A\n'
        ' SG_ Le3 : 61|3@1+ (1,0) [0|7] "" A\n',
        encoding="utf-8",
    )
    names = ("Be16", "BeS12", "LeS7", "Le3")
    dec = Decoder([dbc], [SignalSpec(n, "M", n) for n in names])
    rng = np.random.default_rng(3)
    data = rng.integers(0, 256, (500, 8), dtype=np.uint8)
    batch = dec.decode_batch(np.full(500, 32), np.zeros(500, bool), np.full(500, 8), data, np.arange(500.0))
    db: Any = cantools.database.load_file(str(dbc))
    message = db.get_message_by_name("M")
    expected: list[Any] = [message.decode(row.tobytes(), decode_choices=False) for row in data]
    for name in names:
        rows, values = batch.values[name]
        assert rows.size == 500
        assert np.allclose(values, [e[name] for e in expected[: rows.size]], rtol=0, atol=1e-9)


def test_encode_rows_equals_encode_row_by_row() -> None:
    """The array path the virtual ECU and CSV replay use gives the bytes of the per-frame encoder."""
    rng = np.random.default_rng(5)
    enc = Encoder([ENGINE_DBC, HEALTH_DBC])
    columns = {
        "EngineSpeed": rng.uniform(-100, 20000, 300),  # beyond the DBC range both ends: clamped
        "ThrottlePos": rng.uniform(-5, 105, 300),
        "FuelFlow": rng.uniform(0, 80, 300),
    }
    rows = enc.encode_rows("ECU_Fast", columns, first_counter=13)
    one_by_one = [enc.encode("ECU_Fast", {k: v[i] for k, v in columns.items()}, 13 + i) for i in range(300)]
    assert rows == one_by_one
    status = {"ChtEstimate": rng.uniform(-50, 400, 50), "ModelDeviation": rng.normal(0, 1, 50),
              "DegradationState": rng.integers(0, 6, 50), "ChtRate": rng.uniform(-40, 40, 50)}  # fmt: skip
    assert enc.encode_rows("Health_Status", status) == [
        enc.encode("Health_Status", {k: v[i] for k, v in status.items()}, i) for i in range(50)
    ]
    with pytest.raises(ValueError, match="cannot encode NaN"):
        enc.encode_rows("ECU_Fast", {**columns, "FuelFlow": np.full(300, np.nan)})


_LAYOUT_DBC = """VERSION ""
NS_ :
BS_:
BU_: A B
BO_ 1 Mixed: 8 A
 SG_ BigSigned : 7|12@0- (0.05,-3) [-100|99] "" B
 SG_ LittleOdd : 19|11@1- (0.25,0.5) [-200|200] "" B
 SG_ BigUnsigned : 39|9@0+ (2,10) [10|1000] "" B
 SG_ Flag : 48|1@1+ (1,0) [0|1] "" B
 SG_ Tail : 63|7@0+ (1,0) [0|100] "" B
BO_ 2 Short: 3 A
 SG_ Word : 0|16@1+ (0.1,-5) [-5|6000] "" B
 SG_ Nibble : 20|4@1+ (1,0) [0|15] "" B
BO_ 3 WithFloat: 8 A
 SG_ Real : 0|32@1- (1,0) [-1000|1000] "" B
SIG_VALTYPE_ 3 Real : 1;
"""


def _random_values(rng: np.random.Generator, message: Any, names: tuple[str, ...]) -> list[list[float]]:
    """Rows of physical values: uniform beyond both ends of each DBC range (clipped), the range's ends and
    their neighbours, huge and infinite values, integers."""
    signals = {s.name: s for s in message.signals}
    rows: list[list[float]] = []
    for k in range(400):
        row = []
        for name in names:
            low, high = float(signals[name].minimum), float(signals[name].maximum)
            span = high - low
            pick = k % 8
            if pick == 0:
                row.append(low if k % 16 else high)
            elif pick == 1:
                row.append(float(np.nextafter(low, -np.inf) if k % 16 else np.nextafter(high, np.inf)))
            elif pick == 2:
                row.append(float(rng.choice([-1e300, 1e300, -np.inf, np.inf, 0.0, -0.0])))
            elif pick == 3:
                row.append(int(rng.integers(int(low) - 5, int(high) + 6)))
            else:
                row.append(float(rng.uniform(low - 0.2 * span, high + 0.2 * span)))
        rows.append(row)
    return rows


def test_prepared_layouts_are_bit_exact_against_cantools(tmp_path: Path) -> None:
    """Every message with a FrameLayout packs the bytes cantools encodes from the same clamped values:
    random values across and beyond the DBC ranges, the ranges' ends, huge and infinite values, big- and
    little-endian, signed and unsigned, integer and fractional scales, short messages."""
    custom = tmp_path / "layouts.dbc"
    custom.write_text(_LAYOUT_DBC)
    enc = Encoder([ENGINE_DBC, HEALTH_DBC, RUSEFI_DBC, custom])
    rng = np.random.default_rng(13)
    prepared = [name for name in enc._layouts if enc.layout(name) is not None]
    assert {"ECU_Fast", "ECU_Slow", "AirData", "Health_Status", "Health_Isolation", "Health_Diag"} <= set(prepared)
    assert {"Mixed", "Short"} <= set(prepared) and enc.layout("WithFloat") is None
    checked = 0
    for name in prepared:
        layout = enc.layout(name)
        assert layout is not None
        message = enc.message(name)
        for k, row in enumerate(_random_values(rng, message, layout.signal_names)):
            values = dict(zip(layout.signal_names, row, strict=True))
            counter = k * 7 + int(rng.integers(0, 1000))
            expected = enc.encode_cantools(name, values, counter)
            assert layout.pack(row, counter) == expected, (name, values, counter)
            assert enc.encode(name, values, counter) == expected
            checked += 1
    assert checked >= 8 * 400
    # cantools' own strict encoder agrees on in-range values (the clamp is the only difference)
    db: Any = cantools.database.load_file(str(custom))
    layout = enc.layout("Mixed")
    assert layout is not None
    row = [12.35, -37.75, 512.0, 1.0, 99.0]
    assert layout.pack(row) == db.encode_message("Mixed", dict(zip(layout.signal_names, row, strict=True)))


def test_prepared_layout_refuses_nan_and_a_wrong_count() -> None:
    layout = Encoder([HEALTH_DBC]).layout("Health_Isolation")
    assert layout is not None and layout.signal_names == (
        "GammaQEstimate", "GammaDEstimate", "ThermalHeadroom", "ChtLimitMargin"
    )  # fmt: skip
    with pytest.raises(ValueError, match=r"Health_Isolation.ThermalHeadroom: cannot encode NaN"):
        layout.pack([1.0, 1.0, math.nan, 0.0])
    with pytest.raises(ValueError, match="expected 4 values"):
        layout.pack([1.0, 1.0, 0.0])


def test_messages_without_a_layout_still_encode_through_cantools() -> None:
    enc = Encoder([RUSEFI_DBC])
    assert enc.layout("BASE0") is None  # no DBC range: an unclamped value may not fit its bits
    values = {s.name: 1 for s in enc.message("BASE0").signals}
    assert enc.encode("BASE0", values) == enc.encode_cantools("BASE0", values)


def test_prepared_decode_equals_cantools_decode(tmp_path: Path) -> None:
    """Decoder.decode reads integer signals by shift and mask: the same values, counters and verdicts as
    through cantools' decode, over random payloads of big- and little-endian, signed and unsigned signals."""
    custom = tmp_path / "layouts.dbc"
    custom.write_text(_LAYOUT_DBC)
    specs = [SignalSpec(f"{m}.{s}", m, s) for m, signals in (
        ("Mixed", ("BigSigned", "LittleOdd", "BigUnsigned", "Flag", "Tail")), ("Short", ("Word", "Nibble")),
    ) for s in signals]  # fmt: skip
    engine = [*SPECS, SignalSpec("fuel", "ECU_Fast", "FuelFlow", "lph")]
    rusefi = [SignalSpec(f"BASE1.{s}", "BASE1", s) for s in ("RPM", "IgnitionTiming", "InjDuty", "VehicleSpeed")]
    rng = np.random.default_rng(21)
    for paths, chosen in (([custom], specs), ([ENGINE_DBC], engine), ([RUSEFI_DBC], rusefi)):
        fast = Decoder(paths, chosen)
        reference = Decoder(paths, chosen)
        assert all(plan.extract is not None for plan in fast._plans.values())
        reference._plans = {key: plan._replace(extract=None) for key, plan in reference._plans.items()}
        keys = list(fast._plans)
        for k in range(3000):
            frame_id, extended = keys[k % len(keys)]
            payload = bytearray(rng.integers(0, 256, fast._plans[(frame_id, extended)].message.length, dtype=np.uint8))
            if fast._plans[(frame_id, extended)].counter_name is not None:
                payload[6] = (payload[6] & 0xF0) | (k // len(keys)) % 16  # counter in step: reach the decode
                payload[7] = frame_checksum(payload)
            got = fast.decode(frame_id, extended, bytes(payload), 0.01 * k)
            assert got == reference.decode(frame_id, extended, bytes(payload), 0.01 * k)
        assert fast.counters == reference.counters
        assert fast.counters["ok"] >= 50 and fast.counters["out_of_range"] >= 500  # both verdicts reached


def test_batch_checksum_equals_the_frame_checksum_on_random_payloads() -> None:
    """The batch decoder's compiled CRC-8 of bytes 0..6 is the live path's frame_checksum, row by row."""
    from ecu_monitor.bus.codec import _crc8_rows

    rows = np.random.default_rng(5).integers(0, 256, (2000, 8), dtype=np.uint8)
    assert _crc8_rows(rows).tolist() == [frame_checksum(bytes(row)) for row in rows]
