"""``ecu-monitor history``: the flight history and degradation trend of each engine, printed and plotted.

Reads the daemon's SQLite database (``state_dir`` of ``--config``, or ``--state-dir``) read-only, so it
is safe while the daemon runs. A flight still ``running`` in the database is listed with its last
checkpoint: either the daemon is flying it now, or the daemon was killed and its next start closes it
as ``recovered`` (or resumes it) at that checkpoint: the database alone cannot tell the two apart.
Per engine: flights, hours, maximum CHT, time above the CHT limit, gamma_Q / gamma_D per flight and
their trend over engine hours (least-squares slope per 100 h), and the thermal cycles counted by
rainflow. ``--plot out.png`` draws the same trend.

Across flights: each flight's wear index (how much hotter than the nominal model the head ran, %) and the
across-flight detector's CUSUM over the flights since the last cleared alert (estimation/wear.py; with
``--config``, its ``wear:`` settings and reference). An engine with an open maintenance alert gets a line
starting ``ALERT``, and the plot marks the flight that raised it. ``--clear-alert`` records that the
maintenance was done (the detector starts again from the next flight).

Engine hours: the running hours recorded, the time since overhaul and what is left to the TBO
(``engine.overhaul_hours``, ``engine.tbo_hours`` as the daemon or ``replay --history`` last stored them);
an engine whose overhaul is due gets an ``ALERT`` line. Under each flight, the engine events that started
in it, by kind and cylinder.
"""

from __future__ import annotations

import argparse
import datetime as dt
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ecu_monitor.errors import ConfigError
from ecu_monitor.runtime.persistence import (
    CYCLE_BIN_EDGES_C,
    EngineHours,
    FlightRecord,
    MaintenanceAlert,
    StateStore,
    iter_trend,
)

if TYPE_CHECKING:  # the across-flight detector imports numpy: only the command's run loads it
    from ecu_monitor.estimation.wear import WearReference
    from ecu_monitor.runtime.flight_recorder import EngineWear
from ecu_monitor.userfiles import save_figure

__all__ = ["add_subparser", "engine_trend", "format_history", "plot_history", "trend_figure"]

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
    parser.add_argument(
        "--clear-alert",
        action="store_true",
        help="maintenance done: clear the open maintenance alerts of --engine (the detector restarts after it)",
    )
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


def format_history(
    serial: str,
    records: list[FlightRecord],
    wear: EngineWear | None = None,
    alerts: tuple[MaintenanceAlert, ...] = (),
    hours: EngineHours | None = None,
) -> str:
    """The printed history of one engine: its open alerts (``ALERT ...``, the overhaul due among them), a
    summary line, its hours, the trend, the across-flight detector, one row per flight with its events."""
    trend = engine_trend(records)
    running = sum(1 for r in records if r.status == "running")
    count = f"{len(records)} flights" + (f" ({running} running)" if running else "")
    lines = [
        f"ALERT {a.text} (CUSUM {a.statistic:.1f} >= {a.threshold:.1f}); clear with --clear-alert once maintained"
        for a in alerts
        if a.cleared_utc is None
    ]
    if hours is not None and hours.due:
        lines.append(f"ALERT OVERHAUL DUE engine {serial}: {hours.text()}")
    lines += [
        f"engine {serial}: {count}, {trend['hours']:.2f} h, max CHT {_fmt(trend['max_cht_c'], '.1f')} "
        f"degC, {trend['time_above_limit_s']:.0f} s above limit, {trend['cycles']:.1f} thermal cycles "
        f"({trend['large_cycles']:.1f} of >= {LARGE_CYCLE_C:g} degC)",
        f"  trend: gamma_Q {_fmt(trend['gamma_q_last'], '.3f')} ({_fmt(trend['gamma_q_per_100h'], '+.4f')} per 100 h),"
        f" gamma_D {_fmt(trend['gamma_d_last'], '.3f')} ({_fmt(trend['gamma_d_per_100h'], '+.4f')} per 100 h)",
    ]
    if hours is not None:
        lines.append(f"  engine hours: {hours.text()}")
    if wear is not None:
        lines.append(_wear_line(wear))
    lines.append(
        f"  {'#':>4} {'start (UTC)':<19} {'hours':>6} {'maxCHT':>6} {'>lim s':>7} {'gQ mean':>7} {'gQ end':>7} "
        f"{'gD mean':>7} {'wear %':>6} {'worst':<12} {'cycles':>6} {'>=50C':>5} status"
    )
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
            f"{_fmt(record.gamma_q_end, '7.3f'):>7} {_fmt(record.gamma_d_mean, '7.3f'):>7} "
            f"{_fmt(_percent(record.wear_index), '+6.1f'):>6} {record.worst_state:<12} "
            f"{record.cycles_total:>6.1f} {_large_cycles(record):>5.1f} {status}"
        )
        lines.extend(_cylinder_lines(record))
        if record.events:
            lines.append(f"       events: {_events_text(record.events)}")
    return "\n".join(lines)


