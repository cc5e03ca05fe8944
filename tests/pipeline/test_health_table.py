"""The bulk health writers: the CSV equal to a row-by-row reference (numbers at ``%.10g``),
Parquet / Arrow with the same columns, and one line (exit 2) when pyarrow is missing."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ecu_monitor.bus.codec import INPUT_NAMES
from ecu_monitor.cli import main
from ecu_monitor.errors import ConfigError
from ecu_monitor.pipeline import table as health_table
from ecu_monitor.pipeline.output_table import STATES
from ecu_monitor.pipeline.outputs import (
    ReplayResult,
    column_layout,
    health_columns,
    health_table_columns,
    write_health_csv,
)
from ecu_monitor.pipeline.table import check_table_path, csv_bytes


def _columns(n: int, seed: int, cylinders: int = 1) -> dict[str, Any]:
    """Random replay columns of every row of the output table (nan, inf, -0.0, every state and flag)."""
    rng = np.random.default_rng(seed)

    def floats(name: str) -> np.ndarray:
        if name == "time_s":
            return 1000.0 + 0.1 * np.arange(n)
        values = rng.normal(150.0, 20.0, n) * 10.0 ** rng.integers(-6, 3, n)
        values[rng.random(n) < 0.1] = math.nan
        values[rng.random(n) < 0.03] = math.inf
        values[rng.random(n) < 0.03] = -0.0
        return values

    make = {
        "float": floats,
        "state": lambda name: rng.integers(0, len(STATES), n),
        "flag": lambda name: rng.random(n) < 0.2,
        "cylinder": lambda name: rng.integers(0, cylinders + 1, n),
        "inputs": lambda name: rng.integers(0, 1 << len(INPUT_NAMES), n),
    }
    return {name: make[v.kind](name) for name, v in column_layout(cylinders)}


def _cell(kind: str, x: Any) -> str:
    """One cell of health.csv as Python writes it (the reference of the bulk writer)."""
    if kind == "float":
        return f"{x:.10g}" if math.isfinite(x) else ""
    if kind == "flag":
        return str(int(x))
    if kind == "cylinder":
        return str(x) if x else ""
    if kind == "inputs":
        return "+".join(x)
    return str(x)


def _reference_csv(result: ReplayResult) -> bytes:
    """health.csv row by row with Python's formatter (the writer before the bulk one); the first column
    spells nan and inf."""
    count = result.cylinder_count
    layout = [(name, v) for name, v in column_layout(count) if v.csv]
    lines = [",".join(name for name, _ in layout)]
    for r in result.rows:
        cells = []
        for name, v in layout:
            x = getattr(r, name) if name == v.name else getattr(r.cylinders[int(name[3 : name.index("_")]) - 1], v.name)
            cells.append(f"{x:.10g}" if not cells else _cell(v.kind, x))
        lines.append(",".join(cells))
    return ("\n".join(lines) + "\n").encode("ascii")


@pytest.mark.parametrize(("n", "cylinders"), [(0, 1), (1, 1), (3000, 1), (1000, 4)])
def test_csv_equals_the_row_by_row_reference(n: int, cylinders: int, tmp_path: Path) -> None:
    result = ReplayResult(_columns(n, seed=n, cylinders=cylinders), {})
    reference = _reference_csv(result)
    assert csv_bytes(health_table_columns(result.columns, result.cylinder_count)) == reference
    out = tmp_path / "health.csv"
    assert result.write_csv(out) == n
    assert out.read_bytes() == reference
    assert write_health_csv(result.rows, tmp_path / "live.csv") == n  # the live path's writer: the same bytes
    assert (tmp_path / "live.csv").read_bytes() == reference


@pytest.mark.parametrize("suffix", [".parquet", ".arrow", ".feather"])
def test_parquet_and_arrow_hold_the_csv_columns(suffix: str, tmp_path: Path) -> None:
    pa_feather = pytest.importorskip("pyarrow.feather")
    pq = pytest.importorskip("pyarrow.parquet")
    columns = _columns(500, seed=3, cylinders=2)
    out = tmp_path / f"health{suffix}"
    assert ReplayResult(columns, {}).write_csv(out) == 500
    table = pq.read_table(out) if suffix == ".parquet" else pa_feather.read_table(out)
    assert tuple(table.column_names) == health_columns(2)
    for name in (name for name, v in column_layout(2) if v.kind == "float"):
        np.testing.assert_array_equal(table.column(name).to_numpy(), columns[name])
    assert table.column("state").to_pylist() == [STATES[c] for c in columns["state"].tolist()]
    stale = table.column("stale_inputs").to_pylist()
    bits = columns["stale_inputs"].tolist()
    assert stale == ["+".join(n for b, n in enumerate(INPUT_NAMES) if c >> b & 1) for c in bits]
    assert table.column("sensor_fault").to_pylist() == columns["sensor_fault"].tolist()
    assert table.column("cyl2_state").to_pylist() == [STATES[c] for c in columns["cyl2_state"].tolist()]
    np.testing.assert_array_equal(table.column("cyl1_gamma_q").to_numpy(), columns["cyl1_gamma_q"])


def test_a_missing_pyarrow_or_an_unknown_suffix_is_one_line_exit_2(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    real = importlib.util.find_spec
    monkeypatch.setattr(
        health_table.importlib.util, "find_spec", lambda name, *a: None if name == "pyarrow" else real(name, *a)
    )
    with pytest.raises(ConfigError, match=r"needs pyarrow: pip install 'ecu-monitor\[arrow\]'"):
        check_table_path(tmp_path / "h.parquet")
    assert check_table_path(tmp_path / "h.CSV") == "csv"
    log = tmp_path / "missing.blf"  # the output is checked before the log is read
    for out, words in (("h.parquet", "needs pyarrow"), ("h.xlsx", "unknown output format '.xlsx'")):
        assert main(["replay", str(log), "--out", str(tmp_path / out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0] and out in err[0]


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_a_table_streamed_in_blocks_is_the_table_written_whole(suffix: str, tmp_path: Path) -> None:
    if suffix != ".csv":
        pytest.importorskip("pyarrow")
    columns = _columns(2500, seed=5, cylinders=2)
    whole = tmp_path / f"whole{suffix}"
    ReplayResult(columns, {}).write_csv(whole)
    streamed = tmp_path / f"streamed{suffix}"
    with health_table.table_stream(streamed) as write:
        for a, b in ((0, 1000), (1000, 1000), (1000, 2499), (2499, 2500)):  # an empty block among them
            write(health_table_columns({k: v[a:b] for k, v in columns.items()}, 2))
    assert streamed.read_bytes() == whole.read_bytes()


def test_a_stream_that_fails_or_has_no_rows_leaves_no_file(tmp_path: Path) -> None:
    columns = _columns(100, seed=6)
    out = tmp_path / "health.csv"
    with pytest.raises(RuntimeError, match="the replay stopped"), health_table.table_stream(out) as write:
        write(health_table_columns(columns, 1))
        raise RuntimeError("the replay stopped")
    with health_table.table_stream(out) as write:
        write(health_table_columns({k: v[:0] for k, v in columns.items()}, 1))
    assert list(tmp_path.iterdir()) == []
