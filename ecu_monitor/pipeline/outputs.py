"""The health rows the service produces: :class:`HealthSnapshot` (one per health-status period, with a
:class:`CylinderSnapshot` per cylinder on an engine monitored per cylinder), the columns of health.csv
and their layout (:func:`health_table_columns`; the bytes are written from whole columns by
:mod:`ecu_monitor.pipeline.table`: CSV, Parquet, Arrow), :class:`ReplayResult` (a replay's rows
as columns)."""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.bus.codec import INPUT_NAMES
from ecu_monitor.estimation.headroom import DEFAULT_CAP_S
from ecu_monitor.estimation.regions import REGION_NAMES
from ecu_monitor.pipeline.supervision import STATES
from ecu_monitor.pipeline.table import TableColumn, write_health_table

#: ThermalHeadroom meaning "not limited" (health.dbc; the headroom module's cap).
HEADROOM_NOT_LIMITED_S = DEFAULT_CAP_S


@dataclass(frozen=True)
class CylinderSnapshot:
    """One cylinder at one instant (engines monitored per cylinder, ``cht1_c .. chtN_c``).

    number: 1-based. The other fields mean what HealthSnapshot's do, for this cylinder alone.
    """

    number: int
    cht_meas_c: float
    cht_est_c: float
    deviation: float
    state: str
    gamma_q: float
    gamma_d: float
    headroom_s: float
    cht_rate_c_per_min: float = float("nan")
    gamma_q_sd: float = float("nan")
    gamma_d_sd: float = float("nan")
    isolable: bool = False
    armed: int = 0
    region: int = -1

    @property
    def sensor_fault(self) -> bool:
        """The cylinder's CHT probe is faulty."""
        return self.state == "SENSOR_FAULT"


@dataclass(frozen=True)
class HealthSnapshot:
    """The service's view of the engine at one instant (one health-status period).

    time_s: step time, s (the advance_to clock). cht_meas_c: last CHT reading held, degC (nan: none).
    cht_est_c: estimate, degC (nan when UNAVAILABLE). deviation: model-deviation symptom, degC/s.
    state: one of STATES. gamma_q, gamma_d: isolation estimates (nan when UNAVAILABLE). headroom_s:
    time to the CHT limit at the present inputs, s (HEADROOM_NOT_LIMITED_S = not limited; nan when
    UNAVAILABLE). stale_inputs: names of the stale inputs (a cylinder's ``chtN_c`` is reported as
    ``cht_c``). sensor_fault: the CHT sensor is faulty. gamma_q_sd, gamma_d_sd: the isolation filter's
    standard deviations of the gammas (1). isolable: the gammas can be told apart now; when not, gamma_q
    and gamma_d are nan ("not isolable"). armed: what the detector measures against, bits of
    :data:`ARMED_NAMES` (0: not armed yet). region: the operating region (estimation/regions.py; -1: none).

    Per cylinder (empty for a single CHT channel): ``cylinders``, one CylinderSnapshot each; the fields
    above are then the lead cylinder's (:mod:`ecu_monitor.pipeline.cylinders`, sensor_fault: any
    cylinder's probe); ``cht_spread_c`` hottest minus coldest trusted estimate, degC (nan: fewer than
    two); ``hottest_cylinder`` its number (0: none); ``spread_alarm``: the spread exceeds its limit.
    """

    time_s: float
    cht_meas_c: float
    cht_est_c: float
    deviation: float
    state: str
    gamma_q: float
    gamma_d: float
    headroom_s: float
    stale_inputs: tuple[str, ...]
    sensor_fault: bool
    cylinders: tuple[CylinderSnapshot, ...] = ()
    cht_spread_c: float = float("nan")
    hottest_cylinder: int = 0
    spread_alarm: bool = False
    cht_rate_c_per_min: float = float("nan")
    lead_cylinder: int = 0  # the number of the cylinder the engine-level fields are (0: one CHT channel)
    gamma_q_sd: float = float("nan")
    gamma_d_sd: float = float("nan")
    isolable: bool = False
    armed: int = 0
    region: int = -1

    @property
    def isolation_text(self) -> str:
        """"not isolable" when the gammas cannot be told apart, else empty."""
        return "" if self.isolable else "not isolable"


