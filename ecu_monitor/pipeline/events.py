"""The engine events: what the step reports besides the health values (docs/service.md, "Engine events";
the events table in docs/contracts.md).

An event is a condition that held for a while (``valve_advisory`` is an advisory, not an alarm): its
start (``time_s``, s), its ``kind`` (one of :data:`EVENT_KINDS`; the step writes its index), its
``cylinder`` (1-based; 0: the engine), its worst ``value`` over the condition (the kind's unit in
:data:`EVENT_UNITS`), the ``limit`` it crossed, and its ``duration_s``. The step (pipeline/step.py,
``events_step``) writes an event when its condition ends, or when the log ends (``close_events``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import NamedTuple

__all__ = ["EVENT_COLUMNS", "EVENT_KINDS", "EVENT_UNITS", "Event", "events_csv"]

#: The kinds of event, in code order (the step's ``kind`` is the index here).
EVENT_KINDS: tuple[str, ...] = (
    "shock_cooling",
    "cht_divergence",
    "egt_divergence",
    "valve_advisory",
    "cht_exceedance",
    "egt_exceedance",
    "oil_exceedance",
)
#: The unit of an event's value and limit, by kind.
EVENT_UNITS: dict[str, str] = {
    "shock_cooling": "degC/min",
    "cht_divergence": "degC",
    "egt_divergence": "degC",
    "valve_advisory": "degC",
    "cht_exceedance": "degC",
    "egt_exceedance": "degC",
    "oil_exceedance": "degC",
}
#: The events table's columns (``replay --events``).
EVENT_COLUMNS: tuple[str, ...] = ("time_s", "kind", "cylinder", "value", "limit", "duration_s")


class Event(NamedTuple):
    """One event (module docstring)."""

    time_s: float
    kind: str
    cylinder: int
    value: float
    limit: float
    duration_s: float

    def text(self) -> str:
        """One line for a person: ``cylinder 3 shock_cooling -41.2 degC/min (limit -33) for 12 s``."""
        unit = EVENT_UNITS[self.kind]
        return (
            f"cylinder {self.cylinder} {self.kind} {self.value:.1f} {unit} (limit {self.limit:g})"
            f" for {self.duration_s:.0f} s"
        )


def events_csv(events: Iterable[Event]) -> str:
    """The events table as CSV text (:data:`EVENT_COLUMNS`; numbers to 0.01, a missing one empty)."""

    def number(x: float) -> str:
        return f"{x:.2f}" if math.isfinite(x) else ""

    lines = [",".join(EVENT_COLUMNS)]
    for e in events:
        lines.append(
            f"{number(e.time_s)},{e.kind},{e.cylinder},{number(e.value)},{number(e.limit)},{number(e.duration_s)}"
        )
    return "\n".join(lines) + "\n"
