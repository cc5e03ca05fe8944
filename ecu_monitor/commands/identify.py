"""``ecu-monitor identify FLIGHT.csv [FLIGHT2.csv ...] --out model.yaml [--validate FLIGHT.csv ...]``.

PSO identification of the thermal model (C_w, R_Ce, tau_w and the visited heat-map breakpoints; the
radiative term anchors the scale and the altitude exponents a, b stay at the base values unless freed
with ``--free``) on one or more flights, then a least-squares polish. Shows a progress bar (iteration,
best cost, elapsed) on stderr, prints a table of mean / peak / RMS error in degC and % on every
training and validation flight, writes model.yaml (which every other command accepts) and, with
``--plots DIR``, PNG plots: measured vs simulated CHT per flight, cost per iteration, heat map.

The heat map's axes default to throttle_pct,rpm; a log without throttle but with fuel flow uses
fuel_flow_lph,rpm (say it with ``--heat-axes``). Foreign CSVs load through ``--mapping`` (g1000).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from ecu_monitor.bus.canlog import load_flight
from ecu_monitor.errors import FlightLogError, UserInputError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.identify import (
    DEFAULT_FREE,
    ErrorStats,
    PsoSettings,
    default_space,
    flight_errors,
    identify,
    model_inputs,
    simulate_flight,
)
from ecu_monitor.identify.report import error_table, plot_cost, plot_flight, plot_heat_map
from ecu_monitor.model import load_model, save_model

__all__ = ["add_subparser", "parse_grid", "parse_heat_axes"]

_DEFAULTS = PsoSettings()


def add_subparser(subparsers: Any) -> None:
    """Register the ``identify`` subcommand."""
    parser = subparsers.add_parser(
        "identify",
        help="identify the thermal model from flight logs (PSO) and write model.yaml",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("flights", nargs="+", metavar="FLIGHT.csv", help="training flight log(s)")
    parser.add_argument("--out", required=True, metavar="MODEL.yaml", help="identified model to write")
    parser.add_argument("--validate", nargs="+", default=[], metavar="FLIGHT.csv", help="held-out flight log(s)")
    parser.add_argument("--heat-axes", metavar="COL,COL", help="heat-map axes (default throttle_pct,rpm)")
    parser.add_argument("--grid", metavar="NxM", help="heat-map breakpoints from the data's quantiles, e.g. 4x4")
    parser.add_argument("--base", metavar="MODEL.yaml", help="starting / fixed values (default: paper Table A1)")
    parser.add_argument(
        "--free",
        metavar="NAMES",
        help=f"comma-separated free parameters (default {','.join(DEFAULT_FREE)}; also alpha_r_e, a, b,"
        " effects.<effect>.<parameter>)",
    )
    parser.add_argument("--particles", type=int, default=_DEFAULTS.particles, metavar="N", help="swarm size")
    parser.add_argument("--iterations", type=int, default=_DEFAULTS.iterations, metavar="N", help="PSO iterations")
    parser.add_argument("--seed", type=int, default=0, metavar="N", help="random seed (default 0)")
    parser.add_argument("--dt", type=float, default=_DEFAULTS.dt_s, metavar="S", help="integration step, s")
    parser.add_argument("--no-polish", action="store_true", help="skip the least-squares polish")
    parser.add_argument("--plots", metavar="DIR", help="write PNG plots into DIR")
    parser.add_argument("--mapping", metavar="MAPPING", help="mapping YAML (or shipped name: g1000) for foreign CSVs")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=_run)


def parse_heat_axes(text: str) -> tuple[str, str]:
    """'COL,COL' -> (x, y); UserInputError on anything else."""
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != 2 or not all(parts) or parts[0] == parts[1]:
        raise UserInputError(f"--heat-axes: expected two different column names as COL,COL, got {text!r}")
    return parts[0], parts[1]


def parse_grid(text: str) -> tuple[int, int]:
    """'NxM' -> (n, m) with 2 <= n, m <= 12; UserInputError otherwise."""
    parts = text.lower().split("x")
    try:
        n, m = (int(p) for p in parts)
    except ValueError:
        raise UserInputError(f"--grid: expected NxM such as 4x4, got {text!r}") from None
    if not (2 <= n <= 12 and 2 <= m <= 12):
        raise UserInputError(f"--grid: expected 2 to 12 breakpoints per axis, got {text!r}")
    return n, m


def _load(paths: list[str], mapping: str | None) -> list[FlightLog]:
    return [load_flight(p, mapping=mapping) for p in paths]


def _choose_axes(arg: str | None, flights: list[FlightLog]) -> tuple[str, str]:
    if arg:
        return parse_heat_axes(arg)
    first = flights[0]
    if not first.has("throttle_pct") and first.has("fuel_flow_lph"):
        print(f"{first.source}: no throttle_pct; heat map on fuel_flow_lph,rpm", file=sys.stderr)
        return "fuel_flow_lph", "rpm"
    return "throttle_pct", "rpm"


def _progress_bar(bar: Any) -> Callable[[int, float, float], None]:
    def progress(iteration: int, best: float, elapsed: float) -> None:
        bar.update(iteration - bar.n)
        bar.set_postfix_str(f"best {best:.4f} degC, {elapsed:.1f} s")

    return progress


def _settings(args: argparse.Namespace) -> PsoSettings:
    return PsoSettings(
        particles=args.particles,
        iterations=args.iterations,
        seed=args.seed,
        dt_s=args.dt,
        polish=not args.no_polish,
    )


def _run(args: argparse.Namespace) -> int:
    settings = _settings(args)  # validate the numbers and the output places before the (slow) work
    out = Path(args.out)
    if not out.parent.is_dir():
        raise UserInputError(f"{out}: the directory {out.parent} does not exist")
    if args.plots:
        _make_dir(Path(args.plots))
    flights = _load(args.flights, args.mapping)
    validation = _load(args.validate, args.mapping)
    axes = _choose_axes(args.heat_axes, flights)
    base = load_model(args.base) if args.base else None
    free = tuple(n.strip() for n in args.free.split(",") if n.strip()) if args.free else DEFAULT_FREE
    grid = parse_grid(args.grid) if args.grid else None
    space = default_space(flights, base=base, heat_axes=axes, grid=grid, free=free)
    for log in validation:  # fail early on a validation flight that lacks a column
        model_inputs(log, axes)
        if not log.has("cht_c"):
            raise FlightLogError(f"{log.source}: no column 'cht_c' (measured CHT) to validate against")
    bar = None if args.quiet else tqdm(total=settings.iterations, desc="identify", unit="it", file=sys.stderr)
    progress = None if bar is None else _progress_bar(bar)
    try:
        result = identify(flights, space=space, settings=settings, progress=progress)
    finally:
        if bar is not None:
            bar.close()
    params = result.params
    rows: list[tuple[str, str, ErrorStats]] = [
        ("train", Path(log.source).name, e) for log, e in zip(flights, result.train_errors, strict=True)
    ]
    rows += [("validate", Path(log.source).name, flight_errors(params, log)) for log in validation]
    n_cells = params.heat_map.shape[0] * params.heat_map.shape[1]
    summary = (
        f"{len(space.names)} coordinates ({len(space.heat_cells)}/{n_cells} heat-map breakpoints visited),"
        f" {result.evaluations} particle simulations ({result.failed_particles} failed), {result.restarts} restart(s),"
        f" {result.elapsed_s:.1f} s; cost PSO {result.pso_cost:.4f}"
        + (f", polished {result.polish_cost:.4f}" if result.polish_cost is not None else "")
        + " degC"
    )
    comment = "\n".join(
        [
            "Identified by: ecu-monitor identify " + " ".join(sys.argv[2:] if len(sys.argv) > 2 else args.flights),
            summary,
            "alpha_r_e anchors the common scale of c_w, r_ce, heat map (fixed at the base value);"
            f" free: {', '.join(free)}",
            *(
                f"{role} {name}: mean {e.mean_c:.2f} degC ({e.mean_pct:.2f} %), peak {e.peak_c:.2f} degC"
                f" ({e.peak_pct:.2f} %), RMS {e.rms_c:.2f} degC"
                for role, name, e in rows
            ),
        ]
    )
    try:
        save_model(params, out, comment=comment)
    except OSError as exc:
        raise UserInputError(f"{out}: cannot write the model ({exc.strerror})") from None
    print(error_table(rows))
    print(summary)
    print(
        f"c_w {params.c_w:.4g} J/degC, r_ce {params.r_ce:.4g} degC/W, tau_w {params.tau_w:.3g} s,"
        f" a {params.a:.3g}, b {params.b:.3g}; heat map {params.heat_map.x_axis} x {params.heat_map.y_axis}"
        f" {params.heat_map.shape[0]}x{params.heat_map.shape[1]} -> {args.out}"
    )
    if args.plots:
        _plots(Path(args.plots), result, flights, validation, rows)
    return 0


def _make_dir(directory: Path) -> None:
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserInputError(f"{directory}: cannot create the plot directory ({exc.strerror})") from None


def _plots(
    directory: Path,
    result: Any,
    flights: list[FlightLog],
    validation: list[FlightLog],
    rows: list[tuple[str, str, ErrorStats]],
) -> None:
    params = result.params
    for k, (log, (role, name, errors)) in enumerate(zip([*flights, *validation], rows, strict=True)):
        path = directory / f"cht_{role}_{k + 1}_{Path(name).stem}.png"
        plot_flight(log, simulate_flight(params, log), path, f"{role}: {name}", errors)
    plot_cost(result.cost_history, directory / "cost.png", "PSO best cost per iteration", result.polish_cost)
    identified = np.zeros(params.heat_map.shape, dtype=bool)
    for i, j in result.space.heat_cells:
        identified[i, j] = True
    plot_heat_map(params, identified, directory / "heat_map.png", "identified sea-level heat map")
    print(f"plots -> {directory}/")
