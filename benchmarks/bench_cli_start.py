"""Start-up of ``ecu-monitor --help``, every subcommand's help and ``virtual-ecu --help`` (issue 13 part 4).

    .venv/bin/python benchmarks/bench_cli_start.py [--repeat 7] [--cold]

Each figure is a fresh interpreter (``python -m ecu_monitor.cli ... --help``, output discarded),
median and best of ``--repeat`` runs, beside the baseline measured in the same run: ``python -c pass``
(the interpreter's own start). Warm: the runs follow each other, so the files are in the page cache
and the bytecode compiled. ``--cold`` adds one run per command after dropping the page cache
(``echo 3 > /proc/sys/vm/drop_caches``, needs root; skipped with a note otherwise): every file,
the interpreter's included, is read from the disk again, as on the first command after a boot.
Also prints which heavy modules (numpy, numba, scipy, matplotlib, python-can) ``--help`` imported.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

COMMANDS = ["demo", "run", "replay", "simulate", "identify", "gap", "history", "import", "results", "evaluate",
            "calibrate", "files"]  # fmt: skip
HEAVY = ("numpy", "numba", "scipy", "matplotlib", "can", "cantools")


def run_once(argv: list[str]) -> float:
    """Wall time of one fresh interpreter running ``argv``, s."""
    started = time.perf_counter()
    subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
    return time.perf_counter() - started


def drop_caches() -> bool:
    """Drop the page cache (root only); False when not allowed."""
    try:
        os.sync()
        Path("/proc/sys/vm/drop_caches").write_text("3\n")
    except OSError:
        return False
    return True


def heavy_imported(argv: list[str]) -> list[str]:
    """Heavy modules a ``--help`` run imports (from ``-X importtime``)."""
    done = subprocess.run([sys.executable, "-X", "importtime", *argv], capture_output=True, text=True, check=False)
    names = {line.split("|")[-1].strip() for line in done.stderr.splitlines() if line.startswith("import time:")}
    return sorted(name for name in HEAVY if name in names)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=7, help="runs per figure (median and best)")
    parser.add_argument("--cold", action="store_true", help="also one cold run each (drops the page cache: root)")
    args = parser.parse_args()
    py = sys.executable
    cases: list[tuple[str, list[str]]] = [
        ("python -c pass (baseline)", [py, "-c", "pass"]),
        ("ecu-monitor --help", [py, "-m", "ecu_monitor.cli", "--help"]),
        *((f"ecu-monitor {name} --help", [py, "-m", "ecu_monitor.cli", name, "--help"]) for name in COMMANDS),
        ("virtual-ecu --help", [py, "-m", "virtual_bus.cli", "--help"]),
        ("virtual-ecu record --help", [py, "-m", "virtual_bus.cli", "record", "--help"]),
    ]
    load = os.getloadavg()[0]
    print(f"{len(cases)} cases, {args.repeat} runs each, load average {load:.1f}")
    runs: dict[str, list[float]] = {label: [] for label, _ in cases}
    for _ in range(args.repeat):  # interleaved: a load spike hits every case alike
        for label, argv in cases:
            runs[label].append(run_once(argv))
    base = statistics.median(runs[cases[0][0]])
    print("| command | median s | best s | median / python -c pass | heavy modules imported |")
    print("|---|---|---|---|---|")
    for label, argv in cases:
        times = runs[label]
        heavy = (", ".join(heavy_imported(argv[1:])) or "none") if label != cases[0][0] else ""
        median = statistics.median(times)
        print(f"| `{label}` | {median:.3f} | {min(times):.3f} | {median / base:.1f}x | {heavy} |")
    if args.cold:
        if not drop_caches():
            print("cold runs skipped: dropping the page cache needs root")
            return
        print("| cold (page cache dropped before each run) | s |")
        print("|---|---|")
        for label, argv in cases:
            drop_caches()
            print(f"| `{label}` | {run_once(argv):.3f} |")
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
