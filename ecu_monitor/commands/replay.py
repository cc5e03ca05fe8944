"""``ecu-monitor replay LOG [--model M] [--config C] [--estimator NAME] --out health.csv``.

Runs the service's pipeline (the object the daemon runs live) over a recorded log as fast as the
machine allows: python-can logs (.asc, .blf, .log, .trc) are decoded through the config's DBC mapping;
a canonical flight CSV is turned into the frames the ECU would have sent (each mapped message at its
DBC rate) and goes through the same path. Writes one row per health-status period (100 ms):
``time_s, cht_meas_c, cht_est_c, deviation, state, gamma_q, gamma_d, headroom_s, stale_inputs,
sensor_fault`` (deviation = the model-deviation symptom, degC/s; state = the Health_Status verdict);
``--out`` ending in .parquet, .arrow or .feather writes the same columns as Parquet or Arrow IPC
(needs pyarrow: ``pip install 'ecu-monitor[arrow]'``).
Prints one summary line, then one ``warning:`` line for each setting that does not fit the engine:
the model's CHT limit below what the engine read (the headroom is 0 there), and a detector threshold
not calibrated for this model (``detector.calibrated_for`` absent from the config or naming another
model; ``ecu-monitor calibrate`` writes it). Defaults: config example.yaml (shipped), the model it
names (or --model), its estimator (or --estimator). ``--live`` feeds the frames one by one through
the live path instead of the batch path (same rows, slower; for checking). ``--events EVENTS.csv``
writes the engine events (docs/contracts.md, "Engine events") and ``--plot`` draws them on the CHT panel.

``--history STATE_DIR`` also records the log's flights in the flight history of that state directory
(the daemon's SQLite database, under the config's engine serial), as the daemon would have: the live
path, the same flight recorder, its wear index and across-flight detector (an alert it raises is printed
as a line starting ``ALERT``). A flight's times are the log's own clock when it is a UNIX time (CAN
loggers), else they end at the log file's modification time.

The protocol comes from the config (``protocol: dbc|dronecan``). Without --config, a CAN log whose
frames look like DroneCAN (29-bit ids with DroneCAN tail bytes, ``bus.dronecan.looks_like_dronecan``)
is replayed with the shipped dronecan.yaml, any other log with example.yaml; when no frame of the log
decodes and the log looks like the other protocol, a ``warning:`` line says which config to give.
"""

from __future__ import annotations

import argparse
import collections
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ecu_monitor.commands.names import ESTIMATOR_NAMES
from ecu_monitor.compile_cache import announce_compiles
from ecu_monitor.errors import ConfigError, FlightLogError, ParameterError
from ecu_monitor.shipped import DEFAULT_CONFIG, DRONECAN_CONFIG, MAVLINK_CONFIG
from ecu_monitor.userfiles import save_figure

if TYPE_CHECKING:  # the run imports these: --help stays light
    from collections.abc import Sequence

    from ecu_monitor.bus.canlog import FrameArrays
    from ecu_monitor.config import ServiceConfig
    from ecu_monitor.model import ThermalParams
    from ecu_monitor.offline.replay import ReplayResult

__all__ = ["DEFAULT_CONFIG", "add_subparser", "fit_warnings"]


