"""The ``ecu-monitor`` command line: one thin subcommand per module in ecu_monitor/commands/.

Each module in ``COMMAND_MODULES`` exports ``add_subparser(subparsers)`` which registers its parser and
sets ``func`` (cantools' pattern). Errors: ``UserInputError`` -> one line on stderr, exit 2; any other
``EcuMonitorError`` -> one line, exit 1; ``--debug`` shows the traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from ecu_monitor.errors import EcuMonitorError, UserInputError

__all__ = ["COMMAND_MODULES", "build_parser", "main"]

#: Subcommand modules, in the order ``--help`` lists them (imported lazily, one table, no if-chains).
COMMAND_MODULES: tuple[str, ...] = (
    "demo",
    "run",
    "replay",
    "simulate",
    "identify",
    "gap",
    "history",
    "import_log",
    "results",
    "evaluate",
)


def build_parser() -> argparse.ArgumentParser:
    """Build the top-level parser with every available subcommand registered."""
    parser = argparse.ArgumentParser(
        prog="ecu-monitor",
        description="Model-based thermal health monitoring of a UAV piston engine on CAN.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on error")
    parser.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING or ERROR")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(f"ecu_monitor.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"ecu_monitor.commands.{name}":
                raise
            continue  # subcommand not built yet
        module.add_subparser(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``ecu-monitor``; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=getattr(logging, str(args.log_level).upper(), logging.INFO),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except UserInputError as exc:
        if args.debug:
            raise
        print(f"ecu-monitor: error: {exc}", file=sys.stderr)
        return 2
    except EcuMonitorError as exc:
        if args.debug:
            raise
        print(f"ecu-monitor: internal error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("ecu-monitor: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
