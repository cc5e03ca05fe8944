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

from numpy.typing import NDArray

from ecu_monitor.pipeline.output_table import HealthSnapshot
from ecu_monitor.pipeline.outputs import CylinderSnapshot, column_layout, columns_of, cylinder_snapshots

__all__ = ["SEVERITY", "EngineView", "engine_columns", "engine_snapshot", "engine_view", "lead_index"]

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


def engine_snapshot(
    time_s: float, stale_inputs: tuple[str, ...], cylinders: Sequence[CylinderSnapshot], spread_limit_c: float | None
) -> HealthSnapshot:
    """The engine's snapshot of its cylinders' at one instant: the lead cylinder's values (module docstring),
    ``sensor_fault`` (any cylinder's probe), the spread, the hottest cylinder, the spread alarm; one
    cylinder: its own values (``cylinders`` empty). The one place the ``engine`` and ``cylinders`` rows of
    the output table are computed."""
    if len(cylinders) == 1:
        values = cylinders[0].values()
        del values["number"]
        values.update(time_s=time_s, stale_inputs=stale_inputs, sensor_fault=cylinders[0].sensor_fault)
        return HealthSnapshot._of(values)
    view = engine_view(cylinders, spread_limit_c)
    lead = cylinders[view.lead]
    values = lead.values()
    del values["number"]
    values.update(
        time_s=time_s,
        stale_inputs=stale_inputs,
        sensor_fault=any(c.sensor_fault for c in cylinders),
        cylinders=tuple(cylinders),
        cht_spread_c=view.spread_c,
        hottest_cylinder=view.hottest,
        spread_alarm=view.alarm,
        lead_cylinder=lead.number,
    )
    return HealthSnapshot._of(values)


def engine_columns(
    columns: dict[str, NDArray[Any]], count: int, spread_limit_c: float | None
) -> dict[str, NDArray[Any]]:
    """The engine columns of a replay (the lead cylinder's, sensor_fault and the ``cylinders`` rows of the
    output table) from its per-cylinder columns ``cyl{n}_...``, row by row through :func:`engine_snapshot`,
    the function the live pipeline calls."""
    times = columns["time_s"].tolist()
    snaps = [engine_snapshot(t, (), cyls, spread_limit_c)
             for t, cyls in zip(times, cylinder_snapshots(columns, count), strict=True)]  # fmt: skip
    names = [name for name, _ in column_layout(count) if not name.startswith("cyl")]
    return columns_of(snaps, count, [n for n in names if n not in ("time_s", "stale_inputs")])
