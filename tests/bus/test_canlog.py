"""The one CAN-log reader (ecu_monitor.bus.canlog): CAN logs imported into flight logs, and what the
reader does with damaged logs (cut, empty, two logs back to back, holes in time)."""

from __future__ import annotations

import logging
import re
import struct
from pathlib import Path
from typing import Any

import can
import cantools
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from ecu_monitor.bus.canlog import DEFAULT_SIGNAL_MAP, import_can_log, load_flight
from ecu_monitor.bus.checksum import frame_checksum
from ecu_monitor.bus.codec import Encoder
from ecu_monitor.bus.dbc import shipped_dbc
from ecu_monitor.errors import ConfigError, FlightLogError
from ecu_monitor.flightlog import read_csv
from tests.helpers import run_cli

DEFAULT_ENGINE_DBC = shipped_dbc("engine.dbc")
RUSEFI_DBC = shipped_dbc("third_party/rusEFI_CAN_verbose.dbc")


# --------------------------------------------------------------------------------------------------
# CAN logs
# --------------------------------------------------------------------------------------------------

T0 = 1_700_000_000.0


def _frames() -> list[can.Message]:
    """2 s of engine.dbc traffic, an unknown id and one malformed frame."""
    db: Any = cantools.database.load_file(str(DEFAULT_ENGINE_DBC), strict=True)
    fast, slow, air = (db.get_message_by_name(n) for n in ("ECU_Fast", "ECU_Slow", "AirData"))
    out: list[tuple[float, int, bytes]] = []

    def add(t: float, msg: Any, values: dict[str, float], counter: int) -> None:
        names = [s.name for s in msg.signals]
        data = bytearray(msg.encode({**values, names[-2]: counter % 16, names[-1]: 0}, strict=True))
        data[7] = frame_checksum(data)
        out.append((t, msg.frame_id, bytes(data)))

    for j in range(100):  # ECU_Fast 50 Hz from t=0
        add(0.02 * j, fast, {"EngineSpeed": 2000 + 10 * j, "ThrottlePos": 50.0, "FuelFlow": 12.5}, j)
    for k in range(20):  # ECU_Slow 10 Hz from t=0.01; AirData from t=0.05, its clock 1 ms/frame late
        add(0.01 + 0.1 * k, slow, {"CHT": 100 + k, "OAT": -5.5, "EcuStatus": 0, "ManifoldPressure": 0.0}, k)
        add(0.05 + 0.101 * k, air, {"PressureAltitude": 500 + k, "CalibratedAirspeed": 30.0, "VerticalSpeed": 1}, k)
    out.append((0.5, 0x7FF, bytes(8)))  # unknown id: ignored
    out.append((0.51, 0x101, bytes(3)))  # ECU_Slow with 3 bytes: counted, skipped
    out.sort()
    return [can.Message(timestamp=T0 + t, arbitration_id=i, data=d, is_extended_id=False, channel=0) for t, i, d in out]


