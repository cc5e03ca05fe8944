"""The one DBC loader, and where the shipped DBC files are.

:func:`load_dbc` reads a DBC file with cantools and loads what can be loaded from a vendor's file:

* a file that is not text (a NUL or control byte) or holds no ``BO_`` message is refused:
  ``"FILE: not a DBC file (line N: ...)"`` with the first bad line;
* whole-line comments (``#`` or ``//``, which Vector's format does not have but vendors write) are
  dropped; hexadecimal ids (``BO_ 0x360 ...``, also in ``CM_``, ``BA_``, ``VAL_`` lines) are read as
  numbers;
* a message that fails cantools' strict checks (overlapping signals, a signal outside the frame) is
  kept but marked broken: using it (decoding or encoding) is a ConfigError naming the reason, and
  while nothing uses it it is only a warning;
* any other line cantools cannot parse is a ConfigError naming the line.

Each repair is logged once with ``logging.warning`` and kept in :attr:`Dbc.notes`. Files are parsed
once per (path, size, modification time).

:func:`shipped_dbc` names a DBC file shipped as package data (:mod:`ecu_monitor.shipped`).
"""

from __future__ import annotations

import functools
import logging
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

from ecu_monitor.errors import ConfigError
from ecu_monitor.shipped import shipped_dir
from ecu_monitor.userfiles import read_input_bytes

__all__ = ["Dbc", "load_dbc", "shipped_dbc"]

_log = logging.getLogger(__name__)


def shipped_dbc(name: str) -> Path:
    """Path of a DBC file shipped with ecu-monitor (``engine.dbc``, ``health.dbc``, ``third_party/...``),
    through the package-data resolver :mod:`ecu_monitor.shipped`."""
    return shipped_dir("dbc") / name


@dataclass(frozen=True, eq=False)
class Dbc:
    """A loaded DBC file: the cantools database, the messages that failed strict checks (name ->
    reason) and the repairs made while reading (one line each)."""

    path: str
    database: Any
    broken: Mapping[str, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    @property
    def messages(self) -> list[Any]:
        """Every message of the file (broken ones included: see :meth:`message`)."""
        return list(self.database.messages)

    def find(self, name: str) -> Any | None:
        """The message called ``name``, or None (broken ones too)."""
        for message in self.database.messages:
            if message.name == name:
                return message
        return None

    def check_usable(self, name: str) -> None:
        """ConfigError if message ``name`` is broken (it is about to be decoded or encoded)."""
        if name in self.broken:
            raise ConfigError(f"{self.path}: message '{name}' cannot be used: {self.broken[name]}")


_COMMENT = re.compile(r"^\s*(#|//)")
_HEX_ID = re.compile(
    r"^(\s*(?:BO_|BO_TX_BU_|VAL_|SIG_VALTYPE_|SG_MUL_VAL_|CM_\s+(?:BO_|SG_)|BA_\s+\"[^\"]*\"\s+(?:BO_|SG_))\s+)"
    r"0[xX]([0-9A-Fa-f]+)\b"
)
_SYNTAX = re.compile(r"line (\d+), column (\d+)")


def load_dbc(path: str | os.PathLike[str]) -> Dbc:
    """Load one DBC file (rules in the module docstring); ConfigError naming the file otherwise."""
    src = str(path)
    try:
        stat = os.stat(src)
    except FileNotFoundError:
        raise ConfigError(f"{src}: no such DBC file") from None
    except OSError as exc:
        raise ConfigError(f"{src}: cannot read DBC file: {exc.strerror or exc}") from None
    dbc = _load_cached(src, stat.st_size, stat.st_mtime_ns)
    return dbc


@functools.lru_cache(maxsize=32)
def _load_cached(src: str, size: int, mtime_ns: int) -> Dbc:
    import cantools

    del size, mtime_ns  # part of the cache key only
    raw = read_input_bytes(src, "DBC file", ConfigError)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("cp1252", errors="replace")  # cantools' default encoding for DBC files
    lines = text.split("\n")
    for number, line in enumerate(lines, start=1):
        bad = next((c for c in line.rstrip("\r") if ord(c) < 32 and c != "\t"), None)
        if bad is not None:
            raise ConfigError(f"{src}: not a DBC file (line {number} holds the control byte 0x{ord(bad):02X})")
    if not any(line.lstrip().startswith("BO_ ") for line in lines):
        first = next((i for i, line in enumerate(lines, start=1) if line.strip()), 1)
        raise ConfigError(f"{src}: not a DBC file (no BO_ message definition; line {first} does not start one)")
    notes: list[str] = []
    comments = [i for i, line in enumerate(lines, start=1) if _COMMENT.match(line)]
    if comments:
        lines = ["" if _COMMENT.match(line) else line for line in lines]  # keep the line numbers
        notes.append(f"{len(comments)} comment line(s) ignored (first at line {comments[0]})")
    hex_lines = [i for i, line in enumerate(lines, start=1) if _HEX_ID.match(line)]
    if hex_lines:
        lines = [_HEX_ID.sub(lambda m: f"{m.group(1)}{int(m.group(2), 16)}", line) for line in lines]
        notes.append(f"{len(hex_lines)} hexadecimal id(s) read as numbers (first at line {hex_lines[0]})")
    try:
        database = cantools.database.load_string("\n".join(lines), database_format="dbc", strict=False)
    except (cantools.database.UnsupportedDatabaseFormatError, cantools.database.Error) as exc:
        message = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        where = _SYNTAX.search(message)
        if where is not None:
            number = int(where.group(1))
            shown = lines[number - 1].strip() if 0 < number <= len(lines) else ""
            if len(shown) > 60:
                shown = shown[:57] + "..."
            raise ConfigError(f"{src}: not a valid DBC file: syntax error at line {number}: {shown!r}") from None
        raise ConfigError(f"{src}: not a valid DBC file: {message[:200]}") from None
    broken: dict[str, str] = {}
    for frame_def in database.messages:  # type: ignore[union-attr]  # load_string of a .dbc gives a CAN database
        try:
            frame_def.refresh(strict=True)
        except (cantools.database.Error, ValueError) as exc:
            broken[frame_def.name] = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            frame_def.refresh(strict=False)
    if broken:
        shown = "; ".join(f"{name}: {reason}" for name, reason in list(broken.items())[:3])
        more = f" (and {len(broken) - 3} more)" if len(broken) > 3 else ""
        notes.append(f"{len(broken)} message(s) fail strict checks and cannot be used: {shown}{more}")
    for note in notes:
        _log.warning("%s: %s", src, note)
    return Dbc(src, database, MappingProxyType(broken), tuple(notes))
