"""Files shipped inside the package, and the one rule by which a user names a file.

The DBCs, service configs, virtual-ECU missions, foreign-CSV mappings, the systemd unit and detector files
(a calibrated ``detector:`` section that configs share through ``detector.file``) are
package data under ``ecu_monitor/data/<kind>/`` (found through :mod:`importlib.resources`, so an
installed wheel finds them from any directory). Wherever a command line or a config names one of
these files, :func:`resolve_file` applies the same rule: a path that exists wins (relative paths
are taken from ``base``, the folder of the file that names it, or the working directory); otherwise
the name is looked up among the shipped files of that kind, with or without its suffix
(``example.yaml``, ``example``, ``engine.dbc``, ``third_party/rusEFI_CAN_verbose.dbc``).
``ecu-monitor files`` lists them.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path, PurePosixPath

from ecu_monitor.errors import ConfigError

__all__ = [
    "DEFAULT_CONFIG",
    "DRONECAN_CONFIG",
    "KINDS",
    "MAVLINK_CONFIG",
    "resolve_file",
    "shipped_dir",
    "shipped_file",
    "shipped_files",
]

#: kind -> (folder under ecu_monitor/data, suffix a bare name is completed with, what it is)
KINDS: dict[str, tuple[str, str, str]] = {
    "dbc": ("dbc", ".dbc", "DBC file"),
    "config": ("configs", ".yaml", "config file"),
    "mission": ("missions", ".yaml", "mission file"),
    "mapping": ("mappings", ".yaml", "mapping file"),
    "unit": ("systemd", ".service", "systemd unit file"),
    "detector": ("detectors", ".yaml", "detector file"),
}


def shipped_dir(kind: str) -> Path:
    """The folder of the shipped files of ``kind``."""
    if kind not in KINDS:
        raise ValueError(f"unknown kind of shipped file {kind!r} (known: {', '.join(KINDS)})")
    folder = resources.files("ecu_monitor").joinpath("data", KINDS[kind][0])
    # installed as plain files (pip, editable or not): the Traversable is a real path cantools can open
    return Path(str(folder))


#: The service config the commands use when none is given: the shipped example for engine.dbc.
DEFAULT_CONFIG = shipped_dir("config") / "example.yaml"
#: The shipped config of a DroneCAN bus (replay takes it by default for a log that looks like DroneCAN).
DRONECAN_CONFIG = shipped_dir("config") / "dronecan.yaml"
#: The shipped config of the service on an autopilot's MAVLink link.
MAVLINK_CONFIG = shipped_dir("config") / "mavlink.yaml"


def shipped_files(kind: str) -> tuple[str, ...]:
    """Names (relative to their folder, '/'-separated) of the shipped files of ``kind``, sorted."""
    folder = shipped_dir(kind)
    suffix = KINDS[kind][1]
    found = (p.relative_to(folder).as_posix() for p in folder.rglob(f"*{suffix}") if p.is_file())
    return tuple(sorted(found))


def shipped_file(kind: str, name: str) -> Path | None:
    """The shipped file of ``kind`` called ``name`` (suffix optional), or None."""
    relative = PurePosixPath(name.replace(os.sep, "/"))
    if relative.is_absolute() or ".." in relative.parts or not relative.parts:
        return None
    folder = shipped_dir(kind)
    suffix = KINDS[kind][1]
    for candidate in (relative, relative.with_name(relative.name + suffix)):
        path = folder.joinpath(*candidate.parts)
        if path.is_file():
            return path
    return None


def resolve_file(name: str | os.PathLike[str], kind: str, base: Path | None = None) -> Path:
    """The file a user means by ``name``: an existing path (relative to ``base`` or the working
    directory), else the shipped file of ``kind`` of that name. Raises ConfigError naming the shipped
    choices when neither exists."""
    text = os.path.expanduser(os.fspath(name))
    path = Path(text)
    if not path.is_absolute() and base is not None:
        path = base / path
    if path.exists():
        return path
    shipped = shipped_file(kind, text)
    if shipped is not None:
        return shipped
    choices = ", ".join(shipped_files(kind)) or "none"
    raise ConfigError(f"{path}: no such {KINDS[kind][2]} (shipped: {choices})")
