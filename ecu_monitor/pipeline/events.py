"""The engine events: what the step reports besides the health values (docs/service.md, "Engine events";
the events table in docs/contracts.md).

An event is a condition that held for a while (``valve_advisory`` is an advisory, not an alarm): its
start (``time_s``, s), its ``kind`` (one of :data:`EVENT_KINDS`; the step writes its index), its
``cylinder`` (1-based; 0: the engine), its worst ``value`` over the condition (the kind's unit in
:data:`EVENT_UNITS`), the ``limit`` it crossed, and its ``duration_s``. The step (pipeline/step.py,
``events_step``) writes two records of each event: its start (``ongoing`` True, the worst value and the
duration so far), once the condition has held for its minimum time, which the health outputs publish at
once (:meth:`Event.start_text`); and its end (``ongoing`` False), when the condition ends or the log
ends (``close_events``), which the events table lists (:func:`finished`). Every start has its end.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import NamedTuple

__all__ = ["EVENT_COLUMNS", "EVENT_KINDS", "EVENT_UNITS", "Event", "events_csv", "finished"]

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
    ongoing: bool = False  # the start record (module docstring)

    @property
    def advisory(self) -> bool:
        """An advisory for the maintainer (the exhaust-valve advisory), not an alarm for the pilot."""
        return self.kind == "valve_advisory"

    def start_text(self) -> str:
        """The one line the health outputs publish when the event starts, at most 50 characters (one
        STATUSTEXT chunk): ``ENGINE cyl 3: shock cooling -41 C/min``."""
        who = f"ENGINE cyl {self.cylinder}" if self.cylinder else "ENGINE"
        unit = EVENT_UNITS[self.kind].replace("deg", "")
        return f"{who}: {self.kind.replace('_', ' ')} {self.value:+.0f} {unit}"[:50]

    def text(self) -> str:
        """One line for a person: ``cylinder 3 shock_cooling -41.2 degC/min (limit -33) for 12 s``."""
        unit = EVENT_UNITS[self.kind]
        return (
            f"cylinder {self.cylinder} {self.kind} {self.value:.1f} {unit} (limit {self.limit:g})"
            f" for {self.duration_s:.0f} s"
        )


def finished(events: Iterable[Event]) -> list[Event]:
    """The end records of ``events`` (the events table's rows), in order."""
    return [e for e in events if not e.ongoing]


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