def _events_text(events: dict[str, dict[str, int]]) -> str:
    """A flight's event counts: ``shock_cooling 3 (cyl 1: 1, cyl 3: 2), oil_exceedance 1 (engine)``."""

    def where(cylinder: str) -> str:
        return "engine" if cylinder == "0" else f"cyl {cylinder}"

    parts = []
    for kind, counts in sorted(events.items()):
        total = sum(counts.values())
        each = ", ".join(f"{where(c)}: {n}" for c, n in sorted(counts.items(), key=lambda kv: int(kv[0])))
        parts.append(f"{kind} {total} ({each})")
    return ", ".join(parts)


def _wear_line(wear: EngineWear) -> str:
    """The across-flight detector in one line: its last CUSUM against h, the reference."""
    verdict, reference = wear.verdict, wear.verdict.reference
    statistic = next((s for s in reversed(verdict.statistic) if s is not None), None)
    if reference is None:
        return f"  across flights: learning the engine's reference ({len(wear.flights)} flights so far)"
    source = f"its first {reference.flights} flights" if verdict.learned else f"{reference.flights} nominal flights"
    state = "ALERT" if verdict.alerted else "no alert"
    return (
        f"  across flights: CUSUM {_fmt(statistic, '.2f')} of h {verdict.threshold:.2f} ({state}); wear index"
        f" reference {100.0 * reference.mean:+.2f} % sd {100.0 * reference.sd:.2f} % from {source}"
    )


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


def plot_history(
    histories: dict[str, list[FlightRecord]], out: Path, wear: dict[str, EngineWear] | None = None
) -> None:
    """Trend plot over engine hours: gamma estimates, max CHT and time above limit, cumulative cycles, the wear
    index with the across-flight CUSUM (an alert marked on every panel)."""
    import matplotlib.pyplot as plt

    fig = trend_figure(histories, wear)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, out, dpi=110)
    plt.close(fig)


def trend_figure(histories: dict[str, list[FlightRecord]], wear: dict[str, EngineWear] | None = None) -> Any:
    """The figure of :func:`plot_history` (axes: gamma, max CHT with time-above bars, cycles, wear and CUSUM)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 1, figsize=(9, 11.5), sharex=True)
    ax_gamma, ax_cht, ax_cycles, ax_wear = axes
    for serial, records in histories.items():
        points = list(iter_trend(records))
        _wear_panel(ax_wear, axes, serial, points, (wear or {}).get(serial))
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
    ax_wear.set_ylabel("wear index, % (CUSUM dashed)")
    ax_wear.set_xlabel("engine hours")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    return fig


def _percent(value: float | None) -> float | None:
    return None if value is None else 100.0 * value


def _wear_panel(
    ax: Any, axes: Any, serial: str, points: list[tuple[float, FlightRecord]], wear: EngineWear | None
) -> None:
    """Each flight's wear index (%), the across-flight CUSUM on a twin axis with its h, the alert on every panel."""
    hours = [h for h, _ in points]
    ax.plot(hours, [math.nan if r.wear_index is None else 100.0 * r.wear_index for _, r in points], "o-",
            label=f"{serial} wear index")  # fmt: skip
    ax.axhline(0.0, color="grey", linewidth=0.8)
    if wear is None:
        return
    at_hours = {r.id: h for h, r in points}
    cusum = ax.twinx()
    xs = [at_hours.get(r.id, math.nan) for r in wear.flights]
    cusum.plot(xs, [math.nan if s is None else s for s in wear.verdict.statistic], "k--", linewidth=1.0,
               label=f"{serial} across-flight CUSUM")  # fmt: skip
    cusum.axhline(wear.verdict.threshold, color="red", linewidth=0.8, linestyle=":")
    cusum.set_ylabel("CUSUM (h dotted)")
    cusum.set_ylim(bottom=0.0)
    if wear.verdict.alert_at is not None:
        x = xs[wear.verdict.alert_at]
        for panel in axes:
            panel.axvline(x, color="red", linewidth=1.5, alpha=0.7)
        ax.annotate(f"ALERT {serial}", (x, 0.95), xycoords=("data", "axes fraction"), color="red", ha="right",
                    fontsize=9)  # fmt: skip


