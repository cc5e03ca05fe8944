"""One entry for any flight CSV: :func:`load_csv` dispatches on the layout; :func:`require_distinct` refuses a
flight given twice to a command that pools flights."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from ecu_monitor.errors import FlightLogError
from ecu_monitor.flightlog.canonical import read_csv
from ecu_monitor.flightlog.cylinders import choose_cht
from ecu_monitor.flightlog.foreign import import_mapped_csv
from ecu_monitor.flightlog.layout import detect_layout
from ecu_monitor.flightlog.log import FlightLog
from ecu_monitor.flightlog.mapping import resolve_mapping
from ecu_monitor.userfiles import check_input


def load_csv(
    path: str | os.PathLike[str],
    mapping: str | os.PathLike[str] | None = None,
    *,
    engine: int | None = None,
    cht: str | int | None = None,
) -> FlightLog:
    """Load a flight CSV: canonical (:func:`read_csv`), or foreign through ``mapping`` (a path or a
    shipped mapping's name, see :func:`resolve_mapping`; None or ``"auto"`` detects the layout with
    :func:`detect_layout`). ``engine`` picks the engine of a multi-engine CSV; ``cht`` makes ``cht_c``
    from the cylinders (``mean``, ``hottest`` or a cylinder number; foreign CSVs default to ``mean``).
    For any suffix, CAN logs included, use :func:`ecu_monitor.bus.canlog.load_flight`."""
    path = Path(path)
    check_input(path, "flight CSV", FlightLogError)
    if mapping is None or str(mapping) == "auto":
        layout = detect_layout(path)
        if layout is None:
            if engine not in (None, 1):
                raise FlightLogError(f"{path}: a canonical flight CSV holds one engine, engine {engine} asked for")
            log = read_csv(path)
            return log if cht is None else choose_cht(log, cht)
        return import_mapped_csv(path, layout, engine=engine, cht=cht)
    return import_mapped_csv(path, resolve_mapping(mapping), engine=engine, cht=cht)


def require_distinct(paths: Sequence[str | os.PathLike[str]], command: str) -> None:
    """Refuse a flight given twice (the same file, however it is spelled): pooled flights would count it
    twice. Raises FlightLogError naming the file."""
    seen: dict[Path, str] = {}
    for path in paths:
        key = Path(path).resolve()
        if key in seen:
            same = "" if str(path) == seen[key] else f" (the same file as {seen[key]})"
            raise FlightLogError(f"{command}: {path}: given twice{same}; each flight counts once")
        seen[key] = str(path)
