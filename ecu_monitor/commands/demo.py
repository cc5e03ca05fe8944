"""``ecu-monitor demo [--out DIR] [--seed N] [--inject-at S] [--gamma-q G]``: a first demo of the virtual ECU.

Flies the default step-climb mission (virtual_bus/missions/default.yaml) through the truth plant with
a heat-input degradation gamma_Q = 1.2 injected mid-flight (t = 1800 s, during the climb), faster
than real time, with a progress line on stderr, and writes DIR/flight.csv (canonical columns plus the
truth: cht_true_c, gamma_q, gamma_d) and DIR/flight.png (CHT measured and true against the limit,
throttle, altitude, degradation factors). It does not run the monitoring service yet: the full
service demo (DESIGN.md section 4) replaces this module when the service lands.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from ecu_monitor.errors import ConfigError
from ecu_monitor.flightlog import FlightLog, write_csv
from ecu_monitor.model import paper_table_a1

__all__ = ["add_subparser", "plot_flight"]


def add_subparser(subparsers: Any) -> None:
    """Register the ``demo`` subcommand."""
    parser = subparsers.add_parser(
        "demo",
        help="fly the default mission on the virtual ECU with a degradation injected; write a CSV and a plot",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument("--out", default="demo-out", metavar="DIR", help="output directory (default demo-out)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the pilot's variations and the sensor noise")
    parser.add_argument("--inject-at", type=float, default=1800.0, metavar="S", help="injection time, s (1800)")
    parser.add_argument("--gamma-q", type=float, default=1.2, metavar="G", help="injected gamma_Q (default 1.2)")
    parser.set_defaults(func=_run)


def plot_flight(log: FlightLog, path: Path, cht_limit_c: float, title: str) -> None:
    """Four stacked panels over time (min): CHT measured/true with the limit, throttle, altitude, gammas."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t_min = log.time_s / 60.0
    fig, axes = plt.subplots(4, 1, figsize=(11, 10), sharex=True, height_ratios=(3, 1.3, 1.3, 1))
    ax = axes[0]
    ax.plot(t_min, log["cht_c"], lw=0.6, color="tab:orange", label="CHT measured (1 degC sensor)")
    ax.plot(t_min, log["cht_true_c"], lw=1.0, color="black", label="CHT true")
    ax.axhline(cht_limit_c, color="tab:red", ls="--", lw=1.0, label=f"limit {cht_limit_c:.0f} degC")
    ax.set_ylim(top=max(cht_limit_c, float(log["cht_true_c"].max())) + 8.0)
    ax.set_ylabel("CHT (degC)")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(title, fontsize=10)
    axes[1].plot(t_min, log["throttle_pct"], lw=0.6, color="tab:blue")
    axes[1].set_ylabel("throttle (%)")
    axes[1].set_ylim(0, 105)
    axes[2].plot(t_min, log["altitude_m"], lw=0.8, color="tab:green")
    axes[2].set_ylabel("altitude (m)")
    axes[3].plot(t_min, log["gamma_q"], lw=1.2, label="gamma_Q (heat in)")
    axes[3].plot(t_min, log["gamma_d"], lw=1.2, ls="--", label="gamma_D (dissipation)")
    axes[3].set_ylabel("degradation")
    axes[3].legend(loc="upper left", fontsize=8)
    axes[3].set_xlabel("mission time (min)")
    for a in axes:
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _run(args: argparse.Namespace) -> int:
    from virtual_bus.missions import load_mission
    from virtual_bus.plant import Degradation, collect, iter_steps, record_every

    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{out}: cannot create output directory: {exc.strerror or exc}") from None
    mission = load_mission("default")
    params = paper_table_a1()
    injection = Degradation("gamma_q", args.gamma_q, args.inject_at)
    start = time.perf_counter()
    tty = sys.stderr.isatty()
    last = [0.0]

    def progress(blocks: Any) -> Any:
        for block in blocks:
            now = time.perf_counter()
            if now - last[0] >= (0.5 if tty else 5.0):
                last[0] = now
                t = float(block.time_s[-1])
                cht, gamma_q = block.measured.cht_c[-1], block.gamma_q[-1]
                line = f"demo: flying {mission.name}: t = {t:5.0f} s, CHT {cht:.0f} degC, gamma_Q {gamma_q:.2f}"
                print(f"\r{line}" if tty else line, end="" if tty else "\n", file=sys.stderr, flush=True)
            yield block

    blocks = iter_steps(mission, params, degradation=(injection,), seed=args.seed)
    log = collect(progress(blocks), record_every(0.02, 0.1), source=f"demo:{mission.name}:seed={args.seed}")
    if tty:
        print(file=sys.stderr)
    csv_path, png_path = out / "flight.csv", out / "flight.png"
    write_csv(log, csv_path)
    title = f"virtual ECU, mission {mission.name}, {injection} (seed {args.seed})"
    plot_flight(log, png_path, params.cht_limit_c, title)
    cht_true = log["cht_true_c"]
    print(
        f"flew {log.duration_s / 60.0:.1f} min of mission {mission.name} in {time.perf_counter() - start:.1f} s;"
        f" injected {injection}; max CHT {log['cht_c'].max():.0f} degC measured, {cht_true.max():.1f} degC true"
        f" (limit {params.cht_limit_c:.0f})"
    )
    print(f"wrote {csv_path} ({len(log)} rows) and {png_path}")
    return 0
