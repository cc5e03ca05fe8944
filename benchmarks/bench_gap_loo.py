"""``gap --leave-one-out`` against a plain ``gap`` run on the same real flights, both without ``--model``,
in one run (issue 28: at most 3x).

    nice -n 10 .venv/bin/python benchmarks/bench_gap_loo.py [--data DIR] [--test-flight N]

Both are the command as a user runs it (``ecu-monitor gap``, a child process each, one after the other):
the plain run trains on three of the four given N550ND flights and tests on the fourth (``--test-flight``,
default the last), the leave-one-out run holds each of the four out in turn. Each is timed in wall
seconds and in CPU seconds of the command and its forked workers; the ratio is within this run. The
numba cache is warmed first by a short ``gap`` run (one candidate: the swarm, the refit and the estimator's
kernels; the compile is not what is measured, and would otherwise fall on the plain run alone). Prints each
run's verdict line and the ratios; ``--out DIR`` keeps both runs' gap.json and reports.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: The given real flights: $REAL_DATA, else the data folder beside the checkout (not shipped).
DATA = Path(os.environ.get("REAL_DATA", REPO.parent / "shared" / "data" / "real"))
FLIGHTS = tuple(
    f"ngafid_c172s_n550nd_{stamp}.csv" for stamp in ("20170504_1559", "20170504_1836", "20170505_0835", "20170509_1456")
)
COMMAND = ("gap", "--mapping", "g1000", "--heat-axes", "fuel_flow_lph,rpm")


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _run(args: list[str], log: Path | None = None) -> tuple[float, float, str]:
    """Wall s, CPU s (the command and its workers) and the output of ``ecu-monitor ARGS`` (its progress,
    timestamped, into ``log``)."""
    exe = str(Path(sys.executable).with_name("ecu-monitor"))
    started, cpu = time.perf_counter(), _children_cpu_s()
    done = subprocess.run([exe, *args], capture_output=True, text=True, check=False)
    wall, used = time.perf_counter() - started, _children_cpu_s() - cpu
    if log is not None:
        log.write_text(done.stderr, encoding="utf-8")
    if done.returncode != 0:
        raise SystemExit(f"ecu-monitor {' '.join(args)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return wall, used, done.stdout.strip()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA, help="folder of the given real flights")
    parser.add_argument("--test-flight", type=int, default=3, help="which of the four the plain run tests on (0-3)")
    parser.add_argument("--out", type=Path, help="keep both runs' outputs here (plain/, loo/; default: discarded)")
    args = parser.parse_args()
    paths = [str(args.data / name) for name in FLIGHTS]
    missing = [p for p in paths if not Path(p).is_file()]
    if missing:
        raise SystemExit(f"bench_gap_loo: {missing[0]}: not found (--data DIR or $REAL_DATA)")
    test = paths[args.test_flight]
    train = [p for p in paths if p != test]
    with tempfile.TemporaryDirectory() as scratch:
        out = args.out or Path(scratch)
        out.mkdir(parents=True, exist_ok=True)
        _run([*COMMAND, "--train", train[0], "--test", test, "--candidates", "sensor_lag", "--out", f"{out}/warm"])
        plain = _run([*COMMAND, "--train", *train, "--test", test, "--out", f"{out}/plain"], out / "plain.log")
        print(f"plain gap (train 3, test {Path(test).stem}): {plain[0]:.0f} s wall, {plain[1]:.0f} s CPU")
        print("  " + plain[2].replace("\n", "\n  "))
        loo = _run([*COMMAND, "--leave-one-out", "--train", *paths, "--out", f"{out}/loo"], out / "loo.log")
        print(f"gap --leave-one-out over the four: {loo[0]:.0f} s wall, {loo[1]:.0f} s CPU")
        print("  " + loo[2].replace("\n", "\n  "))
    print(f"ratio: {loo[0] / plain[0]:.2f}x wall, {loo[1] / plain[1]:.2f}x CPU")


if __name__ == "__main__":
    main()
