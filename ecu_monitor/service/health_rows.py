"""The health rows the service produces: :class:`HealthSnapshot` (one per health-status period), the
columns of health.csv and their writers, :class:`ReplayResult` (a replay's rows as columns)."""

from __future__ import annotations

import functools
import os
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.bus.codec import INPUT_NAMES
from ecu_monitor.errors import FlightLogError
from ecu_monitor.estimation.headroom import DEFAULT_CAP_S
from ecu_monitor.service.supervision import STATES

#: ThermalHeadroom meaning "not limited" (health.dbc; the headroom module's cap).
HEADROOM_NOT_LIMITED_S = DEFAULT_CAP_S


@dataclass(frozen=True)
class HealthSnapshot:
    """The service's view of the engine at one instant (one health-status period).

    time_s: step time, s (the advance_to clock). cht_meas_c: last CHT reading held, degC (nan: none).
    cht_est_c: estimate, degC (nan when UNAVAILABLE). deviation: model-deviation symptom, degC/s.
    state: one of STATES. gamma_q, gamma_d: isolation estimates (nan when UNAVAILABLE). headroom_s:
    time to the CHT limit at the present inputs, s (HEADROOM_NOT_LIMITED_S = not limited; nan when
    UNAVAILABLE). stale_inputs: names of the stale inputs. sensor_fault: the CHT sensor is faulty.
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
)


@dataclass(frozen=True)
class ReplayResult:
    """A replay's rows (one per health-status period) as columns, and the frame counters.

    columns: time_s, cht_meas_c, cht_est_c, deviation, gamma_q, gamma_d, headroom_s (float arrays),
    state (int codes into STATES), stale (int bit field, bit i = INPUT_NAMES[i]), sensor_fault (bool).
    detector_feed (batch path only): per clock segment whose estimator started, what the detector was
    fed: (step times s from its start, symptom per step, nan where the supervisor was not NOMINAL).
    gaps (batch path only): (last frame time before, first after) of every hole in the frames longer
    than :data:`~ecu_monitor.bus.canlog.GAP_S`; holes longer than the pipeline's MAX_CLOCK_GAP_S
    restart the clock (``counters["clock_restarts"]``): no step runs inside them.
    """

    columns: dict[str, NDArray[Any]]
    counters: dict[str, int]
    detector_feed: tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...] = ()
    gaps: tuple[tuple[float, float], ...] = ()

    def __len__(self) -> int:
        return int(self.columns["time_s"].size)

    @functools.cached_property
    def rows(self) -> list[HealthSnapshot]:
        """The rows as HealthSnapshot objects (what Pipeline.drain_rows gives)."""
        c = self.columns
        names = _stale_names()
        floats = [c[k].tolist() for k in _FLOAT_COLUMNS]
        return [
            HealthSnapshot(t, meas, est, dev, STATES[state], gq, gd, head, names[stale], fault)
            for t, meas, est, dev, gq, gd, head, state, stale, fault in zip(
                *floats, c["state"].tolist(), c["stale"].tolist(), c["sensor_fault"].tolist(), strict=True
            )
        ]

    def write_csv(self, path: str | os.PathLike[str]) -> int:
        """Write health.csv (as :func:`write_health_csv`, from the columns at once); returns the row count."""
        c = self.columns
        names = ["+".join(n) for n in _stale_names()]
        cells = [[f"{v:.10g}" for v in c[k].tolist()] for k in _FLOAT_COLUMNS]
        state = [STATES[v] for v in c["state"].tolist()]
        stale = [names[v] for v in c["stale"].tolist()]
        fault = [str(int(v)) for v in c["sensor_fault"].tolist()]
        t, meas, est, dev, gq, gd, head = cells
        lines = [",".join(HEALTH_COLUMNS)]
        lines += [",".join(row) for row in zip(t, meas, est, dev, state, gq, gd, head, stale, fault, strict=True)]
        return _write_lines(lines, path)


#: Float columns of ReplayResult.columns, in health.csv order.
_FLOAT_COLUMNS = ("time_s", "cht_meas_c", "cht_est_c", "deviation", "gamma_q", "gamma_d", "headroom_s")


@functools.cache
def _stale_names() -> tuple[tuple[str, ...], ...]:
    """Stale input names of every StaleInputs bit field value."""
    return tuple(tuple(n for i, n in enumerate(INPUT_NAMES) if bits >> i & 1) for bits in range(1 << len(INPUT_NAMES)))


def empty_columns() -> dict[str, NDArray[Any]]:
    """The columns of a replay without rows."""
    columns: dict[str, NDArray[Any]] = {k: np.zeros(0) for k in _FLOAT_COLUMNS}
    columns.update(state=np.zeros(0, dtype=np.int64), stale=np.zeros(0, dtype=np.int64),
                   sensor_fault=np.zeros(0, dtype=bool))  # fmt: skip
    return columns


def rows_to_columns(rows: list[HealthSnapshot]) -> dict[str, NDArray[Any]]:
    """HealthSnapshot rows as the columns of :class:`ReplayResult`."""
    if not rows:
        return empty_columns()
    columns: dict[str, NDArray[Any]] = {k: np.array([getattr(r, k) for r in rows], dtype=float) for k in _FLOAT_COLUMNS}
    columns["state"] = np.array([STATES.index(r.state) for r in rows], dtype=np.int64)
    columns["stale"] = np.array(
        [sum(1 << i for i, n in enumerate(INPUT_NAMES) if n in r.stale_inputs) for r in rows], dtype=np.int64
    )
    columns["sensor_fault"] = np.array([r.sensor_fault for r in rows], dtype=bool)
    return columns


def write_health_csv(rows: Iterable[HealthSnapshot], path: str | os.PathLike[str]) -> int:
    """Write health.csv (:data:`HEALTH_COLUMNS`, nan as an empty cell); returns the number of rows.
    FlightLogError if the file cannot be written."""
    lines = [",".join(HEALTH_COLUMNS)]
    for r in rows:
        lines.append(
            f"{r.time_s:.10g},{r.cht_meas_c:.10g},{r.cht_est_c:.10g},{r.deviation:.10g},{r.state},{r.gamma_q:.10g},"
            f"{r.gamma_d:.10g},{r.headroom_s:.10g},{'+'.join(r.stale_inputs)},{int(r.sensor_fault)}"
        )
    return _write_lines(lines, path)


def _write_lines(lines: list[str], path: str | os.PathLike[str]) -> int:
    text = "\n".join(lines).replace(",nan", ",").replace(",-inf", ",").replace(",inf", ",") + "\n"
    try:
        with open(path, "w", newline="", encoding="utf-8") as handle:
            handle.write(text)
    except OSError as exc:
        raise FlightLogError(f"{path}: cannot write ({exc.strerror or exc})") from None
    return len(lines) - 1
