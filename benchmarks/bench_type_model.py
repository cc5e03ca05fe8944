"""A type model over the given Cessna 172 flights, leave one airframe out: how well does it carry to an
airframe it never saw, with zero, 20 minutes and one whole flight of that airframe's own?

    nice -n 10 .venv/bin/python benchmarks/bench_type_model.py --data DIR [--g1000 DIR2] [--quick]

DIR holds the G1000 exports ngafid_c172s_n550nd_*.csv and cafuc_*.csv, DIR2 (default DIR/../g1000) the
2011 172S log_*.csv. The airframe of each flight is its G1000 system_id. For each airframe X, the type
model (``identify --type``: the shared fit, then each airframe's own heat scale, cooling scale and probe
lag where its data need them) is fitted on the other airframes' flights only, in each of two forms
(:data:`FORMS`: the heat map on fuel flow x rpm with the EGT as a mixture index, and on rpm x EGT with the
altitude factor), then:

- zero flights: the type model as is (the first form), scored on every flight of X;
- 20 minutes: ``--base TYPE --or-base TYPE2 --first-minutes 20`` on one flight of X (the form X's own
  halves predict best), scored on X's other flights, or, where X has one flight only, on the rest of that
  flight (from minute 20);
- one whole flight: ``--base TYPE --or-base TYPE2`` on one flight of X, scored on X's other flights, or,
  where X has one flight only, adapted on its first half and scored on its second half.

``--one-form`` fits and adapts the first form only (the table before the second form). ``--plot DIR``
draws, for each held-out airframe, its first flight: the measured CHT and each form's type model as is,
with the inputs that tell the forms apart (fuel flow, rpm, EGT, airspeed); and, for an airframe with
several flights, the error on its other flights of each whole-flight adaptation, with its own terms only
and with its heat-map values refitted too.

With several flights of X each of them takes its turn as the adapting flight; the figures are the mean
RMS over the scored flights of every turn. Scores are open loop from the first CHT sample of the scored
part; error is model - mean CHT of the cylinders, degC. Prints a markdown table, each airframe's head
against the others' at the same steady inputs (:func:`ecu_monitor.identify.matched.matched_rise`: what no
form of the model can carry to an airframe with zero flights) and the timings. ``--matched-only`` prints
only that comparison (in a second), with the operating points binned by other inputs too (without the fuel
flow, with the EGT or the altitude) and for each cylinder alone: is the difference one of those?
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from ecu_monitor.bus.canlog import load_flight
from ecu_monitor.flightlog import FlightLog, log_airframe
from ecu_monitor.identify import PsoSettings, flight_errors
from ecu_monitor.identify.matched import BIN_WIDTHS, matched_rise
from ecu_monitor.identify.select import parse_terms
from ecu_monitor.identify.type_model import Adaptation, adapt_choosing, describe_terms, first_minutes, fit_type
from ecu_monitor.model import ThermalParams, load_model, paper_table_a1, save_model

REPO = Path(__file__).resolve().parents[1]
GRID = (4, 4)
#: The type's forms, (heat-map axes, --effects): docs/results/real.md's row 4 (the N550ND
#: leave-one-flight-out best), and the heat on rpm x EGT (a fixed-pitch propeller's rpm sets the power, the
#: EGT where the mixture sits; the paper's altitude factor scales the heat with the air's pressure and temperature).
FORMS = (
    (("fuel_flow_lph", "rpm"), "-altitude_factor,airspeed_cooling,sensor_lag,density_cooling,mixture_index"),
    (("rpm", "egt_c"), "altitude_factor,airspeed_cooling,sensor_lag,density_cooling,-mixture_index"),
)
#: Labels of the airframes in the given data (G1000 system_id -> aircraft).
LABELS = {
    "2E90B4BED": "C172S N550ND (2017)",
    "25BA2E6F4": "C172S 25BA (CAFUC, 2023)",
    "2D87A31FD": "C172R 2D87 (CAFUC, 2023)",
    "24B6FD7AC": "C172S (KGFK, 2011)",
}
TARGETS = (6.0, 4.0, 3.5)
#: Other inputs to bin the operating points by for ``--matched-only`` (label -> column: bin width).
BINNINGS: dict[str, dict[str, float]] = {
    "rpm x fuel flow x airspeed": BIN_WIDTHS,
    "rpm x airspeed (no fuel flow)": {"rpm": 150.0, "airspeed_mps": 10.0},
    "rpm x EGT x airspeed": {"rpm": 150.0, "egt_c": 25.0, "airspeed_mps": 10.0},
    "rpm x fuel flow x EGT x airspeed": {**BIN_WIDTHS, "egt_c": 25.0},
    "rpm x airspeed x altitude": {"rpm": 150.0, "airspeed_mps": 10.0, "altitude_m": 500.0},
}


def _form(spec: str) -> tuple[tuple[str, str], str]:
    """``--form AXIS1,AXIS2:EFFECTS`` -> (heat-map axes, --effects)."""
    axes, sep, effects = spec.partition(":")
    names = tuple(a.strip() for a in axes.split(","))
    if not sep or len(names) != 2 or not all(names):
        raise SystemExit(f"--form: expected AXIS1,AXIS2:EFFECTS, got {spec!r}")
    return (names[0], names[1]), effects


def _load(paths: list[Path]) -> tuple[list[FlightLog], list[str]]:
    flights, airframes = [], []
    for path in paths:
        airframe = log_airframe(path)
        if airframe is None:
            raise SystemExit(f"{path}: names no airframe (system_id)")
        flights.append(load_flight(path, mapping="g1000"))
        airframes.append(airframe)
    return flights, airframes


def _rms(params: ThermalParams, logs: list[FlightLog]) -> float:
    return float(np.mean([flight_errors(params, log).rms_c for log in logs]))


def _rest(log: FlightLog, start_s: float) -> FlightLog:
    t0 = float(log.time_s[0])
    return log.select(t0 + start_s, float(log.time_s[-1]))


def _halves(log: FlightLog) -> tuple[FlightLog, FlightLog]:
    t = np.asarray(log.time_s, dtype=float)
    middle = t[0] + 0.5 * (t[-1] - t[0])
    return log.select(t[0], middle), log.select(float(t[t > middle][0]), t[-1])


def _plain(params: ThermalParams) -> ThermalParams:
    return params.replace(engine_type="", airframes=())


def _described(result: Adaptation) -> str:
    """The form an adaptation chose (its heat-map axes), the held-out RMS of each form, and its terms."""
    axes = ",".join(result.params.heat_axes)
    scores = "/".join(f"{v:.2f}" for v in result.held_out_by_type)
    fit = result.fit
    prior = f" (prior {100 * fit.heat_map_prior:g} %)" if fit.heat_values else ""
    return f"[{axes}; halves {scores}] {describe_terms(fit.terms, fit.heat_values)}{prior}"


def plot_airframe(types: list[ThermalParams], log: FlightLog, path: Path, label: str) -> None:
    """One flight of an airframe the type models never saw: measured CHT and each type model as is (open
    loop), and below it fuel flow, rpm, EGT and airspeed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ecu_monitor.identify import simulate_flight

    minutes = (np.asarray(log.time_s, dtype=float) - float(log.time_s[0])) / 60.0
    fig, axes = plt.subplots(4, 1, figsize=(11, 10), sharex=True, height_ratios=(3, 1.2, 1.2, 1.2))
    axes[0].plot(minutes, log["cht_c"], color="black", label="measured CHT (mean of the cylinders)")
    for params in types:
        simulated = simulate_flight(_plain(params), log, 1.0)
        rms = float(np.sqrt(np.mean((simulated - np.asarray(log["cht_c"], dtype=float)) ** 2)))
        axes[0].plot(
            minutes, simulated, label=f"type model as is, heat on {' x '.join(params.heat_axes)}: {rms:.1f} degC RMS"
        )
    axes[0].set_ylabel("CHT, degC")
    axes[0].set_title(f"{label}: a type model fitted without this airframe")
    axes[0].legend(loc="lower right")
    axes[1].plot(minutes, log["fuel_flow_lph"], color="tab:blue")
    axes[1].set_ylabel("fuel flow, L/h")
    twin = axes[1].twinx()
    twin.plot(minutes, log["rpm"], color="tab:red", linewidth=0.8)
    twin.set_ylabel("rpm", color="tab:red")
    axes[2].plot(minutes, log["egt_c"], color="tab:orange")
    axes[2].set_ylabel("EGT, degC")
    axes[3].plot(minutes, log["airspeed_mps"], color="tab:green")
    axes[3].set_ylabel("airspeed, m/s")
    axes[3].set_xlabel("minutes from the log's start")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)


