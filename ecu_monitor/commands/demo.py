"""``ecu-monitor demo [--out DIR] [--seed N] [--inject-at S] [--gamma-q G] [--mission NAME] [--protocol P]``.

The virtual ECU flies the default step-climb mission (the shipped mission default.yaml) through its
truth plant with a heat-input degradation gamma_Q = 1.2 injected mid-flight (t = 1800 s), and sends
its frames (engine.dbc: ECU_Fast 50 Hz, ECU_Slow and AirData 10 Hz) onto an in-process python-can
``virtual`` bus. The service listens on a second Bus instance of the same channel through a
python-can Notifier: each frame goes into the service pipeline (the shipped example.yaml), and the health
frames that fall due (health.dbc) go back onto the bus, where the ECU side counts them as the
autopilot would. The virtual clock runs as fast as the machine allows (mission time is carried in the
frame timestamps); a progress line shows mission time, CHT measured and estimated and the health
state; the detection time is printed at the end. ``--protocol dronecan``: the virtual ECU speaks
DroneCAN instead (an engine node's ICE status and an air-data node's messages, 10 Hz), the service
reads them through the shipped dronecan.yaml and answers as a DroneCAN node (NodeStatus, KeyValue,
LogMessage), which the ECU side counts as the autopilot would. ``--protocol mavlink``: the virtual ECU
sends the stream an autopilot would (virtual_bus/mavlink_emitter.py: HEARTBEAT, EFI_STATUS 10 Hz, VFR_HUD
and SCALED_PRESSURE 5 Hz), no bus between: each message is parsed by pymavlink from its bytes and fed to
the service (the shipped mavlink.yaml) at its mission time, and what the service would send as a MAVLink
component (HEARTBEAT, STATUSTEXT, NAMED_VALUE_FLOAT) is counted; its STATUSTEXT texts, the pilot's view,
are printed with their mission times and written to statustext.csv.

Writes into DIR (default demo-out): flight.csv (the virtual ECU's canonical log with the truth:
cht_true_c, gamma_q, gamma_d), health.csv (the service's rows, 10 Hz), and the plots cht.png (CHT
measured / estimated / true), detection.png (deviation symptom and detector state), gammas.png
(gamma_Q and gamma_D estimates against the truth) and headroom.png (time to the CHT limit).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ecu_monitor.compile_cache import announce_compiles
from ecu_monitor.errors import ConfigError
from ecu_monitor.shipped import DEFAULT_CONFIG, DRONECAN_CONFIG, MAVLINK_CONFIG
from ecu_monitor.userfiles import atomic_output, prepare_output_dir, save_figure

if TYPE_CHECKING:  # the run and the plots import these: --help stays light
    import can

    from ecu_monitor.config import ServiceConfig
    from ecu_monitor.flightlog import FlightLog
    from ecu_monitor.pipeline.outputs import HealthSnapshot
    from ecu_monitor.runtime.publishers import LiveMonitor

__all__ = ["DEFAULT_CONFIG", "ServiceListener", "add_subparser", "plot_report"]

#: Frames the ECU side may run ahead of the service before it waits (bounds the bus queue).
_MAX_BACKLOG = 2000


def add_subparser(subparsers: Any) -> None:
    """Register the ``demo`` subcommand."""
    parser = subparsers.add_parser(
        "demo",
        help="virtual ECU + the service on an in-process virtual CAN bus, gamma_Q = 1.2 injected mid-flight",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument("--out", default="demo-out", metavar="DIR", help="output directory (default demo-out)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the pilot's variations and the sensor noise")
    parser.add_argument("--inject-at", type=float, default=1800.0, metavar="S", help="injection time, s (1800)")
    parser.add_argument("--gamma-q", type=float, default=1.2, metavar="G", help="injected gamma_Q (default 1.2)")
    parser.add_argument("--mission", default="default", metavar="NAME", help="mission name or YAML file")
    parser.add_argument(
        "--cylinders",
        type=int,
        default=1,
        metavar="N",
        help="an engine with N (2-4) cylinders whose models differ, monitored per cylinder (four_cylinders.yaml's"
        " frames); gamma_Q is injected in cylinder 1 alone (default 1: one CHT channel)",
    )
    parser.add_argument(
        "--protocol",
        choices=("dbc", "dronecan", "mavlink"),
        default="dbc",
        help="what the virtual ECU and the service speak: engine.dbc/health.dbc frames (dbc, default), DroneCAN, or"
        " MAVLink (the autopilot's stream in, HEARTBEAT/STATUSTEXT/NAMED_VALUE_FLOAT out; one CHT channel)",
    )
    parser.set_defaults(func=announce_compiles(_run))  # a first run says it compiles


class ServiceListener:
    """The service side of the demo: pipeline.advance_to + feed per frame, health frames sent back.

    A python-can message recipient: can.Notifier calls it with each frame, and ``on_error`` with what a
    frame's handling raised (kept in :attr:`failure`: the demo's main thread raises it, the flight cannot go
    on without the service).
    """

    def __init__(self, pipeline: LiveMonitor, bus: can.BusABC) -> None:
        import can

        self.send_error = can.CanError
        self.pipeline = pipeline
        self.bus = bus
        self.lock = threading.Lock()
        self.rows: list[HealthSnapshot] = []
        self.processed = 0
        self.failure: Exception | None = None

    def on_message_received(self, msg: can.Message) -> None:
        with self.lock:
            due = self.pipeline.advance_to(msg.timestamp)
            self.pipeline.feed(msg)
            self.rows.extend(self.pipeline.drain_rows())
            self.processed += 1
        for frame in due:
            try:
                self.bus.send(frame)
            except self.send_error:
                self.pipeline.counters["send_errors"] += 1

    __call__ = on_message_received

    def on_error(self, exc: Exception) -> None:
        if self.failure is None:
            self.failure = exc

    def check(self) -> None:
        """Raise what the service side raised, if it did."""
        if self.failure is not None:
            raise self.failure


def _run(args: argparse.Namespace) -> int:
    import can

    from ecu_monitor.config import load_config
    from ecu_monitor.runtime.publishers import LiveMonitor
    from virtual_bus.cylinders import cylinder_models
    from virtual_bus.missions import load_mission
    from virtual_bus.plant import Degradation, collect, iter_steps, record_every
    from virtual_bus.recorder import frame_encoder

    out = prepare_output_dir(args.out, "--out", ConfigError)
    mission = load_mission(args.mission)
    if args.protocol == "mavlink":
        if args.cylinders != 1:
            raise ConfigError("--cylinders: MAVLink's EFI_STATUS carries one CHT: --protocol mavlink flies one channel")
        return _run_mavlink(args, out, mission, load_config(MAVLINK_CONFIG))
    if args.cylinders == 1:
        config = load_config(DRONECAN_CONFIG if args.protocol == "dronecan" else DEFAULT_CONFIG)
    else:
        config = cylinder_config(args.cylinders, args.protocol)
    params = config.load_params()
    heads = cylinder_models(params, args.cylinders, seed=args.seed) if args.cylinders > 1 else ()
    injection = Degradation("gamma_q", args.gamma_q, args.inject_at, cylinder=1 if heads else None)
    pipeline = LiveMonitor(config, heads or params)
    channel = f"ecu-monitor-demo-{os.getpid()}"
    ecu_bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    service_bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    listener = ServiceListener(pipeline, service_bus)
    notifier = can.Notifier(service_bus, [listener], timeout=0.1)
    encoder = frame_encoder(args.protocol, cht_limit_c=params.cht_limit_c, cylinders=len(heads) or 1)
    tty = sys.stderr.isatty()
    started = time.perf_counter()
    counts = {"sent": 0, "health_back": 0}
    last_line = [0.0]

    def progress(t_mission: float) -> None:
        now = time.perf_counter()
        if now - last_line[0] < (0.5 if tty else 10.0):
            return
        last_line[0] = now
        with listener.lock:
            snap = pipeline.snapshot()
        line = (f"demo: t = {t_mission:6.0f} s  CHT measured {snap.cht_meas_c:5.1f}  estimated {snap.cht_est_c:6.2f}"
                f" degC  state {snap.state:<12s} gamma_Q {snap.gamma_q:4.2f}")  # fmt: skip
        print(f"\r{line}" if tty else line, end="" if tty else "\n", file=sys.stderr, flush=True)

    def fly() -> Iterator[Any]:
        for block in iter_steps(mission, params, degradation=(injection,), seed=args.seed, cylinders=heads):
            for msg in encoder.frames(block):
                while counts["sent"] - listener.processed > _MAX_BACKLOG:
                    listener.check()
                    time.sleep(0.0005)
                ecu_bus.send(msg)
                counts["sent"] += 1
            while ecu_bus.recv(timeout=0.0) is not None:  # health frames, as the autopilot sees them
                counts["health_back"] += 1
            progress(float(block.time_s[-1]))
            yield block

    try:
        log: FlightLog = collect(fly(), record_every(0.02, 0.1), source=f"demo:{mission.name}:seed={args.seed}")
        deadline = time.perf_counter() + 30.0
        while listener.processed < counts["sent"] and time.perf_counter() < deadline:
            listener.check()
            time.sleep(0.01)
        listener.check()
    finally:
        notifier.stop()
        while ecu_bus.recv(timeout=0.05) is not None:
            counts["health_back"] += 1
        ecu_bus.shutdown()
        service_bus.shutdown()
    wall = time.perf_counter() - started
    if tty:
        print(file=sys.stderr)
    rows = listener.rows
    c = pipeline.counters
    back = "DroneCAN node" if args.protocol == "dronecan" else "health"
    print(
        f"flew {log.duration_s / 60.0:.1f} min of mission {mission.name} in {wall:.1f} s "
        f"({log.duration_s / wall:.0f}x real time); {counts['sent']} frames over the virtual bus, "
        f"{c['ok']} decoded, {c['malformed']} malformed, {counts['health_back']} {back} frames back"
    )
    plots = _write_report(
        args, out, log, rows, mission=mission.name, cht_limit_c=params.cht_limit_c, cylinders=bool(heads)
    )
    print(f"wrote {out}/flight.csv, health.csv ({len(rows)} rows){plots}")
    return 0


def _write_report(
    args: argparse.Namespace,
    out: Path,
    log: FlightLog,
    rows: list[HealthSnapshot],
    *,
    mission: str,
    cht_limit_c: float,
    cylinders: bool,
) -> str:
    """flight.csv, health.csv and the plots written, the detection line printed; returns the plots' part of the
    closing line."""
    from ecu_monitor.flightlog import write_csv
    from ecu_monitor.offline.replay import write_health_csv

    write_csv(log, out / "flight.csv")
    write_health_csv(rows, out / "health.csv")
    detected = _first(rows, "DEGRADED")
    suspect = _first(rows, "SUSPECT")
    try:
        plot_report(log, rows, out, cht_limit_c, args.inject_at, args.gamma_q, detected)
        plots = ", cht.png, detection.png, gammas.png, headroom.png" + (", cylinders.png" if cylinders else "")
    except ModuleNotFoundError as exc:  # the daemon's lean install: CSVs only
        if exc.name != "matplotlib":
            raise
        plots = "; no plots: pip install 'ecu-monitor[tools]' for them"
    if args.inject_at >= log.duration_s:
        print(
            f"gamma_Q = {args.gamma_q:g} NOT injected: --inject-at {args.inject_at:g} s is after the end of the flight"
            f" ({log.duration_s:.0f} s of mission {mission})"
        )
    elif detected is None:
        print(
            f"gamma_Q = {args.gamma_q:g} injected at t = {args.inject_at:.0f} s: NOT detected by the end of the flight"
        )
    else:
        lead = f" (SUSPECT from t = {suspect:.1f} s)" if suspect is not None else ""
        # the last isolable estimate: at the end of a flight (descent, ground) the gammas cannot be told apart
        isolated = [r for r in rows if not r.not_isolable and math.isfinite(r.gamma_q)]
        estimate = (
            f"gamma_Q estimate {isolated[-1].gamma_q:.3f} (last isolable, t = {isolated[-1].time_s:.0f} s)"
            if isolated
            else "gamma_Q not isolable during the flight"
        )
        print(
            f"gamma_Q = {args.gamma_q:g} injected at t = {args.inject_at:.0f} s: DEGRADED at t = {detected:.1f} s, "
            f"detected after {detected - args.inject_at:.1f} s{lead}; {estimate}"
        )
    return plots


#: MAV_SEVERITY names (common.xml), for the STATUSTEXT lines of the MAVLink demo.
_SEVERITY_NAMES = ("EMERGENCY", "ALERT", "CRITICAL", "ERROR", "WARNING", "NOTICE", "INFO", "DEBUG")


def _run_mavlink(args: argparse.Namespace, out: Path, mission: Any, config: ServiceConfig) -> int:
    """The demo over MAVLink (module docstring): the virtual autopilot's messages straight into the service."""
    from ecu_monitor.bus.mavlink import mavlink_module
    from ecu_monitor.runtime.publishers import LiveMonitor
    from virtual_bus.mavlink_emitter import MavlinkFrameEncoder
    from virtual_bus.plant import Degradation, collect, iter_steps, record_every

    params = config.load_params()
    injection = Degradation("gamma_q", args.gamma_q, args.inject_at)
    monitor = LiveMonitor(config, params)
    encoder = MavlinkFrameEncoder()
    parser = mavlink_module().MAVLink(None)  # the bytes of each message parsed as a link's receiver would
    parser.robust_parsing = True
    rows: list[HealthSnapshot] = []
    sent: dict[str, int] = {}
    back: dict[str, int] = {}
    texts: list[tuple[float, int, str]] = []  # (mission time s, severity, the whole text)
    chunks: dict[int, list[str]] = {}  # STATUSTEXT id -> chunks so far (the last one is shorter than 50)
    tty = sys.stderr.isatty()
    started = time.perf_counter()
    last_line = [0.0]

    def take(time_s: float, messages: list[Any]) -> None:
        for msg in messages:
            kind = msg.get_type()
            back[kind] = back.get(kind, 0) + 1
            if kind != "STATUSTEXT":
                continue
            parts = chunks.setdefault(msg.id, []) if msg.id else []
            parts.append(msg.text)
            if msg.id and len(msg.text) == 50:
                continue
            chunks.pop(msg.id, None)
            texts.append((time_s, int(msg.severity), "".join(parts)))

    def fly() -> Iterator[Any]:
        for block in iter_steps(mission, params, degradation=(injection,), seed=args.seed):
            for frame in encoder.frames(block):
                sent[frame.name] = sent.get(frame.name, 0) + 1
                for msg in parser.parse_buffer(frame.data) or ():
                    take(frame.timestamp, monitor.advance_to(frame.timestamp))
                    monitor.feed(msg)
                rows.extend(monitor.drain_rows())
            now = time.perf_counter()
            if now - last_line[0] >= (0.5 if tty else 10.0):
                last_line[0] = now
                snap = monitor.snapshot()
                line = (f"demo: t = {block.time_s[-1]:6.0f} s  CHT measured {snap.cht_meas_c:5.1f}  estimated "
                        f"{snap.cht_est_c:6.2f} degC  state {snap.state:<12s} gamma_Q {snap.gamma_q:4.2f}")  # fmt: skip
                print(f"\r{line}" if tty else line, end="" if tty else "\n", file=sys.stderr, flush=True)
            yield block

    log: FlightLog = collect(fly(), record_every(0.02, 0.1), source=f"demo:{mission.name}:seed={args.seed}")
    wall = time.perf_counter() - started
    if tty:
        print(file=sys.stderr)
    c = monitor.counters
    print(
        f"flew {log.duration_s / 60.0:.1f} min of mission {mission.name} in {wall:.1f} s "
        f"({log.duration_s / wall:.0f}x real time); {sum(sent.values())} MAVLink messages from the virtual autopilot"
        f" ({', '.join(f'{n} {k}' for k, n in sent.items())}), {c['ok']} decoded, {c['malformed']} malformed;"
        f" the service sent {', '.join(f'{n} {k}' for k, n in sorted(back.items()))}"
    )
    print("STATUSTEXT, as the ground station shows it:")
    for time_s, severity, text in texts:
        print(f"  t = {time_s:7.1f} s  {_SEVERITY_NAMES[severity]:<8s}  {text}")
    with atomic_output(out / "statustext.csv", text=True) as f:
        f.write("time_s,severity,text\n")
        f.writelines(f'{time_s:.1f},{_SEVERITY_NAMES[severity]},"{text}"\n' for time_s, severity, text in texts)
    plots = _write_report(args, out, log, rows, mission=mission.name, cht_limit_c=params.cht_limit_c, cylinders=False)
    print(f"wrote {out}/flight.csv, health.csv ({len(rows)} rows), statustext.csv ({len(texts)} texts){plots}")
    return 0


