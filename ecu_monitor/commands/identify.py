"""``ecu-monitor identify FLIGHT.csv [FLIGHT2.csv ...] --out model.yaml [--effects auto] [--cht-limit C]``.

PSO identification of the thermal model on one or more flights (several flights make one model), then
a least-squares polish. The common scale of C_w, R_Ce, the radiation and the heat map is not observable
from temperatures: R_Ce keeps the base model's value and the search runs in coordinates the data pin
(time constant C_w R_Ce, temperature rise Q R_Ce per heat-map breakpoint, radiated share of the heat),
with a smooth, power-monotone prior on the heat map. ``--effects`` fits the model jointly with terms
(airspeed cooling with a propeller-wash floor, density cooling, probe lag, mixture cooling) or without
parts of the paper's form (``-altitude_factor``, ``-radiation``; ``radiation_kelvin`` for T^4 in kelvin); ``auto``
keeps what lowers the error on held-out flights. With 2+ flights each flight is also predicted by a
model fitted on the others (leave-one-flight-out). Prints a table of mean / peak / RMS error in degC
and % per flight, any parameter that ended at a bound, writes model.yaml (header: how it was made,
the errors, the bounds hit) and, with ``--plots DIR``, PNG plots.

The heat map's axes default to throttle_pct,rpm; a log without throttle but with fuel flow uses
fuel_flow_lph,rpm (say it with ``--heat-axes``). Foreign CSVs load through ``--mapping`` (g1000).
Give the engine's CHT limit with ``--cht-limit`` (the manufacturer's value, degC): it goes into
model.yaml for headroom and monitoring, and identify warns when the flights exceed it.
``--cylinder N`` identifies cylinder N's CHT (column ``chtN_c``); ``--cylinder all`` every cylinder
of the flights, one model.yaml each (``model_cyl1.yaml`` ...), for the service's ``cylinders.models``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ecu_monitor.commands import identify_type
from ecu_monitor.commands.names import IDENTIFY_DEFAULT_FREE as DEFAULT_FREE
from ecu_monitor.commands.names import PSO_DT_S, PSO_ITERATIONS, PSO_PARTICLES
from ecu_monitor.compile_cache import announce_compiles
from ecu_monitor.errors import FlightLogError, ParameterError, UserInputError

if TYPE_CHECKING:  # the run imports these: --help stays light
    from ecu_monitor.flightlog import FlightLog
    from ecu_monitor.identify import ErrorStats, PsoSettings
    from ecu_monitor.identify.select import CrossValidation, Selection

__all__ = ["add_subparser", "cylinder_output", "parse_cylinder", "parse_grid", "parse_heat_axes"]


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
    parser.add_argument(
        "--heat-axes",
        metavar="COL,COL",
        help="heat-map axes (default throttle_pct,rpm; fuel_flow_lph,rpm for a log without throttle)",
    )
    parser.add_argument(
        "--grid",
        metavar="NxM",
        help="heat-map breakpoints from the data's quantiles, e.g. 4x4; 1 on an axis: the heat does not depend on it",
    )
    parser.add_argument("--base", metavar="MODEL.yaml", help="starting / fixed values (default: paper Table A1)")
    parser.add_argument(
        "--free",
        metavar="NAMES",
        help=f"comma-separated free parameters (default {','.join(DEFAULT_FREE)}; also alpha_r_e, a, b,"
        " effects.<effect>.<parameter>)",
    )
    parser.add_argument(
        "--effects",
        metavar="NAMES|auto",
        help="terms to fit with the model, comma-separated (a leading '-' removes one; an unknown name lists the"
        " known, e.g. airspeed_cooling, sensor_lag); auto keeps those that lower the held-out error (other flights,"
        " or the halves of one)",
    )
    parser.add_argument("--cht-limit", type=float, metavar="C", help="the engine's CHT limit, degC (into model.yaml)")
    parser.add_argument("--no-lofo", action="store_true", help="skip the leave-one-flight-out check (2+ flights)")
    parser.add_argument("--particles", type=int, default=PSO_PARTICLES, metavar="N", help="swarm size")
    parser.add_argument("--iterations", type=int, default=PSO_ITERATIONS, metavar="N", help="PSO iterations")
    parser.add_argument("--seed", type=int, default=0, metavar="N", help="random seed (default 0)")
    parser.add_argument("--dt", type=float, default=PSO_DT_S, metavar="S", help="integration step, s")
    parser.add_argument("--no-polish", action="store_true", help="skip the least-squares polish")
    parser.add_argument("--plots", metavar="DIR", help="write PNG plots into DIR")
    parser.add_argument("--mapping", metavar="MAPPING", help="mapping YAML (or shipped name: g1000) for foreign CSVs")
    parser.add_argument(
        "--cylinder",
        metavar="N|all",
        help="identify cylinder N's CHT (column chtN_c) instead of cht_c; all: every cylinder the first flight"
        " carries, one model each (OUT with _cylN before its suffix) for the service's cylinders.models",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    identify_type.add_arguments(parser)  # --type, --airframe, --first-minutes (a type model and its adaptation)
    parser.set_defaults(func=announce_compiles(_run))  # a first run says it compiles


def parse_heat_axes(text: str) -> tuple[str, str]:
    """'COL,COL' -> (x, y); UserInputError on anything else."""
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != 2 or not all(parts) or parts[0] == parts[1]:
        raise UserInputError(f"--heat-axes: expected two different column names as COL,COL, got {text!r}")
    return parts[0], parts[1]


def parse_grid(text: str) -> tuple[int, int]:
    """'NxM' -> (n, m) with 1 <= n, m <= 12 (1: the heat does not depend on that axis); UserInputError otherwise."""
    parts = text.lower().split("x")
    try:
        n, m = (int(p) for p in parts)
    except ValueError:
        raise UserInputError(f"--grid: expected NxM such as 4x4, got {text!r}") from None
    if not (1 <= n <= 12 and 1 <= m <= 12):
        raise UserInputError(f"--grid: expected 1 to 12 breakpoints per axis, got {text!r}")
    return n, m


def _load(paths: list[str], mapping: str | None, cylinder: int | None = None) -> list[FlightLog]:
    from ecu_monitor.bus.canlog import load_flight

    return [load_flight(p, mapping=mapping, cht=cylinder) for p in paths]


def parse_cylinder(text: str | None) -> int | str | None:
    """``--cylinder``: None, ``"all"`` or a cylinder number >= 1; UserInputError otherwise."""
    if text is None or text.strip().lower() == "all":
        return None if text is None else "all"
    if not text.strip().isdigit() or int(text) < 1:
        raise UserInputError(f"--cylinder: expected a cylinder number (1, 2, ...) or all, got {text!r}")
    return int(text)


def cylinder_output(out: Path, cylinder: int) -> Path:
    """The model file of one cylinder for ``--cylinder all``: ``model.yaml`` -> ``model_cyl3.yaml``."""
    return out.with_name(f"{out.stem}_cyl{cylinder}{out.suffix or '.yaml'}")


def choose_heat_axes(arg: str | None, flights: list[FlightLog]) -> tuple[str, str]:
    """``--heat-axes`` when given; else throttle_pct,rpm, or fuel_flow_lph,rpm (said on stderr) when the
    first flight has fuel flow but no throttle (a G1000 or NGAFID log). identify and gap share it."""
    if arg:
        return parse_heat_axes(arg)
    first = flights[0]
    if not first.has("throttle_pct") and first.has("fuel_flow_lph"):
        print(f"{first.source}: no throttle_pct; heat map on fuel_flow_lph,rpm", file=sys.stderr)
        return "fuel_flow_lph", "rpm"
    return "throttle_pct", "rpm"


def _service_axis_warnings(axes: tuple[str, str]) -> list[str]:
    """One line per heat-map axis the service cannot read from a bus (a column of the logs only, such as
    manifold_pressure_kpa): such a model simulates and diagnoses, but replay, calibrate and run refuse it."""
    from ecu_monitor.bus.codec import INPUT_NAMES

    return [
        f"heat-map axis {axis} is not an input the service reads (inputs: {', '.join(INPUT_NAMES)}): simulate and"
        " gap take this model, replay, calibrate and run do not"
        for axis in axes
        if axis not in INPUT_NAMES
    ]


def _progress_bar(bar: Any) -> Callable[[int, float, float], None]:
    def progress(iteration: int, best: float, elapsed: float) -> None:
        if iteration < bar.n:  # the next of several fits (leave-one-flight-out, effects auto)
            bar.reset()
        bar.update(iteration - bar.n)
        bar.set_postfix_str(f"best {best:.4f} degC, {elapsed:.1f} s")

    return progress


def _settings(args: argparse.Namespace) -> PsoSettings:
    from ecu_monitor.identify import PsoSettings

    return PsoSettings(
        particles=args.particles,
        iterations=args.iterations,
        seed=args.seed,
        dt_s=args.dt,
        polish=not args.no_polish,
    )


def _run(args: argparse.Namespace) -> int:
    from ecu_monitor.userfiles import check_output_file, prepare_output_dir

    out = check_output_file(args.out, "--out")  # before any work or heavy import: identify takes minutes
    if args.plots:
        prepare_output_dir(args.plots, "--plots")
    from ecu_monitor.flightlog import cylinder_columns, require_distinct

    cylinder = parse_cylinder(args.cylinder)
    if cylinder != "all":
        return _run_one(args, cylinder if isinstance(cylinder, int) else None, out)
    require_distinct([*args.flights, *(args.validate or [])], "identify")
    first = _load(args.flights[:1], args.mapping)[0]
    numbers = [int(c[3:-2]) for c in cylinder_columns(first, "cht")]
    if not numbers:
        raise FlightLogError(f"{first.source}: --cylinder all: no per-cylinder CHT columns (cht1_c ..)")
    written = []
    for number in numbers:
        print(f"== cylinder {number} of {max(numbers)} ==")
        path = cylinder_output(out, number)
        _run_one(args, number, path)
        written.append(str(path))
    absent = sorted(set(range(1, max(numbers) + 1)) - set(numbers))
    if absent:  # a probe blank in every row is dropped on import: the service cannot number around the hole
        print(
            f"no model for cylinder(s) {', '.join(map(str, absent))}: {first.source} has no CHT column for them."
            " The service numbers its cylinders cht1_c .. chtN_c without gaps and takes one model per cylinder in"
            " that order: map only the cylinders with a probe, renumbered, and list their models in that order"
        )
    print("for the service config (docs/service.md, Every cylinder):")
    print(f"cylinders: {{models: [{', '.join(written)}]}}")
    return 0


def _run_one(args: argparse.Namespace, cylinder: int | None, out: Path) -> int:
    """Identify one model (of ``cht_c``, or of cylinder ``cylinder``'s CHT) into ``out``."""
    from tqdm import tqdm

    from ecu_monitor.flightlog import require_distinct
    from ecu_monitor.identify import default_space, flight_errors, model_inputs
    from ecu_monitor.identify.report import error_table
    from ecu_monitor.identify.select import identify_flights
    from ecu_monitor.model import load_model, paper_table_a1, save_model
    from ecu_monitor.userfiles import prepare_output_dir

    settings = _settings(args)  # validate the numbers before the (slow) work (the outputs: in _run)
    if args.cht_limit is not None and not 20.0 <= args.cht_limit <= 500.0:
        raise UserInputError(f"--cht-limit: expected a temperature in [20, 500] degC, got {args.cht_limit:g}")
    terms: dict[str, bool] | str | None = None
    if args.effects:
        terms = "auto" if args.effects.strip() == "auto" else _parse_terms(args.effects)
    base = load_model(args.base) if args.base else paper_table_a1()
    if base.engine_type and args.type:
        raise UserInputError(
            f"--type with --base {args.base}: that is already a type model; give its flights without --base"
        )
    if (args.type or base.engine_type) and (args.validate or args.plots or args.cylinder == "all"):
        raise UserInputError("--validate, --plots and --cylinder all: not with --type or --base TYPE.yaml")
    if args.first_minutes is not None and not base.engine_type:
        raise UserInputError("--first-minutes: applies to --base TYPE.yaml (adapting a type model to an airframe)")
    if args.or_base and not base.engine_type:
        raise UserInputError("--or-base: applies to --base TYPE.yaml (adapting a type model to an airframe)")
    fleet = identify_type.flight_airframes(args.flights, args.airframe) if args.type or base.engine_type else []
    plots = None if not args.plots else Path(args.plots) / (f"cyl{cylinder}" if cylinder is not None else "")
    if plots is not None:
        prepare_output_dir(plots, "--plots")
    require_distinct([*args.flights, *(args.validate or [])], "identify")
    flights = _load(args.flights, args.mapping, cylinder)
    validation = _load(args.validate, args.mapping, cylinder)
    axes = choose_heat_axes(args.heat_axes, flights)
    if args.cht_limit is not None:
        base = base.replace(cht_limit_c=args.cht_limit)
    free = tuple(n.strip() for n in args.free.split(",") if n.strip()) if args.free else DEFAULT_FREE
    grid = parse_grid(args.grid) if args.grid else None
    default_space(flights, base=base, heat_axes=axes, grid=grid, free=free)  # fail early on a bad space
    for log in validation:  # fail early on a validation flight that lacks a column
        model_inputs(log, axes)
        if not log.has("cht_c"):
            raise FlightLogError(f"{log.source}: no column 'cht_c' (measured CHT) to validate against")
    warnings = _limit_warnings(flights, base.cht_limit_c, args.cht_limit is not None) + _service_axis_warnings(axes)
    for line in warnings:
        print(f"warning: {line}", file=sys.stderr)
    bar = None if args.quiet else tqdm(total=settings.iterations, desc="identify", unit="it", file=sys.stderr)
    progress = None if bar is None else _progress_bar(bar)
    notes = None if args.quiet else (lambda line: print(line, file=sys.stderr))
    try:
        if base.engine_type:  # --base TYPE.yaml: fit only the new airframe's own terms
            return identify_type.run_adapt(args, settings, flights, fleet, base)
        if args.type:
            context = {"base": base, "heat_axes": axes, "grid": grid, "terms": terms, "free": free}
            context |= {"progress": notes, "pso_progress": progress}
            return identify_type.run_type(args, settings, flights, fleet, context)
        result, cv, selection = identify_flights(
            flights,
            base=base,
            heat_axes=axes,
            grid=grid,
            settings=settings,
            terms=terms,
            free=free,
            lofo=not args.no_lofo,
            progress=notes,
            pso_progress=progress,
        )
    finally:
        if bar is not None:
            bar.close()
    params = result.params.replace(engine_type="", airframes=identify_type.known_airframes(args.flights, args.airframe))
    rows: list[tuple[str, str, ErrorStats]] = [
        ("train", Path(log.source).name, e) for log, e in zip(flights, result.train_errors, strict=True)
    ]
    if cv is not None:
        rows += [("held out (LOFO)", Path(f.held_out).name, f.errors) for f in cv.folds]
    rows += [("validate", Path(log.source).name, flight_errors(params, log)) for log in validation]
    space = result.space
    n_cells = params.heat_map.shape[0] * params.heat_map.shape[1]
    summary = (
        f"{len(space.names)} coordinates ({len(space.heat_cells)}/{n_cells} heat-map breakpoints free),"
        f" {result.evaluations} particle simulations ({result.failed_particles} failed), {result.restarts} restart(s),"
        f" {result.elapsed_s:.1f} s; cost PSO {result.pso_cost:.4f}"
        + (f", polished {result.polish_cost:.4f}" if result.polish_cost is not None else "")
        + " degC"
    )
    bounds = [f"AT BOUND: {line}" for line in result.at_bounds] or ["no parameter ended within 1 % of a bound"]
    lines = [
        "Identified by: ecu-monitor identify " + " ".join(sys.argv[2:] if len(sys.argv) > 2 else args.flights),
        *([f"cylinder {cylinder}: the CHT of column cht{cylinder}_c"] if cylinder is not None else []),
        summary,
        f"r_ce anchors the common scale of c_w, r_ce, alpha_r_e, heat map (kept at {params.r_ce:g});"
        f" radiated share at the reference point {space.radiation_share(params):.3f}",
        f"terms: {_terms_label(params)}",
        *_selection_lines(selection),
        *bounds,
        *(f"warning: {line}" for line in warnings),
        *(
            f"{role} {name}: mean {e.mean_c:.2f} degC ({e.mean_pct:.2f} %), peak {e.peak_c:.2f} degC"
            f" ({e.peak_pct:.2f} %), RMS {e.rms_c:.2f} degC"
            for role, name, e in rows
        ),
        *_lofo_lines(cv),
    ]
    try:
        save_model(params, out, comment="\n".join(lines))
    except OSError as exc:
        raise UserInputError(f"{out}: cannot write the model ({exc.strerror})") from None
    print(error_table(rows))
    for line in (*_lofo_lines(cv), summary, f"terms: {_terms_label(params)}", *_selection_lines(selection), *bounds):
        print(line)
    print(
        f"c_w {params.c_w:.4g} J/degC, r_ce {params.r_ce:.4g} degC/W, alpha_r_e {params.alpha_r_e:.4g},"
        f" tau_w {params.tau_w:.3g} s, a {params.a:.3g}, b {params.b:.3g}, CHT limit {params.cht_limit_c:g} degC;"
        f" heat map {params.heat_map.x_axis} x {params.heat_map.y_axis}"
        f" {params.heat_map.shape[0]}x{params.heat_map.shape[1]} -> {out}"
    )
    if plots is not None:  # the identified model on each training and validation flight (not the LOFO folds')
        _plots(plots, result, flights, validation, [row for row in rows if row[0] in ("train", "validate")])
    return 0


def _parse_terms(text: str) -> dict[str, bool]:
    from ecu_monitor.identify.select import parse_terms

    try:
        return parse_terms(text)
    except ParameterError as exc:
        raise UserInputError(str(exc)) from None


def _terms_label(params: Any) -> str:
    from ecu_monitor.identify.select import TERM_NAMES, term_is_on

    return ", ".join(f"{'+' if term_is_on(params, n) else '-'}{n}" for n in TERM_NAMES)


def _selection_lines(selection: Selection | None) -> list[str]:
    if selection is None:
        return []
    out = [f"effects auto ({selection.elapsed_s:.0f} s): mean held-out RMS, degC, by round:"]
    out += [f"  round {r} {label}: {value:.3f}{'  kept' if kept else ''}" for r, label, value, kept in selection.steps]
    return out


def _lofo_lines(cv: CrossValidation | None) -> list[str]:
    if cv is None:
        return []
    values = cv.rms_c
    return [f"leave-one-flight-out held-out RMS: mean {values.mean():.2f} degC, worst {values.max():.2f} degC"]


def _limit_warnings(flights: list[FlightLog], limit_c: float, given: bool) -> list[str]:
    """One line per flight whose measured CHT exceeds the model's CHT limit."""
    import numpy as np

    out = []
    for log in flights:
        if not log.has("cht_c"):
            continue
        peak = float(np.nanmax(np.asarray(log["cht_c"], dtype=float)))
        if peak > limit_c:
            hint = "" if given else " (the base model's limit: give your engine's with --cht-limit)"
            out.append(
                f"{Path(log.source).name}: measured CHT reaches {peak:.1f} degC, above the limit {limit_c:g} degC{hint}"
            )
    return out


def _plots(
    directory: Path,
    result: Any,
    flights: list[FlightLog],
    validation: list[FlightLog],
    rows: list[tuple[str, str, ErrorStats]],
) -> None:
    import numpy as np

    from ecu_monitor.identify import simulate_flight
    from ecu_monitor.identify.report import plot_cost, plot_flight, plot_heat_map

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