def add_subparser(subparsers: Any) -> None:
    """Register the ``replay`` subcommand."""
    parser = subparsers.add_parser(
        "replay",
        help="run the service pipeline over a recorded log (.asc/.blf/.log/.trc or canonical CSV) -> health.csv",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument("log", metavar="LOG", help="flight log: .asc/.blf/.log/.trc CAN log or canonical .csv")
    parser.add_argument("--model", metavar="MODEL.yaml", help="thermal model (default: the config's model)")
    parser.add_argument("--config", metavar="CONFIG.yaml", help=f"service config (default: {DEFAULT_CONFIG.name})")
    parser.add_argument(
        "--estimator", metavar="NAME", help=f"estimator: {', '.join(sorted(ESTIMATOR_NAMES))} (default: the config's)"
    )
    parser.add_argument(
        "--out",
        required=True,
        metavar="HEALTH.csv",
        help="output: .csv, or .parquet / .arrow / .feather (pip install 'ecu-monitor[arrow]')",
    )
    parser.add_argument(
        "--events",
        metavar="EVENTS.csv",
        help="also write the engine events (shock cooling, CHT divergence, exceedances): time_s, kind, cylinder,"
        " value, limit, duration_s (docs/contracts.md)",
    )
    parser.add_argument("--live", action="store_true", help="feed frames one by one through the live path")
    parser.add_argument(
        "--history",
        metavar="STATE_DIR",
        help="also record the log's flights in the flight history (SQLite) of this state directory, as the daemon"
        " does (implies --live)",
    )
    parser.add_argument(
        "--plot",
        metavar="HEALTH.png",
        help="also draw the replay: CHT measured and estimated, the deviation symptom, gamma_Q/gamma_D and the"
        " headroom over time, the service's state shaded behind (needs the tools extra)",
    )
    parser.set_defaults(func=announce_compiles(_run))  # a first run says it compiles


def _replay_into_history(
    config: ServiceConfig, models: Sequence[ThermalParams], frames: FrameArrays, path: Path, state_dir: Path
) -> ReplayResult:
    """The live replay with its rows fed to the flight recorder of ``state_dir`` (module docstring)."""
    import numpy as np

    from ecu_monitor.offline.replay import replay_live
    from ecu_monitor.runtime.flight_recorder import FlightRecorder, flight_samples, held_inputs
    from ecu_monitor.runtime.persistence import StateStore
    from ecu_monitor.runtime.state_lock import StateDirLock

    times = np.asarray(frames.time_s, dtype=np.float64)
    last = float(np.max(times)) if times.size else 0.0
    offset = 0.0 if times.size and float(np.min(times)) > _UNIX_TIME_S else path.stat().st_mtime - last
    with StateDirLock(state_dir), StateStore(state_dir) as store:  # never beside a daemon on the same history
        recorder = FlightRecorder(
            store,
            config.engine_serial,
            models[0].cht_limit_c,
            wear=config.wear,
            reference=config.wear_reference,
            hours=(config.overhaul_hours, config.tbo_hours),
        )

        def record(pipeline: Any, rows: list[Any], events: list[Any]) -> None:
            for sample in flight_samples(rows, held_inputs(pipeline), offset):
                recorder.add(sample)
            recorder.add_events(events)

        result = replay_live(config, models, frames.messages(), on_rows=record)
        recorder.close("log_end")
    kept = ", ".join(str(i) for i in recorder.finished) or "none"
    print(f"history {store.path}: engine {config.engine_serial}, flights recorded: {kept}")
    for alert in recorder.alerts:
        print(f"ALERT {alert.text} (CUSUM {alert.statistic:.1f} >= {alert.threshold:.1f})")
    return result


#: A log whose first stamp is later than this (2001-09-09) runs on the UNIX clock, s.
_UNIX_TIME_S = 1e9


def _run(args: argparse.Namespace) -> int:
    import numpy as np

    from ecu_monitor.bus.canlog import CAN_LOG_SUFFIXES, load_flight, read_frames
    from ecu_monitor.config import load_config
    from ecu_monitor.estimation import ESTIMATORS
    from ecu_monitor.flightlog import log_airframe
    from ecu_monitor.model import airframe_warning, load_model
    from ecu_monitor.offline.calibration import without_foreign_reference
    from ecu_monitor.offline.replay import frames_from_flight, replay_frames, replay_live, replay_tlog, tlog_messages
    from ecu_monitor.pipeline.engine import model_input_names
    from ecu_monitor.pipeline.table import check_table_path
    from ecu_monitor.userfiles import check_output_file, check_output_not_input

    started = time.perf_counter()
    for option, out in (("--out", args.out), ("--plot", args.plot), ("--events", args.events)):
        if out:
            check_output_not_input(out, (args.log, args.config, args.model), ConfigError)
            check_output_file(out, option, ConfigError)
    check_table_path(args.out)  # an unknown suffix or a missing pyarrow: one line before any work
    if args.plot:
        _check_plot_path(Path(args.plot))
    path = Path(args.log)
    given = load_config(args.config) if args.config else None
    tlog = path.suffix.lower() == ".tlog"
    log_frames = read_frames(path) if path.suffix.lower() in CAN_LOG_SUFFIXES else None
    if tlog:
        config = given or load_config(MAVLINK_CONFIG)
    else:
        config = given or load_config(
            DRONECAN_CONFIG if log_frames is not None and _is_dronecan(log_frames) else DEFAULT_CONFIG
        )
    if args.estimator is not None:
        if args.estimator not in ESTIMATORS:
            raise ConfigError(
                f"--estimator: unknown estimator {args.estimator!r} (known: {', '.join(sorted(ESTIMATORS))})"
            )
        config = config.replace(estimator_name=args.estimator)
    models = (load_model(args.model),) * len(config.cylinder_inputs) if args.model else config.load_cylinder_params()
    params = models[0]
    stripped = without_foreign_reference(config, models)
    config = stripped or config
    mismatch = airframe_warning(params, log_airframe(path), str(args.model or config.source), path.name)
    if mismatch:
        print(f"warning: {mismatch}")
    result: ReplayResult
    streamed = not args.live and (tlog or not args.history)  # health.csv written by the replay as it runs
    if tlog:
        if args.live:
            result = replay_live(config, models, tlog_messages(path))
        else:
            result = replay_tlog(path, config, models, out=args.out)
        if len(result) == 0:
            raise FlightLogError(f"{path}: nothing to replay: no health period of the mapped messages")
    else:
        if log_frames is not None:
            frames = log_frames
        else:
            needed = (*model_input_names(params, config.input_names), *config.cylinder_inputs)
            frames = frames_from_flight(load_flight(path), config, needed)
        if args.history:
            result = _replay_into_history(config, models, frames, path, Path(args.history))
        else:
            live = args.live
            if live:
                result = replay_live(config, models, frames.messages())
            else:
                result = replay_frames(config, models, frames, out=args.out)
        if len(result) == 0:
            span = float(np.max(frames.time_s) - np.min(frames.time_s)) if len(frames) else 0.0
            raise FlightLogError(f"{path}: nothing to replay: the frames span {span:.2f} s, not one health period")
    rows = len(result) if streamed else result.write_csv(args.out)
    print(_summary(args.out, path, config.estimator_name, result, rows, time.perf_counter() - started))
    if args.events:
        from ecu_monitor.pipeline.events import events_csv
        from ecu_monitor.userfiles import write_output_bytes

        write_output_bytes(args.events, events_csv(result.events).encode(), ParameterError, (args.log, args.config))
        kinds = collections.Counter(e.kind for e in result.events)
        listed = ", ".join(f"{n} {kind}" for kind, n in sorted(kinds.items())) or "none"
        dropped = result.counters.get("events_dropped", 0)
        print(f"events: {args.events}: {listed}" + (f" ({dropped} dropped: buffer full)" if dropped else ""))
    for line in _cylinder_lines(result):
        print(line)
    if log_frames is not None and result.counters.get("ok", 0) == 0:
        dronecan = _is_dronecan(log_frames)
        if dronecan != (config.protocol == "dronecan"):
            other = "a DroneCAN config (protocol: dronecan, e.g. dronecan.yaml)" if dronecan else "a DBC config"
            kind = "DroneCAN" if dronecan else "DBC frames"
            print(f"warning: no frame of {path.name} decoded with {config.source} (protocol {config.protocol});"
                  f" the log looks like {kind}: give --config with {other}")  # fmt: skip
    for line in fit_warnings(config, params, result, models):
        print(f"warning: {line}")
    if stripped is not None:
        print("warning: the config's engine reference (detector.nominal_*) is another model's: its test was off")
    if args.plot:
        plot_replay(result, Path(args.plot), title=path.name, cht_limit_c=params.cht_limit_c)
        print(f"plot: {args.plot}")
    return 0


def _check_plot_path(path: Path) -> None:
    """Refuse a --plot path that cannot be written, before the replay runs."""
    import matplotlib  # the tools extra: a missing one is reported by the CLI as one line

    del matplotlib
    if path.suffix.lower() not in {".png", ".svg", ".pdf"}:
        raise ParameterError(f"--plot: {path} must end in .png, .svg or .pdf")
    if path.parent != Path("") and not path.parent.is_dir():
        raise ParameterError(f"--plot: no such folder {path.parent}")


#: Background colour of each non-NOMINAL state in the replay plot.
_STATE_SHADES = {
    "SUSPECT": "gold",
    "DEGRADED": "tab:red",
    "INPUT_STALE": "grey",
    "SENSOR_FAULT": "tab:purple",
    "UNAVAILABLE": "black",
}


def plot_replay(result: ReplayResult, path: Path, title: str, cht_limit_c: float) -> None:
    """One figure of a replay (time in minutes from the first row): CHT measured and estimated (every
    cylinder on an engine monitored per cylinder) with the model's CHT limit, the deviation symptom
    (degC/s), gamma_Q and gamma_D, and the thermal headroom (s); each panel shaded where the service's
    state was not NOMINAL."""
    import matplotlib
    import numpy as np

    from ecu_monitor.pipeline.output_table import HEADROOM_CAP_S, STATES

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = result.columns
    time_s = np.asarray(c["time_s"], dtype=float)
    t = (time_s - time_s[0]) / 60.0
    count = result.cylinder_count
    fig, axes = plt.subplots(4, 1, figsize=(13, 10), sharex=True, height_ratios=(2.2, 1.2, 1.2, 1.0))
    ax_cht, ax_dev, ax_gamma, ax_head = axes
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    if count == 1:
        ax_cht.plot(t, c["cht_meas_c"], lw=0.7, color="tab:orange", label="CHT measured")
        ax_cht.plot(t, c["cht_est_c"], lw=0.9, color="tab:blue", ls="--", label="CHT estimated")
        ax_dev.plot(t, c["deviation"], lw=0.6, color="tab:blue", label="deviation symptom")
        ax_gamma.plot(t, c["gamma_q"], lw=0.9, color="tab:blue", label="gamma_Q (heat in)")
        ax_gamma.plot(t, c["gamma_d"], lw=0.9, color="tab:green", label="gamma_D (dissipation)")
    else:
        for n in range(1, count + 1):
            colour = colours[(n - 1) % len(colours)]
            ax_cht.plot(t, c[f"cyl{n}_cht_meas_c"], lw=0.6, color=colour, label=f"cylinder {n} measured")
            ax_cht.plot(t, c[f"cyl{n}_cht_est_c"], lw=0.8, color=colour, ls="--")
            ax_dev.plot(t, c[f"cyl{n}_deviation"], lw=0.5, color=colour, label=f"cylinder {n}")
            ax_gamma.plot(t, c[f"cyl{n}_gamma_q"], lw=0.8, color=colour, label=f"cylinder {n} gamma_Q")
            ax_gamma.plot(t, c[f"cyl{n}_gamma_d"], lw=0.8, color=colour, ls=":")
        ax_cht.plot([], [], color="black", ls="--", lw=0.8, label="estimated (dashed)")
        ax_gamma.plot([], [], color="black", ls=":", lw=0.8, label="gamma_D (dotted)")
    measured = np.asarray(c["cht_meas_c"], dtype=float)
    top = float(np.nanmax(measured)) if np.isfinite(measured).any() else cht_limit_c
    if cht_limit_c <= top + 30.0:
        ax_cht.axhline(cht_limit_c, color="tab:red", ls="--", lw=1.0, label=f"model's CHT limit {cht_limit_c:g} degC")
    ax_cht.set_ylabel("CHT (degC)")
    ax_dev.axhline(0.0, color="grey", lw=0.6)
    ax_dev.set_ylabel("deviation (degC/s)")
    ax_gamma.axhline(1.0, color="grey", lw=0.6)
    ax_gamma.set_ylabel("degradation factor")
    headroom = np.asarray(c["headroom_s"], dtype=float)
    ax_head.plot(t, np.where(headroom >= HEADROOM_CAP_S, np.nan, headroom), lw=0.9, color="tab:red",
                 label="time to the CHT limit at the present power")  # fmt: skip
    ax_head.set_ylabel("headroom (s)")
    ax_head.set_xlabel("time from the first health row (min)")
    states = np.asarray(c["state"])
    for name, colour in _STATE_SHADES.items():
        inside = states == STATES.index(name)
        if not inside.any():
            continue
        for i, ax in enumerate(axes):
            ax.fill_between(t, 0, 1, where=inside, step="post", color=colour, alpha=0.15, lw=0,
                            transform=ax.get_xaxis_transform(), label=name if i == 0 else None)  # fmt: skip
    _plot_events(ax_cht, result, time_s[0])
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=7, borderaxespad=0.0)  # beside the traces
    ax_cht.set_title(f"{title}: the service's replay (shaded: state not NOMINAL)")
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=110, error=ParameterError)
    finally:
        plt.close(fig)


