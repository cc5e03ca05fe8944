"""ecu_monitor.flightlog: the canonical flight CSV contract and the foreign-log importers."""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ecu_monitor.errors import ConfigError, FlightLogError, UserInputError
from ecu_monitor.flightlog import (
    CANONICAL_COLUMNS,
    MAPPINGS_DIR,
    FlightLog,
    cht_limit_warning,
    cht_peak,
    cylinder_columns,
    describe_cht,
    detect_layout,
    import_mapped_csv,
    load_csv,
    load_mapping,
    read_csv,
    resolve_mapping,
    seconds_above,
    write_csv,
)
from tests.helpers import REPO, run_cli

DATA = REPO / "tests" / "data"
# CI places the clone beside shared/ (../shared/data/g1000 relative to the repository root).
G1000_CSV = REPO.parent / "shared" / "data" / "g1000" / "log_110701_131851_KGFK.csv"

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


def test_mapped_unit_may_be_scale_and_offset(tmp_path: Path) -> None:
    """A unit the table does not know (ft as scale 0.3048, degF as 5/9 and -160/9) reads like the named one."""
    custom = _mapping_text(
        **{
            "unit: ft}": "unit: {scale: 0.3048, offset: 0}}",
            "unit: degF}": "unit: {scale: 0.5555555556, offset: -17.77777778}}",
        }
    )
    assert "scale: 0.3048" in custom and "offset: -17.7" in custom
    named = import_mapped_csv(DATA / "foreign_small.csv", DATA / "foreign_small.yaml")
    log = import_mapped_csv(DATA / "foreign_small.csv", _write(tmp_path, custom, "custom.yaml"))
    for name in ("altitude_m", "cht_c"):
        assert log[name].tolist() == pytest.approx(named[name].tolist())


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
    "custom unit without scale": ({"unit: ft}": "unit: {offset: 1}}"}, r"key 'columns.altitude_m.unit': a custom"),
    "custom unit scale 0": ({"unit: ft}": "unit: {scale: 0}}"}, r"key 'columns.altitude_m.unit': custom unit scale"),
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
    log = load_csv(G1000_CSV, mapping="g1000")
    assert not log.has("throttle_pct") and log.has("fuel_flow_lph")
    for name in CANONICAL_COLUMNS[2:]:
        assert log.has(name)
    assert 6100 < len(log) < 6250 and 6300 < log.duration_s < 6400  # ~105 min with skipped seconds
    assert log.time_s[0] == 0.0 and log.time_s[1] == 0.5  # the second logged twice at the start: both rows kept
    assert log["airspeed_mps"].min() == 0.0  # slightly negative IAS clipped
    cht = log["cht_c"]
    assert 30 < cht[0] < 45 and 150 < cht.max() < 200  # engine warming from a cold start, cruise ~170 degC
    assert 1000 < log["altitude_m"].max() < 1200  # climb to 3,500 ft
    notes = " | ".join(log.notes)
    assert "truncated last row" in notes and "share a whole-second stamp" in notes and "clipped to 0" in notes
    assert cylinder_columns(log, "cht") == ["cht1_c", "cht2_c", "cht3_c", "cht4_c"]


# --------------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------------


