"""``ecu-monitor gap [--model M] --train A.csv [B.csv ...] --test C.csv [D.csv ...] --out DIR``
(and ``gap --blind N --out DIR``).

Sim-to-real gap diagnosis: where the model departs from the test flights (segments, operating
regions, correlations, spectrum, innovation whiteness), which candidate effect explains it (each
refitted on all the train flights together and scored on every test flight, with a bootstrap
significance test that resamples whole test flights and blocks within them) and how far the
held-out error shrinks, pooled and per test flight, and in which segments. Writes DIR/gap.json,
DIR/report.md, PNG plots and DIR/model.yaml (the model with the winning effect, or the nominal model
when unexplained).

Without ``--model`` the nominal model is identified on the train flights (PSO, ``--heat-axes`` as for
identify) and each candidate is then re-identified jointly with the whole model (``--refit
reidentify``: the nominal heat map has absorbed what it could of any effect on that same flight);
with ``--model`` the candidates are refitted locally from it (``--refit local``). ``--leave-one-out``
with ``--train A B ...`` alone holds out each flight in turn (every candidate refitted on the others,
from a nominal model identified on the others when ``--model`` is not given) and pools the scores
over all the held-out flights; model.yaml is then the winner refitted on all of them.
``--choose-on-train`` (three ``--train`` flights or more, and ``--test``) chooses the verdict by
such a leave-one-out over the train flights and then scores it on the test flights (which take no
part in the choice). ``--split-at S``
with ``--train`` alone splits one flight at S seconds: before = train, after = test (``--test-first``:
the other way round). ``--blind N`` runs N generated blind cases on the virtual ECU instead and
writes DIR/blind.json and DIR/blind.md (scores and confusion matrix); ``--blind N --forms`` the
non-circular ones (truths of a form the library does not hold; DIR/forms.json, DIR/forms.md).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ecu_monitor.commands.identify import choose_heat_axes, parse_heat_axes
from ecu_monitor.compile_cache import announce_compiles
from ecu_monitor.errors import ConfigError, UserInputError
from ecu_monitor.userfiles import write_output_bytes

if TYPE_CHECKING:  # the run imports these: --help stays light
    from ecu_monitor.flightlog import FlightLog
    from ecu_monitor.gap import GapSettings
    from ecu_monitor.model import ThermalParams

__all__ = ["add_subparser"]


def add_subparser(subparsers: Any) -> None:
    """Register the ``gap`` subcommand."""
    parser = subparsers.add_parser(
        "gap",
        help="sim-to-real gap diagnosis: where, which effect, how far it shrinks (gap.json, report, model.yaml)",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--model", metavar="MODEL.yaml", help="nominal model (default: identified on --train)")
    parser.add_argument("--train", nargs="+", metavar="A.csv", help="flight(s) the candidate effects are refitted on")
    parser.add_argument("--test", nargs="+", metavar="C.csv", help="held-out flight(s) they are scored on")
    parser.add_argument(
        "--leave-one-out",
        action="store_true",
        help="with --train A B ... only: hold out each flight in turn (refits on the others), pool the scores",
    )
    parser.add_argument(
        "--choose-on-train",
        action="store_true",
        help="with 3+ --train flights and --test: choose the verdict by a leave-one-out over the train flights,"
        " the test flights only score it",
    )
    parser.add_argument("--out", required=True, metavar="DIR", help="output directory")
    parser.add_argument(
        "--heat-axes",
        metavar="COL,COL",
        help="heat-map axes when identifying (default throttle_pct,rpm; fuel_flow_lph,rpm for a log without throttle)",
    )
    parser.add_argument("--mapping", metavar="MAPPING", help="mapping YAML (or shipped name: g1000) for foreign CSVs")
    parser.add_argument("--split-at", type=float, metavar="S", help="with --train only: train before S s, test after")
    parser.add_argument("--test-first", action="store_true", help="with --split-at: test before S s, train after")
    parser.add_argument(
        "--candidates",
        metavar="IDS",
        help="comma-separated candidate effects (default: the library's default set, plus the ones the logged"
        " columns call for: no_altitude_factor with a heat map on fuel flow, mixture_index when every flight logs"
        " manifold_pressure_kpa (the fuel/air ratio) or egt_c; an unknown name lists the known)",
    )
    parser.add_argument(
        "--refit",
        choices=("local", "reidentify"),
        help="local: refit effect + R_Ce/heat factors from the nominal model (default with --model);"
        " reidentify: PSO re-identification of the whole model jointly with each effect (default without --model)",
    )
    parser.add_argument("--blind", type=int, metavar="N", help="run N blind cases on the virtual ECU instead")
    parser.add_argument(
        "--forms",
        action="store_true",
        help="with --blind: the non-circular cases (truth forms the library does not hold; DIR/forms.md)",
    )
    parser.add_argument("--seed", type=int, default=0, metavar="N", help="seed of the blind cases (default 0)")
    parser.add_argument("--duration", type=float, default=3600.0, metavar="S", help="blind-case flight length, s")
    parser.set_defaults(func=announce_compiles(_run))  # a first run says it compiles


def _say(message: str) -> None:
    print(f"gap: {message}", file=sys.stderr, flush=True)


def _flights(args: argparse.Namespace) -> tuple[list[FlightLog], list[FlightLog]]:
    from ecu_monitor.bus.canlog import load_flight

    if not args.train:
        raise UserInputError("gap: --train is required (or --blind N)")
    if args.test_first and args.split_at is None:
        raise UserInputError("gap: --test-first needs --split-at S")
    named = [*args.train, *(args.test or [])]
    repeated = sorted({path for path in named if named.count(path) > 1})
    if repeated:
        raise UserInputError(f"gap: {repeated[0]}: given twice (a flight is either train or test, once)")
    if args.choose_on_train and (len(args.train) < 3 or not args.test):
        raise UserInputError("gap: --choose-on-train needs at least three --train flights and --test")
    if args.leave_one_out:
        if args.test or args.split_at is not None:
            raise UserInputError("gap: --leave-one-out takes its flights from --train alone (no --test, --split-at)")
        if len(args.train) < 2:
            raise UserInputError("gap: --leave-one-out needs at least two --train flights")
        return [load_flight(path, mapping=args.mapping) for path in args.train], []
    if args.split_at is not None:
        if args.test:
            raise UserInputError("gap: give either --test or --split-at, not both")
        if len(args.train) != 1:
            raise UserInputError("gap: --split-at splits one flight: give exactly one --train flight")
        train = load_flight(args.train[0], mapping=args.mapping)
        t = train.time_s
        if not t[0] + 60.0 < args.split_at < t[-1] - 60.0:
            raise UserInputError(
                f"--split-at {args.split_at:g}: expected a time at least 60 s inside the flight ({t[0]:g}-{t[-1]:g} s)"
            )
        before, after = train.select(t[0], args.split_at), train.select(args.split_at, t[-1])
        return ([after], [before]) if args.test_first else ([before], [after])
    if not args.test:
        raise UserInputError("gap: --test is required (or --split-at S to split the train flight)")
    trains = [load_flight(path, mapping=args.mapping) for path in args.train]
    return trains, [load_flight(path, mapping=args.mapping) for path in args.test]


def _writable_out(path: str) -> Path:
    """Create the output directory and prove it writable before the long work (ConfigError if not)."""
    from ecu_monitor.userfiles import prepare_output_dir

    return prepare_output_dir(path, "--out", ConfigError)


def _candidate_ids(args: argparse.Namespace) -> tuple[str, ...] | None:
    """The ids named by --candidates (None: not given); UserInputError if one is unknown."""
    if not args.candidates:
        return None
    ids = tuple(c.strip() for c in args.candidates.split(",") if c.strip())
    from ecu_monitor.gap import CANDIDATE_IDS

    unknown = [c for c in ids if c not in CANDIDATE_IDS]
    if unknown or not ids:
        raise UserInputError(f"--candidates: unknown effect(s) {unknown or ids} (known: {', '.join(CANDIDATE_IDS)})")
    return ids


def _settings(args: argparse.Namespace, candidates: tuple[str, ...] | None = None) -> GapSettings:
    from ecu_monitor.gap import GapSettings

    mode = args.refit or ("local" if args.model or args.blind is not None else "reidentify")
    ids = _candidate_ids(args) or candidates
    chosen = {"choose_on_train_from": 3} if getattr(args, "choose_on_train", False) else {}
    if ids is None:
        return GapSettings(refit_mode=mode, **chosen)
    return GapSettings(candidates=ids, refit_mode=mode, **chosen)


def _check_blind(args: argparse.Namespace) -> Path:
    if args.blind < 1:
        raise UserInputError(f"--blind: expected a positive number of cases, got {args.blind}")
    if args.duration < 600.0:
        raise UserInputError(f"--duration: expected at least 600 s, got {args.duration:g}")
    return _writable_out(args.out)


def _run_forms(args: argparse.Namespace, settings: GapSettings) -> int:
    from ecu_monitor.research.blind_forms import forms_markdown, forms_summary, run_form_cases

    out = _check_blind(args)
    started = time.perf_counter()

    def progress(result: Any) -> None:
        c = result.case
        _say(
            f"case {c.index + 1}/{args.blind} {c.kind}: expected {'+'.join(c.expected) or 'null'},"
            f" verdict {'+'.join(result.verdict) or 'null'} {'ok' if result.right else 'WRONG'}"
            f" ({time.perf_counter() - started:.0f} s)"
        )

    results = run_form_cases(args.blind, args.seed, args.duration, settings, progress)
    command = "ecu-monitor " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:] else None
    doc = {
        "seed": args.seed,
        "duration_s": args.duration,
        "summary": forms_summary(results),
        "cases": [r.to_dict() for r in results],
    }
    write_output_bytes(out / "forms.json", (json.dumps(doc, indent=2) + "\n").encode("utf-8"), ConfigError)
    write_output_bytes(out / "forms.md", forms_markdown(results, command).encode("utf-8"), ConfigError)
    right = sum(r.right for r in results)
    print(f"non-circular blind cases: {right}/{len(results)} verdicts right; {out / 'forms.md'}")
    return 0


def _run_blind(args: argparse.Namespace, settings: GapSettings) -> int:
    from ecu_monitor.research.blind import blind_markdown, confusion_matrix, run_blind_cases, summary

    if args.forms:
        return _run_forms(args, settings)
    out = _check_blind(args)
    started = time.perf_counter()

    def progress(result: Any) -> None:
        d = result.to_dict()
        mark = "ok" if result.verdict_right else "WRONG"
        _say(
            f"case {d['index'] + 1}/{args.blind} {d['kind']}: expected {d['expected'] or 'null'},"
            f" verdict {d['verdict'] or 'null'} {mark} ({time.perf_counter() - started:.0f} s)"
        )

    results = run_blind_cases(args.blind, args.seed, args.duration, settings, progress)
    command = "ecu-monitor " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:] else None
    doc = {
        "seed": args.seed,
        "duration_s": args.duration,
        "summary": summary(results),
        "confusion": confusion_matrix(results),
        "cases": [r.to_dict() for r in results],
    }
    write_output_bytes(out / "blind.json", (json.dumps(doc, indent=2) + "\n").encode("utf-8"), ConfigError)
    write_output_bytes(out / "blind.md", blind_markdown(results, command).encode("utf-8"), ConfigError)
    right = sum(r.verdict_right for r in results)
    print(f"blind cases: {right}/{len(results)} verdicts right; {out / 'blind.md'}")
    return 0


def _identify(flights: list[FlightLog], axes: tuple[str, str], label: str) -> ThermalParams:
    """The nominal model identified on ``flights`` (PSO), with progress on stderr."""
    from ecu_monitor.identify import PsoSettings, identify

    names = ", ".join(log.source for log in flights)
    _say(f"{label}no --model: identifying the nominal model on {names} (PSO, heat axes {','.join(axes)})")
    pso = PsoSettings()
    started = time.perf_counter()

    def identifying(iteration: int, best: float, elapsed: float) -> None:
        if iteration % 20 == 0 or iteration == pso.iterations:
            _say(f"{label}identify: iteration {iteration}/{pso.iterations}, RMS {best:.2f} degC ({elapsed:.0f} s)")

    params = identify(flights, heat_axes=axes, settings=pso, progress=identifying).params
    _say(f"{label}identified in {time.perf_counter() - started:.1f} s")
    return params


def _fold_nominals(trains: list[FlightLog], axes: tuple[str, str]) -> tuple[list[ThermalParams], ThermalParams]:
    """For each flight, the nominal model identified on the others (PSO; the swarms on every core at once),
    and the one on every flight (the first fold's polished on all: :func:`ecu_monitor.gap.folds.swarm_nominals`).

    Not warm-started from the fit on every flight (:func:`ecu_monitor.gap.folds.fold_nominals`): on the
    real N550ND flights that saved no CPU (the joint refits dominate) and moved the held-out baselines
    towards the held-out flights (docs/results/gap_real.md)."""
    from ecu_monitor.gap.folds import swarm_nominals
    from ecu_monitor.identify import PsoSettings

    _say(f"no --model: one nominal model per held-out flight (PSO, heat axes {','.join(axes)}), then one on all")
    return swarm_nominals(trains, axes, PsoSettings(), progress=_say)


def _run(args: argparse.Namespace) -> int:
    _writable_out(args.out)  # before any work or heavy import
    from ecu_monitor.gap import cross_validate, diagnose, write_report
    from ecu_monitor.identify import model_inputs
    from ecu_monitor.identify.library import candidates_for
    from ecu_monitor.model import load_model

    if args.blind is not None:
        return _run_blind(args, _settings(args))
    _candidate_ids(args)  # a bad --candidates fails before the flights are read
    trains, tests = _flights(args)
    nominal = load_model(args.model) if args.model else None
    if nominal is not None and args.heat_axes and parse_heat_axes(args.heat_axes) != nominal.heat_axes:
        raise UserInputError(f"--heat-axes {args.heat_axes}: the model's heat map is on {','.join(nominal.heat_axes)}")
    axes = nominal.heat_axes if nominal is not None else choose_heat_axes(args.heat_axes, [*trains, *tests])
    for log in (*trains, *tests):
        model_inputs(log, axes)  # fail early, naming the flight and the missing column
    settings = _settings(args, candidates_for(axes, [*trains, *tests]))
    started = time.perf_counter()
    if args.leave_one_out:
        nominals, final = ([nominal] * len(trains), nominal) if nominal is not None else _fold_nominals(trains, axes)
        diag = cross_validate(nominals, trains, final, settings, progress=_say)
    else:
        nominal = nominal or _identify(trains, axes, "")
        diag = diagnose(nominal, trains, tests, settings, progress=_say)
    command = "ecu-monitor " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:] else None
    doc = write_report(diag, args.out, command)
    verdict = doc["verdict"]
    base = doc["baseline"]
    if verdict["effect"] is None and verdict["lead"] is not None:
        print(verdict["lead"]["text"])
    elif verdict["effect"] is None:
        print(
            "unexplained: no effect improves the held-out flight significantly;"
            f" test RMS {base['test_rms_c']:.2f} degC,"
            f" mostly in {doc['where'][0]['segment']} ({100 * doc['where'][0]['share']:.0f} %)"
        )
    else:
        print(
            f"{verdict['label']}: held-out RMS {base['test_rms_c']:.2f} -> {verdict['test_rms_c']:.2f} degC"
            f" (shrink {verdict['shrink_pct']:.0f} %), mostly in {verdict['segment']}"
        )
    for row in doc["per_flight"]:
        after = f" -> {row['test_rms_c']:.2f} ({row['shrink_pct']:+.0f} %)" if "test_rms_c" in row else ""
        print(f"  {row['flight']}: RMS {row['baseline_rms_c']:.2f}{after} degC")
    print(
        f"wrote {Path(args.out) / 'gap.json'}, report.md, model.yaml and plots ({time.perf_counter() - started:.1f} s)"
    )
    return 0