#: The colour of each kind of engine event on the replay plot.
_EVENT_COLOURS = {
    "shock_cooling": "tab:cyan",
    "cht_divergence": "tab:olive",
    "egt_divergence": "tab:brown",
    "valve_advisory": "tab:pink",
    "cht_exceedance": "tab:red",
    "egt_exceedance": "darkred",
    "oil_exceedance": "tab:orange",
}


def _plot_events(ax: Any, result: ReplayResult, origin_s: float) -> None:
    """The engine events on the CHT panel: each a band over its duration and its cylinder's number above."""
    labelled: set[str] = set()
    for event in result.events:
        start = (event.time_s - origin_s) / 60.0
        end = start + event.duration_s / 60.0
        colour = _EVENT_COLOURS[event.kind]
        ax.axvspan(start, max(end, start + 0.05), color=colour, alpha=0.35, lw=0,
                   label=None if event.kind in labelled else event.kind.replace("_", " "))  # fmt: skip
        ax.text(start, 1.0, str(event.cylinder), color=colour, fontsize=6, ha="left", va="bottom",
                transform=ax.get_xaxis_transform())  # fmt: skip
        labelled.add(event.kind)


def _is_dronecan(frames: FrameArrays) -> bool:
    from ecu_monitor.bus.dronecan import looks_like_dronecan

    return looks_like_dronecan(frames.arbitration_id, frames.is_extended, frames.dlc, frames.data)