def plot_adaptations(
    types: list[ThermalParams], own: list[FlightLog], adapted: list[Adaptation], path: Path, label: str
) -> None:
    """An airframe with several flights, adapted from each whole flight in turn: model - measured CHT on its
    other flights, with the adaptation's own terms only (above) and with its heat-map values refitted too
    (below)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ecu_monitor.identify import simulate_flight
    from ecu_monitor.identify.type_model import airframe_model

    fig, axes = plt.subplots(2, 1, figsize=(11, 8), sharex=True, sharey=True)
    for k, result in enumerate(adapted):
        terms_only = airframe_model(_plain(types[result.chosen]), result.fit.terms)
        for j, log in enumerate(own):
            if j == k:
                continue
            minutes = (np.asarray(log.time_s, dtype=float) - float(log.time_s[0])) / 60.0
            measured = np.asarray(log["cht_c"], dtype=float)
            for ax, params in zip(axes, (terms_only, result.params), strict=True):
                error = simulate_flight(params, log, 1.0) - measured
                rms = float(np.sqrt(np.mean(error**2)))
                ax.plot(minutes, error, linewidth=0.7, label=f"flight {j + 1} from flight {k + 1}: {rms:.1f}")
    for ax, title in zip(axes, ("its own terms only", "its own terms and the heat-map values it visits"), strict=True):
        ax.axhline(0.0, color="black", linewidth=0.5)
        ax.set_ylabel("model - CHT, degC")
        ax.set_title(f"{label} adapted from one whole flight: {title} (RMS, degC)")
        ax.legend(fontsize=6, ncol=4, loc="lower right")
    axes[1].set_xlabel("minutes from the log's start")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)


def print_matched(flights: list[FlightLog], airframes: list[str]) -> None:
    """Each airframe's head against the others' at the steady operating points they share: markdown."""
    print("Each airframe against the others at the steady operating points they share (rpm x fuel flow x airspeed):")
    print()
    print(
        "| airframe | CHT rise vs the others, degC (spread over the points) | EGT vs the others, degC"
        " | oil above the air vs the others, degC | matched / steady time, s |"
    )
    print("|---|---:|---:|---:|---:|")
    for name, m in matched_rise(flights, airframes).items():
        print(
            f"| {LABELS.get(name, name)} | {m.offset_c:+.1f} ({m.spread_c:.1f}) | {m.egt_offset_c:+.1f} |"
            f" {m.oil_offset_c:+.1f} | {m.matched_s:.0f} / {m.steady_s:.0f} in {m.bins} points |"
        )


def _airframe_table(title: str, corner: str, names: list[str]) -> None:
    """A markdown table's title and header: one column per airframe."""
    print(title)
    print()
    print(f"| {corner} | " + " | ".join(LABELS.get(n, n) for n in names) + " |")
    print("|---|" + "---:|" * len(names))


