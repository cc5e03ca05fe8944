"""Which airframe (or engine) a flight log comes from, as the log itself says.

A Garmin G1000 export opens with ``#airframe_info, ..., system_id="2E90B4BED", ...``: the system id
names the avionics installation, so one airframe. A log whose first line is a ``#`` comment with
``engine_serial="..."`` (or ``engine_serial=...``) names its engine. Anything else names nothing.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

__all__ = ["IDENTITY_KEYS", "log_airframe"]

#: Keys of a log's first comment line that name its airframe or engine, in order of preference.
IDENTITY_KEYS: tuple[str, ...] = ("engine_serial", "system_id")
_PAIR = re.compile(r'([A-Za-z_]+)\s*=\s*(?:"([^"]*)"|([^,\s]+))')
#: Bytes read from the start of a file: the identity sits on its first line.
_HEAD_BYTES = 4096


def log_airframe(path: str | os.PathLike[str]) -> str | None:
    """The airframe id the log at ``path`` names in its first line (:data:`IDENTITY_KEYS`), else None.

    Binary logs, files that cannot be read and logs without such a line name nothing (None): the
    caller then asks the user (``identify --airframe NAME=GLOB``)."""
    try:
        with Path(path).open("rb") as handle:
            head = handle.read(_HEAD_BYTES)
    except OSError:
        return None
    first = head.split(b"\n", 1)[0].decode("utf-8", errors="replace").lstrip("\ufeff").strip()
    if not first.startswith("#"):
        return None
    pairs = {m.group(1).lower(): (m.group(2) if m.group(2) is not None else m.group(3)) for m in _PAIR.finditer(first)}
    for key in IDENTITY_KEYS:
        value = (pairs.get(key) or "").strip()
        if value:
            return value
    return None