#: Columns of health.csv (one row per health-status period): HealthSnapshot fields; stale_inputs as
#: names joined by "+", sensor_fault as 0/1; empty cells for nan.
HEALTH_COLUMNS: tuple[str, ...] = (
    "time_s",
    "cht_meas_c",
    "cht_est_c",
    "deviation",
    "state",
    "gamma_q",
    "gamma_d",
    "headroom_s",
    "stale_inputs",
    "sensor_fault",
    "cht_rate_c_per_min",
    "gamma_q_sd",
    "gamma_d_sd",
    "isolable",
    "detector_armed",
    "region",
)
#: What ``detector_armed`` says for each value of the ``armed`` bits (ARMED_REFERENCE = 1, ARMED_BASELINE = 2
#: of pipeline/step.py): empty while the detector is not armed.
ARMED_NAMES: tuple[str, ...] = ("", "reference", "baseline", "reference+baseline")
#: Per-cylinder columns of health.csv (engines monitored per cylinder), ``{n}`` = 1 .. N, after HEALTH_COLUMNS.
CYLINDER_COLUMNS: tuple[str, ...] = (
    "cyl{n}_cht_meas_c",
    "cyl{n}_cht_est_c",
    "cyl{n}_deviation",
    "cyl{n}_state",
    "cyl{n}_gamma_q",
    "cyl{n}_gamma_d",
    "cyl{n}_headroom_s",
    "cyl{n}_cht_rate_c_per_min",
)
#: Engine columns of health.csv after the per-cylinder ones: CHT spread (degC), hottest cylinder (1-based,
#: empty: none), spread alarm (0/1).
SPREAD_COLUMNS: tuple[str, ...] = ("cht_spread_c", "hottest_cylinder", "spread_alarm")
#: Float fields of CylinderSnapshot, in CYLINDER_COLUMNS order (the state is the fourth column).
_CYLINDER_FLOATS: tuple[str, ...] = (
    "cht_meas_c", "cht_est_c", "deviation", "gamma_q", "gamma_d", "headroom_s", "cht_rate_c_per_min",
)  # fmt: skip


