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
from typing import Any

from ecu_monitor import __version__
from ecu_monitor.compile_cache import use_cache_dir
from ecu_monitor.errors import TOOLS_MODULES, run_command

__all__ = ["COMMANDS", "COMMAND_MODULES", "build_parser", "main"]

#: Subcommand name -> module in ecu_monitor.commands, in the order ``--help`` lists them. Modules are
#: imported lazily (one table, no if-chains): a run imports only its own subcommand's module, so a
#: config error or ``--help`` of one command does not pay for scipy and numba in all the others.
COMMANDS: dict[str, str] = {
    "demo": "demo",
    "run": "run",
    "replay": "replay",
    "simulate": "simulate",
    "identify": "identify",
    "gap": "gap",
    "history": "history",
    "import": "import_log",
    "results": "results",
    "evaluate": "evaluate",
    "calibrate": "calibrate",
    "files": "files",
    "fleet": "fleet",
}
COMMAND_MODULES: tuple[str, ...] = tuple(COMMANDS.values())


def _requested_command(argv: Sequence[str]) -> str | None:
    """The subcommand named on the command line (skipping the global options), if any."""
    skip_next = False
    for arg in argv:
        if skip_next:
            skip_next = False
            continue
        if arg == "--log-level":
            skip_next = True
            continue
        if arg.startswith("-"):
            continue
        return arg
    return None


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The top-level parser with every subcommand registered (or just ``only``, when it is known)."""
    parser = argparse.ArgumentParser(
        prog="ecu-monitor",
        description="Model-based thermal health monitoring of a UAV piston engine on CAN.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on error")
    parser.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING or ERROR")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    names = [only] if only in COMMANDS else list(COMMANDS)
    for name in names:
        try:
            module = importlib.import_module(f"ecu_monitor.commands.{COMMANDS[name]}")
        except ModuleNotFoundError as exc:
            if (exc.name or "").split(".")[0] not in TOOLS_MODULES:
                raise
            _needs_tools(subparsers, name, exc)
            continue
        module.add_subparser(subparsers)
    return parser


def _needs_tools(subparsers: Any, name: str, missing: ModuleNotFoundError) -> None:
    """Register ``name`` as a command that says which extra to install (the daemon's lean install)."""
    parser = subparsers.add_parser(name, help=f"(needs: pip install 'ecu-monitor[tools]', {missing.name} is missing)")
    parser.add_argument("arguments", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)

    def fail(args: argparse.Namespace) -> int:
        raise missing

    parser.set_defaults(func=fail)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``ecu-monitor``; returns the process exit code."""
    use_cache_dir()  # NUMBA_CACHE_DIR before anything imports numba (unless the user set it)
    arguments = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(only=_requested_command(arguments))
    args = parser.parse_args(arguments)
    logging.basicConfig(
        level=getattr(logging, str(args.log_level).upper(), logging.INFO),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    return run_command("ecu-monitor", lambda: args.func(args), debug=args.debug)


if __name__ == "__main__":
    sys.exit(main())