def fit_warnings(
    config: ServiceConfig, params: ThermalParams, result: ReplayResult, models: Sequence[ThermalParams] = ()
) -> list[str]:
    """One line per setting that does not fit the replayed engine: the model's CHT limit below the
    measured CHT, and a detector threshold not calibrated for ``params`` (by its fingerprint)."""
    import numpy as np

    from ecu_monitor.offline.calibration import uncalibrated_detectors

    out = []
    cht = np.asarray(result.columns["cht_meas_c"], dtype=float)
    cht = cht[np.isfinite(cht)]
    limit = params.cht_limit_c
    if cht.size and float(cht.max()) > limit:
        share = 100.0 * np.count_nonzero(cht > limit) / cht.size
        out.append(
            f"the model's CHT limit {limit:g} degC is below what the engine read (up to {float(cht.max()):.1f} degC,"
            f" {share:.0f} % of the rows above): headroom is 0 there; set the engine's cht_limit_c in the model"
        )
    return out + uncalibrated_detectors(config, models or (params,))


def _cylinder_lines(result: ReplayResult) -> list[str]:
    """One line per cylinder of an engine monitored per cylinder: its states, first DEGRADED, the spread."""
    import numpy as np

    from ecu_monitor.pipeline.output_table import STATES

    count = result.cylinder_count
    if count == 1:
        return []
    c = result.columns
    time_s = c["time_s"]
    lines = []
    for n in range(1, count + 1):
        codes = c[f"cyl{n}_state"]
        counts = collections.Counter(STATES[code] for code in codes.tolist())
        degraded = np.flatnonzero(codes == STATES.index("DEGRADED"))
        detected = f", DEGRADED from t={time_s[degraded[0]] - time_s[0]:.1f} s" if degraded.size else ""
        lines.append(f"cylinder {n}: {', '.join(f'{s} {k}' for s, k in counts.most_common())}{detected}")
    spread = c["cht_spread_c"][np.isfinite(c["cht_spread_c"])]
    hottest = collections.Counter(int(h) for h in c["hottest_cylinder"].tolist() if h)
    if spread.size:
        most = ", ".join(f"{h} ({100.0 * k / len(time_s):.0f} %)" for h, k in hottest.most_common())
        lines.append(
            f"CHT spread: median {np.median(spread):.1f} degC, max {spread.max():.1f} degC,"
            f" alarm in {100.0 * np.mean(c['spread_alarm']):.1f} % of the rows; hottest cylinder {most}"
        )
    return lines


