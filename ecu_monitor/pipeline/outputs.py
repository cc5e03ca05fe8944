"""The health rows the service produces, made from the output table (:mod:`ecu_monitor.pipeline.output_table`):
:class:`HealthSnapshot` (one per health-status period, with a :class:`CylinderSnapshot` per cylinder on an
engine monitored per cylinder), the columns of health.csv and their layout (:func:`health_columns`,
:func:`health_table_columns`; the bytes are written from whole columns by :mod:`ecu_monitor.pipeline.table`:
CSV, Parquet, Arrow), :class:`ReplayResult` (a replay's rows as columns)."""

from __future__ import annotations

import functools
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.bus.codec import INPUT_NAMES
from ecu_monitor.pipeline.events import Event
from ecu_monitor.pipeline.output_table import (
    HEALTH_VALUES,
    STATES,
    CylinderSnapshot,
    HealthSnapshot,
    HealthValue,
    cylinder_values,
    engine_values,
)
from ecu_monitor.pipeline.table import TableColumn, write_health_table

__all__ = [
    "CylinderSnapshot",
    "HealthSnapshot",
    "ReferenceFeed",
    "ReplayResult",
    "column_layout",
    "column_value",
    "columns_of",
    "cylinder_snapshots",
    "empty_columns",
    "health_columns",
    "health_table_columns",
    "rows_to_columns",
    "write_health_csv",
]


def health_columns(cylinders: int) -> tuple[str, ...]:
    """The columns of health.csv for an engine with ``cylinders`` CHT channels: the ``csv`` rows of the
    output table (the engine's values; each cylinder's ``cyl{n}_<name>`` and the ``cylinders`` rows
    after them on an engine monitored per cylinder)."""
    return tuple(name for name, v in column_layout(cylinders) if v.csv)


def column_layout(cylinders: int) -> list[tuple[str, HealthValue]]:
    """Every column of a replay (ReplayResult.columns; health.csv's are its ``csv`` ones), in health.csv
    order, with its row of the output table."""
    first = [(v.name, v) for v in engine_values(cylinders) if v.scope != "cylinders"]
    if cylinders <= 1:
        return first
    per = [(f"cyl{n}_{v.name}", v) for n in range(1, cylinders + 1) for v in cylinder_values()]
    return [*first, *per, *((v.name, v) for v in HEALTH_VALUES if v.scope == "cylinders")]


#: The numpy type of a replay column of each kind of value (a state: its code; the stale inputs: the
#: Health_Diag.StaleInputs bit field, bit i = INPUT_NAMES[i]).
_COLUMN_TYPES: dict[str, Any] = {"float": np.float64, "state": np.int64, "flag": np.bool_, "cylinder": np.int64,
                                 "inputs": np.int64}  # fmt: skip


class ReferenceFeed(NamedTuple):
    """The open-loop reference over one clock segment of a batch replay, from the step the detector starts at
    (the replay keeps it when asked, ``replay_frames(..., keep_reference=True)``): step times s, and per step
    the held CHT reading, the open-loop reference model's CHT (the nominal model run from the first reading
    of each estimator stretch, as the supervisor sees it) and the held OAT, degC; nan wherever the supervisor
    was not NOMINAL (where the detector is fed nothing). The open-loop residual is cht_c - model_c."""

    time_s: NDArray[np.float64]
    cht_c: NDArray[np.float64]
    model_c: NDArray[np.float64]
    oat_c: NDArray[np.float64]


@dataclass(frozen=True)
class ReplayResult:
    """A replay's rows (one per health-status period) as columns, and the frame counters.

    columns: one array per row of the output table (the engine's values; on an engine monitored per
    cylinder also ``cyl{n}_<name>`` per cylinder row and the ``cylinders`` rows): floats, states as int
    codes into STATES, flags as bool, cylinder numbers as int (0: none), stale_inputs as the int bit
    field (bit i = INPUT_NAMES[i]).
    detector_feed (batch path only): per clock segment whose estimator started, what the detector was
    fed: (step times s from its start, symptom per step, nan where the supervisor was not NOMINAL).
    gaps (batch path only): (last frame time before, first after) of every hole in the frames longer
    than :data:`~ecu_monitor.bus.canlog.GAP_S`; holes longer than the pipeline's MAX_CLOCK_GAP_S
    restart the clock (``counters["clock_restarts"]``): no step runs inside them.
    cross_feeds (batch path, cross-cylinder detectors on): per cylinder, per clock segment, what its
    cross-cylinder detector was fed (as detector_feed).
    reference_feed (batch path, when asked): per clock segment as detector_feed, the open-loop reference
    (:class:`ReferenceFeed`; the first cylinder's on an engine monitored per cylinder).
    events: the engine events (pipeline/events.py), their end records in the order the step wrote them.
    detector_regions (batch path only): per clock segment as detector_feed, the operating region of each
    step (estimation/regions.py), what the reference test measures the feed against.
    start_fits (batch path only): per clock segment as detector_feed, the start fits at its end (pipeline/step.py,
    START_FIT_NAMES order; nan: a window that never closed), what calibrate learns their nominal spread from.
    """

    columns: dict[str, NDArray[Any]]
    counters: dict[str, int]
    detector_feed: tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...] = ()
    gaps: tuple[tuple[float, float], ...] = ()
    cross_feeds: tuple[tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...], ...] = ()
    reference_feed: tuple[ReferenceFeed, ...] = ()
    events: tuple[Event, ...] = ()
    detector_regions: tuple[NDArray[np.int64], ...] = ()
    start_fits: tuple[NDArray[np.float64], ...] = ()

    def __len__(self) -> int:
        return int(self.columns["time_s"].size)

    @property
    def cylinder_count(self) -> int:
        """CHT channels of the replayed engine (1: a single channel, no per-cylinder columns)."""
        return sum(1 for key in self.columns if key.startswith("cyl") and key.endswith("_state")) or 1

    @functools.cached_property
    def rows(self) -> list[HealthSnapshot]:
        """The rows as HealthSnapshot objects (what Pipeline.drain_rows gives)."""
        count = self.cylinder_count
        engine = list(engine_values(count))
        rows = [
            dict(zip((v.name for v in engine), values, strict=True))
            for values in zip(*(_values(v, self.columns[v.name]) for v in engine), strict=True)
        ]
        if count == 1:
            return [HealthSnapshot(**row) for row in rows]
        per = cylinder_snapshots(self.columns, count)
        return [HealthSnapshot(**row, cylinders=cyls) for row, cyls in zip(rows, per, strict=True)]

    def write_csv(self, path: str | os.PathLike[str]) -> int:
        """Write the rows to ``path``: health.csv, or Parquet / Arrow by the suffix
        (:func:`~ecu_monitor.pipeline.table.write_health_table`); returns the row count."""
        return write_health_table(health_table_columns(self.columns, self.cylinder_count), path)


