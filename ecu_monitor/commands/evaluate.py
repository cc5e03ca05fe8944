"""``ecu-monitor evaluate [--hours 50] [--out evaluate-out] [--seed N] [--workers 2]``.

Simulates nominal and degraded flights with the virtual ECU and measures degradation detection
(false alarms per 100 flight hours, detection delay), isolation of gamma_Q vs gamma_D, the CBEKF-AU
reset (midpoint vs boundary) and the thermal headroom against the truth plant; writes
OUT/detection.md and plots under OUT/detection/ (ecu_monitor.research.evaluation).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import zipfile
from pathlib import Path
from typing import Any

from ecu_monitor.compile_cache import announce_compiles
from ecu_monitor.errors import ConfigError
from ecu_monitor.userfiles import atomic_output, open_input

__all__ = ["add_subparser"]


def add_subparser(subparsers: Any) -> None:
    """Register the ``evaluate`` subcommand."""
    parser = subparsers.add_parser(
        "evaluate",
        help="measure detection, isolation, reset and headroom on simulated flights (writes detection.md)",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument("--hours", type=float, default=50.0, help="nominal flight hours per set (default 50)")
    parser.add_argument(
        "--out",
        default="evaluate-out",
        metavar="DIR",
        help="report folder (default ./evaluate-out: a new folder, never the checkout's docs/results;"
        " give --out docs/results to regenerate those)",
    )
    parser.add_argument("--seed", type=int, default=0, help="base seed of the campaign (default 0)")
    parser.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--degraded-seeds", type=int, default=4, help="missions per degradation case (default 4)")
    parser.add_argument(
        "--target", type=float, default=1.0, help="false alarms per 100 flight hours to calibrate for (default 1)"
    )
    parser.add_argument(
        "--full-size-hours",
        type=float,
        default=10.0,
        help="hours of nominal flights with full-size effects (default 10)",
    )
    parser.add_argument(
        "--flights-cache",
        metavar="FILE",
        help="the simulated flights (.npz): loaded if it exists (skips the simulation), else written",
    )
    parser.set_defaults(func=announce_compiles(_run))  # a first run says it compiles


def _check(args: argparse.Namespace) -> None:
    if not (math.isfinite(args.hours) and 2.0 <= args.hours <= 2000.0):
        raise ConfigError(f"--hours: expected a number of hours in [2, 2000], got {args.hours!r}")
    if not 1 <= args.workers <= 64:
        raise ConfigError(f"--workers: expected 1-64, got {args.workers!r}")
    if not 1 <= args.degraded_seeds <= 100:
        raise ConfigError(f"--degraded-seeds: expected 1-100, got {args.degraded_seeds!r}")
    if not (math.isfinite(args.target) and 0.0 < args.target < 100.0):
        raise ConfigError(f"--target: expected a rate in (0, 100), got {args.target!r}")
    if not (math.isfinite(args.full_size_hours) and 0.0 <= args.full_size_hours <= 2000.0):
        raise ConfigError(f"--full-size-hours: expected [0, 2000], got {args.full_size_hours!r}")
    from ecu_monitor.userfiles import check_output_file, prepare_output_dir

    prepare_output_dir(args.out, "--out", ConfigError)
    if args.flights_cache and not Path(args.flights_cache).exists():
        check_output_file(args.flights_cache, "--flights-cache", ConfigError)


def _run(args: argparse.Namespace) -> int:
    _check(args)
    from tqdm import tqdm

    from ecu_monitor.research.evaluation import (
        EvaluationConfig,
        headroom_check,
        run_campaign,
        save_flight_results,
        score,
        write_report,
    )

    config = EvaluationConfig(
        hours=args.hours,
        seed=args.seed,
        degraded_seeds=args.degraded_seeds,
        target_per_100h=args.target,
        workers=args.workers,
        full_size_hours=args.full_size_hours,
    )
    started = time.monotonic()
    cache = Path(args.flights_cache) if args.flights_cache else None
    if cache is not None and cache.exists():
        results, simulated_s = _load(cache)
        started -= simulated_s  # report the time the simulation took when it ran
    else:
        with tqdm(total=1, desc="flights", unit="flight", file=sys.stderr) as bar:

            def progress(done: int, total: int) -> None:
                bar.total = total
                bar.n = done
                bar.refresh()

            results = run_campaign(config, progress=progress)
        if cache is not None:
            with atomic_output(cache, ConfigError) as handle:
                save_flight_results(results, time.monotonic() - started, handle)
    campaign = score(config, results)
    checks = headroom_check()
    command = (
        f"ecu-monitor evaluate --hours {args.hours:g} --out {args.out} --seed {args.seed}"
        f" --degraded-seeds {args.degraded_seeds} --target {args.target:g} --full-size-hours {args.full_size_hours:g}"
    )
    path = write_report(campaign, checks, Path(args.out), command, time.monotonic() - started)
    best = campaign.best()
    alarms, hours = campaign.false_alarms[best.name]
    print(
        f"{path}: detector {best.name}, h = {campaign.calibration[best.name].threshold:.2f},"
        f" {alarms} false alarms in {hours:.1f} nominal h"
    )
    return 0


def _load(path: Path) -> Any:
    """Flights an earlier run of this command saved (an .npz of arrays and JSON: nothing in it runs)."""
    from ecu_monitor.research.evaluation import load_flight_results

    try:
        with open_input(path, "flights cache", ConfigError) as handle:
            return load_flight_results(handle)
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ConfigError(f"{path}: not a flights cache this command wrote ({reason})") from None
