"""``ecu-monitor simulate --model model.yaml FLIGHT.csv --out sim.csv``.

Open-loop model prediction driven by a flight's inputs (the heat-map axes named in the model,
altitude, airspeed, OAT), starting from the first measured CHT, RK4 on a fixed step (0.02 s by
default) with the inputs held between samples. Writes ``time_s, cht_meas_c, cht_model_c, error_c``
(error = measured - model, degC: the one residual sign of every output, docs/contracts.md) at the
flight's sample times and prints mean / peak / RMS error.
Without ``--model`` the paper's Table A1 preset is used.
"""

from __future__ import annotations

import argparse
from typing import Any

from ecu_monitor.commands.names import SIMULATE_DT_S
from ecu_monitor.compile_cache import announce_compiles
from ecu_monitor.errors import FlightLogError

__all__ = ["SIM_COLUMNS", "add_subparser"]

#: Columns of sim.csv, in order.
SIM_COLUMNS = ("time_s", "cht_meas_c", "cht_model_c", "error_c")


def add_subparser(subparsers: Any) -> None:
    """Register the ``simulate`` subcommand."""
    parser = subparsers.add_parser(
        "simulate",
        help="open-loop model prediction over a flight's inputs; writes sim.csv",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument("flight", metavar="FLIGHT", help="flight log: canonical .csv (or a mapped CSV / CAN log)")
    parser.add_argument("--model", metavar="MODEL.yaml", help="thermal model (default: the paper's Table A1)")
    parser.add_argument("--out", required=True, metavar="SIM.csv", help="output CSV")
    parser.add_argument("--mapping", metavar="MAPPING", help="mapping YAML (or shipped name: g1000) for a foreign CSV")
    parser.add_argument("--dt", type=float, default=SIMULATE_DT_S, metavar="S", help="integration step, s (0.02)")
    parser.set_defaults(func=announce_compiles(_run))  # a first run says it compiles


def _run(args: argparse.Namespace) -> int:
    import numpy as np

    from ecu_monitor.bus.canlog import load_flight
    from ecu_monitor.flightlog import FlightLog, write_csv
    from ecu_monitor.identify import ErrorStats, simulate_flight
    from ecu_monitor.model import load_model, paper_table_a1
    from ecu_monitor.userfiles import check_output_file, check_output_not_input

    check_output_not_input(args.out, (args.flight, args.model), FlightLogError)
    check_output_file(args.out, "--out", FlightLogError)
    params = load_model(args.model) if args.model else paper_table_a1()
    log = load_flight(args.flight, mapping=args.mapping)
    if not log.has("cht_c"):
        raise FlightLogError(f"{log.source}: no column 'cht_c' (measured CHT; columns: {', '.join(log.names)})")
    model = simulate_flight(params, log, args.dt)
    measured = np.asarray(log["cht_c"])
    out = FlightLog(
        {"time_s": log.time_s, "cht_meas_c": measured, "cht_model_c": model, "error_c": measured - model},
        source=str(args.out),
    )
    write_csv(out, args.out)
    e = ErrorStats.from_series(model, measured)
    print(
        f"{args.flight}: {len(log)} samples, {log.duration_s / 60.0:.1f} min; |measured - model| CHT: mean"
        f" {e.mean_c:.2f} degC ({e.mean_pct:.2f} %), peak {e.peak_c:.2f} degC ({e.peak_pct:.2f} %),"
        f" RMS {e.rms_c:.2f} degC -> {args.out}"
    )
    return 0
