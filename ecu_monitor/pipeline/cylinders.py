"""Every cylinder: the engine's view made from one estimator per cylinder (docs/service.md, "Every cylinder").

An engine monitored per cylinder maps ``cht1_c .. chtN_c`` (config ``inputs:``); the pipeline runs
one estimator, isolation filter, detector and supervisor per cylinder on the shared inputs and each
cylinder's own model. :func:`engine_view` folds the cylinders of one instant into the engine's:

* the **lead cylinder** gives the engine-level values (Health_Status, Health_Isolation and the
  health.csv columns without a ``cylN_`` prefix): the cylinder in the most severe state (DEGRADED,
  SUSPECT, SENSOR_FAULT, INPUT_STALE, NOMINAL, UNAVAILABLE in that order), among equals the hottest
  estimate, among equals the lowest number. On a healthy engine that is the hottest cylinder; a
  degraded cylinder takes the lead over hotter healthy ones;
* the **spread** is the hottest minus the coldest estimate of the cylinders whose probe is trusted
  (estimating and not SENSOR_FAULT), nan with fewer than two; the **hottest cylinder** is the number
  (1-based) of the hottest of them, 0 if none;
* the **spread alarm** is raised while the spread exceeds ``cylinders.spread_limit_c``.

Live (per step) and batch replay (per health row) call the same function, so their rows are equal.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.pipeline.outputs import DETECTOR_COLUMNS, CylinderSnapshot
from ecu_monitor.pipeline.supervision import STATES

__all__ = ["SEVERITY", "EngineView", "engine_columns", "engine_view", "lead_index"]

#: Rank of each state when the cylinders are folded into the engine's (higher = more severe).
SEVERITY: dict[str, int] = {
    "UNAVAILABLE": 0,
    "NOMINAL": 1,
    "INPUT_STALE": 2,
    "SENSOR_FAULT": 3,
    "SUSPECT": 4,
    "DEGRADED": 5,
}


class EngineView(NamedTuple):
    """The engine's view of its cylinders at one instant."""

    lead: int  # index (0-based) of the lead cylinder
    spread_c: float  # CHT spread, degC (nan: fewer than two trusted cylinders)
    hottest: int  # number (1-based) of the hottest trusted cylinder, 0: none
    alarm: bool  # the spread exceeds the configured limit


def lead_index(cylinders: Sequence[CylinderSnapshot]) -> int:
    """Index of the lead cylinder (module docstring): most severe state, then hottest estimate, then first."""
    best = 0
    best_key = (-1, -math.inf)
    for i, cyl in enumerate(cylinders):
        est = cyl.cht_est_c
        key = (SEVERITY[cyl.state], est if est == est else -math.inf)  # est == est: not nan
        if key > best_key:
            best, best_key = i, key
    return best


def engine_view(cylinders: Sequence[CylinderSnapshot], spread_limit_c: float | None) -> EngineView:
    """The engine's lead cylinder, CHT spread, hottest cylinder and spread alarm (module docstring)."""
    hottest = 0
    high = -math.inf
    low = math.inf
    trusted = 0
    for cyl in cylinders:
        est = cyl.cht_est_c
        if cyl.sensor_fault or not math.isfinite(est):
            continue
        trusted += 1
        if est > high:
            high, hottest = est, cyl.number
        low = min(low, est)
    spread = high - low if trusted >= 2 else math.nan
    alarm = spread_limit_c is not None and spread > spread_limit_c
    return EngineView(lead_index(cylinders), spread, hottest, alarm)


def engine_columns(
    columns: dict[str, NDArray[Any]], count: int, spread_limit_c: float | None
) -> dict[str, NDArray[Any]]:
    """The engine columns of a replay (cht_meas_c .. sensor_fault of the lead cylinder, cht_spread_c,
    hottest_cylinder, spread_alarm) from its per-cylinder columns ``cyl{n}_...``, row by row through
    :func:`engine_view`, the function the live pipeline calls."""
    fields = ("cht_meas_c", "cht_est_c", "deviation", "state", "gamma_q", "gamma_d", "headroom_s", "cht_rate_c_per_min")
    per = [
        [
            CylinderSnapshot(n, meas, est, dev, STATES[state], gq, gd, head, rate, *more)
            for meas, est, dev, state, gq, gd, head, rate, *more in zip(
                *(columns[f"cyl{n}_{k}"].tolist() for k in (*fields, *DETECTOR_COLUMNS)), strict=True
            )
        ]
        for n in range(1, count + 1)
    ]
    rows = columns["time_s"].size
    lead_values = {k: np.empty(rows) for k in fields if k != "state"}
    lead_values.update({k: np.empty(rows, dtype=columns[f"cyl1_{k}"].dtype) for k in DETECTOR_COLUMNS})
    state = np.empty(rows, dtype=np.int64)
    spread = np.empty(rows)
    hottest = np.empty(rows, dtype=np.int64)
    alarm = np.empty(rows, dtype=bool)
    fault = np.empty(rows, dtype=bool)
    lead_number = np.empty(rows, dtype=np.int64)
    for i, cylinders in enumerate(zip(*per, strict=True)):
        view = engine_view(cylinders, spread_limit_c)
        lead = cylinders[view.lead]
        for k, out in lead_values.items():
            out[i] = getattr(lead, k)
        state[i] = STATES.index(lead.state)
        spread[i], hottest[i], alarm[i] = view.spread_c, view.hottest, view.alarm
        fault[i] = any(c.sensor_fault for c in cylinders)
        lead_number[i] = lead.number
    return {**lead_values, "state": state, "sensor_fault": fault, "cht_spread_c": spread,
            "hottest_cylinder": hottest, "spread_alarm": alarm, "lead_cylinder": lead_number}  # fmt: skip
