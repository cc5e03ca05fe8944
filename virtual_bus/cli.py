"""The ``virtual-ecu`` command line: fly a mission through the truth plant to files or onto a CAN bus.

    virtual-ecu record --mission FILE|NAME --out f.csv|f.asc|f.blf|f.log|f.tlog [--out ...] [--seed N]
                       [--degrade gamma_q=1.2@1800] [--degrade gamma_d=1.1@600:ramp=300]
                       [--effect airspeed_cooling] [--effect sensor_lag:time_constant_s=12] [--model model.yaml]
                       [--protocol dbc|dronecan|mavlink]
    virtual-ecu run --config FILE | --interface NAME --channel CH | --protocol mavlink --connection LINK
                    --mission FILE|NAME [--degrade ...] [--effect ...] [--realtime] [--speed X]
    virtual-ecu campaign --flights N --out-dir DIR [--wear gamma_q+0.005] [--format blf] [--duration S]
                         [--seed N] [--effect ...] [--model model.yaml] [--protocol ...]
    virtual-ecu jsbsim --aircraft c172x --mission pattern|cross_country|step_climb --out flight.csv [--seed N]

``campaign``: N flights of one engine, each a random mission of its own seed, with a per-flight degradation
schedule (``--wear gamma_q+0.005``: gamma_Q 1.0 on the first flight, 1.005 on the second, ..., from engine
start), one log per flight (``DIR/flight_001.blf`` ...), a day apart on the UNIX clock (virtual_bus/campaign.py):
``ecu-monitor replay LOG --history STATE_DIR`` each in turn gives the engine's history of slow wear.

``jsbsim``: one of JSBSim's piston aircraft flown through a seeded mission, its engine model's CHT, EGT, oil,
fuel flow and manifold pressure logged to a canonical CSV (virtual_bus/jsbsim_flight.py; the ``jsbsim`` extra).

``--protocol``: engine.dbc frames (dbc, the default), DroneCAN messages (virtual_bus/dronecan_emitter.py) or
an autopilot's MAVLink stream (virtual_bus/mavlink_emitter.py: recorded to a .tlog, sent over ``--connection``,
e.g. ``udpout:127.0.0.1:14550``, or over the counterpart of ``--config``'s ``mavlink.connection`` on this
machine); ``run --config`` takes the config's own ``protocol:`` when the option is not given.

Errors (bad mission file, bad --degrade syntax, unknown effect, bus that cannot open) print one line
and exit 2, as ``ecu-monitor`` does; ``--debug`` shows the traceback.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING, Any

from ecu_monitor.compile_cache import use_cache_dir
from ecu_monitor.errors import ConfigError, run_command
from ecu_monitor.shipped import shipped_files

if TYPE_CHECKING:  # the commands import these (numpy, python-can, the plant): --help stays light
    from ecu_monitor.model import ThermalParams
    from virtual_bus.busconfig import BusConfig
    from virtual_bus.emitter import EmitStats
    from virtual_bus.missions import Mission
    from virtual_bus.plant import StepBlock

__all__ = ["build_parser", "main"]


class _Progress:
    """A progress line on stderr, at most once a second: rewritten in place on a terminal, one line
    every 10 s otherwise."""

    def __init__(self, label: str) -> None:
        self.label = label
        self.tty = sys.stderr.isatty()
        self.start = self.last = time.perf_counter()
        self.shown = False

    def __call__(self, text: str) -> None:
        now = time.perf_counter()
        if now - self.last < (1.0 if self.tty else 10.0):
            return
        self.last = now
        line = f"{self.label}: {text} ({now - self.start:.0f} s elapsed)"
        if self.tty:
            print(f"\r{line}\033[K", end="", file=sys.stderr, flush=True)
        else:
            print(line, file=sys.stderr, flush=True)
        self.shown = True

    def done(self) -> None:
        if self.shown and self.tty:
            print(file=sys.stderr)


def _add_flight_options(parser: argparse.ArgumentParser) -> None:
    missions = ", ".join(name.removesuffix(".yaml") for name in shipped_files("mission"))  # list_missions(), light
    parser.add_argument(
        "--mission",
        default="default",
        metavar="FILE|NAME",
        help=f"mission YAML or a shipped mission's name ({missions}); default: default",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the pilot's variations and the sensor noise")
    parser.add_argument(
        "--degrade",
        action="append",
        default=[],
        metavar="SPEC",
        help="degradation event gamma_q|gamma_d=VALUE@START_S[:ramp=SECONDS][:cylinder=N] (repeatable)",
    )
    parser.add_argument(
        "--cylinders",
        type=int,
        default=1,
        metavar="N",
        help="an engine with N cylinders whose models differ (heat +-8 %%, wall mass +-5 %%, drawn from --seed):"
        " frames of cylinders.dbc, CSV columns cht1_c..chtN_c (default 1)",
    )
    parser.add_argument(
        "--effect",
        action="append",
        default=[],
        metavar="SPEC",
        help="unmodelled effect in the truth: NAME or NAME:key=value,... (airspeed_cooling, density_cooling,"
        " sensor_lag, mixture_cooling; repeatable)",
    )
    parser.add_argument("--model", metavar="model.yaml", help="truth model (default: the paper's Table A1)")
    parser.add_argument("--dt", type=float, default=0.02, help="integration step, s (default 0.02)")
    parser.add_argument(
        "--protocol",
        choices=("dbc", "dronecan", "mavlink"),  # virtual_bus.recorder.PROTOCOLS (not imported: --help stays light)
        help="frames of engine.dbc (dbc), DroneCAN messages (dronecan) or an autopilot's MAVLink stream (mavlink);"
        " default dbc, or run --config's protocol",
    )


class _Flight:
    """The parsed flight options: mission, truth model, effects and degradation."""

    def __init__(self, args: argparse.Namespace) -> None:
        from ecu_monitor.model import load_model, paper_table_a1
        from virtual_bus.cylinders import cylinder_models
        from virtual_bus.missions import load_mission
        from virtual_bus.plant import Degradation, parse_effects

        self.mission: Mission = load_mission(args.mission)
        self.params: ThermalParams = load_model(args.model) if args.model else paper_table_a1()
        self.degradation = tuple(Degradation.parse(spec) for spec in args.degrade)
        self.effects = parse_effects(args.effect, base=self.params.effects) if args.effect else None
        self.seed: int = args.seed
        self.dt_s: float = args.dt
        self.cylinders = cylinder_models(self.params, args.cylinders, seed=args.seed) if args.cylinders != 1 else ()

    def describe(self) -> str:
        effects = (self.effects or self.params.effects).active
        parts = [f"mission {self.mission.name}", f"seed {self.seed}"]
        if self.cylinders:
            parts.append(f"{len(self.cylinders)} cylinders")
        parts.append("degradation " + (", ".join(map(str, self.degradation)) or "none"))
        parts.append("effects " + (", ".join(effects) or "none"))
        return "; ".join(parts)

    def blocks(self) -> Iterator[StepBlock]:
        """The flown steps of this flight, block by block (the truth plant, its sensors)."""
        from virtual_bus.plant import iter_steps

        return iter_steps(self.mission, self.params, effects=self.effects, degradation=self.degradation,
                          seed=self.seed, dt_s=self.dt_s, cylinders=self.cylinders)  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    """The ``virtual-ecu`` parser with its two subcommands."""
    parser = argparse.ArgumentParser(
        prog="virtual-ecu",
        description="Virtual engine ECU: fly a mission through the thermal truth plant to files or onto a CAN bus.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on error")
    parser.add_argument("--log-level", default="WARNING", help="DEBUG, INFO, WARNING or ERROR")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    rec = sub.add_parser(
        "record", help="simulate a mission to a canonical CSV and/or CAN logs (.asc, .blf, .log) or a MAVLink .tlog"
    )
    _add_flight_options(rec)
    rec.add_argument(
        "--out",
        action="append",
        default=[],
        metavar="FILE",
        help="output .csv, .asc, .blf, .log or (--protocol mavlink) .tlog (repeatable)",
    )
    rec.add_argument("--record-dt", type=float, default=0.1, help="CSV sample step, s (default 0.1)")
    rec.add_argument(
        "--start-time",
        type=float,
        default=0.0,
        help="timestamp of mission time 0 in the CAN logs and the .tlog, s (a .tlog's clock: s since 1970; default 0)",
    )
    rec.set_defaults(func=_record)

    run = sub.add_parser("run", help="emit a mission's frames onto a CAN bus")
    _add_flight_options(run)
    run.add_argument("--config", metavar="FILE", help="YAML file with a bus: {interface, channel, ...} section")
    run.add_argument("--interface", help="python-can interface (overrides the config)")
    run.add_argument("--channel", help="bus channel (overrides the config)")
    run.add_argument(
        "--connection",
        metavar="LINK",
        help="--protocol mavlink: where to send, as MAVProxy takes it (udpout:127.0.0.1:14550, /dev/ttyUSB0,57600);"
        " default: the counterpart of --config's mavlink.connection on this machine",
    )
    run.add_argument(
        "--realtime", action="store_true", help="pace frames to the wall clock (default: as fast as possible)"
    )
    run.add_argument("--speed", type=float, default=1.0, help="with --realtime: times real time (default 1)")
    run.add_argument("--start-time", type=float, default=0.0, help="timestamp of mission time 0, s (default 0)")
    run.set_defaults(func=_run)

    camp = sub.add_parser("campaign", help="fly N random missions of one engine with a per-flight degradation schedule")
    camp.add_argument("--flights", type=int, required=True, metavar="N", help="number of flights")
    camp.add_argument("--out-dir", required=True, metavar="DIR", help="one log per flight: DIR/flight_001.<format> ...")
    camp.add_argument(
        "--wear",
        default="gamma_q+0",
        metavar="SPEC",
        help="per-flight schedule gamma_q|gamma_d+STEP from 1.0 on the first flight (default gamma_q+0: nominal)",
    )
    camp.add_argument("--format", choices=("blf", "asc", "log", "csv"), default="blf", help="log format (default blf)")
    camp.add_argument("--duration", type=float, default=3600.0, help="each random mission's length, s (default 3600)")
    camp.add_argument("--seed", type=int, default=0, help="the campaign's seed (each flight draws its own from it)")
    camp.add_argument("--start-time", type=float, default=1.7e9, help="UNIX time of the first flight (default 1.7e9)")
    camp.add_argument(
        "--effect", action="append", default=[], metavar="SPEC", help="unmodelled effect in the truth (as record)"
    )
    camp.add_argument("--model", metavar="model.yaml", help="truth model (default: the paper's Table A1)")
    camp.add_argument("--protocol", choices=("dbc", "dronecan"), default="dbc", help="frames (default dbc)")
    camp.set_defaults(func=_campaign)

    jsb = sub.add_parser(
        "jsbsim", help="fly one of JSBSim's piston aircraft (its own engine model) to a canonical CSV (docs/jsbsim.md)"
    )
    jsb.add_argument(
        "--aircraft", default="c172x", help="a piston aircraft of the jsbsim package: c172x, c172p, c172r, pa28, c182"
        " or c310 (default c172x)"
    )  # fmt: skip
    jsb.add_argument(
        "--mission", default="pattern", help="pattern, cross_country or step_climb, drawn from --seed (default pattern)"
    )
    jsb.add_argument("--seed", type=int, default=0, help="seed of the mission: field, day, levels, power, mixture")
    jsb.add_argument("--out", required=True, metavar="FILE.csv", help="the canonical flight CSV")
    jsb.add_argument("--record-dt", type=float, default=1.0, help="CSV sample step, s (default 1)")
    jsb.set_defaults(func=_jsbsim)
    return parser


def _jsbsim(args: argparse.Namespace) -> int:
    from ecu_monitor.flightlog import write_csv
    from ecu_monitor.userfiles import check_output_file
    from virtual_bus.jsbsim_flight import fly

    out = check_output_file(args.out, "--out", ConfigError)
    progress = _Progress(f"virtual-ecu jsbsim {args.aircraft} {args.mission}")
    log = fly(args.aircraft, args.mission, args.seed, record_dt_s=args.record_dt,
              progress=lambda t: progress(f"t = {t:.0f} s"))  # fmt: skip
    progress.done()
    write_csv(log, out)
    cht = log["cht_c"]
    print(f"{log.source}: flew {log.duration_s / 60.0:.1f} min, CHT {cht.min():.0f}-{cht.max():.0f} degC")
    print(f"wrote {out}: {len(log)} rows")
    return 0


def _campaign(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ecu_monitor.model import load_model, paper_table_a1
    from virtual_bus.campaign import WearSchedule, campaign_flights
    from virtual_bus.plant import parse_effects
    from virtual_bus.recorder import record

    schedule = WearSchedule.parse(args.wear)
    params = load_model(args.model) if args.model else paper_table_a1()
    effects = parse_effects(args.effect, base=params.effects) if args.effect else None
    out_dir = Path(args.out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{out_dir}: --out-dir: cannot create it ({exc.strerror})") from None
    flights = campaign_flights(args.flights, schedule, seed=args.seed, duration_s=args.duration,
                               start_time_s=args.start_time)  # fmt: skip
    for flight in flights:
        path = out_dir / f"flight_{flight.number:03d}.{args.format}"
        progress = _Progress(f"virtual-ecu campaign flight {flight.number}/{args.flights}")
        summary = record(flight.mission, [path], params, effects=effects, degradation=flight.degradation,
                         seed=flight.seed, start_time_s=flight.start_time_s, protocol=args.protocol,
                         progress=lambda t, p=progress: p(f"t = {t:.0f} s"))  # fmt: skip
        progress.done()
        print(f"{path}: {schedule.factor} {schedule.value(flight.number):.4f}, {summary.duration_s / 60.0:.0f} min,"
              f" max CHT {summary.max_cht_c:.0f} degC")  # fmt: skip
    return 0


def _record(args: argparse.Namespace) -> int:
    from virtual_bus.recorder import check_outputs, record

    outputs = check_outputs(args.out)
    flight = _Flight(args)
    progress = _Progress(f"virtual-ecu record {flight.mission.name}")
    summary = record(
        flight.mission,
        outputs,
        flight.params,
        effects=flight.effects,
        degradation=flight.degradation,
        seed=flight.seed,
        dt_s=flight.dt_s,
        record_dt_s=args.record_dt,
        progress=lambda t: progress(f"t = {t:.0f} s"),
        cylinders=flight.cylinders,
        protocol=args.protocol or "dbc",
        start_time_s=args.start_time,
    )
    progress.done()
    print(f"{flight.describe()}")
    print(
        f"flew {summary.duration_s:.1f} s ({summary.duration_s / 60.0:.1f} min); max CHT {summary.max_cht_c:.0f} degC"
        f" measured, {summary.max_cht_true_c:.1f} degC true (limit {flight.params.cht_limit_c:.0f} degC)"
    )
    for path, what in summary.files.items():
        print(f"wrote {path}: {what}")
    return 0


def _bus_config(args: argparse.Namespace) -> BusConfig:
    from virtual_bus.busconfig import BusConfig, load_bus_config

    if args.config:
        return load_bus_config(args.config).replace(args.interface, args.channel)
    if not (args.interface and args.channel):
        raise ConfigError("run: give --config FILE or both --interface and --channel")
    return BusConfig(args.interface, args.channel)


def _run(args: argparse.Namespace) -> int:
    from virtual_bus.busconfig import config_protocol, open_bus
    from virtual_bus.emitter import FrameEmitter
    from virtual_bus.recorder import frame_encoder

    protocol = args.protocol or (config_protocol(args.config) if args.config else "dbc")
    if protocol == "mavlink":
        return _run_mavlink(args)
    if args.connection:
        raise ConfigError("--connection: a MAVLink link, for --protocol mavlink (a CAN bus: --interface, --channel)")
    flight = _Flight(args)
    config = _bus_config(args)
    if not args.speed > 0.0:
        raise ConfigError(f"--speed: expected a positive factor, got {args.speed!r}")
    if args.realtime and args.speed > 1.0:
        # a daemon on the bus (ecu-monitor run) steps its filter on the wall clock, so frames paced
        # faster than real time compress the thermal dynamics it sees: a healthy engine looks degraded
        print(
            f"virtual-ecu: warning: --speed {args.speed:g} is faster than real time; a monitoring daemon on this bus"
            " runs on the wall clock and will misread the engine (use `ecu-monitor replay` on a recorded log"
            " for faster than real time)",
            file=sys.stderr,
        )
    progress = _Progress(f"virtual-ecu run {flight.mission.name} on {config.interface}:{config.channel}")

    def show(stats: EmitStats) -> None:
        t = stats.mission_time_s - args.start_time
        progress(f"t = {t:.0f} s, {stats.frames_sent} frames, {stats.send_errors} send errors")

    blocks = flight.blocks()
    count = len(flight.cylinders) or 1
    encoder = frame_encoder(
        protocol, cht_limit_c=flight.params.cht_limit_c, start_time_s=args.start_time, cylinders=count
    )
    with open_bus(config) as bus:
        emitter = FrameEmitter(bus, encoder, realtime=args.realtime, speed=args.speed, progress=show)
        stats = emitter.emit(blocks)
    progress.done()
    print(flight.describe())
    print(
        f"sent {stats.frames_sent} frames ({stats.send_errors} send errors) on {config.interface}:{config.channel};"
        f" mission time {stats.mission_time_s - args.start_time:.1f} s in {stats.wall_time_s:.1f} s wall"
    )
    return 0


def _run_mavlink(args: argparse.Namespace) -> int:
    """``run --protocol mavlink``: the autopilot's MAVLink stream over ``--connection`` (or the counterpart of the
    config's ``mavlink.connection``)."""
    from virtual_bus.busconfig import config_mavlink_connection
    from virtual_bus.mavlink_emitter import MavlinkEmitter, MavlinkFrameEncoder, emitter_connection

    if args.interface or args.channel:
        raise ConfigError("--interface/--channel: a CAN bus; --protocol mavlink sends over --connection")
    if args.cylinders != 1:
        print("virtual-ecu: note: EFI_STATUS carries one CHT: the cylinders' mean is sent", file=sys.stderr)
    if args.connection:
        link = args.connection
    elif args.config:
        link = emitter_connection(config_mavlink_connection(args.config))
    else:
        raise ConfigError(
            "run --protocol mavlink: give --connection LINK (e.g. udpout:127.0.0.1:14550) or --config FILE"
        )
    flight = _Flight(args)
    if not args.speed > 0.0:
        raise ConfigError(f"--speed: expected a positive factor, got {args.speed!r}")
    progress = _Progress(f"virtual-ecu run {flight.mission.name} on {link}")

    def show(stats: EmitStats) -> None:
        t = stats.mission_time_s - args.start_time
        progress(f"t = {t:.0f} s, {stats.frames_sent} messages, {stats.send_errors} send errors")

    blocks = flight.blocks()
    encoder = MavlinkFrameEncoder(start_time_s=args.start_time)
    emitter = MavlinkEmitter(link, encoder, realtime=args.realtime, speed=args.speed, progress=show)
    try:
        stats = emitter.emit(blocks)
    finally:
        emitter.close()
    progress.done()
    print(flight.describe())
    print(
        f"sent {stats.frames_sent} MAVLink messages ({stats.send_errors} send errors) on {link};"
        f" mission time {stats.mission_time_s - args.start_time:.1f} s in {stats.wall_time_s:.1f} s wall"
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``virtual-ecu``; returns the process exit code."""
    use_cache_dir()  # NUMBA_CACHE_DIR before anything imports numba (unless the user set it)
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=getattr(logging, str(args.log_level).upper(), logging.WARNING),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    func: Any = getattr(args, "func", None)
    if func is None:
        parser.print_help()
        return 2
    return run_command("virtual-ecu", lambda: func(args), debug=args.debug)


if __name__ == "__main__":
    sys.exit(main())
