"""A large flight CSV is read in blocks of rows, not whole (issue 31: a 100 MB CSV took 13x its size):
the memory a read takes grows with the float arrays it returns, not with the text of the file."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np

from ecu_monitor.flightlog import load_csv


def _write(path: Path, n: int) -> int:
    rng = np.random.default_rng(3)
    t = np.arange(n) * 0.1
    with path.open("w", encoding="utf-8") as fh:
        fh.write("time_s,throttle_pct,rpm,altitude_m,airspeed_mps,oat_c,cht_c,note\n")
        for k in range(n):
            fh.write(
                f"{t[k]:.1f},{50 + rng.normal():.2f},{5000 + rng.normal(0, 20):.1f},{1000 + rng.normal():.2f},"
                f"{25 + rng.normal(0, 0.5):.3f},{15 + rng.normal(0, 0.2):.2f},{150 + k % 7},"
                f"{'' if k % 5 else 'text'}\n"
            )
    return path.stat().st_size


def _peak(path: Path) -> int:
    tracemalloc.start()
    try:
        log = load_csv(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    n = len(log)
    assert "note" not in log.columns  # a column that holds text is still dropped
    assert log["cht_c"][-1] == 150 + (n - 1) % 7 and np.all(np.diff(log.time_s) > 0)
    return peak


def test_the_memory_of_a_read_grows_with_its_arrays_not_with_the_file(tmp_path: Path) -> None:
    small, large = tmp_path / "small.csv", tmp_path / "large.csv"
    n = 8315  # rows: a few blocks of the reader, the last one partial
    size_small, size_large = _write(small, n), _write(large, 5 * n)
    growth = (_peak(large) - _peak(small)) / (size_large - size_small)  # the fixed costs cancel
    # whole-file reading held the text and a Python string per field: about 10x; streamed, the returned
    # arrays (7 columns of 8 bytes for ~47 bytes of text a row) and the log's own copy of them
    assert growth < 4.0, f"{growth:.1f} x the added file size"


def test_rows_past_the_lines_counted_still_read(tmp_path: Path) -> None:
    """Old Mac line ends (a lone CR) with one LF: the reader counted 2 lines and reads every row."""
    path = tmp_path / "mixed.csv"
    _write(path, 9000)
    text = path.read_text(encoding="utf-8").replace("\n", "\r")
    path.write_text(text[:-1] + "\n", encoding="utf-8", newline="")
    log = load_csv(path)
    assert len(log) == 9000 and log["cht_c"][-1] == 150 + 8999 % 7