def print_matched_variants(flights: list[FlightLog], airframes: list[str]) -> None:
    """The CHT rise against the others binned by each of :data:`BINNINGS` and for each cylinder alone (the
    default binning), against each other airframe alone, and the other readings at rpm x airspeed: degC
    (matched time, s), markdown."""
    names = sorted(set(airframes))
    _airframe_table(
        "Each airframe's head against the others' (degC; matched steady time, s), by what sets the operating point:",
        "binned by / head",
        names,
    )
    cylinders = [c for c in ("cht1_c", "cht2_c", "cht3_c", "cht4_c") if all(log.has(c) for log in flights)]
    rows = [(label, widths, "cht_c") for label, widths in BINNINGS.items()]
    rows += [(f"rpm x fuel flow x airspeed, cylinder {c[3]} alone", BIN_WIDTHS, c) for c in cylinders]
    for label, widths, column in rows:
        result = matched_rise(flights, airframes, widths=widths, cht_column=column)
        cells = [f"{result[n].offset_c:+.1f} ({result[n].matched_s:.0f})" for n in names]
        print(f"| {label} | " + " | ".join(cells) + " |")
    print()
    _airframe_table(
        "Each airframe's head against each other airframe alone (rpm x fuel flow x airspeed; degC, matched s):",
        "airframe / against",
        names,
    )
    for name in names:
        cells = []
        for other in names:
            pair = [(f, a) for f, a in zip(flights, airframes, strict=True) if a in (name, other)]
            m = matched_rise([f for f, _ in pair], [a for _, a in pair])[name] if other != name else None
            cells.append("" if m is None else f"{m.offset_c:+.1f} ({m.matched_s:.0f})")
        print(f"| {LABELS.get(name, name)} | " + " | ".join(cells) + " |")
    print()
    _airframe_table(
        "At rpm x airspeed (no fuel flow): the other readings against the others' (degC, L/h):", "reading", names
    )
    result = matched_rise(flights, airframes, widths=BINNINGS["rpm x airspeed (no fuel flow)"])
    for label, field in (
        ("fuel flow, L/h", "fuel_offset_lph"),
        ("EGT", "egt_offset_c"),
        ("oil above the air", "oil_offset_c"),
    ):
        print(f"| {label} | " + " | ".join(f"{getattr(result[n], field):+.1f}" for n in names) + " |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data" / "real")
    parser.add_argument("--g1000", type=Path, help="directory of the 2011 log (default DATA/../g1000)")
    parser.add_argument("--quick", action="store_true", help="fewer PSO iterations (a smoke run)")
    parser.add_argument("--only", help="comma-separated system_ids to hold out (default every airframe)")
    parser.add_argument("--save", type=Path, help="write each fold's type model into this directory")
    parser.add_argument("--one-form", action="store_true", help="the first form only (no choice of form)")
    parser.add_argument(
        "--types",
        type=Path,
        help="read each fold's type models from this directory (written by --save) instead of fitting",
    )
    parser.add_argument("--plot", type=Path, help="draw each held-out airframe's first flight into this directory")
    parser.add_argument(
        "--form",
        action="append",
        metavar="AXIS1,AXIS2:EFFECTS",
        help="a form to fit instead of FORMS (repeat for several; the first is the zero-flight one), e.g."
        " rpm,airspeed_mps:altitude_factor,airspeed_cooling,sensor_lag,density_cooling,mixture_index",
    )
    parser.add_argument(
        "--matched-only", action="store_true", help="only the airframes' heads compared at the same inputs (no fit)"
    )
    args = parser.parse_args()
    g1000 = args.g1000 or args.data.parent / "g1000"
    paths = sorted(args.data.glob("ngafid_c172s_*.csv")) + sorted(args.data.glob("cafuc_c172*.csv"))
    paths += sorted(g1000.glob("log_*.csv"))
    forms = tuple(_form(spec) for spec in args.form) if args.form else FORMS
    forms = forms[:1] if args.one_form else forms
    flights, airframes = _load(paths)
    if args.matched_only:
        print_matched(flights, airframes)
        print()
        print_matched_variants(flights, airframes)
        return 0
    settings = PsoSettings(particles=24, iterations=10 if args.quick else 30, polish_evaluations=100, dt_s=1.0)
    names = list(dict.fromkeys(airframes))
    held = args.only.split(",") if args.only else names
    rows = []
    timings: dict[str, list[float]] = defaultdict(list)
    for name in held:
        train = [(f, a) for f, a in zip(flights, airframes, strict=True) if a != name]
        own = [f for f, a in zip(flights, airframes, strict=True) if a == name]
        types = []
        for k, (axes, form) in enumerate(forms):
            if args.types:
                types.append(load_model(args.types / f"type{k}_without_{name}.yaml"))
                continue
            started = time.process_time()
            fit = fit_type(
                [f for f, _ in train], [a for _, a in train], engine_type="c172", base=paper_table_a1(),
                heat_axes=axes, grid=GRID, settings=settings, terms=parse_terms(form),
                progress=lambda line: print(line, file=sys.stderr),
            )  # fmt: skip
            timings["type fit, one form (CPU s)"].append(time.process_time() - started)
            types.append(fit.params)
            if args.save:
                args.save.mkdir(parents=True, exist_ok=True)
                save_model(fit.params, args.save / f"type{k}_without_{name}.yaml")
        kept = " ".join(
            f"[{','.join(t.heat_axes)}] "
            + "; ".join(f"{LABELS.get(a.id, a.id)}: {describe_terms(a)}" for a in t.airframes)
            for t in types
        )
        if args.plot:
            plot_airframe(types, own[0], args.plot / f"type_model_{name}.png", LABELS.get(name, name))
        zero = _rms(_plain(types[0]), own)
        zero_forms = [_rms(_plain(t), own) for t in types]
        short, whole, short_terms, whole_terms, adapted = [], [], [], [], []
        for k, log in enumerate(own):
            others = own[:k] + own[k + 1 :]
            started = time.process_time()
            twenty = adapt_choosing(types, [first_minutes(log, 20.0)], name, settings)
            timings["adapt, 20 min (CPU s)"].append(time.process_time() - started)
            short.append(_rms(twenty.params, others or [_rest(log, 20.0 * 60.0)]))
            short_terms.append(_described(twenty))
            first, second = _halves(log)
            started = time.process_time()
            full = adapt_choosing(types, [log] if others else [first], name, settings)
            timings["adapt, one flight (CPU s)"].append(time.process_time() - started)
            whole.append(_rms(full.params, others or [second]))
            whole_terms.append(_described(full))
            adapted.append(full)
        if args.plot and len(own) > 1:
            plot_adaptations(types, own, adapted, args.plot / f"type_adapted_{name}.png", LABELS.get(name, name))
        zeros = " / ".join(f"{z:.2f}" for z in zero_forms)
        rows.append((name, len(own), zero, float(np.mean(short)), float(np.mean(whole)), kept, short_terms,
                     whole_terms, zeros))  # fmt: skip
        print(f"{name}: zero {zeros} (by form), 20 min {np.mean(short):.2f}, whole {np.mean(whole):.2f} degC")
    print(
        "| held-out airframe | its flights | zero flights (type as is) | each form as is | 20 min of one flight"
        " | one whole flight |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    for name, n, zero, short, whole, *_, zeros in rows:
        marks = ["" if v < t else " (miss)" for v, t in zip((zero, short, whole), TARGETS, strict=True)]
        print(
            f"| {LABELS.get(name, name)} | {n} | {zero:.2f}{marks[0]} | {zeros} | {short:.2f}{marks[1]}"
            f" | {whole:.2f}{marks[2]} |"
        )
    means = np.mean([[r[2], r[3], r[4]] for r in rows], axis=0)
    print(f"| mean | | {means[0]:.2f} | | {means[1]:.2f} | {means[2]:.2f} |")
    print()
    for name, _n, _z, _s, _w, kept, short_terms, whole_terms, _zeros in rows:
        print(f"- held out {LABELS.get(name, name)}: the type's airframes' own terms: {kept}")
        print(f"  its own terms from 20 min: {' / '.join(short_terms)}; from one flight: {' / '.join(whole_terms)}")
    print()
    print_matched(flights, airframes)
    print()
    for label, values in timings.items():
        print(f"- {label}: mean {np.mean(values):.1f}, max {np.max(values):.1f} over {len(values)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
