"""``identify --type`` (a type model over several airframes) and ``identify --base TYPE.yaml`` (one
airframe adapted from it): the two fleet forms of ``ecu-monitor identify`` (docs/identify_your_engine.md).

The airframe of each flight is the one its log names (a G1000 export's ``system_id``, a log's
``engine_serial``), or the one ``--airframe NAME=GLOB`` gives (that wins).
"""

from __future__ import annotations

import argparse
import fnmatch
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ecu_monitor.errors import UserInputError

if TYPE_CHECKING:
    from ecu_monitor.flightlog import FlightLog
    from ecu_monitor.identify.type_model import AirframeFit
    from ecu_monitor.model import AirframeTerms, ThermalParams

__all__ = ["add_arguments", "airframe_names", "flight_airframes", "known_airframes", "run_adapt", "run_type"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The fleet options of ``identify``."""
    parser.add_argument(
        "--type",
        action="store_true",
        help="one type model over flights of several airframes of one engine type, with each airframe's own terms"
        " (heat scale, cooling scale, probe lag) where its data need them",
    )
    parser.add_argument("--type-name", metavar="NAME", help="the engine type's name in the model (default: OUT's stem)")
    parser.add_argument(
        "--airframe",
        action="append",
        default=[],
        metavar="NAME=GLOB",
        help="flights matching GLOB are of airframe NAME (default: the log's G1000 system_id or engine serial)",
    )
    parser.add_argument(
        "--or-base",
        action="append",
        default=[],
        metavar="TYPE2.yaml",
        help="with --base TYPE.yaml: another type model of the type in another form (heat-map axes, effects);"
        " the adaptation keeps TYPE.yaml's form unless another predicts the flights' second halves clearly better",
    )
    parser.add_argument(
        "--first-minutes",
        type=float,
        metavar="M",
        help="with --base TYPE.yaml: adapt from the first M minutes of the flight(s) only",
    )


def airframe_names(specs: list[str]) -> list[tuple[str, str]]:
    """``--airframe NAME=GLOB`` options -> (name, glob); UserInputError on a malformed one."""
    out = []
    for spec in specs:
        name, sep, pattern = spec.partition("=")
        if not sep or not name.strip() or not pattern.strip():
            raise UserInputError(f"--airframe: expected NAME=GLOB, got {spec!r}")
        out.append((name.strip(), pattern.strip()))
    return out


def _named(path: str, named: list[tuple[str, str]]) -> str | None:
    """The first ``--airframe`` name whose glob matches the path as given or its file name."""
    return next((n for n, g in named if fnmatch.fnmatch(path, g) or fnmatch.fnmatch(Path(path).name, g)), None)


def flight_airframes(paths: list[str], specs: list[str]) -> list[str]:
    """The airframe of each flight: the first ``--airframe`` whose glob matches the path (as given, or its
    file name), else what the log names; UserInputError naming a flight with neither."""
    from ecu_monitor.flightlog import log_airframe

    named = airframe_names(specs)
    out = []
    for path in paths:
        airframe = _named(path, named) or log_airframe(path)
        if airframe is None:
            raise UserInputError(
                f"{path}: the log names no airframe (no G1000 system_id, no engine serial):"
                " name it with --airframe NAME=GLOB"
            )
        out.append(airframe)
    return out


def _fit_lines(name: str, fit: AirframeFit, sources: list[str]) -> list[str]:
    from ecu_monitor.identify.type_model import describe_terms

    lines = [f"airframe {name}: {describe_terms(fit.terms, fit.heat_values)}"]
    if fit.held_out:
        tried = ", ".join(f"{'+'.join(k) or 'none'} {v:.2f}" for k, v in fit.held_out.items())
        lines.append(f"  held-out RMS on the second halves, degC, by own terms: {tried}")
    else:
        lines.append("  flights too short to halve: every candidate term kept, held near the type by its prior")
    if fit.heat_map_held_out:
        tried = ", ".join(f"{100 * k:g} % {v:.2f}" for k, v in fit.heat_map_held_out.items())
        kept = (
            f"heat-map values refitted with a prior {100 * fit.heat_map_prior:g} % of the type's"
            if fit.heat_values
            else "the type's heat map kept"
        )
        lines.append(f"  {kept}; held-out RMS of the halves both ways, degC, by prior width: {tried}")
    for source, own, as_type in zip(sources, fit.errors, fit.as_type, strict=True):
        lines.append(f"  {Path(source).name}: RMS {own.rms_c:.2f} degC with its terms, {as_type.rms_c:.2f} as the type")
    return lines


def _matched_lines(fit: AirframeFit) -> list[str]:
    """An airframe's head against the other airframes' at the steady operating points they share (the
    difference no form of the model carries to an airframe with no flight of its own); nothing where the
    flights lack a column it reads."""
    m = fit.matched
    if m is None:
        return []
    if m.bins == 0:
        return ["  shares no steady operating point (rpm x fuel flow x airspeed) with the other airframes"]
    others = [
        f", {label} {value:+.0f} degC"
        for label, value in (("EGT", m.egt_offset_c), ("oil above the air", m.oil_offset_c))
        if math.isfinite(value)
    ]
    return [
        f"  at the steady operating points it shares with the others ({m.matched_s:.0f} s): its head"
        f" {m.offset_c:+.1f} degC against theirs (spread {m.spread_c:.1f}){''.join(others)}"
    ]


#: After the airframes' matched lines: what they mean.
_MATCHED_NOTE = (
    "(a model reads the inputs, not the airframe: a new airframe with no flight of its own can be as far from the"
    " type as these heads are from each other at the same inputs)"
)


def _write(params: ThermalParams, out: Path, lines: list[str]) -> None:
    from ecu_monitor.model import save_model

    try:
        save_model(params, out, comment="\n".join(lines))
    except OSError as exc:
        raise UserInputError(f"{out}: cannot write the model ({exc.strerror})") from None


def known_airframes(paths: list[str], specs: list[str]) -> tuple[AirframeTerms, ...]:
    """The airframes the flights name (``--airframe`` or the logs), each once, for a model's record."""
    from ecu_monitor.flightlog import log_airframe
    from ecu_monitor.model import AirframeTerms

    named = airframe_names(specs)
    ids: list[str] = []
    for path in paths:
        airframe = _named(path, named) or log_airframe(path)
        if airframe is not None and airframe not in ids:
            ids.append(airframe)
    return tuple(AirframeTerms(a) for a in ids)


def run_type(
    args: argparse.Namespace, settings: Any, flights: list[FlightLog], airframes: list[str], context: dict[str, Any]
) -> int:
    """``identify --type FLIGHTS... --out TYPE.yaml`` on the loaded ``flights`` of ``airframes``
    (:func:`flight_airframes`); ``context`` holds identify's checked base, heat axes, grid, terms, free
    parameters and progress callbacks."""
    from ecu_monitor.identify.type_model import fit_type

    out = Path(args.out)
    name = args.type_name or out.stem
    fit = fit_type(flights, airframes, engine_type=name, settings=settings, **context)
    lines = [
        "Identified by: ecu-monitor identify " + " ".join(sys.argv[2:] if len(sys.argv) > 2 else args.flights),
        f"type model {name}: {len(flights)} flights of {len(fit.airframes)} airframes, {fit.elapsed_s:.0f} s"
        + (f"; joint polish cost {fit.joint_cost:.3f} degC" if fit.joint_cost is not None else ""),
    ]
    for airframe, airframe_fit in fit.airframes.items():
        sources = [log.source for log, a in zip(flights, airframes, strict=True) if a == airframe]
        lines += _fit_lines(airframe, airframe_fit, sources) + _matched_lines(airframe_fit)
    if any(f.matched is not None for f in fit.airframes.values()):
        lines.append(_MATCHED_NOTE)
    _write(fit.params, out, lines)
    for line in lines[1:]:
        print(line)
    print(
        f"type model -> {out}; adapt it to a new airframe with:"
        f" ecu-monitor identify --base {out} FLIGHT --out AIRFRAME.yaml"
    )
    return 0


def run_adapt(
    args: argparse.Namespace, settings: Any, flights: list[FlightLog], airframes: list[str], type_params: ThermalParams
) -> int:
    """``identify --base TYPE.yaml FLIGHT... --out AIRFRAME.yaml [--first-minutes M]`` on the loaded ``flights``
    of ``airframes`` (:func:`flight_airframes`: one airframe)."""
    from ecu_monitor.identify.type_model import adapt_choosing, first_minutes
    from ecu_monitor.model import load_model

    out = Path(args.out)
    bases = [args.base, *args.or_base]
    types = [type_params, *(load_model(path) for path in args.or_base)]
    for path, params in zip(bases[1:], types[1:], strict=True):
        if not params.engine_type:
            raise UserInputError(f"--or-base {path}: not a type model (made by identify --type): it has no engine type")
    airframes = sorted(set(airframes))
    if len(airframes) != 1:
        raise UserInputError(
            f"--base {args.base}: the flights are of {len(airframes)} airframes ({', '.join(airframes)}):"
            " adapt one at a time"
        )
    if args.first_minutes is not None:
        flights = [first_minutes(log, args.first_minutes) for log in flights]
    result = adapt_choosing(types, flights, airframes[0], settings)
    part = f"the first {args.first_minutes:g} min of " if args.first_minutes is not None else ""
    chosen = types[result.chosen]
    lines = [
        "Identified by: ecu-monitor identify " + " ".join(sys.argv[2:] if len(sys.argv) > 2 else args.flights),
        f"airframe {airframes[0]} adapted from the {chosen.engine_type} type model {bases[result.chosen]} on {part}"
        f"{len(flights)} flight(s), {result.elapsed_s:.1f} s",
    ]
    if len(types) > 1:
        scores = ", ".join(f"{path} {v:.2f}" for path, v in zip(bases, result.held_out_by_type, strict=True))
        lines.append(f"  held-out RMS on the second halves, degC, by type model: {scores}")
    lines += _fit_lines(airframes[0], result.fit, [log.source for log in flights])
    _write(result.params, out, lines)
    for line in lines[1:]:
        print(line)
    print(f"airframe model -> {out}")
    return 0
