"""``ecu-monitor import SOURCE --out flight.csv [--mapping MAPPING] [--dbc FILE ...] [--signal C=M.S ...]``.

Converts a foreign flight log into the canonical flight CSV (DESIGN.md section 3): a canonical CSV
(validated and rewritten), a foreign CSV through a mapping YAML (``--mapping g1000`` names the shipped
Garmin G1000 mapping), or a python-can log (.asc, .blf, .log, .trc) decoded through DBC files
(default: the repository's dbc/engine.dbc) with a signal map (default: engine.dbc's signals; ``--signal
rpm=BASE1.RPM`` entries replace it, for a user's own ECU). Prints one summary line; repairs made to the input are
logged as warnings and counted in the summary.
"""

from __future__ import annotations

import argparse
from typing import Any

from ecu_monitor.errors import UserInputError
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
    parser.add_argument(
        "--signal",
        action="append",
        metavar="COLUMN=MESSAGE.SIGNAL",
        help="CAN log signal map entry, e.g. rpm=BASE1.RPM (repeatable; replaces the default engine.dbc map)",
    )
    parser.set_defaults(func=_run)


def _signal_map(entries: list[str] | None) -> dict[str, str] | None:
    if not entries:
        return None
    pairs = [entry.partition("=") for entry in entries]
    for entry, (column, sep, ref) in zip(entries, pairs, strict=True):
        if not (sep and column.strip() and "." in ref):
            raise UserInputError(f"--signal {entry!r}: expected COLUMN=MESSAGE.SIGNAL")
    return {column.strip(): ref.strip() for column, _, ref in pairs}


def _run(args: argparse.Namespace) -> int:
    log = load_flight(args.source, mapping=args.mapping, dbc_paths=args.dbc, signal_map=_signal_map(args.signal))
    write_csv(log, args.out)
    print(
        f"{args.out}: {len(log)} rows, {log.duration_s:.1f} s ({log.duration_s / 60.0:.1f} min),"
        f" columns {', '.join(log.names)}; {len(log.notes)} warning(s)"
    )
    return 0
