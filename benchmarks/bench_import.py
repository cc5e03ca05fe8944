"""Import speed on the real flight exports (issue 10 item 1): every file against a bare CSV read.

    .venv/bin/python benchmarks/bench_import.py [--data DIR ...] [--repeat 3]

For each CSV under the data directories (default: ../shared/data/real and ../shared/data/g1000 beside
the repository) measures, best of ``--repeat`` runs in one process:

* baseline: Python's ``csv.reader`` over the whole file, fields left as text (the least any import
  must do);
* import: :func:`ecu_monitor.bus.canlog.load_flight` (layout detection, time from the stamps, every
  mapped column and cylinder converted, validation and repairs); a twin's export is read for engine 1;
* write: :func:`ecu_monitor.flightlog.write_csv` of the imported log to a temporary file.

Prints a Markdown table: rows, import and write time, and import / baseline.
"""

from __future__ import annotations

import argparse
import csv
import logging
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from ecu_monitor.bus.canlog import load_flight
from ecu_monitor.errors import FlightLogError
from ecu_monitor.flightlog import FlightLog, write_csv

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def best_of(repeat: int, work: Callable[[], object]) -> float:
    """Shortest wall time of ``repeat`` runs of ``work``, s."""
    times = []
    for _ in range(repeat):
        started = time.perf_counter()
        work()
        times.append(time.perf_counter() - started)
    return min(times)


def bare_read(path: Path) -> int:
    with path.open(newline="", encoding="utf-8-sig") as fh:
        return sum(1 for _ in csv.reader(fh))


def load(path: Path) -> FlightLog:
    try:
        return load_flight(path)
    except FlightLogError as exc:
        if "engines" not in str(exc):
            raise
        return load_flight(path, engine=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, action="append", help="directory of CSV exports (repeatable)")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    logging.disable(logging.WARNING)  # the repairs' warnings are not what is measured
    dirs = args.data or [SHARED / "real", SHARED / "g1000"]
    files = sorted(p for d in dirs for p in d.glob("*.csv"))
    if not files:
        raise SystemExit(f"no CSV files under {', '.join(map(str, dirs))}")
    print("| file | rows | csv.reader (baseline) | import | write | import / baseline |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "flight.csv"
        for path in files:
            base = best_of(args.repeat, lambda p=path: bare_read(p))
            log = load(path)
            imp = best_of(args.repeat, lambda p=path: load(p))
            wrt = best_of(args.repeat, lambda lg=log: write_csv(lg, out))
            print(
                f"| {path.name} | {len(log)} | {base * 1e3:.0f} ms | {imp * 1e3:.0f} ms | {wrt * 1e3:.0f} ms"
                f" | {imp / base:.1f} |"
            )


if __name__ == "__main__":
    main()