def cylinder_config(count: int, protocol: str = "dbc") -> ServiceConfig:
    """The shipped four_cylinders.yaml for an engine of ``count`` (2-4) cylinders: cht1_c .. cht<count>_c;
    ``protocol="dronecan"``: the shipped dronecan.yaml with those inputs on ``cylinder_status[0..count-1]``
    and four_cylinders.yaml's cylinders and health sections."""
    from ecu_monitor.config import parse_config
    from ecu_monitor.shipped import resolve_file
    from ecu_monitor.yamlfile import load_yaml_file

    if not 2 <= count <= 4:
        raise ConfigError(f"--cylinders: expected 1 to 4 (the cylinders of ECU_Cht1to4), got {count}")
    path = resolve_file("four_cylinders.yaml", "config")
    data = load_yaml_file(path, "config file", ConfigError)
    for n in range(count + 1, 5):
        del data["inputs"][f"cht{n}_c"]
    if protocol != "dronecan":
        return parse_config(data, path)
    dronecan_path = resolve_file("dronecan.yaml", "config")
    dronecan = load_yaml_file(dronecan_path, "config file", ConfigError)
    inputs = {name: spec for name, spec in dronecan["inputs"].items() if not name.startswith("cht")}
    field = "uavcan.equipment.ice.reciprocating.Status.cylinder_status[{}].cylinder_head_temperature"
    for n in range(1, count + 1):
        inputs[f"cht{n}_c"] = {"field": field.format(n - 1), "unit": "K", "stale_after_s": 1.0}
    dronecan.update(inputs=inputs, cylinders=data["cylinders"], health=data["health"])
    return parse_config(dronecan, dronecan_path)


