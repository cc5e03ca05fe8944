"""Per-cylinder columns and the choice of ``cht_c`` from them.

A file holding several engines (``E1 RPM``, ``E2 RPM``) needs the engine
chosen (``engine=``); ``cht_c`` is made from the cylinders by :func:`choose_cht` (``mean`` by default,
``hottest`` per row, or one cylinder), ``egt_c`` is the mean EGT and ``egt_max_c`` the hottest.
:func:`describe_cht` says which from the data; :func:`cht_peak` and :func:`seconds_above` give the
hottest reading of a flight and the time above a CHT limit.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ecu_monitor.errors import FlightLogError, UserInputError
from ecu_monitor.flightlog.log import CHT_CHOICES, CYLINDER_COLUMN, FlightLog


def cylinder_columns(log: FlightLog, kind: str = "cht") -> list[str]:
    """The per-cylinder columns of ``kind`` (``cht`` or ``egt``) that ``log`` carries, in cylinder order."""
    found = []
    for name in log.names:
        match = CYLINDER_COLUMN.match(name)
        if match is not None and match.group(1) == kind:
            found.append((int(match.group(2)), name))
    return [name for _, name in sorted(found)]


def _cylinder_number(column: str) -> int:
    match = CYLINDER_COLUMN.match(column)
    if match is None:
        raise ValueError(f"not a cylinder column: {column!r}")
    return int(match.group(2))


def _cylinder_list(columns: Sequence[str]) -> str:
    numbers = [_cylinder_number(c) for c in columns]
    if numbers == list(range(numbers[0], numbers[-1] + 1)) and len(numbers) > 2:
        return f"{numbers[0]}-{numbers[-1]}"
    return ", ".join(map(str, numbers))


def parse_cht_choice(text: str | int) -> str | int:
    """``"mean"``, ``"hottest"`` or a 1-based cylinder number (``"2"`` -> 2); anything else is an error."""
    if isinstance(text, int) and not isinstance(text, bool):
        number = text
    else:
        word = str(text).strip().lower()
        if word in CHT_CHOICES:
            return word
        if not word.isdigit():
            raise UserInputError(f"CHT choice {text!r}: expected mean, hottest or a cylinder number (1, 2, ...)")
        number = int(word)
    if number < 1:
        raise UserInputError(f"CHT choice {text!r}: cylinders are numbered from 1")
    return number


def choose_cht(log: FlightLog, choice: str | int) -> FlightLog:
    """``log`` with ``cht_c`` made from its cylinders ``cht1_c ..``: their mean, the hottest per row, or one.

    ``choice`` is ``"mean"``, ``"hottest"`` or a 1-based cylinder number (see :func:`parse_cht_choice`).
    """
    choice = parse_cht_choice(choice)
    columns = cylinder_columns(log, "cht")
    if not columns:
        raise FlightLogError(f"{log.source}: no per-cylinder CHT columns (cht1_c ..) to choose cht_c from")
    if isinstance(choice, int):
        column = f"cht{choice}_c"
        if not log.has(column):
            raise FlightLogError(
                f"{log.source}: cylinder {choice} chosen for cht_c, the log has cylinder(s) {_cylinder_list(columns)}"
            )
        return log.with_columns(cht_c=log[column])
    stack = np.vstack([log[c] for c in columns])
    return log.with_columns(cht_c=stack.mean(axis=0) if choice == "mean" else stack.max(axis=0))


def describe_cht(log: FlightLog) -> str:
    """Which cylinders ``cht_c`` carries, read from the data (e.g. ``"mean of cylinders 1-4"``)."""
    columns = cylinder_columns(log, "cht")
    if not log.has("cht_c"):
        return "absent (no CHT in the log: the model cannot be identified or checked on it)"
    if not columns:
        return "the log's own channel (no per-cylinder columns)"
    cht = log["cht_c"]
    if len(columns) == 1:
        candidates = [(f"cylinder {_cylinder_number(columns[0])} (the only one)", log[columns[0]])]
    else:
        stack = np.vstack([log[c] for c in columns])
        every = _cylinder_list(columns)
        candidates = [
            (f"mean of cylinders {every}", stack.mean(axis=0)),
            (f"hottest of cylinders {every} (per row)", stack.max(axis=0)),
            *((f"cylinder {_cylinder_number(c)} of {every}", log[c]) for c in columns),
        ]
    for text, values in candidates:
        if np.allclose(cht, values, rtol=0.0, atol=1e-9, equal_nan=True):
            return text
    return "the log's own channel (not made from cht1_c ..)"
