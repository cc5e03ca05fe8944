"""Peak memory of reading a large canonical flight CSV (issue 31: a 100 MB CSV took 13x its size).

Generates a canonical CSV of ``--mb`` MB (20 Hz rows of a long flight with noise, so fields have the
digits a real logger writes), then reads it with ``flightlog.load_csv`` in a child process and reports
the child's peak resident memory (``ru_maxrss``) beside the baseline of the same run: a child that only
imports the reader. The figure is (peak - baseline) / file size, and the same over the bytes the read
flight's arrays hold (the least any reader that returns them needs).

    .venv/bin/python benchmarks/bench_csv_memory.py --mb 100

The child imports ``ecu_monitor`` as the environment finds it: ``PYTHONPATH=OTHER_CHECKOUT`` measures
another version on the same file (``--keep``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

_CHILD = """
import json, resource, sys
from ecu_monitor.flightlog import load_csv
if sys.argv[1] != "-":
    log = load_csv(sys.argv[1])
    held = sum(log[c].nbytes for c in log.columns) + log.time_s.nbytes
    rows = len(log)
else:
    held = rows = 0
print(json.dumps({"peak_kib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, "held": held, "rows": rows}))
"""


def write_flight(path: Path, megabytes: float, seed: int = 1) -> int:
    """A canonical CSV of about ``megabytes`` MB; returns its size in bytes."""
    rng = np.random.default_rng(seed)
    rows_per_block = 100_000
    with path.open("w", encoding="utf-8") as fh:
        fh.write("time_s,throttle_pct,rpm,altitude_m,airspeed_mps,oat_c,cht_c,fuel_flow_lph\n")
        start = 0
        while fh.tell() < megabytes * 1e6:
            t = (start + np.arange(rows_per_block)) * 0.05  # 20 Hz: 100 MB is about a day
            cols = [
                t,
                np.clip(60 + 20 * np.sin(t / 300) + rng.normal(0, 1, t.size), 0, 100),
                5000 + 800 * np.sin(t / 500) + rng.normal(0, 20, t.size),
                np.abs(1000 + 500 * np.sin(t / 900) + rng.normal(0, 2, t.size)),
                25 + rng.normal(0, 0.5, t.size),
                15 + rng.normal(0, 0.2, t.size),
                np.round(150 + 20 * np.sin(t / 400)),
                20 + rng.normal(0, 0.3, t.size),
            ]
            text = np.column_stack(cols)
            fh.writelines(
                f"{r[0]:.2f},{r[1]:.2f},{r[2]:.1f},{r[3]:.2f},{r[4]:.3f},{r[5]:.2f},{r[6]:.0f},{r[7]:.3f}\n"
                for r in text
            )
            start += rows_per_block
    return path.stat().st_size


def child(csv: str) -> dict[str, int]:
    done = subprocess.run([sys.executable, "-c", _CHILD, csv], capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mb", type=float, default=100.0, help="size of the generated CSV, MB")
    parser.add_argument("--keep", metavar="CSV", help="write the CSV here and keep it (read again if it exists)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        path = Path(args.keep) if args.keep else Path(folder) / "flight.csv"
        size = path.stat().st_size if path.exists() else write_flight(path, args.mb)
        base = child("-")
        read = child(str(path))
    extra = (read["peak_kib"] - base["peak_kib"]) * 1024
    print(f"file {size / 1e6:.1f} MB, {read['rows']} rows; arrays held {read['held'] / 1e6:.1f} MB")
    print(f"peak RSS: baseline (import only) {base['peak_kib'] / 1024:.0f} MiB, read {read['peak_kib'] / 1024:.0f} MiB")
    ratio_file, ratio_arrays = extra / size, extra / read["held"]
    print(f"read - baseline = {extra / 1e6:.0f} MB = {ratio_file:.2f} x the file, {ratio_arrays:.2f} x the arrays")


if __name__ == "__main__":
    main()