@pytest.mark.parametrize("suffix", [".blf", ".asc", ".log"])
def test_can_log_import(suffix: str, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / f"flight{suffix}"
    with can.Logger(str(path)) as writer:
        for msg in _frames():
            writer.on_message_received(msg)
    with caplog.at_level(logging.WARNING, logger="ecu_monitor.bus.canlog"):
        log = load_flight(path)
    assert set(log.names) == {"time_s", *DEFAULT_SIGNAL_MAP}
    # the grid starts when every signal has been seen (first AirData, t=0.05) and runs at 10 Hz
    assert log.time_s.tolist() == pytest.approx([0.1 * k for k in range(len(log))])
    assert len(log) == 20  # last frame at 0.05 + 0.101 * 19 = 1.969 s -> grid 0.05 .. 1.95
    k = np.arange(len(log))
    np.testing.assert_allclose(log["rpm"], 2000 + 10 * (2 + 5 * k))  # ECU_Fast frame at 0.04 + 0.1 k
    np.testing.assert_allclose(log["cht_c"], 100 + k, atol=0.05)  # ECU_Slow frame at 0.01 + 0.1 k
    np.testing.assert_allclose(log["altitude_m"], 500 + np.maximum(k - 1, 0))  # held: late frames
    np.testing.assert_allclose(log["oat_c"], -5.5)
    np.testing.assert_allclose(log["throttle_pct"], 50.0)
    np.testing.assert_allclose(log["fuel_flow_lph"], 12.5)
    np.testing.assert_allclose(log["airspeed_mps"], 30.0)
    assert "1 frame(s) failed to decode" in caplog.text


def test_can_log_signal_map_errors(tmp_path: Path) -> None:
    path = tmp_path / "x.asc"
    with can.Logger(str(path)) as writer:
        for msg in _frames()[:4]:  # up to t=0.04 s: no AirData yet
            writer.on_message_received(msg)
    with pytest.raises(ConfigError, match="key 'rpm': no message 'Nope'"):
        import_can_log(path, [DEFAULT_ENGINE_DBC], {"rpm": "Nope.EngineSpeed"})
    with pytest.raises(ConfigError, match="has no signal 'Rpm'"):
        import_can_log(path, [DEFAULT_ENGINE_DBC], {"rpm": "ECU_Fast.Rpm"})
    with pytest.raises(FlightLogError, match=r"signal 'AirData.PressureAltitude' for column 'altitude_m' never seen"):
        import_can_log(path, [DEFAULT_ENGINE_DBC], {"altitude_m": "AirData.PressureAltitude"})
    with pytest.raises(ConfigError, match="no such DBC file"):
        import_can_log(path, [tmp_path / "missing.dbc"])


def test_load_flight_unknown_suffix(tmp_path: Path) -> None:
    (tmp_path / "x.parquet").write_bytes(b"PAR1")
    with pytest.raises(FlightLogError, match=r"unknown log type '.parquet'"):
        load_flight(tmp_path / "x.parquet")


def test_cli_import_can_log_of_another_ecu_is_configuration(tmp_path: Path) -> None:
    rus: Any = cantools.database.load_file(str(RUSEFI_DBC), strict=False)
    ours: Any = cantools.database.load_file(str(DEFAULT_ENGINE_DBC), strict=True)
    base1, base2, base3 = (rus.get_message_by_name(n) for n in ("BASE1", "BASE2", "BASE3"))
    air = ours.get_message_by_name("AirData")
    air_encoder = Encoder([DEFAULT_ENGINE_DBC])  # the autopilot's frame: counter and checksum
    air_values = {"PressureAltitude": 800.0, "CalibratedAirspeed": 25.0, "VerticalSpeed": 0.0}

    def zeros(msg: Any, **values: float) -> bytes:
        return bytes(msg.encode({**{s.name: 0 for s in msg.signals}, **values}, strict=False))

    frames = []
    for k in range(12):
        t = T0 + 0.1 * k
        frames += [
            (t, base1.frame_id, zeros(base1, RPM=5000 + k)),
            (t + 0.01, base2.frame_id, zeros(base2, TPS1=42.0)),
            (t + 0.02, base3.frame_id, zeros(base3, AUX1Temp=150 + k, IntakeTemp=20, CoolantTemp=0, MCUTemp=0)),
            (t + 0.03, air.frame_id, air_encoder.encode("AirData", air_values, k)),
        ]
    path = tmp_path / "rusefi.blf"
    with can.Logger(str(path)) as writer:
        for t, i, d in frames:
            writer.on_message_received(can.Message(timestamp=t, arbitration_id=i, data=d, is_extended_id=False))
    signals = {
        "rpm": "BASE1.RPM",
        "throttle_pct": "BASE2.TPS1",
        "cht_c": "BASE3.AUX1Temp",
        "oat_c": "BASE3.IntakeTemp",
        "altitude_m": "AirData.PressureAltitude",
        "airspeed_mps": "AirData.CalibratedAirspeed",
    }
    out = tmp_path / "flight.csv"
    args: list[str | Path] = ["import", path, "--out", out, "--dbc", RUSEFI_DBC, "--dbc", DEFAULT_ENGINE_DBC]
    args += [arg for column, ref in signals.items() for arg in ("--signal", f"{column}={ref}")]
    result = run_cli(*args, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    log = read_csv(out)
    assert set(log.names) == {"time_s", *signals}
    assert log["rpm"][0] == 5000 and log["cht_c"][0] == 150 and log["throttle_pct"][0] == 42.0


# --------------------------------------------------------------------------------------------------
# Damaged logs: cut, empty, two logs back to back, a hole in time
# --------------------------------------------------------------------------------------------------


def _write_log(path: Path, frames: list[can.Message]) -> Path:
    with can.Logger(str(path)) as writer:
        for msg in frames:
            writer.on_message_received(msg)
    return path


@pytest.mark.parametrize("suffix", [".blf", ".log"])
def test_a_log_cut_in_the_middle_is_read_up_to_the_cut_with_a_warning(
    suffix: str, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from ecu_monitor.bus.canlog import read_frames

    whole = read_frames(_write_log(tmp_path / f"whole{suffix}", _frames()))
    data = (tmp_path / f"whole{suffix}").read_bytes()
    cut = tmp_path / f"cut{suffix}"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    with caplog.at_level(logging.WARNING, logger="ecu_monitor.bus.canlog"):
        frames = read_frames(cut)
    assert 0 < len(frames) < len(whole)
    np.testing.assert_array_equal(frames.time_s, whole.time_s[: len(frames)])
    reached = f"up to t={frames.time_s[-1]:.3f} s"
    assert "cut in the middle" in caplog.text and reached in caplog.text


@pytest.mark.parametrize("command", ["import", "replay"])
def test_a_zero_byte_log_exits_2_with_one_line(command: str, tmp_path: Path) -> None:
    empty = tmp_path / "empty.blf"
    empty.write_bytes(b"")
    result = run_cli(command, empty, "--out", tmp_path / "out.csv", cwd=tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and f"{empty}: empty file (0 bytes)" in lines[0]


def test_two_logs_back_to_back_are_refused_with_one_line(tmp_path: Path) -> None:
    first = _write_log(tmp_path / "a.log", _frames())
    both = tmp_path / "both.log"
    both.write_bytes(first.read_bytes() * 2)  # cat a.log a.log > both.log: the clock restarts
    result = run_cli("import", both, "--out", tmp_path / "out.csv", cwd=tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "time goes back" in lines[0] and "two logs back to back" in lines[0]
    assert not (tmp_path / "out.csv").exists()


def test_import_writes_no_row_inside_a_hole_of_the_log(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    frames = _frames()
    later = [
        can.Message(timestamp=m.timestamp + 60.0, arbitration_id=m.arbitration_id, data=m.data, is_extended_id=False)
        for m in frames
    ]
    path = _write_log(tmp_path / "hole.blf", frames + later)
    with caplog.at_level(logging.WARNING, logger="ecu_monitor.bus.canlog"):
        log = load_flight(path)
    steps = np.diff(log.time_s)
    assert np.count_nonzero(steps > 1.0) == 1 and 55.0 < steps.max() < 60.0  # the hole stays a hole
    assert len(log) < 45  # two stretches of ~2 s at 10 Hz, not 62 s of held values
    assert "1 hole(s) in the log longer than 5 s" in caplog.text


def test_a_unit_in_the_signal_map_converts_on_import(tmp_path: Path) -> None:
    path = _write_log(tmp_path / "f.blf", _frames())
    smap = {**DEFAULT_SIGNAL_MAP, "altitude_m": "AirData.PressureAltitude:ft", "cht_c": "ECU_Slow.CHT:K"}
    log = import_can_log(path, [DEFAULT_ENGINE_DBC], smap)
    plain = import_can_log(path, [DEFAULT_ENGINE_DBC])
    np.testing.assert_allclose(log["altitude_m"], plain["altitude_m"] * 0.3048)
    np.testing.assert_allclose(log["cht_c"], plain["cht_c"] - 273.15)
    with pytest.raises(ConfigError, match="unknown unit 'furlong'"):
        import_can_log(path, [DEFAULT_ENGINE_DBC], {**smap, "rpm": "ECU_Fast.EngineSpeed:furlong"})


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    suffix=st.sampled_from([".blf", ".asc", ".log", ".trc"]),
    cut=st.floats(0.0, 1.0),
    noise=st.binary(max_size=64),
)
@example(suffix=".trc", cut=0.0, noise=b"\x00\x0b\x00\n")  # a vertical tab in the skipped line python-can quotes
def test_any_damage_to_a_log_is_read_or_one_error(tmp_path: Path, suffix: str, cut: float, noise: bytes) -> None:
    """A log cut anywhere, with random bytes appended: frames or a FlightLogError, never anything else."""
    from ecu_monitor.bus.canlog import read_frames

    source = tmp_path / f"source{suffix}"
    if not source.exists():
        _write_log(source, _frames() if suffix != ".trc" else _frames()[:50])
    data = source.read_bytes()
    damaged = tmp_path / f"damaged{suffix}"
    damaged.write_bytes(data[: int(len(data) * cut)] + noise)
    try:
        frames = read_frames(damaged)
    except FlightLogError as exc:
        assert len(str(exc).splitlines()) == 1
    else:
        assert len(frames) > 0 and frames.data.shape == (len(frames), 8)


# --------------------------------------------------------------------------------------------------
# A real logger's clock (issue 31)
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".blf", ".asc", ".log"])
def test_epoch_stamps_become_time_since_the_start_of_the_log(suffix: str, tmp_path: Path) -> None:
    from ecu_monitor.bus.canlog import read_frames

    path = _write_log(tmp_path / f"flight{suffix}", _frames())  # stamped in seconds since 1970
    frames = read_frames(path)
    assert frames.time_s.min() == 0.0 and frames.time_s.max() < 2.0
    log = import_can_log(path, [DEFAULT_ENGINE_DBC])
    assert 0.0 <= log.time_s[0] < 1.0


def test_replay_of_an_epoch_stamped_log_has_one_stamp_per_row(tmp_path: Path) -> None:
    from ecu_monitor.cli import main

    path = _write_log(tmp_path / "flight.log", _frames())
    out = tmp_path / "health.csv"
    assert main(["replay", str(path), "--out", str(out)]) == 0
    times = read_csv_times(out)
    assert len(times) >= 10 and times[0] < 1.0
    assert np.all(np.diff(times) > 0.0)  # 10 Hz rows, each its own stamp


def read_csv_times(path: Path) -> NDArray[np.float64]:
    lines = path.read_text().splitlines()
    column = lines[0].split(",").index("time_s")
    return np.array([float(line.split(",")[column]) for line in lines[1:]])


def test_one_frame_stamped_far_ahead_is_dropped_and_the_log_read(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from ecu_monitor.bus.canlog import read_frames

    frames = _frames()
    glitch = frames[60]
    frames[60] = can.Message(
        timestamp=99_999_999.0, arbitration_id=glitch.arbitration_id, data=glitch.data, is_extended_id=False
    )
    with caplog.at_level(logging.WARNING):
        read = read_frames(_write_log(tmp_path / "glitch.asc", frames))
    assert len(read) == len(frames) - 1 and read.time_s.max() < 2.0
    assert "1 frame(s) with a stamp out of line" in caplog.text


def _trc(tmp_path: Path, name: str, edit: Any) -> Path:
    source = _write_log(tmp_path / "source.trc", _frames()[:50])
    path = tmp_path / name
    path.write_text(edit(source.read_text()))
    return path


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (lambda t: t.replace("$COLUMNS=N,O,T,B,I,d,R,L,D", "$COLUMNS=N,O,B,I,d,R,L,D"), "no column 'T'"),
        (lambda t: re.sub(r"\$STARTTIME=\S+", "$STARTTIME=1e300", t), "beyond any calendar"),
        (lambda t: t.replace("$FILEVERSION=2.1", "$FILEVERSION=1.1"), "no frames: python-can skipped 50 line(s)"),
    ],
    ids=["no-T-column", "starttime-1e300", "header-1.1-body-2.1"],
)
def test_a_broken_trc_is_one_line(tmp_path: Path, caplog: pytest.LogCaptureFixture, edit: Any, words: str) -> None:
    from ecu_monitor.bus.canlog import read_frames

    path = _trc(tmp_path, "broken.trc", edit)
    assert path.read_text() != (tmp_path / "source.trc").read_text()
    with caplog.at_level(logging.INFO), pytest.raises(FlightLogError) as info:
        read_frames(path)
    assert words in str(info.value) and len(str(info.value).splitlines()) == 1
    assert len(caplog.records) <= 1  # not one INFO line per frame


_STAMP = st.one_of(
    st.floats(allow_nan=True, allow_infinity=False, width=64),
    st.sampled_from([0.0, -1.0, 1e12, 99_999_999.0, T0]),
)


@settings(max_examples=int(__import__("os").environ.get("ECU_FUZZ_EXAMPLES", "40")), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
@given(
    suffix=st.sampled_from([".blf", ".asc", ".log"]),
    stamps=st.lists(st.tuples(st.integers(0, 99), _STAMP), max_size=6),
    shift=st.sampled_from([0.0, T0, -T0 + 5.0]),
)
def test_bad_time_stamps_are_read_or_one_error(
    tmp_path: Path, suffix: str, stamps: list[tuple[int, float]], shift: float
) -> None:
    """A log with some stamps spoiled (NaN, negative, huge, the epoch): frames whose time runs from 0, or
    one FlightLogError line; never another exception."""
    from ecu_monitor.bus.canlog import read_frames

    frames = [m for m in _frames()[:100]]
    for index, stamp in stamps:
        m = frames[index]
        frames[index] = can.Message(timestamp=stamp, arbitration_id=m.arbitration_id, data=m.data, is_extended_id=False)
    frames = [
        can.Message(timestamp=m.timestamp - T0 + shift if abs(m.timestamp - T0) < 10 else m.timestamp,
                    arbitration_id=m.arbitration_id, data=m.data, is_extended_id=False)
        for m in frames
    ]  # fmt: skip
    path = tmp_path / f"stamps{suffix}"
    try:
        _write_log(path, frames)
    except (ValueError, OverflowError, OSError, struct.error):
        return  # python-can cannot write such a stamp: nothing for a logger to hand us either
    try:
        read = read_frames(path)
    except FlightLogError as exc:
        assert len(str(exc).splitlines()) == 1
    else:
        assert np.all(np.isfinite(read.time_s)) and read.time_s.min() == 0.0
