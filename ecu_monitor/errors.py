"""One exception tree for the whole package.

``EcuMonitorError`` is the root. ``UserInputError`` and its children mean "the user gave us something
we cannot use" (a bad file, config key, CSV row, mapping): the CLI prints their one-line message and
exits 2. Any other ``EcuMonitorError`` is an internal failure (exit 1).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable

__all__ = [
    "TOOLS_MODULES",
    "BusError",
    "ConfigError",
    "EcuMonitorError",
    "EstimationError",
    "FlightLogError",
    "ParameterError",
    "StorageError",
    "UserInputError",
    "run_command",
]


#: Modules of the ``tools`` extra (plots, progress bars, identification and gap diagnosis); the daemon's
#: own install (``pip install ecu-monitor``) does without them.
TOOLS_MODULES = frozenset({"matplotlib", "tqdm", "scipy"})


class EcuMonitorError(Exception):
    """Root of every error raised on purpose by ecu_monitor and virtual_bus."""


class UserInputError(EcuMonitorError):
    """Bad input from the user: the message names the file and the field (CLI exit code 2)."""


class ConfigError(UserInputError):
    """A YAML configuration (service config, model.yaml, mission, mapping) is invalid."""


class FlightLogError(UserInputError):
    """A flight log (canonical CSV, foreign CSV, CAN log) cannot be read as asked."""


class ParameterError(UserInputError):
    """A model parameter is outside its physical range or has the wrong shape."""


class BusError(EcuMonitorError):
    """The CAN bus failed (open, send or receive) in a way the caller must handle."""


class StorageError(EcuMonitorError):
    """The service's flight history cannot be opened or written (read-only, disk full): the service
    monitors on, keeps the flight in memory and retries (runtime/flight_recorder.py)."""


class EstimationError(EcuMonitorError):
    """An estimator was used wrongly (for example, estimate() before initialise())."""


def run_command(prog: str, command: Callable[[], int | None], debug: bool = False) -> int:
    """Run one CLI command and turn our errors into the contract's exit codes.

    UserInputError -> its one-line message, exit 2; any other EcuMonitorError -> one line, exit 1; a
    missing module of the ``tools`` extra -> one line saying how to install it, exit 1; Ctrl-C -> 130;
    a closed output pipe (``| head``) -> 141, silently.
    With ``debug`` the exception propagates (traceback). Shared by ``ecu-monitor`` and ``virtual-ecu``.
    """
    try:
        return int(command() or 0)
    except UserInputError as exc:
        if debug:
            raise
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except EcuMonitorError as exc:
        if debug:
            raise
        print(f"{prog}: internal error: {exc}", file=sys.stderr)
        return 1
    except ModuleNotFoundError as exc:
        if debug or (exc.name or "").split(".")[0] not in TOOLS_MODULES:
            raise
        print(f"{prog}: error: this command needs {exc.name}: pip install 'ecu-monitor[tools]'", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of our output went away (``| head``): stop quietly, as SIGPIPE would
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # Python's own flush at exit must not raise again
        return 141
