"""``ecu-monitor replay FLIGHT --model model.yaml [--estimator NAME] --out health.csv``.

Runs an estimator over a recorded flight (a canonical CSV, or any log :func:`load_flight` reads) as
fast as the machine allows, on the filter's fixed step (0.02 s), and writes one row per input sample:
``time_s, cht_meas_c, cht_est_c, deviation, state, variance, innovation, nis, reset``
(deviation = model-deviation symptom Delta/dt in degC/s; state is NOMINAL until the detector is
wired in; innovation and nis are empty where no reading fell on the step). Prints one summary line.
Without ``--model`` the paper's Table A1 preset is used.
"""

from __future__ import annotations

import argparse
import csv
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from ecu_monitor.errors import UserInputError
from ecu_monitor.estimation import ESTIMATORS, EstimatorSettings, run_estimator
from ecu_monitor.estimation.runner import EstimateTrace, sample_indices
from ecu_monitor.flightlog import FlightLog, load_flight
from ecu_monitor.model import load_model, paper_table_a1

__all__ = ["HEALTH_COLUMNS", "add_subparser", "write_health_csv"]

#: Columns of health.csv, in order.
HEALTH_COLUMNS = ("time_s", "cht_meas_c", "cht_est_c", "deviation", "state", "variance", "innovation", "nis", "reset")


def add_subparser(subparsers: Any) -> None:
    """Register the ``replay`` subcommand."""
    parser = subparsers.add_parser(
        "replay",
        help="run an estimator over a recorded flight log and write health.csv",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument("flight", metavar="FLIGHT", help="flight log: canonical .csv (or .asc/.blf/.log/.trc)")
    parser.add_argument("--model", metavar="MODEL.yaml", help="thermal model (default: the paper's Table A1)")
    parser.add_argument(
        "--estimator",
        default="cbekf-au",
        metavar="NAME",
        help=f"estimator: {', '.join(sorted(ESTIMATORS))} (default cbekf-au)",
    )
    parser.add_argument("--out", required=True, metavar="HEALTH.csv", help="output CSV")
    parser.set_defaults(func=_run)


def _fmt(value: float) -> str:
    return "" if not math.isfinite(value) else f"{value:.10g}"


def write_health_csv(trace: EstimateTrace, path: str | Path, states: list[str] | None = None) -> None:
    """Write a (decimated) trace as health.csv; ``states`` defaults to NOMINAL on every row."""
    rows = len(trace)
    labels = states if states is not None else ["NOMINAL"] * rows
    try:
        with open(path, "w", newline="", encoding="utf-8") as handle:
            writer = csv.writer(handle)
            writer.writerow(HEALTH_COLUMNS)
            for k in range(rows):
                writer.writerow(
                    (
                        _fmt(float(trace.time_s[k])),
                        _fmt(float(trace.cht_meas_c[k])),
                        _fmt(float(trace.cht_est_c[k])),
                        _fmt(float(trace.deviation[k])),
                        labels[k],
                        _fmt(float(trace.variance[k])),
                        _fmt(float(trace.innovation[k])),
                        _fmt(float(trace.nis[k])),
                        int(bool(trace.reset[k])),
                    )
                )
    except OSError as exc:
        raise UserInputError(f"{path}: cannot write ({exc.strerror})") from None


def replay_log(log: FlightLog, params: Any, estimator: str, settings: EstimatorSettings) -> EstimateTrace:
    """Run ``estimator`` over ``log`` and return the trace at the log's own sample times."""
    trace = run_estimator(log, params, estimator, settings)
    steps = sample_indices(log.time_s, float(log.time_s[0]), settings.dt_s, len(trace))
    decimated = trace.take(steps)
    # report each row at the log's time stamp; the values are those of the step the reading fell on
    return EstimateTrace(
        decimated.estimator,
        np.asarray(log.time_s, dtype=float),
        np.asarray(log["cht_c"], dtype=float),
        decimated.cht_est_c,
        decimated.deviation,
        decimated.variance,
        decimated.innovation,
        decimated.nis,
        decimated.reset,
        decimated.measured,
    )


def _run(args: argparse.Namespace) -> int:
    params = load_model(args.model) if args.model else paper_table_a1()
    settings = EstimatorSettings()
    log = load_flight(args.flight)
    started = time.perf_counter()
    health = replay_log(log, params, args.estimator, settings)
    elapsed = time.perf_counter() - started
    write_health_csv(health, args.out)
    error = health.cht_est_c - health.cht_meas_c
    rms = float(np.sqrt(np.mean(error * error)))
    print(
        f"{args.out}: {len(health)} rows, {args.estimator} over {log.duration_s:.1f} s of flight in {elapsed:.2f} s;"
        f" estimate - reading RMS {rms:.2f} degC; deviation mean {float(np.mean(health.deviation)):.3f},"
        f" max |.| {float(np.max(np.abs(health.deviation))):.3f} degC/s; {int(np.sum(health.reset))} reset(s)"
    )
    return 0
