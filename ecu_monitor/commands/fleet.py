"""``ecu-monitor fleet run FLEET.yaml --out DIR [--scheduler tcp://HOST:8786] [--workers N]``,
``ecu-monitor fleet query DIR "SQL"``, ``ecu-monitor fleet demo DIR``.

``run``: every log of every engine that FLEET.yaml lists (flight CSVs, G1000 exports, CAN logs, MAVLink
logs, daemons' flight databases; docs/fleet.md) is replayed with its engine's config, model and detector
and summarised, one Dask task per log (a local cluster of one worker process per core, or the cluster of
``--scheduler``); then per engine, in flight order, the across-flight detector (the daemon's rule) and the
ranking. Writes DIR/engines.parquet (rank 1 = most concern), the Parquet datasets DIR/flights/ and
DIR/events/ partitioned by engine, DIR/failures/ (one row per unreadable log) and DIR/report.html. A rerun
processes only the logs it has not seen (by content hash); a run stopped at any moment resumes. Prints
progress (logs done, failed, time left), then one line per engine in rank order, ``ALERT`` first on an
alerted engine's line.

``query``: SQL over DIR with DuckDB; the views ``engines``, ``flights``, ``events``, ``failures``.

``demo``: a virtual fleet from nothing in DIR (FLEET.yaml, the logs, the engine type's detector calibrated as
``calibrate`` does on hour-long reference flights of a sister engine): 20 engines, 200 random-mission
flights, three of them slowly degrading; then ``fleet run`` it.

Needs the fleet extra: ``pip install 'ecu-monitor[fleet]'`` (dask[distributed], pyarrow, duckdb).
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path
from typing import Any

from ecu_monitor.errors import ConfigError

__all__ = ["add_subparser"]

#: The fleet extra's modules (pyproject ``fleet``).
_FLEET_MODULES = ("dask", "distributed", "pyarrow", "duckdb")


def add_subparser(subparsers: Any) -> None:
    """Register the ``fleet`` subcommand and its ``run``, ``query`` and ``demo``."""
    parser = subparsers.add_parser(
        "fleet",
        help="every flight of every engine of a fleet (Dask) -> Parquet tables, a ranking and report.html",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    actions = parser.add_subparsers(dest="fleet_command", metavar="ACTION", required=True)
    run = actions.add_parser("run", help="process the fleet's unseen logs and rank its engines")
    run.add_argument("fleet", metavar="FLEET.yaml", help="the engines and their logs (docs/fleet.md)")
    run.add_argument("--out", required=True, metavar="DIR", help="output folder (made if missing; reruns resume)")
    _cluster_arguments(run)
    run.set_defaults(func=_run)
    query = actions.add_parser("query", help="SQL over a fleet folder (DuckDB: engines, flights, events, failures)")
    query.add_argument("dir", metavar="DIR", help="the --out folder of fleet run")
    query.add_argument(
        "sql", metavar="SQL", help='e.g. "SELECT serial, rank, alert, reason FROM engines ORDER BY rank"'
    )
    query.set_defaults(func=_query)
    demo = actions.add_parser("demo", help="make a virtual fleet from nothing in DIR, then run it")
    demo.add_argument("dir", metavar="DIR", help="new folder for the fleet (FLEET.yaml, logs, out/)")
    demo.add_argument("--engines", type=int, default=20, help="engines (default 20)")
    demo.add_argument("--flights", type=int, default=200, help="flights shared among the engines (default 200)")
    demo.add_argument("--degrading", type=int, default=3, choices=(0, 1, 2, 3),
                      help="engines that wear slowly, each at its own rate (default 3)")  # fmt: skip
    demo.add_argument("--format", default="csv", choices=("csv", "blf", "asc"), help="log format (default csv)")
    demo.add_argument("--seed", type=int, default=0, help="the fleet's seed (default 0)")
    _cluster_arguments(demo)
    demo.set_defaults(func=_demo)


def _cluster_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scheduler", metavar="tcp://HOST:8786", help="a running Dask scheduler (default: local)")
    parser.add_argument("--workers", type=int, metavar="N", help="local worker processes (default: one per core)")


def _need_fleet_extra() -> None:
    missing = [name for name in _FLEET_MODULES if importlib.util.find_spec(name) is None]
    if missing:
        raise ConfigError(f"fleet needs {', '.join(missing)}: pip install 'ecu-monitor[fleet]'")


def _check_cluster(args: argparse.Namespace) -> None:
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers {args.workers}: expected at least 1")
    if args.workers is not None and args.scheduler:
        raise ConfigError("--workers: a --scheduler's cluster has its own workers")


def _run(args: argparse.Namespace) -> int:
    _need_fleet_extra()
    _check_cluster(args)
    from ecu_monitor.fleet.run import run_fleet

    run = run_fleet(args.fleet, args.out, scheduler=args.scheduler, workers=args.workers)
    _print_run(run, Path(args.out))
    return 0


def _print_run(run: Any, out: Path) -> None:
    for line in run.empty_globs:
        print(f"warning: {line}")
    failed = f", {len(run.failed)} failed" if run.failed else ""
    print(f"{out}: {run.processed} logs processed, {run.skipped} seen before{failed}; {len(run.engines)} engines;"
          f" {run.wall_s:.0f} s")  # fmt: skip
    for log, reason in run.failed:
        print(f"failed: {log}: {reason}")
    for row in run.engines:
        mark = "ALERT " if row["alert"] else ""
        print(f"{mark}#{row['rank']} {row['serial']}: {row['flights']} flights, {row['hours']:.1f} h; {row['reason']}")
    print(f"report: {out / 'report.html'}")


def _query(args: argparse.Namespace) -> int:
    _need_fleet_extra()
    import duckdb

    from ecu_monitor.fleet.store import FleetStore

    root = Path(args.dir)
    if not root.is_dir():
        raise ConfigError(f"{root}: no such folder")
    con = FleetStore(root).connect()
    try:
        cursor = con.execute(args.sql)
    except duckdb.Error as exc:
        raise ConfigError(f"query: {str(exc).splitlines()[0]}") from None
    if cursor.description is None:
        return 0
    names = [d[0] for d in cursor.description]
    rows = cursor.fetchall()
    print("\t".join(names))
    for row in rows:
        print("\t".join("" if v is None else f"{v:.6g}" if isinstance(v, float) else str(v) for v in row))
    print(f"({len(rows)} rows)", file=sys.stderr)
    return 0


def _demo(args: argparse.Namespace) -> int:
    _need_fleet_extra()
    _check_cluster(args)
    from ecu_monitor.fleet.demo import DEFAULT_RATES, make_virtual_fleet
    from ecu_monitor.fleet.run import open_client, run_fleet

    root = Path(args.dir)
    if root.exists() and any(root.iterdir()):
        raise ConfigError(f"{root}: not empty: give a new folder")
    if not root.parent.is_dir():
        raise ConfigError(f"{root}: no such folder {root.parent}")
    client = open_client(args.scheduler, args.workers)
    try:
        rates = DEFAULT_RATES[: args.degrading]
        fleet = make_virtual_fleet(
            root,
            client,
            engines=args.engines,
            flights=args.flights,
            rates=rates,
            log_format=args.format,
            seed=args.seed,
        )
        degrading = ", ".join(f"{serial} (gamma_Q +{rate:g} a flight)" for serial, rate in fleet.degrading.items())
        print(f"{fleet.fleet_file}: {args.engines} engines, {fleet.flights} flights; degrading: {degrading or 'none'}")
        run = run_fleet(fleet.fleet_file, root / "out", client=client)
    finally:
        cluster = client.cluster
        client.close()
        if cluster is not None:
            cluster.close()
    _print_run(run, root / "out")
    return 0