def _cylinder_value(record: FlightRecord, index: int, key: str) -> float:
    """One cylinder's stored value for a flight (nan: none, or a flight without cylinders)."""
    cylinders = record.cylinders.get("per_cylinder", [])
    value = cylinders[index].get(key) if index < len(cylinders) else None
    return float(value) if value is not None else math.nan


def _run(args: argparse.Namespace) -> int:
    import time

    from ecu_monitor.config import load_config
    from ecu_monitor.estimation.wear import WearSettings
    from ecu_monitor.runtime.flight_recorder import engine_wear
    from ecu_monitor.userfiles import check_output_file, prepare_output_dir

    if args.plot:  # its folder is made for it
        prepare_output_dir(Path(args.plot).parent, "--plot", ConfigError)
        check_output_file(args.plot, "--plot", ConfigError)
    config = load_config(args.config) if args.config else None
    state_dir = Path(args.state_dir) if config is None else config.state_dir
    settings = config.wear if config is not None else WearSettings()
    if args.clear_alert:
        if args.engine is None:
            raise ConfigError("--clear-alert: give --engine SERIAL (the engine that was maintained)")
        with StateStore(state_dir) as store:
            cleared = store.clear_alerts(args.engine, time.time())
        print(f"engine {args.engine}: {cleared} maintenance alert(s) cleared")
    with StateStore(state_dir, readonly=True) as store:
        serials = store.engines()
        if args.engine is not None:
            if args.engine not in serials:
                raise ConfigError(f"{store.path}: --engine: no engine {args.engine!r} (engines: {', '.join(serials)})")
            serials = [args.engine]
        histories = {serial: store.flights(serial, include_running=True) for serial in serials}
        hours = {serial: store.engine_hours(serial) for serial in serials}
        alerts = {serial: tuple(store.alerts(serial)) for serial in serials}
        wear = {
            serial: engine_wear(store, serial, settings, _reference(config, alerts[serial], serial))
            for serial in serials
        }
    if not histories:
        print(f"{store.path}: no engine recorded yet")
        return 0
    print("\n\n".join(format_history(s, records, wear[s], alerts[s], hours[s]) for s, records in histories.items()))
    if args.plot:
        with_flights = {serial: records for serial, records in histories.items() if records}
        if not with_flights:
            raise ConfigError(f"{store.path}: --plot: no flight to plot")
        plot_history(with_flights, Path(args.plot), wear)
        print(f"plot written to {args.plot}")
    return 0


def _reference(config: Any, alerts: tuple[MaintenanceAlert, ...], serial: str) -> WearReference | None:
    """The wear reference the detector used: the config's (``--config``, this engine's serial), else the one its
    last alert stored (when that was not learned), else None (learned from the first flights)."""
    if config is not None and config.engine_serial == serial:
        return config.wear_reference  # type: ignore[no-any-return]
    from ecu_monitor.estimation.wear import WearReference

    stored = next((a for a in reversed(alerts) if not a.reference_learned), None)
    if stored is None:
        return None
    return WearReference(stored.reference_mean, stored.reference_sd, stored.reference_flights)