def test_cli_import_bad_csv_exits_2_with_one_line(tmp_path: Path) -> None:
    result = run_cli("import", DATA / "bad_rpm_text.csv", "--out", tmp_path / "out.csv", cwd=tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "bad_rpm_text.csv: row 3, column 'rpm': 'abc' is not a number" in lines[0]
    assert not (tmp_path / "out.csv").exists()


def test_cli_import_bad_mapping_exits_2_with_one_line(tmp_path: Path) -> None:
    args = ("import", DATA / "foreign_small.csv", "--mapping", DATA / "bad_mapping_unit.yaml")
    result = run_cli(*args, "--out", tmp_path / "out.csv", cwd=tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "bad_mapping_unit.yaml: key 'columns.altitude_m.unit'" in lines[0]


def test_cli_import_mapped_csv(tmp_path: Path) -> None:
    out = tmp_path / "flight.csv"
    args = ("--log-level", "ERROR", "import", DATA / "foreign_small.csv", "--mapping", DATA / "foreign_small.yaml")
    result = run_cli(*args, "--out", out, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().startswith(f"{out}: 4 rows, 2.0 s") and "4 warning(s)" in result.stdout
    assert read_csv(out).names == ("time_s", "throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c", "cht_c")


def test_trailing_comma_column_is_dropped(tmp_path: Path) -> None:
    text = "\n".join([HEADER + ",", *(row + "," for row in _good(3))]) + "\n"
    log = read_csv(_write(tmp_path, text))
    assert log.names == CANONICAL_COLUMNS and len(log) == 3


# --------------------------------------------------------------------------------------------------
# Real exports: layouts, firmware versions, engines and cylinders
# --------------------------------------------------------------------------------------------------

REAL_DIR = G1000_CSV.parents[1] / "real"

G1000_UNITS = "#yyy-mm-dd, hh:mm:ss, hh:mm, ft, deg C, kt, gph, rpm, {cht}, {cht}, deg F, deg F, deg F, fpm"
G1000_NAMES = "  Lcl Date, Lcl Time, UTCOfst, {alt}, OAT, IAS, " + (
    "E1 FFlow, E1 RPM, E1 CHT1, E1 CHT2, E1 EGT1, E1 EGT2, E1 OilT, VSpd"
)


def _g1000(
    tmp_path: Path,
    rows: list[tuple[str, str, str]] | list[tuple[str, str, str, str]],
    *,
    date_style: str = "iso",
    alt: str = "AltB",
    cht_unit: str = "deg F",
    trailing: str = "",
) -> Path:
    """A small G1000 export: rows of (time, altitude ft, 'CHT1 CHT2' degF[, UTC offset]) on 2023-04-24
    (or 2023/4/24)."""
    date = "2023-04-24" if date_style == "iso" else "2023/4/24"
    header = '#airframe_info, log_version="1.01", airframe_name="Cessna 172S", system_id="25BA2E6F4"'
    if date_style != "iso":
        header += ', flightstream_header="25BA2E6F4_20000101_000000", ,,,,,,'
    lines = [header, G1000_UNITS.format(cht=cht_unit) + trailing, G1000_NAMES.format(alt=alt) + trailing]
    for clock, altitude, chts, *offset in rows:
        c1, c2 = chts.split()
        utc = offset[0] if offset else "+08:00"
        lines.append(
            f"{date}, {clock}, {utc}, {altitude}, 15.0, 60.0, 10.0, 2400, {c1}, {c2}, 1300, 1400, 180, 0{trailing}"
        )
    path = tmp_path / f"g1000_{date_style}_{alt}.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


def _degc(f: float) -> float:
    return (f - 32.0) * 5.0 / 9.0


GOOD_ROWS = [
    ("10:00:00", "1000", "300 320"),
    ("10:00:01", "1010", "302 322"),
    ("10:00:01", "1020", "304 324"),  # a second logged twice: spread over that second
    ("10:00:03", "", "306 326"),  # a skipped second; blank altitude (interpolated)
    ("10:00:04", "1040", "308 328"),
]


@pytest.mark.parametrize(("date_style", "alt"), [("iso", "AltB"), ("slash", "AltInd")])
def test_g1000_firmware_versions_import_alike(date_style: str, alt: str, tmp_path: Path) -> None:
    path = _g1000(tmp_path, GOOD_ROWS, date_style=date_style, alt=alt, trailing=", ," if alt == "AltInd" else "")
    for log in (load_csv(path), load_csv(path, mapping="g1000")):  # recognised, or named
        assert log.time_s.tolist() == [0.0, 1.0, 1.5, 3.0, 4.0]
        feet = [1000, 1010, 1020, 1020 + 20 * 1.5 / 2.5, 1040]  # the blank at 3 s interpolated in time
        assert log["altitude_m"].tolist() == pytest.approx([0.3048 * f for f in feet])
        assert log["airspeed_mps"][0] == pytest.approx(60 * 1852 / 3600)
        assert log["fuel_flow_lph"][0] == pytest.approx(37.85411784)
        assert log["cht1_c"].tolist() == pytest.approx([_degc(f) for f in (300, 302, 304, 306, 308)])
        assert log["cht2_c"].tolist() == pytest.approx([_degc(f) for f in (320, 322, 324, 326, 328)])
        assert log["cht_c"].tolist() == pytest.approx([_degc(f) for f in (310, 312, 314, 316, 318)])  # the mean
        assert log["egt_c"][0] == pytest.approx(_degc(1350)) and log["egt_max_c"][0] == pytest.approx(_degc(1400))
        assert log["oil_temp_c"][0] == pytest.approx(_degc(180))
        assert describe_cht(log) == "mean of cylinders 1, 2"
        notes = " | ".join(log.notes)
        assert "1 row(s) share a whole-second stamp" in notes and "'altitude_m': 1 blank field(s) interpolated" in notes


def test_time_is_utc_across_a_clock_change(tmp_path: Path) -> None:
    rows = [
        ("01:59:58", "1000", "300 320", "-05:00"),
        ("01:59:59", "1000", "300 320", ""),  # a blank offset takes the row before's
        ("01:00:00", "1000", "300 320", "-06:00"),  # local clock back one hour: one second later in UTC
        ("01:00:01", "1000", "300 320", "-06:00"),
    ]
    log = load_csv(_g1000(tmp_path, rows))
    assert log.time_s.tolist() == [0.0, 1.0, 2.0, 3.0]
    assert any("UTC offset changes 1 time(s) (first at row 6, -5 h -> -6 h)" in n for n in log.notes)
    bad = _g1000(tmp_path, [("10:00:00", "1000", "300 320", "EST")])
    with pytest.raises(FlightLogError, match=r"row 4, column 'UTCOfst': 'EST' is not a UTC offset like \+08:00"):
        load_csv(bad)


def test_fractional_seconds_in_the_clock(tmp_path: Path) -> None:
    rows = [("10:00:00", "1000", "300 320"), ("10:00:00.5", "1000", "300 320"), ("10:00:01.25", "1000", "300 320")]
    assert load_csv(_g1000(tmp_path, rows)).time_s.tolist() == [0.0, 0.5, 1.25]


def test_joined_exports_and_latin1_text(tmp_path: Path) -> None:
    first = _g1000(tmp_path, GOOD_ROWS[:2]).read_text().splitlines()
    second = _g1000(tmp_path, [("10:00:05", "1050", "310 330")]).read_text().splitlines()
    joined = tmp_path / "joined.csv"
    joined.write_bytes(("\n".join(first + second) + "\n").replace("Cessna", "Cessna \u00b0").encode("latin-1"))
    log = load_csv(joined)
    assert log.time_s.tolist() == [0.0, 1.0, 5.0]
    assert log["cht1_c"][-1] == pytest.approx(_degc(310))
    notes = " | ".join(log.notes)
    assert "3 repeated header line(s) dropped (first at row 6)" in notes and "read as Latin-1" in notes


def test_cht_choice_mean_hottest_or_one(tmp_path: Path) -> None:
    rows = [("10:00:00", "1000", "300 320"), ("10:00:01", "1000", "340 320"), ("10:00:02", "1000", "350 310")]
    path = _g1000(tmp_path, rows)
    hottest = load_csv(path, cht="hottest")
    assert hottest["cht_c"].tolist() == pytest.approx([_degc(320), _degc(340), _degc(350)])
    assert describe_cht(hottest) == "hottest of cylinders 1, 2 (per row)"
    second = load_csv(path, cht="2")
    assert second["cht_c"].tolist() == pytest.approx([_degc(320)] * 2 + [_degc(310)])
    assert describe_cht(second) == "cylinder 2 of 1, 2"
    with pytest.raises(FlightLogError, match=r"cylinder 3 chosen for cht_c, the log has cylinder\(s\) 1, 2"):
        load_csv(path, cht=3)
    with pytest.raises(UserInputError, match=r"CHT choice 'coolest': expected mean, hottest or a cylinder number"):
        load_csv(path, cht="coolest")
    peak = cht_peak(second)
    assert (peak.cylinder, peak.column, peak.time_s) == (1, "cht1_c", 2.0)
    assert peak.value_c == pytest.approx(_degc(350))
    assert seconds_above(second, _degc(330)) == 1.0  # 340 F at 1 s (interval 1-2 s); 350 F is the last sample
    assert cht_limit_warning(second, _degc(350) + 0.01) is None
    warning = cht_limit_warning(second, _degc(330))
    assert warning == (
        f"{path}: CHT reaches {_degc(350):.1f} degC (cylinder 1 at 2 s), above the limit {_degc(330):g} degC"
        " for 1 s (50 % of the flight)"
    )
    # per-cylinder columns survive the canonical CSV, and the choice can be remade from it
    out = tmp_path / "flight.csv"
    write_csv(second, out)
    again = read_csv(out)
    assert again.names[: len(CANONICAL_COLUMNS) - 1] == CANONICAL_COLUMNS[:1] + CANONICAL_COLUMNS[2:]
    assert describe_cht(again) == "cylinder 2 of 1, 2"
    assert describe_cht(load_csv(out, cht="mean")) == "mean of cylinders 1, 2"


def test_dead_cylinder_probe_is_dropped(tmp_path: Path) -> None:
    rows = [("10:00:00", "1000", "300 X"), ("10:00:01", "1000", "302 X"), ("10:00:02", "1000", "304 X")]
    path = _g1000(tmp_path, rows)
    path.write_text(path.read_text().replace(", X,", ",    ,"))
    log = load_csv(path)
    assert cylinder_columns(log, "cht") == ["cht1_c"] and describe_cht(log) == "cylinder 1 (the only one)"
    assert "column 'cht2_c': blank in every row: dropped" in log.notes
    with pytest.raises(FlightLogError, match=r"cylinder 2 chosen for cht_c, the log has cylinder\(s\) 1"):
        load_csv(path, cht=2)


def test_an_export_without_one_cylinders_column_keeps_the_others_and_says_so(tmp_path: Path) -> None:
    """A G1000 export whose EGT1 column is missing (not blank: absent) kept no EGT at all before, silently;
    now cylinder 2's EGT is kept, the hole is warned, and egt_c is the mean of what is there."""
    path = _g1000(tmp_path, GOOD_ROWS[:2])
    path.write_text(path.read_text().replace("E1 EGT1,", "E1 EGTX,"))
    log = load_csv(path, mapping="g1000")
    assert cylinder_columns(log, "egt") == ["egt2_c"] and log.has("egt_c")
    assert np.allclose(log["egt_c"], log["egt2_c"])
    assert "no column 'E1 EGT1' among cylinders 1-2: egt1_c absent, the others kept" in log.notes


def test_describe_cht_of_a_log_without_cylinders_or_without_any_cht() -> None:
    """A CAN log imported with a partial signal map may carry no CHT at all: the summary says so
    instead of calling a missing column "the log's own channel"."""
    t = np.arange(3.0)
    assert (
        describe_cht(FlightLog({"time_s": t, "cht_c": t + 100.0})) == "the log's own channel (no per-cylinder columns)"
    )
    assert describe_cht(FlightLog({"time_s": t, "rpm": t + 2000.0})).startswith("absent (no CHT in the log")


def test_units_row_of_the_file_wins(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = _g1000(tmp_path, [("10:00:00", "1000", "150 160"), ("10:00:01", "1000", "151 161")], cht_unit="deg C")
    log = load_csv(path)
    assert log["cht1_c"].tolist() == [150.0, 151.0] and log["cht_c"][0] == 155.0
    assert "column 'E1 CHT1': the file's units row says 'deg C': read as degC, not the mapping's degF" in log.notes
    wrong = _g1000(tmp_path, [("10:00:00", "1000", "150 160")], cht_unit="kt")
    with pytest.raises(FlightLogError, match=r"row 2, column 'E1 CHT1': unit 'kt' is a speed unit, 'cht1_c' needs"):
        load_csv(wrong)


NGAFID_NAMES = "AltAGL,AltB,E1 CHT1,E1 EGT1,E1 EGT2,E1 FFlow,E1 MAP,E1 RPM,{twin}IAS,OAT,VSpd"
NGAFID_TWIN = "E2 CHT1,E2 EGT1,E2 EGT2,E2 FFlow,E2 MAP,E2 RPM,"


def _ngafid(tmp_path: Path, *, time: bool, units: bool, twin: bool) -> Path:
    names = NGAFID_NAMES.format(twin=NGAFID_TWIN if twin else "")
    lines = [("Time," if time else "") + names]
    if units:
        unit_text = "ft,ft,deg F,deg F,deg F,gph,inch,rpm," + ("deg F,deg F,deg F,gph,inch,rpm," if twin else "")
        lines.append(("s," if time else "") + unit_text + "kt,deg C,fpm")
    for k in range(4):
        cht = "NaN" if k == 2 else str(350 + k)
        e2 = f"{300 + k},1200,1250,8.0,20.0,2300," if twin else ""
        row = f"10,{2000 + 10 * k},{cht},1300,1320,10.0,25.0,2500,{e2}90,12.5,100"
        lines.append((f"{10 + 2 * k}," if time else "") + row)
    path = tmp_path / f"ngafid_time{int(time)}_units{int(units)}_twin{int(twin)}.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(("time", "units"), [(True, False), (False, True), (True, True)])
def test_ngafid_processed_layout(time: bool, units: bool, tmp_path: Path) -> None:
    log = load_csv(_ngafid(tmp_path, time=time, units=units, twin=False))
    assert log.time_s.tolist() == ([0.0, 2.0, 4.0, 6.0] if time else [0.0, 1.0, 2.0, 3.0])
    assert log["altitude_m"].tolist() == pytest.approx([0.3048 * (2000 + 10 * k) for k in range(4)])
    expected_f = [350.0, 351.0, (351.0 + 353.0) / 2 if time else 352.0, 353.0]  # NaN interpolated in time
    assert log["cht_c"].tolist() == pytest.approx([_degc(f) for f in expected_f])
    assert log["manifold_pressure_kpa"][0] == pytest.approx(25.0 * 3.386389)
    assert log["oat_c"][0] == 12.5 and log["egt_c"][0] == pytest.approx(_degc(1310))
    assert describe_cht(log) == "cylinder 1 (the only one)"
    assert any("no column 'Time'" in n for n in log.notes) is not time


def test_baro_corrected_altitude_becomes_pressure_altitude(tmp_path: Path) -> None:
    rows = ["Time,AltB,BaroA,E1 CHT1,E1 FFlow,E1 RPM,IAS,OAT"]
    rows += [f"{k},{1000 + 100 * k},{baro},350,10,2400,90,15" for k, baro in enumerate(["29.92", "30.92", "", "28.5"])]
    log = load_csv(_write(tmp_path, "\n".join(rows) + "\n", "baro.csv"))

    def pressure_altitude_ft(feet: float, inhg: float) -> float:  # NOAA: ft and inHg, datum 29.9213 inHg
        return feet + (1.0 - (inhg / 29.9213) ** 0.190263) * 145366.45

    expected_ft = [pressure_altitude_ft(1000 + 100 * k, b) for k, b in enumerate([29.92, 30.92, 30.92, 28.5])]
    assert log["altitude_m"].tolist() == pytest.approx([0.3048 * f for f in expected_ft], abs=0.05)
    assert log["altitude_m"][1] < 0.3048 * 1100 - 250  # 1 inHg above standard: ~1000 ft below the reading
    silly = _write(tmp_path, "\n".join([*rows[:2], rows[2].replace("30.92", "3092")]) + "\n", "silly.csv")
    with pytest.raises(FlightLogError, match=r"row 3, column 'BaroA': altimeter setting 10470.7 kPa is outside 85"):
        load_csv(silly)


def test_twin_engine_is_the_users_choice(tmp_path: Path) -> None:
    path = _ngafid(tmp_path, time=True, units=True, twin=True)
    with pytest.raises(FlightLogError, match=r"2 engines \('E1 RPM', 'E2 RPM'\): choose one with --engine N"):
        load_csv(path)
    first, second = load_csv(path, engine=1), load_csv(path, engine=2)
    assert first["rpm"][0] == 2500 and second["rpm"][0] == 2300
    assert first["cht_c"][0] == pytest.approx(_degc(350)) and second["cht_c"][0] == pytest.approx(_degc(300))
    assert second["fuel_flow_lph"][0] == pytest.approx(8.0 * 3.785411784)
    with pytest.raises(FlightLogError, match=r"no engine 3 in the file \(engines: 1, 2\)"):
        load_csv(path, engine=3)
    single = _g1000(tmp_path, GOOD_ROWS)
    with pytest.raises(FlightLogError, match=r"no engine 2 in the file \(engines: 1\)"):
        load_csv(single, engine=2)


def test_unknown_layout_says_why_no_layout_fits(tmp_path: Path) -> None:
    path = _write(tmp_path, "Clock,Height,Temp\n1,2,3\n", "other.csv")
    with pytest.raises(FlightLogError) as info:
        load_csv(path)
    message = str(info.value)
    assert message.startswith(f"{path}: not a canonical flight CSV (no column 'time_s') and no known layout fits")
    assert (
        "g1000: no column 'Lcl Date'" in message
        and "ngafid_processed: no column 'AltB' or 'AltInd' or 'AltMSL'" in message
    )
    assert "ecu-monitor import" in message and "--mapping MAPPING.yaml" in message and "\n" not in message


def test_detect_layout(tmp_path: Path) -> None:
    assert detect_layout(DATA / "flight_small.csv") is None  # canonical
    assert detect_layout(_g1000(tmp_path, GOOD_ROWS)) == MAPPINGS_DIR / "g1000.yaml"
    assert detect_layout(_ngafid(tmp_path, time=False, units=True, twin=True)) == MAPPINGS_DIR / "ngafid_processed.yaml"


BAD_CYLINDER_MAPPINGS = {
    "no placeholder": (
        'cht: {column: "E{engine} CHT{n}"',
        'cht: {column: "E{engine} CHT1"',
        r"cylinder number placeholder",
    ),
    "cht_c mapped too": ("columns:\n", 'columns:\n  cht_c: {column: "E1 CHT1", unit: degF}\n', r"cht_c is made from"),
    "optional canonical": (
        '{column: "IAS", unit: kt}',
        '{column: "IAS", unit: kt, optional: true}',
        r"cannot be optional",
    ),
    "units row inside data": ("units_row: 2", "units_row: 5", r"key 'units_row': expected a line above the header"),
}


@pytest.mark.parametrize("case", sorted(BAD_CYLINDER_MAPPINGS))
def test_bad_cylinder_mapping_names_key(case: str, tmp_path: Path) -> None:
    old, new, pattern = BAD_CYLINDER_MAPPINGS[case]
    text = (MAPPINGS_DIR / "g1000.yaml").read_text()
    assert old in text
    mapping = _write(tmp_path, text.replace(old, new, 1), "bad.yaml")
    with pytest.raises(ConfigError, match=pattern) as info:
        load_mapping(mapping)
    assert str(info.value).startswith(f"{mapping}: ")


def test_cli_import_several_files_one_line_per_bad_file(tmp_path: Path) -> None:
    good = _g1000(tmp_path, GOOD_ROWS)
    twin = _ngafid(tmp_path, time=True, units=False, twin=True)
    bad = _write(tmp_path, "Clock,Height\n1,2\n", "other.csv")
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    result = run_cli(
        "--log-level", "ERROR", "import", good, twin, bad, "--out-dir", out_dir, "--cht", "hottest", cwd=tmp_path
    )
    assert result.returncode == 2
    errors = result.stderr.strip().splitlines()
    assert len(errors) == 2
    assert f"{twin}: 2 engines" in errors[0] and f"{bad}: not a canonical flight CSV" in errors[1]
    assert result.stdout.count("\n") == 1 and "cht_c = hottest of cylinders 1, 2 (per row)" in result.stdout
    assert read_csv(out_dir / good.name).has("cht2_c")
    result = run_cli(
        "--log-level", "ERROR", "import", twin, "--engine", "2", "--out", tmp_path / "e2.csv", cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr
    assert "cht_c = cylinder 1 (the only one)" in result.stdout


# README durations of the given flights (minutes); every given export must import.
REAL_FLIGHTS = {
    "ngafid_c172s_n550nd_20170504_1559.csv": 106,
    "ngafid_c172s_n550nd_20170504_1836.csv": 96,
    "ngafid_c172s_n550nd_20170505_0835.csv": 110,
    "ngafid_c172s_n550nd_20170509_1456.csv": 82,
    "cafuc_c172s_25BA_20230424_circuits.csv": 60,
    "cafuc_c172r_2D87_20230425_circuits.csv": 52,
    "ngafid_pa44_flight_17270.csv": 90,
}


@pytest.mark.skipif(not REAL_DIR.exists(), reason=f"shared real flight data not found at {REAL_DIR}")
@pytest.mark.parametrize("name", sorted(REAL_FLIGHTS))
def test_every_given_real_export_imports(name: str) -> None:
    twin = "pa44" in name
    log = load_csv(REAL_DIR / name, engine=1 if twin else None)
    assert abs(log.duration_s / 60.0 - REAL_FLIGHTS[name]) < 1.0
    assert np.all(np.diff(log.time_s) > 0.0) and np.median(np.diff(log.time_s)) == 1.0
    chts = cylinder_columns(log, "cht")
    assert len(chts) == (1 if twin else 4) and len(cylinder_columns(log, "egt")) == 4
    stack = np.vstack([log[c] for c in chts])
    assert np.all(log["cht_c"] >= stack.min(axis=0)) and np.all(log["cht_c"] <= stack.max(axis=0))
    for column in ("rpm", "fuel_flow_lph", "altitude_m", "airspeed_mps", "oat_c", "egt_c", "oil_temp_c"):
        assert np.all(np.isfinite(log[column])), column
    assert 60.0 < np.median(log["cht_c"]) < 250.0  # degC, not degF
    assert log.has("manifold_pressure_kpa") is twin


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    cut=st.integers(min_value=0, max_value=2000),
    junk=st.one_of(st.binary(max_size=40), st.text(alphabet=" ,.-+:/#0123456789NaE\n\r", max_size=40).map(str.encode)),
    at=st.integers(min_value=0, max_value=2000),
    ngafid=st.booleans(),
)
def test_damaged_export_reads_or_fails_in_one_line(
    tmp_path: Path, cut: int, junk: bytes, at: int, ngafid: bool
) -> None:
    """Any export cut anywhere with bytes inserted anywhere is read, or refused with one line."""
    source = _ngafid(tmp_path, time=False, units=True, twin=False) if ngafid else _g1000(tmp_path, GOOD_ROWS)
    data = source.read_bytes()
    data = data[: max(cut, 1)] if cut < len(data) else data
    data = data[:at] + junk + data[at:]
    path = tmp_path / "damaged.csv"
    path.write_bytes(data)
    try:
        log = load_csv(path)
    except UserInputError as exc:
        assert "\n" not in str(exc) and str(exc)
    else:
        assert len(log) >= 1 and log.has("cht_c")


def test_a_last_row_cut_mid_field_is_warned(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A log cut inside the last number of its last row (``...,15,8`` of ``...,15,88``): every field is there,
    only the missing line break tells; the row is kept and the cut is warned."""
    text = "\n".join([HEADER, *(ROW.format(t=k, cht=88) for k in range(3))])[:-1]
    with caplog.at_level(logging.WARNING, logger="ecu_monitor.flightlog"):
        log = read_csv(_write(tmp_path, text))
    assert len(log) == 3 and log["cht_c"][-1] == 8
    assert "row 4: no line break after the last row: it may be cut mid-field" in caplog.text
    assert any("cut mid-field" in note for note in log.notes)
    whole = read_csv(_write(tmp_path, text + "8\n", name="whole.csv"))
    assert not whole.notes
