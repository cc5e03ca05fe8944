"""``ecu-monitor history``: the flight history and degradation trend of each engine, printed and plotted.

Reads the daemon's SQLite database (``state_dir`` of ``--config``, or ``--state-dir``) read-only, so it
is safe while the daemon runs. A flight still ``running`` in the database is listed with its last
checkpoint: either the daemon is flying it now, or the daemon was killed and its next start closes it
as ``recovered`` (or resumes it) at that checkpoint: the database alone cannot tell the two apart.
Per engine: flights, hours, maximum CHT, time above the CHT limit, gamma_Q / gamma_D per flight and
their trend over engine hours (least-squares slope per 100 h), and the thermal cycles counted by
rainflow. ``--plot out.png`` draws the same trend.
"""

from __future__ import annotations

import argparse
import datetime as dt
import math
from pathlib import Path
from typing import Any

from ecu_monitor.errors import ConfigError
from ecu_monitor.runtime.persistence import CYCLE_BIN_EDGES_C, FlightRecord, StateStore, iter_trend
from ecu_monitor.userfiles import save_figure

__all__ = ["add_subparser", "engine_trend", "format_history", "plot_history"]

#: Cycles at least this large (degC range) are shown as "large" (full heat-up / cool-down cycles).
LARGE_CYCLE_C = 50.0


