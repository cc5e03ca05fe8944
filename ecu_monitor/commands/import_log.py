"""``ecu-monitor import SOURCE --out flight.csv [--mapping MAPPING] [--dbc FILE ...]``.

Converts a foreign flight log into the canonical flight CSV (DESIGN.md section 3): a canonical CSV
(validated and rewritten), a foreign CSV through a mapping YAML (``--mapping g1000`` names the shipped
Garmin G1000 mapping), or a python-can log (.asc, .blf, .log, .trc) decoded through DBC files
(default: the repository's dbc/engine.dbc). Prints one summary line; repairs made to the input are
logged as warnings and counted in the summary.
"""

from __future__ import annotations

import argparse
from typing import Any

from ecu_monitor.flightlog import load_flight, write_csv

__all__ = ["add_subparser"]


def add_subparser(subparsers: Any) -> None:
    """Register the ``import`` subcommand."""
    parser = subparsers.add_parser(
        "import",
        help="convert a foreign flight log (mapped CSV or CAN log) into a canonical flight CSV",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument("source", metavar="SOURCE", help="flight log: .csv, .asc, .blf, .log or .trc")
    parser.add_argument("--out", required=True, metavar="FLIGHT.csv", help="canonical CSV to write")
    parser.add_argument(
        "--mapping",
        metavar="MAPPING",
        help="mapping YAML for a foreign CSV, or the name of a shipped one (g1000)",
    )
    parser.add_argument(
        "--dbc",
        action="append",
        metavar="FILE",
        help="DBC file to decode a CAN log (repeatable; default dbc/engine.dbc)",
    )
    parser.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    log = load_flight(args.source, mapping=args.mapping, dbc_paths=args.dbc)
    write_csv(log, args.out)
    print(
        f"{args.out}: {len(log)} rows, {log.duration_s:.1f} s ({log.duration_s / 60.0:.1f} min),"
        f" columns {', '.join(log.names)}; {len(log.notes)} warning(s)"
    )
    return 0