def health_table_columns(columns: dict[str, NDArray[Any]], cylinders: int = 1) -> list[TableColumn]:
    """The columns of :func:`health_columns` from a replay's columns, as the table writer takes them."""
    out = []
    for name, value in column_layout(cylinders):
        if not value.csv:
            continue
        data = columns[name]
        if value.kind == "flag":
            out.append(TableColumn(name, data.astype(np.int64), ("0", "1")))
        elif value.kind == "state":
            out.append(TableColumn(name, data, STATES))
        elif value.kind == "cylinder":
            out.append(TableColumn(name, data, ("", *(str(n) for n in range(1, cylinders + 1)))))
        elif value.kind == "inputs":
            out.append(TableColumn(name, data, tuple("+".join(n) for n in _stale_names())))
        else:
            out.append(TableColumn(name, data))
    return out


@functools.cache
def _stale_names() -> tuple[tuple[str, ...], ...]:
    """Stale input names of every StaleInputs bit field value."""
    return tuple(tuple(n for i, n in enumerate(INPUT_NAMES) if bits >> i & 1) for bits in range(1 << len(INPUT_NAMES)))


def _values(value: HealthValue, column: NDArray[Any]) -> list[Any]:
    """A replay column as the snapshot values of its row of the output table."""
    if value.kind == "state":
        return [STATES[c] for c in column.tolist()]
    if value.kind == "inputs":
        names = _stale_names()
        return [names[c] for c in column.tolist()]
    return column.tolist()


def column_value(value: HealthValue, x: Any) -> Any:
    """A snapshot's value of ``value`` as it is held in a replay column (a state's code, the stale bits)."""
    if value.kind == "state":
        return STATES.index(x)
    if value.kind == "inputs":
        return sum(1 << i for i, n in enumerate(INPUT_NAMES) if n in x)
    return x


def empty_columns(cylinders: int = 1) -> dict[str, NDArray[Any]]:
    """The columns of a replay without rows (of an engine with ``cylinders`` CHT channels)."""
    return {name: np.zeros(0, dtype=_COLUMN_TYPES[v.kind]) for name, v in column_layout(cylinders)}


def cylinder_snapshots(columns: dict[str, NDArray[Any]], cylinders: int) -> list[tuple[CylinderSnapshot, ...]]:
    """Per row of a replay's columns, its cylinders' snapshots (from the ``cyl{n}_<name>`` columns)."""
    names = [v.name for v in cylinder_values()]
    per = []
    for n in range(1, cylinders + 1):
        values = [_values(v, columns[f"cyl{n}_{v.name}"]) for v in cylinder_values()]
        per.append([CylinderSnapshot(number=n, **dict(zip(names, row, strict=True)))
                    for row in zip(*values, strict=True)])  # fmt: skip
    return list(zip(*per, strict=True))


def rows_to_columns(rows: Sequence[HealthSnapshot], cylinders: int = 1) -> dict[str, NDArray[Any]]:
    """HealthSnapshot rows as the columns of :class:`ReplayResult` (``cylinders``: CHT channels)."""
    if not rows:
        return empty_columns(cylinders)
    return columns_of(rows, cylinders, [name for name, _ in column_layout(cylinders)])


def columns_of(rows: Sequence[HealthSnapshot], cylinders: int, names: Sequence[str]) -> dict[str, NDArray[Any]]:
    """The replay columns ``names`` of HealthSnapshot rows (``cylinders``: CHT channels)."""
    columns: dict[str, NDArray[Any]] = {}
    wanted = set(names)
    for name, v in column_layout(cylinders):
        if name not in wanted:
            continue
        if name == v.name:
            items = [getattr(r, name) for r in rows]
        else:
            i = int(name[3 : name.index("_")]) - 1
            items = [getattr(r.cylinders[i], v.name) for r in rows]
        columns[name] = np.array([column_value(v, x) for x in items], dtype=_COLUMN_TYPES[v.kind])
    return columns


def write_health_csv(rows: Iterable[HealthSnapshot], path: str | os.PathLike[str]) -> int:
    """Write health.csv (:func:`health_columns`, numbers as ``%.10g``, nan as an empty cell; or Parquet /
    Arrow by the suffix); returns the number of rows. FlightLogError if the file cannot be written."""
    rows = list(rows)
    count = len(rows[0].cylinders) if rows and rows[0].cylinders else 1
    return write_health_table(health_table_columns(rows_to_columns(rows, count), count), path)
