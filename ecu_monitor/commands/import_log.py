"""``ecu-monitor import SOURCE ... (--out flight.csv | --out-dir DIR) [--mapping MAPPING] [--engine N] [--cht C]``.

Converts flight logs into canonical flight CSVs (docs/flight_logs.md): a canonical CSV
(validated and rewritten); a foreign CSV, its layout recognised from its header (Garmin G1000
exports of every firmware, NGAFID processed exports) or given with ``--mapping`` (a mapping YAML, or
the name of a shipped one: ``g1000``, ``ngafid_processed``); a python-can log (.asc, .blf, .log,
.trc) decoded through DBC files (default: the shipped engine.dbc) with a signal map
(default: engine.dbc's signals; ``--signal rpm=BASE1.RPM`` entries replace it, for a user's own ECU);
or a MAVLink telemetry log (.tlog, as ground stations record it) through the MAVLink mapping
(EFI_STATUS, VFR_HUD, SCALED_PRESSURE; docs/service.md, "MAVLink").

Every cylinder is kept (``cht1_c ..``, ``egt1_c ..``); ``--cht`` says which feeds ``cht_c``, the
channel the model reads: ``mean`` (default), ``hottest`` (per row) or a cylinder number. A twin's
export needs ``--engine 1`` or ``--engine 2``. Prints one summary line per file, saying how ``cht_c``
was made; repairs made to the input are logged as warnings and counted. A file that cannot be read
gets one line naming it and what is wrong; the others are still converted, and the exit code is 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ecu_monitor.errors import UserInputError
from ecu_monitor.shipped import resolve_file
from ecu_monitor.userfiles import check_output_file, check_output_not_input

__all__ = ["add_subparser"]


def add_subparser(subparsers: Any) -> None:
    """Register the ``import`` subcommand."""
    parser = subparsers.add_parser(
        "import",
        help="convert foreign flight logs (G1000 / NGAFID CSV, mapped CSV, CAN log, MAVLink .tlog) into canonical"
        " flight CSVs",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument(
        "source", metavar="SOURCE", nargs="+", help="flight log(s): .csv, .asc, .blf, .log, .trc or .tlog"
    )
    out = parser.add_mutually_exclusive_group(required=True)
    out.add_argument("--out", metavar="FLIGHT.csv", help="canonical CSV to write (one SOURCE)")
    out.add_argument("--out-dir", metavar="DIR", help="directory for the canonical CSVs, one per SOURCE, same name")
    parser.add_argument(
        "--mapping",
        metavar="MAPPING",
        help="mapping YAML for a foreign CSV, or a shipped one's name (g1000, ngafid_processed);"
        " default: recognise the layout",
    )
    parser.add_argument(
        "--engine", type=int, metavar="N", help="engine of a multi-engine export (1, 2, ...); required for a twin"
    )
    parser.add_argument(
        "--cht",
        metavar="mean|hottest|N",
        help="what feeds cht_c: the mean of the cylinders (default), the hottest per row, or cylinder N",
    )
    parser.add_argument(
        "--dbc",
        action="append",
        metavar="FILE",
        help="DBC file or shipped DBC name to decode a CAN log (repeatable; default: engine.dbc)",
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


def _targets(args: argparse.Namespace) -> list[tuple[str, Path]]:
    sources: list[str] = args.source
    if args.out is not None:
        if len(sources) > 1:
            raise UserInputError(f"--out {args.out}: {len(sources)} sources given, use --out-dir DIR for several")
        check_output_not_input(args.out, (sources[0], args.mapping))
        return [(sources[0], check_output_file(args.out, "--out"))]
    out_dir = Path(args.out_dir)
    if not out_dir.is_dir():
        raise UserInputError(f"--out-dir {out_dir}: no such directory")
    for source in sources:
        check_output_file(out_dir / f"{Path(source).stem}.csv", "--out-dir")
    targets = [(s, out_dir / f"{Path(s).stem}.csv") for s in sources]
    seen: dict[Path, str] = {}
    for source, target in targets:
        if target in seen:
            raise UserInputError(f"--out-dir {out_dir}: {seen[target]} and {source} would both be written to {target}")
        if target.resolve() == Path(source).resolve():
            raise UserInputError(f"--out-dir {out_dir}: {source} would be overwritten by its own import")
        seen[target] = source
    return targets


def _run(args: argparse.Namespace) -> int:
    from ecu_monitor.bus.canlog import load_flight
    from ecu_monitor.flightlog import describe_cht, parse_cht_choice, write_csv

    cht = None if args.cht is None else parse_cht_choice(args.cht)
    signals = _signal_map(args.signal)
    dbc_paths = [resolve_file(name, "dbc") for name in args.dbc] if args.dbc else None
    targets = _targets(args)
    failed = 0
    for source, target in targets:
        try:
            log = load_flight(
                source, mapping=args.mapping, dbc_paths=dbc_paths, signal_map=signals, engine=args.engine, cht=cht
            )
            write_csv(log, target)
        except UserInputError as exc:
            if len(targets) == 1:
                raise
            print(f"ecu-monitor: error: {exc}", file=sys.stderr)
            failed += 1
            continue
        print(
            f"{target}: {len(log)} rows, {log.duration_s:.1f} s ({log.duration_s / 60.0:.1f} min),"
            f" columns {', '.join(log.names)}; cht_c = {describe_cht(log)}; {len(log.notes)} warning(s)"
        )
    return 2 if failed else 0
