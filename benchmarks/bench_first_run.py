"""The first ``ecu-monitor replay`` after an install against the second (issue 25 item 7, "No silent first run").

    .venv/bin/python benchmarks/bench_first_run.py [--mission short_hop] [--repeat 1]

Records one log with the virtual ECU (``virtual-ecu record --mission M``, a canonical CSV), then, for
each repeat, gives two fresh interpreters the same empty cache (XDG_CACHE_HOME in a new temporary
directory, no NUMBA_* variable, so numba's cache is ``$XDG_CACHE_HOME/ecu-monitor/numba``) and runs
``python -m ecu_monitor.cli replay LOG --out health.csv`` in each, one after the other: the first
compiles the kernels and writes the cache, the second loads it. Prints the wall time of each, their
ratio, the compile seconds the first run reported (its ``compiled in X s`` line) and whether each
printed ``compiling (first run only) ...``.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ecu_monitor.compile_cache import COMPILING_LINE


def replay_once(log: Path, out: Path, env: dict[str, str]) -> tuple[float, str]:
    """Wall time of one fresh ``ecu-monitor replay`` process, s, and its stderr."""
    argv = [sys.executable, "-m", "ecu_monitor.cli", "replay", str(log), "--out", str(out)]
    started = time.perf_counter()
    done = subprocess.run(argv, env=env, capture_output=True, text=True, check=False)
    wall_s = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"replay failed ({done.returncode}): {done.stderr[-2000:]}")
    return wall_s, done.stderr


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mission", default="short_hop", help="shipped mission (or YAML) of the log")
    parser.add_argument("--repeat", type=int, default=1, help="first/second pairs, each on a fresh cache")
    args = parser.parse_args()
    base_env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    with tempfile.TemporaryDirectory(prefix="ecu-monitor-first-run-") as tmp:
        root = Path(tmp)
        log = root / "flight.csv"
        subprocess.run(
            [sys.executable, "-m", "virtual_bus.cli", "record", "--mission", args.mission, "--out", str(log)],
            env=base_env, check=True, capture_output=True, text=True,
        )  # fmt: skip
        rows = sum(1 for _ in log.open(encoding="utf-8")) - 1
        print(f"log: virtual-ecu record --mission {args.mission}: {rows} rows; load average {os.getloadavg()[0]:.1f}")
        print("| pair | first run s | second run s | first / second | compile s (first run's line) | line printed |")
        print("|---|---|---|---|---|---|")
        for n in range(1, args.repeat + 1):
            env = dict(base_env, XDG_CACHE_HOME=str(root / f"cache{n}"))
            first_s, first_err = replay_once(log, root / "health1.csv", env)
            second_s, second_err = replay_once(log, root / "health2.csv", env)
            compiled = re.search(r"compiled in ([\d.]+) s", first_err)
            said = [COMPILING_LINE in err for err in (first_err, second_err)]
            print(
                f"| {n} | {first_s:.2f} | {second_s:.2f} | {first_s / second_s:.1f}x"
                f" | {compiled.group(1) if compiled else '-'}"
                f" | first {'yes' if said[0] else 'no'}, second {'yes' if said[1] else 'no'} |"
            )
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
