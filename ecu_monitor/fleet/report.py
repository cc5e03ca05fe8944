"""DIR/report.html: one static page (no server, no script) a maintainer opens in a browser.

The fleet at a glance (engines ranked by concern: alert, the across-flight CUSUM against its threshold, the
wear trend, engine events, hours to overhaul, the reason in words), then per engine its trend plot (wear index
and CUSUM per flight, max CHT, gamma_Q / gamma_D; a PNG embedded as base64), its engine events and its last
flights, then the logs that could not be read.
"""

from __future__ import annotations

import base64
import datetime
import html
import io
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from ecu_monitor.errors import ConfigError

if TYPE_CHECKING:
    from ecu_monitor.fleet.engines import EngineTrend
    from ecu_monitor.fleet.spec import Fleet
    from ecu_monitor.fleet.store import FleetStore

__all__ = ["REPORT_NAME", "render_report", "write_report"]

REPORT_NAME = "report.html"
#: Rows of each engine's last flights and events shown.
_LAST_FLIGHTS = 10
_LAST_EVENTS = 20

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 1.5em; color: #222; }
h1 { margin-bottom: 0.2em; } h2 { margin-top: 1.6em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.5em; text-align: left; vertical-align: top; }
th { background: #f2f2f2; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
tr.alert td { background: #fde2e2; } .badge { padding: 0.1em 0.4em; border-radius: 0.3em; color: #fff; }
.badge { white-space: nowrap; } .badge.alert { background: #c0392b; } .badge.ok { background: #27ae60; }
.badge.learn { background: #7f8c8d; }
img { max-width: 100%; } .muted { color: #777; }
"""


def write_report(
    store: FleetStore, fleet: Fleet, engines: Sequence[Mapping[str, Any]], trends: Sequence[EngineTrend]
) -> None:
    """Write DIR/report.html atomically: ``engines`` are engines.parquet's rows, ranked."""
    from ecu_monitor.userfiles import write_output_bytes

    events = store.table("events").to_pylist()
    page = render_report(fleet, engines, trends, events, store.table("failures").to_pylist())
    write_output_bytes(store.root / REPORT_NAME, page.encode("utf-8"), ConfigError)


def render_report(
    fleet: Fleet,
    engines: Sequence[Mapping[str, Any]],
    trends: Sequence[EngineTrend],
    events: Sequence[Mapping[str, Any]],
    failures: Sequence[Mapping[str, Any]],
) -> str:
    """The page's HTML."""
    by_serial = {t.serial: t for t in trends}
    by_engine: dict[str, list[Mapping[str, Any]]] = {}
    for event in events:
        by_engine.setdefault(str(event["serial"]), []).append(event)
    alerts = sum(1 for row in engines if row["alert"])
    hours = sum(row["hours"] for row in engines)
    flights = sum(row["flights"] for row in engines)
    now = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    out = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>Fleet report: {_e(fleet.source.name)}</title>",
        '<link rel="icon" href="data:,">',  # no favicon request: a file page loads nothing else
        f"<style>{_STYLE}</style></head><body>",
        f"<h1>Fleet report: {_e(fleet.source.name)}</h1>",
        f'<p class="muted">{len(engines)} engines, {flights} flights, {hours:.1f} flight hours;'
        f" {alerts} engine(s) with an across-flight alert; {len(failures)} log(s) unreadable. Made {now}"
        " by ecu-monitor fleet run.</p>",
        "<h2>The fleet at a glance</h2>",
        _glance(engines),
    ]
    for row in engines:
        serial = str(row["serial"])
        out.append(_engine_section(row, by_serial[serial], by_engine.get(serial, [])))
    out.append("<h2>Logs that could not be read</h2>")
    out.append(_table(("engine", "log", "reason"), [(f["serial"], f["log"], f["reason"]) for f in failures])
               if failures else '<p class="muted">none</p>')  # fmt: skip
    out.append("</body></html>")
    return "\n".join(out)


def _glance(rows: Sequence[Mapping[str, Any]]) -> str:
    head = ("rank", "engine", "state", "flights", "hours", "CUSUM / h", "wear trend / 10 flights", "events",
            "to overhaul", "reason")  # fmt: skip
    body = []
    for row in rows:
        badge = _badge(row)
        ratio = "" if row["cusum"] is None else f"{row['cusum']:.1f} / {row['threshold']:.1f}"
        trend = "" if row["wear_trend_per_10"] is None else f"{100.0 * row['wear_trend_per_10']:+.2f} %"
        overhaul = "" if row["hours_to_overhaul"] is None else f"{row['hours_to_overhaul']:.0f} h"
        body.append(
            f'<tr class="{"alert" if row["alert"] else ""}"><td class="num">{row["rank"]}</td>'
            f'<td><a href="#engine-{_e(row["serial"])}">{_e(row["serial"])}</a></td><td>{badge}</td>'
            f'<td class="num">{row["flights"]}</td><td class="num">{row["hours"]:.1f}</td>'
            f'<td class="num">{ratio}</td><td class="num">{trend}</td><td class="num">{row["events"]}</td>'
            f'<td class="num">{overhaul}</td><td>{_e(row["reason"])}</td></tr>'
        )
    return (
        "<table><thead><tr>"
        + "".join(f"<th>{h}</th>" for h in head)
        + "</tr></thead><tbody>"
        + "".join(body)
        + "</tbody></table>"
    )


def _badge(row: Mapping[str, Any]) -> str:
    if row["alert"]:
        return '<span class="badge alert">ALERT</span>'
    if row["cusum"] is None:
        return '<span class="badge learn">learning</span>'
    return '<span class="badge ok">no alert</span>'


def _engine_section(row: Mapping[str, Any], trend: EngineTrend, events: Sequence[Mapping[str, Any]]) -> str:
    serial = str(row["serial"])
    parts = [
        f'<h2 id="engine-{_e(serial)}">#{row["rank"]} {_e(serial)} {_badge(row)}</h2>',
        f"<p>{_e(row['reason'])}</p>",
    ]
    if trend.flights:
        image = base64.b64encode(_trend_png(trend)).decode("ascii")
        parts.append(f'<img alt="trend of engine {_e(serial)}" src="data:image/png;base64,{image}">')
    else:
        parts.append('<p class="muted">no flight summarised</p>')
    parts.append("<h3>Engine events</h3>")
    if events:
        last = sorted(events, key=lambda e: (str(e["log"]), float(e["time_s"])))[-_LAST_EVENTS:]
        cells = [(e["log"], f"{e['time_s'] / 60.0:.1f}", str(e["kind"]).replace("_", " "), e["cylinder"],
                  f"{e['value']:.1f}", f"{e['limit']:.1f}", f"{e['duration_s']:.1f}") for e in last]  # fmt: skip
        parts.append(_table(("log", "time (min)", "kind", "cylinder", "value", "limit", "duration (s)"), cells))
        if len(events) > _LAST_EVENTS:
            parts.append(f'<p class="muted">the last {_LAST_EVENTS} of {len(events)} events</p>')
    else:
        parts.append('<p class="muted">none</p>')
    parts.append("<h3>Last flights</h3>")
    statistic = trend.verdict.statistic
    rows = []
    for number, (flight, s) in list(enumerate(zip(trend.flights, statistic, strict=True), start=1))[-_LAST_FLIGHTS:]:
        rows.append((number, flight["log"], _when(flight["start_utc"]), f"{flight['duration_s'] / 60.0:.0f}",
                     _num(flight["max_cht_c"], ".0f"), _num(flight["high_power_s"] / 60.0, ".1f"),
                     _num(flight["gamma_q_mean"], ".3f"), _num(flight["gamma_d_mean"], ".3f"),
                     _num(None if flight["wear_index"] is None else 100.0 * flight["wear_index"], "+.1f"),
                     _num(s, ".2f"), flight["worst_state"], flight["events"]))  # fmt: skip
    parts.append(_table(("#", "log", "start", "min", "max CHT (degC)", "min at high power", "gamma_Q mean",
                         "gamma_D mean", "wear index %", "CUSUM", "worst state", "events"), rows))  # fmt: skip
    return "\n".join(parts)


def _trend_png(trend: EngineTrend) -> bytes:
    """The engine's trend over its flights: wear index and CUSUM (with h and the alert), max CHT, gammas."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    flights = trend.flights
    x = list(range(1, len(flights) + 1))

    def values(name: str, scale: float = 1.0) -> list[float]:
        return [math.nan if f[name] is None else scale * float(f[name]) for f in flights]

    fig, (ax_wear, ax_cht, ax_gamma) = plt.subplots(3, 1, figsize=(9, 6), sharex=True)
    try:
        ax_wear.plot(x, values("wear_index", 100.0), "o-", ms=3, color="tab:blue", label="wear index")
        ax_wear.set_ylabel("wear index (%)")
        twin = ax_wear.twinx()
        cusum = [math.nan if s is None else s for s in trend.verdict.statistic]
        twin.plot(x, cusum, "--", color="tab:red", label="across-flight CUSUM")
        twin.axhline(trend.verdict.threshold, color="tab:red", lw=0.8, ls=":", label="h")
        twin.set_ylabel("CUSUM")
        if trend.verdict.alert_at is not None:
            for ax in (ax_wear, ax_cht, ax_gamma):
                ax.axvline(trend.verdict.alert_at + 1, color="tab:red", lw=1.2)
        handles = ax_wear.get_legend_handles_labels()[0] + twin.get_legend_handles_labels()[0]
        ax_wear.legend(handles, [h.get_label() for h in handles], loc="upper left", fontsize=7)
        ax_cht.plot(x, values("max_cht_c"), "o-", ms=3, color="tab:orange")
        ax_cht.set_ylabel("max CHT (degC)")
        ax_gamma.plot(x, values("gamma_q_mean"), "o-", ms=3, label="gamma_Q mean")
        ax_gamma.plot(x, values("gamma_d_mean"), "s-", ms=3, label="gamma_D mean")
        ax_gamma.axhline(1.0, color="grey", lw=0.6)
        ax_gamma.set_ylabel("factor")
        ax_gamma.set_xlabel("flight (in flight order)")
        ax_gamma.legend(loc="upper left", fontsize=7)
        for ax in (ax_wear, ax_cht, ax_gamma):
            ax.grid(alpha=0.3)
        ax_wear.set_title(f"engine {trend.serial}: across flights (red line: the alert)")
        fig.tight_layout()
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=72)
    finally:
        plt.close(fig)
    return buffer.getvalue()


def _table(head: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    cells = "".join(
        "<tr>" + "".join(f'<td class="num">{_e(v)}</td>' if isinstance(v, int | float) else f"<td>{_e(v)}</td>"
                         for v in row) + "</tr>" for row in rows
    )  # fmt: skip
    return (
        "<table><thead><tr>"
        + "".join(f"<th>{_e(h)}</th>" for h in head)
        + f"</tr></thead><tbody>{cells}</tbody></table>"
    )


def _when(start_utc: float | None) -> str:
    if start_utc is None:
        return ""
    return datetime.datetime.fromtimestamp(start_utc, datetime.UTC).strftime("%Y-%m-%d %H:%M")


def _num(value: float | None, fmt: str) -> str:
    return "" if value is None or not math.isfinite(value) else format(value, fmt)


def _e(value: Any) -> str:
    return html.escape("" if value is None else str(value))