def add_subparser(subparsers: Any) -> None:
    """Register ``history``."""
    parser = subparsers.add_parser(
        "history",
        help="print and plot the flight history and degradation trend per engine",
        description="Flights, hours, max CHT, time above limit, gamma trend and thermal cycles per engine, "
        "from the daemon's database.",
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--config", metavar="FILE", help="service configuration (its state_dir is read)")
    source.add_argument("--state-dir", metavar="DIR", help="the daemon's state directory")
    parser.add_argument("--engine", metavar="SERIAL", help="only this engine")
    parser.add_argument("--plot", metavar="out.png", help="write the trend plot here")
    parser.set_defaults(func=_run)


def _slope(xs: list[float], ys: list[float]) -> float | None:
    """Least-squares slope of ys over xs; None with fewer than two distinct xs."""
    if len(xs) < 2:
        return None
    mean_x = sum(xs) / len(xs)
    mean_y = sum(ys) / len(ys)
    sxx = sum((x - mean_x) ** 2 for x in xs)
    if sxx <= 1e-12:
        return None
    return sum((x - mean_x) * (y - mean_y) for x, y in zip(xs, ys, strict=True)) / sxx


def _large_cycles(record: FlightRecord) -> float:
    total = 0.0
    for label, count in record.cycles_histogram.items():
        low = float(label.rstrip("+").split("-")[0])
        if low >= LARGE_CYCLE_C:
            total += count
    return total


def engine_trend(records: list[FlightRecord]) -> dict[str, float | None]:
    """Totals and trends of one engine's flights: hours, cycles, gamma slopes per 100 engine hours."""
    points = list(iter_trend(records))
    hours = [h for h, _ in points]
    q = [(h, r.gamma_q_mean) for h, r in points if r.gamma_q_mean is not None]
    d = [(h, r.gamma_d_mean) for h, r in points if r.gamma_d_mean is not None]
    q_slope = _slope([h for h, _ in q], [v for _, v in q])
    d_slope = _slope([h for h, _ in d], [v for _, v in d])
    return {
        "flights": float(len(records)),
        "hours": hours[-1] if hours else 0.0,
        "max_cht_c": max((r.max_cht_c for r in records if r.max_cht_c is not None), default=None),
        "time_above_limit_s": sum(r.time_above_limit_s for r in records),
        "cycles": sum(r.cycles_total for r in records),
        "large_cycles": sum(_large_cycles(r) for r in records),
        "gamma_q_last": q[-1][1] if q else None,
        "gamma_d_last": d[-1][1] if d else None,
        "gamma_q_per_100h": None if q_slope is None else q_slope * 100.0,
        "gamma_d_per_100h": None if d_slope is None else d_slope * 100.0,
    }


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def format_history(serial: str, records: list[FlightRecord]) -> str:
    """The printed history of one engine: a summary line, the trend, one row per flight."""
    trend = engine_trend(records)
    running = sum(1 for r in records if r.status == "running")
    count = f"{len(records)} flights" + (f" ({running} running)" if running else "")
    lines = [
        f"engine {serial}: {count}, {trend['hours']:.2f} h, max CHT {_fmt(trend['max_cht_c'], '.1f')} "
        f"degC, {trend['time_above_limit_s']:.0f} s above limit, {trend['cycles']:.1f} thermal cycles "
        f"({trend['large_cycles']:.1f} of >= {LARGE_CYCLE_C:g} degC)",
        f"  trend: gamma_Q {_fmt(trend['gamma_q_last'], '.3f')} ({_fmt(trend['gamma_q_per_100h'], '+.4f')} per 100 h),"
        f" gamma_D {_fmt(trend['gamma_d_last'], '.3f')} ({_fmt(trend['gamma_d_per_100h'], '+.4f')} per 100 h)",
        f"  {'#':>4} {'start (UTC)':<19} {'hours':>6} {'maxCHT':>6} {'>lim s':>7} {'gQ mean':>7} {'gQ end':>7} "
        f"{'gD mean':>7} {'worst':<12} {'cycles':>6} {'>=50C':>5} status",
    ]
    for record in records:
        start = dt.datetime.fromtimestamp(record.start_utc, tz=dt.UTC).strftime("%Y-%m-%d %H:%M:%S")
        if record.status == "running":
            checkpoint = dt.datetime.fromtimestamp(record.end_utc, tz=dt.UTC).strftime("%H:%M:%S")
            status = f"running (checkpoint {checkpoint} UTC; in flight, or cut by a crash until the next start)"
        else:
            status = record.status if record.end_reason is None else f"{record.status} ({record.end_reason})"
        lines.append(
            f"  {record.id:>4} {start:<19} {record.hours:>6.2f} {_fmt(record.max_cht_c, '6.1f'):>6} "
            f"{record.time_above_limit_s:>7.0f} {_fmt(record.gamma_q_mean, '7.3f'):>7} "
            f"{_fmt(record.gamma_q_end, '7.3f'):>7} {_fmt(record.gamma_d_mean, '7.3f'):>7} {record.worst_state:<12} "
            f"{record.cycles_total:>6.1f} {_large_cycles(record):>5.1f} {status}"
        )
        lines.extend(_cylinder_lines(record))
    return "\n".join(lines)


def _cylinder_lines(record: FlightRecord) -> list[str]:
    """An engine monitored per cylinder: one line per cylinder and one of the spread, under its flight."""
    cyl = record.cylinders
    if not cyl:
        return []
    out = [
        f"       cylinder {c['number']}: max CHT {_fmt(c['max_cht_c'], '.1f')},"
        f" gQ mean {_fmt(c['gamma_q_mean'], '.3f')} max {_fmt(c['gamma_q_max'], '.3f')},"
        f" gD mean {_fmt(c['gamma_d_mean'], '.3f')}, worst {c['worst_state']}"
        f" ({c['time_degraded_s']:.0f} s SUSPECT/DEGRADED)"
        for c in cyl.get("per_cylinder", [])
    ]
    hottest = cyl.get("hottest_s", {})
    total = sum(hottest.values())
    shares = ", ".join(f"{n} {100.0 * v / total:.0f} %" for n, v in sorted(hottest.items(), key=lambda kv: -kv[1]))
    out.append(
        f"       CHT spread max {_fmt(cyl.get('spread_max_c'), '.1f')} degC, spread alarm"
        f" {cyl.get('spread_alarm_s', 0.0):.0f} s; hottest cylinder: {shares or '-'}"
    )
    return out


def plot_history(histories: dict[str, list[FlightRecord]], out: Path) -> None:
    """Trend plot over engine hours: gamma estimates, max CHT and time above limit, cumulative cycles."""
    import matplotlib.pyplot as plt

    fig = trend_figure(histories)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, out, dpi=110)
    plt.close(fig)