def _summary(out: str, log: Path, estimator: str, result: ReplayResult, rows: int, wall_s: float) -> str:
    import numpy as np

    from ecu_monitor.pipeline.output_table import STATES

    c = result.counters
    time_s = result.columns["time_s"]
    codes = result.columns["state"]
    span = float(time_s[-1] - time_s[0]) if rows else 0.0
    counts = collections.Counter(STATES[code] for code in codes.tolist())
    degraded = np.flatnonzero(codes == STATES.index("DEGRADED"))
    detected = f", DEGRADED from t={time_s[degraded[0]] - time_s[0]:.1f} s" if degraded.size else ""
    share = ", ".join(f"{name} {count}" for name, count in counts.most_common())
    holes = ""
    if result.gaps:
        longest = max(after - before for before, after in result.gaps)
        restarts = c.get("clock_restarts", 0)
        segments = f", {restarts + 1} segments replayed apart" if restarts else ""
        holes = f"; {len(result.gaps)} hole(s) in time without frames (longest {longest:.1f} s{segments})"
    return (
        f"{out}: {rows} rows, {span:.1f} s of {log.name} ({estimator}); frames {c['frames']} "
        f"(ok {c['ok']}, malformed {c['malformed']}, unknown id {c['unknown_id']}); states: {share}{detected}"
        f"{holes}; {wall_s:.1f} s"
    )