def _first(rows: list[HealthSnapshot], state: str) -> float | None:
    return next((r.time_s for r in rows if r.state == state), None)


def plot_report(
    log: FlightLog,
    rows: list[HealthSnapshot],
    out: Path,
    cht_limit_c: float,
    inject_at_s: float,
    gamma_q: float,
    detected_s: float | None,
) -> None:
    """The four demo plots (time in minutes): cht.png, detection.png, gammas.png, headroom.png."""
    import matplotlib
    import numpy as np

    from ecu_monitor.pipeline.output_table import STATES

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t_log = log.time_s / 60.0
    t = np.array([r.time_s for r in rows]) / 60.0

    def column(name: str) -> np.ndarray:
        return np.array([getattr(r, name) for r in rows], dtype=float)

    def marks(ax: Any) -> None:
        ax.axvline(inject_at_s / 60.0, color="tab:purple", ls=":", lw=1.2, label=f"gamma_Q = {gamma_q:g} injected")
        if detected_s is not None:
            ax.axvline(detected_s / 60.0, color="tab:red", ls="-.", lw=1.2, label="DEGRADED")
        ax.grid(alpha=0.3)
        ax.set_xlabel("mission time (min)")

    fig, ax = plt.subplots(figsize=(11, 5))
    ax.plot(t_log, log["cht_c"], lw=0.6, color="tab:orange", label="CHT measured (1 degC sensor)")
    ax.plot(t_log, log["cht_true_c"], lw=1.4, color="black", label="CHT true")
    ax.plot(t, column("cht_est_c"), lw=0.9, color="tab:blue", ls="--", label="CHT estimated (service)")
    ax.axhline(cht_limit_c, color="tab:red", ls="--", lw=1.0, label=f"limit {cht_limit_c:.0f} degC")
    ax.set_ylim(top=max(cht_limit_c, float(np.max(log["cht_c"]))) + 8.0)
    ax.set_ylabel("CHT (degC)")
    ax.set_title("Cylinder head temperature: virtual ECU truth, its sensor, and the service's estimate")
    marks(ax)
    ax.legend(loc="lower center", fontsize=8)
    fig.tight_layout()
    save_figure(fig, out / "cht.png", dpi=110)
    plt.close(fig)

    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(11, 6), sharex=True, height_ratios=(2, 1))
    ax1.plot(t, column("deviation"), lw=0.7, color="tab:blue", label="model-deviation symptom (Health_Status)")
    ax1.axhline(0.0, color="grey", lw=0.6)
    ax1.set_ylabel("deviation (degC/s)")
    ax1.set_title("Detection: the CBEKF model-deviation symptom and the detector's verdict")
    marks(ax1)
    ax1.set_xlabel("")
    ax1.legend(loc="upper left", fontsize=8)
    codes = np.array([STATES.index(r.state) for r in rows])
    ax2.step(t, codes, where="post", color="tab:red", lw=1.0)
    ax2.set_yticks(range(len(STATES)), STATES, fontsize=7)
    ax2.set_ylim(-0.5, len(STATES) - 0.5)
    ax2.set_ylabel("state")
    marks(ax2)
    fig.tight_layout()
    save_figure(fig, out / "detection.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(11, 4.5))
    ax.plot(t, column("gamma_q"), lw=1.0, color="tab:blue", label="gamma_Q estimate (heat in)")
    ax.plot(t, column("gamma_d"), lw=1.0, color="tab:green", label="gamma_D estimate (dissipation)")
    ax.plot(t_log, log["gamma_q"], lw=1.4, color="tab:blue", ls=":", label="gamma_Q true")
    ax.plot(t_log, log["gamma_d"], lw=1.4, color="tab:green", ls=":", label="gamma_D true")
    ax.set_ylabel("degradation factor")
    ax.set_title("Isolation: gamma_Q and gamma_D estimated online (Health_Isolation) against the truth")
    marks(ax)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    save_figure(fig, out / "gammas.png", dpi=110)
    plt.close(fig)

    if rows and rows[0].cylinders:
        _plot_cylinders(log, rows, out, marks)

    fig, ax = plt.subplots(figsize=(11, 4.5))
    headroom = column("headroom_s")
    ax.plot(t, np.where(headroom >= 6000.0, np.nan, headroom), lw=1.0, color="tab:red",
            label="time to the CHT limit at the present power")  # fmt: skip
    limited = headroom < 6000.0
    ax.fill_between(t, 0, 1, where=~limited & np.isfinite(headroom), color="tab:green", alpha=0.12,
                    transform=ax.get_xaxis_transform(), label="not limited (steady state below the limit)")  # fmt: skip
    ax.set_ylabel("thermal headroom (s)")
    ax.set_title("Thermal headroom (Health_Isolation.ThermalHeadroom)")
    marks(ax)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    save_figure(fig, out / "headroom.png", dpi=110)
    plt.close(fig)


def _plot_cylinders(log: FlightLog, rows: list[HealthSnapshot], out: Path, marks: Any) -> None:
    """cylinders.png: each cylinder's CHT estimate (and truth), the CHT spread and hottest cylinder, each
    cylinder's gamma_Q estimate (and truth)."""
    import matplotlib.pyplot as plt
    import numpy as np

    t_log = log.time_s / 60.0
    t = np.array([r.time_s for r in rows]) / 60.0
    count = len(rows[0].cylinders)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    fig, (ax1, ax2, ax3) = plt.subplots(3, 1, figsize=(11, 9), sharex=True, height_ratios=(2, 1, 1.3))
    for i in range(count):
        colour = colours[i % len(colours)]
        ax1.plot(t, [r.cylinders[i].cht_est_c for r in rows], lw=0.9, color=colour, label=f"cylinder {i + 1} estimate")
        if log.has(f"cyl{i + 1}_cht_true_c"):
            ax1.plot(t_log, log[f"cyl{i + 1}_cht_true_c"], lw=0.6, ls=":", color=colour)
        ax3.plot(t, [r.cylinders[i].gamma_q for r in rows], lw=0.9, color=colour, label=f"cylinder {i + 1} gamma_Q")
        if log.has(f"cyl{i + 1}_gamma_q"):
            ax3.plot(t_log, log[f"cyl{i + 1}_gamma_q"], lw=1.2, ls=":", color=colour)
    ax1.set_ylabel("CHT (degC)")
    ax1.set_title("Every cylinder: CHT estimates (dotted: truth), spread and hottest cylinder, gamma_Q (dotted: truth)")
    ax1.legend(loc="lower center", fontsize=8, ncol=count)
    ax2.plot(t, [r.cht_spread_c for r in rows], lw=0.9, color="black", label="CHT spread (hottest - coldest estimate)")
    hottest = ax2.twinx()
    hottest.step(t, [r.hottest_cylinder for r in rows], where="post", lw=0.8, color="tab:red")
    hottest.set_ylabel("hottest cylinder", color="tab:red")
    hottest.set_yticks(range(1, count + 1))
    ax2.set_ylabel("spread (degC)")
    ax2.legend(loc="upper left", fontsize=8)
    ax3.set_ylabel("gamma_Q")
    ax3.legend(loc="upper left", fontsize=8)
    for ax in (ax1, ax2, ax3):
        marks(ax)
    fig.tight_layout()
    save_figure(fig, out / "cylinders.png", dpi=110)
    plt.close(fig)
