"""ecu_monitor.flightlog: the canonical flight CSV contract and the foreign-log importers."""

from __future__ import annotations

import logging
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import can
import cantools
import numpy as np
import pytest

from ecu_monitor.bus.checksum import frame_checksum
from ecu_monitor.errors import ConfigError, FlightLogError
from ecu_monitor.flightlog import (
    CANONICAL_COLUMNS,
    DEFAULT_ENGINE_DBC,
    DEFAULT_SIGNAL_MAP,
    MAPPINGS_DIR,
    FlightLog,
    import_can_log,
    import_mapped_csv,
    load_flight,
    load_mapping,
    read_csv,
    resolve_mapping,
    write_csv,
)

DATA = Path(__file__).resolve().parent / "data"
REPO = Path(__file__).resolve().parents[1]
# CI places the clone beside shared/ (../shared/data/g1000 relative to the repository root).
G1000_CSV = Path(__file__).resolve().parents[2] / "shared" / "data" / "g1000" / "log_110701_131851_KGFK.csv"

HEADER = "time_s,throttle_pct,rpm,altitude_m,airspeed_mps,oat_c,cht_c"
ROW = "{t},50,5000,100,20,15,{cht}"


def _write(tmp_path: Path, text: str, name: str = "flight.csv") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _good(n: int = 10, cht: Any = None) -> list[str]:
    return [ROW.format(t=k, cht=80 + k if cht is None else cht) for k in range(n)]


# --------------------------------------------------------------------------------------------------
# FlightLog
# --------------------------------------------------------------------------------------------------


def _log(n: int = 11) -> FlightLog:
    t = np.arange(n, dtype=float)
    return FlightLog({"time_s": t, "rpm": 1000.0 + 10 * t, "cht_c": 100.0 + t}, "mem")


def test_flightlog_basics() -> None:
    log = _log()
    assert len(log) == 11 and log.duration_s == 10.0
    assert log.has("rpm") and not log.has("oat_c")
    assert log.names == ("time_s", "rpm", "cht_c")
    with pytest.raises(FlightLogError, match=r"mem: no column 'oat_c'"):
        log["oat_c"]
    with pytest.raises(ValueError, match="read-only"):
        log["rpm"][0] = 0.0


def test_flightlog_rejects_bad_construction() -> None:
    with pytest.raises(FlightLogError, match="not strictly increasing"):
        FlightLog({"time_s": np.array([0.0, 1.0, 1.0])}, "mem")
    with pytest.raises(FlightLogError, match="'rpm' has 2 values, expected 3"):
        FlightLog({"time_s": np.array([0.0, 1.0, 2.0]), "rpm": np.array([1.0, 2.0])}, "mem")
    with pytest.raises(FlightLogError, match="no 'time_s'"):
        FlightLog({"rpm": np.array([1.0])}, "mem")


def test_select_with_columns_resample() -> None:
    log = _log()
    part = log.select(2.0, 4.5)
    assert part.time_s.tolist() == [2.0, 3.0, 4.0]  # absolute times kept
    with pytest.raises(FlightLogError, match="no samples between"):
        log.select(20.0, 30.0)
    extra = log.with_columns(oat_c=np.full(len(log), 15.0))
    assert extra.has("oat_c") and not log.has("oat_c")
    fine = log.resample(0.25)
    assert len(fine) == 41 and fine.time_s[-1] == pytest.approx(10.0)
    assert np.allclose(fine["rpm"], 1000.0 + 10 * fine.time_s)
    with pytest.raises(FlightLogError, match="positive"):
        log.resample(0.0)


# --------------------------------------------------------------------------------------------------
# Canonical CSV
# --------------------------------------------------------------------------------------------------


