"""``ecu-monitor files [NAME]``: the files shipped with the package (DBCs, configs, missions, mappings,
systemd unit, detector files).

Without NAME, lists every shipped file by kind with its path. With NAME, prints the path of that
shipped file (suffix optional), e.g. ``cp "$(ecu-monitor files example.yaml)" /etc/ecu-monitor/config.yaml``.
Wherever a command or a config names such a file, a path that exists wins, else the shipped name is used.
"""

from __future__ import annotations

import argparse
from typing import Any

from ecu_monitor.errors import ConfigError
from ecu_monitor.shipped import KINDS, shipped_file, shipped_files

__all__ = ["add_subparser"]


def add_subparser(subparsers: Any) -> None:
    """Register the ``files`` subcommand."""
    parser = subparsers.add_parser(
        "files",
        help="list the shipped DBCs, configs, missions, mappings and systemd unit, or print one's path",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument("name", nargs="?", help="a shipped file's name (e.g. example.yaml, engine.dbc)")
    parser.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    if args.name is None:
        for kind, (_, _, what) in KINDS.items():
            for name in shipped_files(kind):
                print(f"{what:20s} {name:40s} {shipped_file(kind, name)}")
        return 0
    for kind in KINDS:
        path = shipped_file(kind, args.name)
        if path is not None:
            print(path)
            return 0
    raise ConfigError(f"{args.name}: not a shipped file (ecu-monitor files lists them)")