def trend_figure(histories: dict[str, list[FlightRecord]]) -> Any:
    """The figure of :func:`plot_history` (axes: gamma, max CHT with time-above bars, cycles)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    ax_gamma, ax_cht, ax_cycles = axes
    for serial, records in histories.items():
        points = list(iter_trend(records))
        hours = [h for h, _ in points]
        ax_gamma.plot(hours, [r.gamma_q_mean for _, r in points], "o-", label=f"{serial} gamma_Q (flight mean)")
        ax_gamma.plot(hours, [r.gamma_d_mean for _, r in points], "s--", label=f"{serial} gamma_D (flight mean)")
        count = max((len(r.cylinders.get("per_cylinder", [])) for _, r in points), default=0)
        for n in range(count):  # an engine monitored per cylinder: each cylinder's gamma_Q, thin
            ax_gamma.plot(hours, [_cylinder_value(r, n, "gamma_q_mean") for _, r in points], ".:", linewidth=0.8,
                          label=f"{serial} cylinder {n + 1} gamma_Q (flight mean)")  # fmt: skip
            ax_cht.plot(hours, [_cylinder_value(r, n, "max_cht_c") for _, r in points], ".:", linewidth=0.8,
                        label=f"{serial} cylinder {n + 1} max CHT")  # fmt: skip
        ax_cht.plot(hours, [r.max_cht_c for _, r in points], "o-", label=f"{serial} max CHT")
        limits = sorted({r.cht_limit_c for _, r in points})
        for limit in limits:
            ax_cht.axhline(limit, color="red", linewidth=0.8, linestyle=":")
        above = ax_cht.twinx()
        above.bar(hours, [r.time_above_limit_s for _, r in points], width=0.02 * max(hours[-1], 1.0), alpha=0.3)
        above.set_ylabel("time above limit, s (bars)")
        ax_cht.set_zorder(above.get_zorder() + 1)  # the CHT line over the bars
        ax_cht.patch.set_visible(False)
        cumulative = 0.0
        cumulative_large = 0.0
        totals, larges = [0.0], [0.0]
        for _, record in points:
            cumulative += record.cycles_total
            cumulative_large += _large_cycles(record)
            totals.append(cumulative)
            larges.append(cumulative_large)
        ax_cycles.plot([0.0, *hours], totals, "o-", label=f"{serial} all cycles >= {CYCLE_BIN_EDGES_C[0]:g} degC")
        ax_cycles.plot([0.0, *hours], larges, "s--", label=f"{serial} cycles >= {LARGE_CYCLE_C:g} degC")
        above.set_ylim(bottom=0.0)  # durations and counts: no negative ticks when all are 0
    ax_gamma.axhline(1.0, color="grey", linewidth=0.8)
    ax_gamma.ticklabel_format(axis="y", useOffset=False)  # gamma near 1 reads as 1.02, not "+1" and 0.02
    ax_cycles.set_ylim(bottom=0.0)
    ax_cycles.set_xlim(left=0.0)
    ax_gamma.set_ylabel("degradation factor")
    ax_gamma.set_title("Engine health trend per flight (x: engine hours at the end of the flight)")
    ax_cht.set_ylabel("max CHT, degC (limit dotted)")
    ax_cycles.set_ylabel("thermal cycles (rainflow), cumulative")
    ax_cycles.set_xlabel("engine hours")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    return fig


def _cylinder_value(record: FlightRecord, index: int, key: str) -> float:
    """One cylinder's stored value for a flight (nan: none, or a flight without cylinders)."""
    cylinders = record.cylinders.get("per_cylinder", [])
    value = cylinders[index].get(key) if index < len(cylinders) else None
    return float(value) if value is not None else math.nan


def _run(args: argparse.Namespace) -> int:
    from ecu_monitor.config import load_config

    state_dir = Path(args.state_dir) if args.state_dir else load_config(args.config).state_dir
    with StateStore(state_dir, readonly=True) as store:
        serials = store.engines()
        if args.engine is not None:
            if args.engine not in serials:
                raise ConfigError(f"{store.path}: --engine: no engine {args.engine!r} (engines: {', '.join(serials)})")
            serials = [args.engine]
        histories = {serial: store.flights(serial, include_running=True) for serial in serials}
    if not histories:
        print(f"{store.path}: no engine recorded yet")
        return 0
    print("\n\n".join(format_history(serial, records) for serial, records in histories.items()))
    if args.plot:
        with_flights = {serial: records for serial, records in histories.items() if records}
        if not with_flights:
            raise ConfigError(f"{store.path}: --plot: no flight to plot")
        plot_history(with_flights, Path(args.plot))
        print(f"plot written to {args.plot}")
    return 0
