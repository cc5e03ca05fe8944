"""Per engine, after every log: its flights in flight order, the across-flight detector, and the ranking.

Flight order: by start time where the log runs on a UNIX clock (CAN logs, ``.tlog``, daemon databases),
else by the log's position in the engine's listing (FLEET.yaml's globs in order, each sorted by name).
The across-flight detector is :func:`ecu_monitor.estimation.wear.wear_verdict` over the flights' wear
indices with the engine's ``wear:`` settings and stored reference (its detector file or config), the one
rule the daemon's flight history runs after each flight; without a stored reference it learns one from the
engine's first flights, as the daemon does.

Rank 1 is the engine of most concern: alerted engines first, then by the CUSUM statistic over its
threshold h, then flights that went DEGRADED, then engine events.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ecu_monitor.estimation.wear import WearReference, WearSettings, WearVerdict, wear_verdict

__all__ = ["ENGINE_FIELDS", "EngineTrend", "engine_rows", "engine_trend", "engines_schema", "flight_order"]

#: The columns of engines.parquet and their meaning.
ENGINE_FIELDS: dict[str, str] = {
    "serial": "the engine's serial",
    "rank": "1 = the engine of most concern",
    "alert": "the across-flight detector alerted",
    "reason": "why the engine ranks where it does, in words",
    "flights": "flights summarised",
    "hours": "flight hours summarised",
    "cusum": "the across-flight CUSUM after the last flight (null: still learning the reference)",
    "threshold": "the CUSUM's alert threshold h",
    "alert_flight": "the flight (1-based, in flight order) at which the alert was raised",
    "alert_log": "the log of that flight",
    "wear_last": "the last flight's wear index",
    "wear_trend_per_10": "least-squares slope of the wear index per 10 flights (last 20 flights)",
    "degraded_flights": "flights whose worst state was DEGRADED",
    "events": "engine events in all flights",
    "failures": "logs that could not be read",
    "hours_to_overhaul": "tbo_hours - hours since overhaul (null: no tbo_hours given)",
    "last_flight_utc": "UNIX time of the last flight's start (null: unknown)",
}
#: How many of the last flights the wear trend is fitted over.
_TREND_FLIGHTS = 20


def engines_schema() -> Any:
    """The pyarrow schema of engines.parquet (ENGINE_FIELDS)."""
    import pyarrow as pa

    types = {"serial": pa.string(), "rank": pa.int64(), "alert": pa.bool_(), "reason": pa.string(),
             "flights": pa.int64(), "alert_flight": pa.int64(), "alert_log": pa.string(),
             "degraded_flights": pa.int64(), "events": pa.int64(), "failures": pa.int64()}  # fmt: skip
    return pa.schema([(name, types.get(name, pa.float64())) for name in ENGINE_FIELDS])


def flight_order(flight: Mapping[str, Any]) -> tuple[float, int, int]:
    """Sort key of a flight row (module docstring)."""
    start = flight.get("start_utc")
    return (math.inf if start is None else float(start), int(flight["position"]), int(flight["flight"]))


@dataclass(frozen=True)
class EngineTrend:
    """One engine's flights in flight order and the across-flight detector's verdict over them."""

    serial: str
    flights: tuple[dict[str, Any], ...]
    verdict: WearVerdict


def engine_trend(
    serial: str, flights: Sequence[Mapping[str, Any]], settings: WearSettings, reference: WearReference | None
) -> EngineTrend:
    """Order ``flights`` and run the across-flight detector (the daemon's rule, wear.py) over them."""
    ordered = tuple(dict(f) for f in sorted(flights, key=flight_order))
    return EngineTrend(serial, ordered, wear_verdict([f["wear_index"] for f in ordered], settings, reference))


def engine_rows(
    trends: Sequence[EngineTrend],
    events: Mapping[str, Sequence[Mapping[str, Any]]],
    failures: Mapping[str, int],
    overhaul: Mapping[str, tuple[float | None, float]],
    baseline_flights: Mapping[str, int],
) -> list[dict[str, Any]]:
    """engines.parquet's rows (ENGINE_FIELDS), ranked. ``events``: each engine's event rows; ``failures``:
    its failed logs; ``overhaul``: (tbo_hours or None, hours run before the first log);
    ``baseline_flights``: flights its detector learns from without a stored reference."""
    rows = []
    for trend in trends:
        rows.append(_row(trend, events.get(trend.serial, ()), failures.get(trend.serial, 0),
                         overhaul.get(trend.serial, (None, 0.0)), baseline_flights.get(trend.serial, 0)))  # fmt: skip
    rows.sort(key=_concern)
    for rank, row in enumerate(rows, start=1):
        row["rank"] = rank
    return rows


def _concern(row: Mapping[str, Any]) -> tuple[int, float, int, int, str]:
    """Sort key, most concern first."""
    cusum, h = row["cusum"], row["threshold"]
    ratio = cusum / h if cusum is not None and h and h > 0 else -1.0
    return (0 if row["alert"] else 1, -ratio, -row["degraded_flights"], -row["events"], row["serial"])


def _row(
    trend: EngineTrend,
    events: Sequence[Mapping[str, Any]],
    failures: int,
    overhaul: tuple[float | None, float],
    baseline: int,
) -> dict[str, Any]:
    flights = trend.flights
    verdict = trend.verdict
    hours = sum(float(f["duration_s"] or 0.0) for f in flights) / 3600.0
    last = next((s for s in reversed(verdict.statistic) if s is not None), None)
    at = verdict.alert_at
    wear = [(i, f["wear_index"]) for i, f in enumerate(flights) if f["wear_index"] is not None]
    trend_per_10 = _slope(wear[-_TREND_FLIGHTS:])
    degraded = sum(1 for f in flights if f["worst_state"] == "DEGRADED")
    tbo_hours, before = overhaul
    to_overhaul = None if tbo_hours is None else tbo_hours - before - hours
    starts = [f["start_utc"] for f in flights if f["start_utc"] is not None]
    row: dict[str, Any] = {
        "serial": trend.serial,
        "rank": 0,
        "alert": verdict.alerted,
        "reason": "",
        "flights": len(flights),
        "hours": hours,
        "cusum": last,
        "threshold": verdict.threshold,
        "alert_flight": None if at is None else at + 1,
        "alert_log": None if at is None else flights[at]["log"],
        "wear_last": wear[-1][1] if wear else None,
        "wear_trend_per_10": trend_per_10,
        "degraded_flights": degraded,
        "events": len(events),
        "failures": failures,
        "hours_to_overhaul": to_overhaul,
        "last_flight_utc": max(starts) if starts else None,
    }
    row["reason"] = _reason(row, verdict, events, len(wear), baseline)
    return row


def _reason(
    row: Mapping[str, Any], verdict: WearVerdict, events: Sequence[Mapping[str, Any]], indexed: int, baseline: int
) -> str:
    """The engine's ranking in words."""
    parts = []
    reference = verdict.reference
    if verdict.alerted and reference is not None:
        parts.append(
            f"ALERT at flight {row['alert_flight']} ({row['alert_log']}): across-flight CUSUM reached h"
            f" {verdict.threshold:.1f}; last wear index {100.0 * (row['wear_last'] or 0.0):+.1f} % against the"
            f" nominal {100.0 * reference.mean:+.1f} % (sd {100.0 * reference.sd:.1f} %)"
        )
    elif reference is None:
        parts.append(f"learning the wear reference: {indexed} of {baseline} flights with a wear index")
    else:
        parts.append(f"no alert: CUSUM {row['cusum'] or 0.0:.1f} of h {verdict.threshold:.1f}")
    if row["wear_trend_per_10"] is not None:
        parts.append(f"wear index trend {100.0 * row['wear_trend_per_10']:+.1f} % per 10 flights")
    if row["degraded_flights"]:
        parts.append(f"{row['degraded_flights']} flight(s) went DEGRADED")
    if events:
        kinds = collections.Counter(str(e["kind"]) for e in events)
        parts.append("events: " + ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in kinds.most_common()))
    if row["failures"]:
        parts.append(f"{row['failures']} log(s) unreadable")
    if row["hours_to_overhaul"] is not None:
        left = row["hours_to_overhaul"]
        parts.append(f"{left:.0f} h to overhaul" if left > 0 else f"overhaul due ({-left:.0f} h over)")
    return "; ".join(parts)


def _slope(points: Sequence[tuple[int, float]]) -> float | None:
    """Least-squares slope of (flight, value) per 10 flights; None with fewer than 3 points."""
    if len(points) < 3:
        return None
    x, y = np.array(points, dtype=np.float64).T
    return 10.0 * float(np.polyfit(x, y, 1)[0])