def health_columns(cylinders: int) -> tuple[str, ...]:
    """The columns of health.csv for an engine with ``cylinders`` CHT channels (1: HEALTH_COLUMNS alone)."""
    if cylinders <= 1:
        return HEALTH_COLUMNS
    per = tuple(c.format(n=n) for n in range(1, cylinders + 1) for c in CYLINDER_COLUMNS)
    return (*HEALTH_COLUMNS, *per, *SPREAD_COLUMNS)


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

    columns: time_s, cht_meas_c, cht_est_c, deviation, gamma_q, gamma_d, headroom_s (float arrays),
    state (int codes into STATES), stale (int bit field, bit i = INPUT_NAMES[i]), sensor_fault (bool);
    per cylinder on an engine monitored per cylinder: ``cyl{n}_<field>`` for the float fields of
    CylinderSnapshot and ``cyl{n}_state`` (int codes), then cht_spread_c (float), hottest_cylinder (int,
    0: none), spread_alarm (bool), lead_cylinder (int: the cylinder the engine-level columns are).
    detector_feed (batch path only): per clock segment whose estimator started, what the detector was
    fed: (step times s from its start, symptom per step, nan where the supervisor was not NOMINAL).
    gaps (batch path only): (last frame time before, first after) of every hole in the frames longer
    than :data:`~ecu_monitor.bus.canlog.GAP_S`; holes longer than the pipeline's MAX_CLOCK_GAP_S
    restart the clock (``counters["clock_restarts"]``): no step runs inside them.
    cross_feeds (batch path, cross-cylinder detectors on): per cylinder, per clock segment, what its
    cross-cylinder detector was fed (as detector_feed).
    reference_feed (batch path, when asked): per clock segment as detector_feed, the open-loop reference
    (:class:`ReferenceFeed`; the first cylinder's on an engine monitored per cylinder).
    detector_regions (batch path only): per clock segment as detector_feed, the operating region of each
    step (estimation/regions.py), what the reference test measures the feed against.
    """

    columns: dict[str, NDArray[Any]]
    counters: dict[str, int]
    detector_feed: tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...] = ()
    gaps: tuple[tuple[float, float], ...] = ()
    cross_feeds: tuple[tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...], ...] = ()
    reference_feed: tuple[ReferenceFeed, ...] = ()
    detector_regions: tuple[NDArray[np.int64], ...] = ()

    def __len__(self) -> int:
        return int(self.columns["time_s"].size)

    @property
    def cylinder_count(self) -> int:
        """CHT channels of the replayed engine (1: a single channel, no per-cylinder columns)."""
        return sum(1 for key in self.columns if key.startswith("cyl") and key.endswith("_state")) or 1

    @functools.cached_property
    def rows(self) -> list[HealthSnapshot]:
        """The rows as HealthSnapshot objects (what Pipeline.drain_rows gives)."""
        c = self.columns
        names = _stale_names()
        floats = [c[k].tolist() for k in _FLOAT_COLUMNS]
        detector = [c[k].tolist() for k in DETECTOR_COLUMNS]
        rows = [
            HealthSnapshot(t, meas, est, dev, STATES[state], gq, gd, head, names[stale], fault, cht_rate_c_per_min=rate,
                           **dict(zip(DETECTOR_COLUMNS, more, strict=True)))
            for t, meas, est, dev, gq, gd, head, rate, state, stale, fault, *more in zip(
                *floats, c["state"].tolist(), c["stale"].tolist(), c["sensor_fault"].tolist(), *detector, strict=True
            )
        ]  # fmt: skip
        count = self.cylinder_count
        if count == 1:
            return rows
        per = []
        for n in range(1, count + 1):
            meas, est, dev, gq, gd, head, rate = (c[f"cyl{n}_{k}"].tolist() for k in _CYLINDER_FLOATS)
            states = [STATES[v] for v in c[f"cyl{n}_state"].tolist()]
            per.append(
                [
                    CylinderSnapshot(n, *values)
                    for values in zip(meas, est, dev, states, gq, gd, head, rate, strict=True)
                ]
            )
        return [
            dataclasses.replace(row, cylinders=tuple(cyls), cht_spread_c=spread, hottest_cylinder=hottest,
                                spread_alarm=alarm, lead_cylinder=lead)
            for row, spread, hottest, alarm, lead, *cyls in zip(
                rows, c["cht_spread_c"].tolist(), c["hottest_cylinder"].tolist(), c["spread_alarm"].tolist(),
                c["lead_cylinder"].tolist(), *per,
                strict=True,
            )
        ]  # fmt: skip

    def write_csv(self, path: str | os.PathLike[str]) -> int:
        """Write the rows to ``path``: health.csv, or Parquet / Arrow by the suffix
        (:func:`~ecu_monitor.pipeline.table.write_health_table`); returns the row count."""
        return write_health_table(health_table_columns(self.columns, self.cylinder_count), path)


def health_table_columns(columns: dict[str, NDArray[Any]], cylinders: int = 1) -> list[TableColumn]:
    """The columns of :func:`health_columns` from a replay's columns, as the table writer takes them."""
    bit = ("0", "1")
    table = [TableColumn(k, columns[k]) for k in ("time_s", "cht_meas_c", "cht_est_c", "deviation")]
    table.append(TableColumn("state", columns["state"], STATES))
    table += [TableColumn(k, columns[k]) for k in ("gamma_q", "gamma_d", "headroom_s")]
    table.append(TableColumn("stale_inputs", columns["stale"], tuple("+".join(n) for n in _stale_names())))
    table.append(TableColumn("sensor_fault", columns["sensor_fault"].astype(np.int64), bit))
    table.append(TableColumn("cht_rate_c_per_min", columns["cht_rate_c_per_min"]))
    table += [TableColumn(k, columns[k]) for k in ("gamma_q_sd", "gamma_d_sd")]
    table.append(TableColumn("isolable", columns["isolable"].astype(np.int64), bit))
    table.append(TableColumn("detector_armed", columns["armed"], ARMED_NAMES))
    table.append(TableColumn("region", columns["region"] + 1, ("", *REGION_NAMES)))
    if cylinders > 1:
        for n in range(1, cylinders + 1):
            for name in CYLINDER_COLUMNS:
                key = name.format(n=n)
                labels = STATES if name.endswith("_state") else None
                table.append(TableColumn(key, columns[key], labels))
        hottest = ("", *(str(n) for n in range(1, cylinders + 1)))
        table.append(TableColumn("cht_spread_c", columns["cht_spread_c"]))
        table.append(TableColumn("hottest_cylinder", columns["hottest_cylinder"], hottest))
        table.append(TableColumn("spread_alarm", columns["spread_alarm"].astype(np.int64), bit))
    return table


#: The detector's and the isolation's columns of ReplayResult.columns (HealthSnapshot fields of one name):
#: gamma_q_sd, gamma_d_sd (float), isolable (bool), armed, region (int).
DETECTOR_COLUMNS: tuple[str, ...] = ("gamma_q_sd", "gamma_d_sd", "isolable", "armed", "region")
#: Float columns of ReplayResult.columns, in health.csv order.
_FLOAT_COLUMNS = (
    "time_s", "cht_meas_c", "cht_est_c", "deviation", "gamma_q", "gamma_d", "headroom_s", "cht_rate_c_per_min",
)  # fmt: skip


@functools.cache
def _stale_names() -> tuple[tuple[str, ...], ...]:
    """Stale input names of every StaleInputs bit field value."""
    return tuple(tuple(n for i, n in enumerate(INPUT_NAMES) if bits >> i & 1) for bits in range(1 << len(INPUT_NAMES)))


def empty_columns(cylinders: int = 1) -> dict[str, NDArray[Any]]:
    """The columns of a replay without rows (of an engine with ``cylinders`` CHT channels)."""
    columns: dict[str, NDArray[Any]] = {k: np.zeros(0) for k in _FLOAT_COLUMNS}
    columns.update(state=np.zeros(0, dtype=np.int64), stale=np.zeros(0, dtype=np.int64),
                   sensor_fault=np.zeros(0, dtype=bool), gamma_q_sd=np.zeros(0), gamma_d_sd=np.zeros(0),
                   isolable=np.zeros(0, dtype=bool), armed=np.zeros(0, dtype=np.int64),
                   region=np.zeros(0, dtype=np.int64))  # fmt: skip
    if cylinders > 1:
        for n in range(1, cylinders + 1):
            columns.update({f"cyl{n}_{k}": np.zeros(0) for k in _CYLINDER_FLOATS})
            columns[f"cyl{n}_state"] = np.zeros(0, dtype=np.int64)
        columns.update(cht_spread_c=np.zeros(0), hottest_cylinder=np.zeros(0, dtype=np.int64),
                       spread_alarm=np.zeros(0, dtype=bool), lead_cylinder=np.zeros(0, dtype=np.int64))  # fmt: skip
    return columns


def rows_to_columns(rows: list[HealthSnapshot], cylinders: int = 1) -> dict[str, NDArray[Any]]:
    """HealthSnapshot rows as the columns of :class:`ReplayResult` (``cylinders``: CHT channels)."""
    if not rows:
        return empty_columns(cylinders)
    columns: dict[str, NDArray[Any]] = {k: np.array([getattr(r, k) for r in rows], dtype=float) for k in _FLOAT_COLUMNS}
    columns["state"] = np.array([STATES.index(r.state) for r in rows], dtype=np.int64)
    columns["stale"] = np.array(
        [sum(1 << i for i, n in enumerate(INPUT_NAMES) if n in r.stale_inputs) for r in rows], dtype=np.int64
    )
    columns["sensor_fault"] = np.array([r.sensor_fault for r in rows], dtype=bool)
    for k, kind in zip(DETECTOR_COLUMNS, (float, float, bool, np.int64, np.int64), strict=True):
        columns[k] = np.array([getattr(r, k) for r in rows], dtype=kind)
    if cylinders > 1:
        for i in range(cylinders):
            n = i + 1
            for k in _CYLINDER_FLOATS:
                columns[f"cyl{n}_{k}"] = np.array([getattr(r.cylinders[i], k) for r in rows], dtype=float)
            columns[f"cyl{n}_state"] = np.array([STATES.index(r.cylinders[i].state) for r in rows], dtype=np.int64)
        columns["cht_spread_c"] = np.array([r.cht_spread_c for r in rows], dtype=float)
        columns["hottest_cylinder"] = np.array([r.hottest_cylinder for r in rows], dtype=np.int64)
        columns["spread_alarm"] = np.array([r.spread_alarm for r in rows], dtype=bool)
        columns["lead_cylinder"] = np.array([r.lead_cylinder for r in rows], dtype=np.int64)
    return columns


def write_health_csv(rows: Iterable[HealthSnapshot], path: str | os.PathLike[str]) -> int:
    """Write health.csv (:func:`health_columns`, numbers as ``%.10g``, nan as an empty cell; or Parquet /
    Arrow by the suffix); returns the number of rows. FlightLogError if the file cannot be written."""
    rows = list(rows)
    count = len(rows[0].cylinders) if rows and rows[0].cylinders else 1
    return write_health_table(health_table_columns(rows_to_columns(rows, count), count), path)