def test_write_read_round_trip_is_exact(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    n = 50
    t = np.cumsum(rng.uniform(0.01, 1.3, n))
    cols = {
        "egt_c": rng.normal(700, 30, n),  # extra first: written after the canonical ones
        "time_s": t,
        "cht_c": rng.uniform(60, 200, n),
        "oat_c": rng.uniform(-20, 30, n),
        "airspeed_mps": rng.uniform(0, 40, n),
        "altitude_m": rng.uniform(0, 3000, n),
        "rpm": rng.uniform(1000, 6000, n),
        "throttle_pct": rng.uniform(0, 100, n) / 3.0,
        "vspeed_mps": rng.normal(0, 2, n),
    }
    cols["egt_c"][3] = math.nan  # extra columns may keep gaps
    log = FlightLog(cols, "mem")
    path = tmp_path / "out.csv"
    write_csv(log, path)
    assert path.read_text().splitlines()[0] == ",".join((*CANONICAL_COLUMNS, "vspeed_mps", "egt_c"))
    again = read_csv(path)
    assert again.notes == ()
    for name in log.names:
        np.testing.assert_array_equal(again[name], log[name])


def test_golden_fixture(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.DEBUG, logger="ecu_monitor.flightlog"):
        log = read_csv(DATA / "flight_small.csv")
    assert log.names == (*CANONICAL_COLUMNS, "fuel_flow_lph", "egt_c")  # text column 'phase' dropped
    assert "'phase' holds text" in caplog.text
    assert log["rpm"].tolist() == [2000, 2010, 4500, 5200, 5210, 5100]
    assert math.isnan(log["egt_c"][3])
    assert log.duration_s == 5.0


def test_throttle_may_be_replaced_by_fuel_flow(tmp_path: Path) -> None:
    text = "time_s,fuel_flow_lph,rpm,altitude_m,airspeed_mps,oat_c,cht_c\n0,10,2000,100,0,15,80\n1,11,2000,100,0,15,81"
    log = read_csv(_write(tmp_path, text))
    assert not log.has("throttle_pct") and log["fuel_flow_lph"].tolist() == [10, 11]


BAD_CSV = {
    "missing column": (
        "time_s,throttle_pct,rpm,altitude_m,airspeed_mps,oat_c\n0,1,2,3,4,5\n",
        r"row 1, column 'cht_c': required column missing",
    ),
    "no throttle nor fuel flow": (
        "time_s,rpm,altitude_m,airspeed_mps,oat_c,cht_c\n0,1,2,3,4,5\n",
        r"row 1, column 'throttle_pct': required column missing \(a log without throttle",
    ),
    "non numeric": (
        "\n".join([HEADER, ROW.format(t=0, cht=80), "1,50,abc,100,20,15,81"]) + "\n",
        r"row 3, column 'rpm': 'abc' is not a number",
    ),
    "time backwards": (
        "\n".join([HEADER, *_good(3), ROW.format(t=1.5, cht=90)]) + "\n",
        r"row 5, column 'time_s': time goes backwards \(1.5 s after 2 s\)",
    ),
    "blank time": (
        "\n".join([HEADER, *_good(3), ROW.format(t="", cht=90)]) + "\n",
        r"row 5, column 'time_s': blank time",
    ),
    "long blank run": (
        "\n".join([HEADER, *_good(2), *(ROW.format(t=k, cht="") for k in range(2, 8)), ROW.format(t=8, cht=90)]) + "\n",
        r"row 4, column 'cht_c': 6 consecutive blank fields \(rows 4-9\)",
    ),
    "column blank everywhere": (
        "\n".join([HEADER, *_good(4, cht="")]) + "\n",
        r"rows 2-5, column 'cht_c': blank in every row",
    ),
    "rpm absurd": (
        "\n".join([HEADER, *_good(2), "2,50,40000,100,20,15,80"]) + "\n",
        r"row 4, column 'rpm': 40000 is outside the physical range 0..30000",
    ),
    "negative rpm": (
        "\n".join([HEADER, "0,50,-5,100,20,15,80"]) + "\n",
        r"row 2, column 'rpm': -5 is outside",
    ),
    "throttle absurd": (
        "\n".join([HEADER, *_good(2), "2,120,5000,100,20,15,80"]) + "\n",
        r"row 4, column 'throttle_pct': 120 is outside the physical range -1..101",
    ),
    "cht absurd": (
        "\n".join([HEADER, *_good(2), "2,50,5000,100,20,15,600"]) + "\n",
        r"row 4, column 'cht_c': 600 is outside the physical range -60..500",
    ),
    "oat absurd": (
        "\n".join([HEADER, *_good(2), "2,50,5000,100,20,-90,80"]) + "\n",
        r"row 4, column 'oat_c': -90 is outside the physical range -80..70",
    ),
    "empty file": ("", r"empty file"),
    "header only": (HEADER + "\n", r"row 1: header only, no data rows"),
    "short row inside": (
        "\n".join([HEADER, *_good(2), "2,50,5000", *_good(1)]) + "\n",
        r"row 4: 3 fields, the header has 7",
    ),
    "infinite": (
        "\n".join([HEADER, "0,50,5000,inf,20,15,80"]) + "\n",
        r"row 2, column 'altitude_m': 'inf' is not finite",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_CSV))
def test_bad_csv_names_file_row_and_column(case: str, tmp_path: Path) -> None:
    text, pattern = BAD_CSV[case]
    path = _write(tmp_path, text)
    with pytest.raises(FlightLogError, match=pattern) as info:
        read_csv(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and "\n" not in message


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(FlightLogError, match="no such file"):
        read_csv(tmp_path / "nope.csv")


def test_repairs_are_warned_and_noted(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    rows = [
        ROW.format(t=0, cht=80),
        ROW.format(t=1, cht=82),
        ROW.format(t=1, cht=99),  # repeated timestamp: first kept
        ROW.format(t=2, cht=""),  # isolated blank: interpolated
        ROW.format(t=3, cht=""),
        ROW.format(t=4, cht=88),
        ROW.format(t=12, cht=90),  # 8 s gap: kept, warned
        "13,50,5000,100",  # truncated last row: dropped
    ]
    path = _write(tmp_path, "\n".join([HEADER, *rows]))
    with caplog.at_level(logging.WARNING, logger="ecu_monitor.flightlog"):
        log = read_csv(path)
    assert log.time_s.tolist() == [0, 1, 2, 3, 4, 12]
    assert log["cht_c"].tolist() == pytest.approx([80, 82, 84, 86, 88, 90])
    assert len(log.notes) == 4
    for text in (
        "1 repeated timestamp(s) dropped",
        "column 'cht_c': 2 blank field(s) interpolated",
        "1 time gap(s) longer than 5 s",
        "row 9: truncated last row (4 of 7 fields) dropped",
    ):
        assert text in caplog.text


def test_blank_at_edges_holds_nearest(tmp_path: Path) -> None:
    rows = [ROW.format(t=0, cht=""), *(ROW.format(t=k, cht=80 + k) for k in range(1, 4)), ROW.format(t=4, cht="")]
    log = read_csv(_write(tmp_path, "\n".join([HEADER, *rows]) + "\n"))
    assert log["cht_c"].tolist() == [81, 81, 82, 83, 83]


# --------------------------------------------------------------------------------------------------
# Mapped CSV
# --------------------------------------------------------------------------------------------------


def test_mapped_import_converts_units_and_repairs() -> None:
    log = import_mapped_csv(DATA / "foreign_small.csv", DATA / "foreign_small.yaml")
    assert log.time_s.tolist() == [0.0, 0.5, 1.0, 2.0]  # ms -> s, repeated 1000 ms dropped, cut row dropped
    assert log["altitude_m"].tolist() == pytest.approx([304.8, 304.8, 335.28, 365.76])
    assert log["airspeed_mps"].tolist() == pytest.approx([0.0, 0.0, 10 * 1852 / 3600, 20 * 1852 / 3600])
    assert log["oat_c"].tolist() == pytest.approx([15.0, 15.0, 15.0, 14.0])
    f_to_c = [(f - 32) * 5 / 9 for f in (230, 232, 240)]  # hottest of A/B per row
    at_1s = f_to_c[1] + (f_to_c[2] - f_to_c[1]) * (1.0 - 0.5) / (2.0 - 0.5)  # blank A at 1 s -> interpolated
    assert log["cht_c"].tolist() == pytest.approx([f_to_c[0], f_to_c[1], at_1s, f_to_c[2]])
    assert log["rpm"].tolist() == [2000, 2000, 4000, 5000]
    assert len(log.notes) == 4


def _mapping_text(**replace: str) -> str:
    text = (DATA / "foreign_small.yaml").read_text()
    for old, new in replace.items():
        text = text.replace(old, new)
    return text


BAD_MAPPINGS = {
    "unknown unit": ({"unit: ft}": "unit: furlong}"}, r"key 'columns.altitude_m.unit': unknown unit 'furlong'"),
    "wrong quantity": ({"unit: ft}": "unit: kt}"}, r"key 'columns.altitude_m.unit': 'kt' is a speed unit"),
    "absent column": ({'"Alt"': '"AltX"'}, r"key 'columns.altitude_m.column': column 'AltX' not in"),
    "absent time column": ({'"Time ms"': '"Clock"'}, r"key 'time.column': column 'Clock' not in"),
    "unknown key": ({"header_row: 3": "header_line: 3"}, r"key 'header_line': unknown key"),
    "unknown nested key": ({"reduce: max": "reduce: max, scale: 2"}, r"key 'columns.cht_c.scale': unknown key"),
    "bad reduction": ({"reduce: max": "reduce: median"}, r"key 'columns.cht_c.reduce': unknown reduction"),
    "bad time kind": ({"kind: seconds": "kind: epoch"}, r"key 'time.kind': unknown time kind 'epoch'"),
    "missing canonical": ({'  rpm: {column: "RPM", unit: rpm}\n': ""}, r"key 'columns': canonical column 'rpm'"),
    "wrong type": ({"header_row: 3": "header_row: three"}, r"key 'header_row': expected int"),
    "not yaml": ({"format: csv": "format: [csv"}, r"not valid YAML"),
}


@pytest.mark.parametrize("case", sorted(BAD_MAPPINGS))
def test_bad_mapping_names_file_and_key(case: str, tmp_path: Path) -> None:
    replace, pattern = BAD_MAPPINGS[case]
    mapping = _write(tmp_path, _mapping_text(**replace), "bad.yaml")
    with pytest.raises(ConfigError, match=pattern) as info:
        import_mapped_csv(DATA / "foreign_small.csv", mapping)
    assert str(info.value).startswith(f"{mapping}: ") and "\n" not in str(info.value)


def test_resolve_shipped_mapping() -> None:
    assert resolve_mapping("g1000") == MAPPINGS_DIR / "g1000.yaml"
    assert load_mapping(resolve_mapping("g1000")).header_row == 3
    with pytest.raises(ConfigError, match=r"shipped: .*g1000"):
        resolve_mapping("nonexistent")


@pytest.mark.skipif(not G1000_CSV.exists(), reason=f"shared G1000 data not found at {G1000_CSV}")
def test_g1000_import() -> None:
    log = load_flight(G1000_CSV, mapping="g1000")
    assert not log.has("throttle_pct") and log.has("fuel_flow_lph")
    for name in CANONICAL_COLUMNS[2:]:
        assert log.has(name)
    assert 6100 < len(log) < 6250 and 6300 < log.duration_s < 6400  # ~105 min with skipped seconds
    assert log.time_s[0] == 0.0 and np.all(np.diff(log.time_s) >= 1.0)
    assert log["airspeed_mps"].min() == 0.0  # slightly negative IAS clipped
    cht = log["cht_c"]
    assert 30 < cht[0] < 45 and 150 < cht.max() < 200  # engine warming from a cold start, cruise ~170 degC
    assert 1000 < log["altitude_m"].max() < 1200  # climb to 3,500 ft
    notes = " | ".join(log.notes)
    assert "truncated last row" in notes and "repeated timestamp" in notes and "clipped to 0" in notes


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
        add(0.01 + 0.1 * k, slow, {"CHT": 100 + k, "OAT": -5.5, "EcuStatus": 0}, k)
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
    with caplog.at_level(logging.WARNING, logger="ecu_monitor.flightlog"):
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
    with pytest.raises(FlightLogError, match=r"unknown log type '.parquet'"):
        load_flight(tmp_path / "x.parquet")


# --------------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------------


def _cli(*args: str | Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ecu_monitor.cli", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=60,
        check=False,
    )


def test_cli_import_bad_csv_exits_2_with_one_line(tmp_path: Path) -> None:
    result = _cli("import", DATA / "bad_rpm_text.csv", "--out", tmp_path / "out.csv", cwd=tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "bad_rpm_text.csv: row 3, column 'rpm': 'abc' is not a number" in lines[0]
    assert not (tmp_path / "out.csv").exists()


def test_cli_import_bad_mapping_exits_2_with_one_line(tmp_path: Path) -> None:
    args = ("import", DATA / "foreign_small.csv", "--mapping", DATA / "bad_mapping_unit.yaml")
    result = _cli(*args, "--out", tmp_path / "out.csv", cwd=tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "bad_mapping_unit.yaml: key 'columns.altitude_m.unit'" in lines[0]


def test_cli_import_mapped_csv(tmp_path: Path) -> None:
    out = tmp_path / "flight.csv"
    args = ("--log-level", "ERROR", "import", DATA / "foreign_small.csv", "--mapping", DATA / "foreign_small.yaml")
    result = _cli(*args, "--out", out, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().startswith(f"{out}: 4 rows, 2.0 s") and "4 warning(s)" in result.stdout
    assert read_csv(out).names == ("time_s", "throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c", "cht_c")


RUSEFI_DBC = G1000_CSV.parents[1] / "dbc" / "rusEFI_CAN_verbose.dbc"


@pytest.mark.skipif(not RUSEFI_DBC.exists(), reason=f"shared rusEFI DBC not found at {RUSEFI_DBC}")
def test_cli_import_can_log_of_another_ecu_is_configuration(tmp_path: Path) -> None:
    rus: Any = cantools.database.load_file(str(RUSEFI_DBC), strict=False)
    ours: Any = cantools.database.load_file(str(DEFAULT_ENGINE_DBC), strict=True)
    base1, base2, base3 = (rus.get_message_by_name(n) for n in ("BASE1", "BASE2", "BASE3"))
    air = ours.get_message_by_name("AirData")

    def zeros(msg: Any, **values: float) -> bytes:
        return bytes(msg.encode({**{s.name: 0 for s in msg.signals}, **values}, strict=False))

    frames = []
    for k in range(12):
        t = T0 + 0.1 * k
        frames += [
            (t, base1.frame_id, zeros(base1, RPM=5000 + k)),
            (t + 0.01, base2.frame_id, zeros(base2, TPS1=42.0)),
            (t + 0.02, base3.frame_id, zeros(base3, AUX1Temp=150 + k, IntakeTemp=20, CoolantTemp=0, MCUTemp=0)),
            (t + 0.03, air.frame_id, zeros(air, PressureAltitude=800, CalibratedAirspeed=25.0)),
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
    result = _cli(*args, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    log = read_csv(out)
    assert set(log.names) == {"time_s", *signals}
    assert log["rpm"][0] == 5000 and log["cht_c"][0] == 150 and log["throttle_pct"][0] == 42.0


def test_trailing_comma_column_is_dropped(tmp_path: Path) -> None:
    text = "\n".join([HEADER + ",", *(row + "," for row in _good(3))]) + "\n"
    log = read_csv(_write(tmp_path, text))
    assert log.names == CANONICAL_COLUMNS and len(log) == 3
