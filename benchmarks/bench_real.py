"""Real engines: leave-one-flight-out identification on the given Cessna 172S N550ND flights, before and
after each model change, and the other given aircraft. Writes docs/results/real.md and its plots.

    nice -n 10 .venv/bin/python benchmarks/bench_real.py --data DIR         # all of it (about 15 min CPU)
    nice -n 10 .venv/bin/python benchmarks/bench_real.py --data DIR --quick # fewer PSO iterations

DIR holds the real flight logs (the G1000 exports named ngafid_c172s_n550nd_*.csv, cafuc_*.csv and, one
level up, g1000/log_*.csv). Every N550ND figure is leave-one-flight-out: the model is identified on
three flights and scored on the fourth, which it never saw, for each of the four; the choices made
inside ``--effects auto`` use the three training flights only (nested), so no choice looks at the
flight it is scored on. Errors are |model - measured| of the mean CHT of the four cylinders, by
segment (ground, climb, cruise, descent: ecu_monitor.gap.segments) and per cylinder.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from ecu_monitor.bus.canlog import load_flight
from ecu_monitor.errors import EcuMonitorError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.gap.segments import SEGMENT_NAMES, segment_flight
from ecu_monitor.identify import ErrorStats, PsoSettings, identify, simulate_flight
from ecu_monitor.identify.report import plot_flight
from ecu_monitor.identify.select import identify_flights, model_form, term_is_on
from ecu_monitor.model import ThermalParams, paper_table_a1, save_model

REPO = Path(__file__).resolve().parents[1]
OUT_MD = REPO / "docs" / "results" / "real.md"
PLOTS = REPO / "docs" / "results" / "real"
AXES = ("fuel_flow_lph", "rpm")
GRID = (4, 4)

#: Model changes, each measured on its own: (label, --effects value).
VARIANTS: tuple[tuple[str, str], ...] = (
    ("paper form (heat map on fuel flow x rpm)", ""),
    ("- altitude factor g", "-altitude_factor"),
    ("+ airspeed cooling (prop-wash floor)", "-altitude_factor,airspeed_cooling"),
    ("+ probe lag", "-altitude_factor,airspeed_cooling,sensor_lag"),
    ("+ density cooling", "-altitude_factor,airspeed_cooling,sensor_lag,density_cooling"),
    ("+ mixture index (mean EGT)", "-altitude_factor,airspeed_cooling,sensor_lag,density_cooling,mixture_index"),
    ("radiation in kelvin", "-altitude_factor,airspeed_cooling,sensor_lag,density_cooling,radiation_kelvin"),
    ("--effects auto (nested)", "auto"),
)


def load_dir(data: Path, pattern: str) -> list[FlightLog]:
    """Every file of ``pattern`` in ``data`` through the shipped g1000 mapping (a failure is reported)."""
    out = []
    for path in sorted(data.glob(pattern)):
        try:
            out.append(load_flight(path, mapping="g1000"))
        except EcuMonitorError as exc:
            print(f"skipped {path.name}: {exc}", file=sys.stderr)
    return out


def twin_engines(data: Path) -> list[FlightLog]:
    """Each engine of the NGAFID processed twin logs (ngafid_pa44_*.csv, mapping auto), as its own flight."""
    out = []
    for path in sorted(data.glob("ngafid_pa44_*.csv")):
        for engine in (1, 2):
            try:
                log = load_flight(path, engine=engine)
                out.append(replace(log, source=f"{path.with_suffix('')}_e{engine}.csv"))
            except EcuMonitorError as exc:
                print(f"skipped {path.name} engine {engine}: {exc}", file=sys.stderr)
    return out


def with_cht(log: FlightLog, column: str) -> FlightLog:
    """The flight with ``column`` (one cylinder, chtK_c) as the measured CHT and, where the log has it,
    the same cylinder's EGT (egtK_c) as its mixture index: each cylinder runs at its own mixture."""
    egt = column.replace("cht", "egt")
    extra = {"egt_c": np.asarray(log[egt], dtype=float)} if column != "cht_c" and log.has(egt) else {}
    return log.with_columns(cht_c=np.asarray(log[column], dtype=float), **extra)


def terms_of(text: str) -> dict[str, bool] | str:
    from ecu_monitor.identify.select import parse_terms

    return "auto" if text == "auto" else (parse_terms(text) if text else {})


def fit(flights: Sequence[FlightLog], effects: str, settings: PsoSettings) -> ThermalParams:
    """One identification on ``flights`` with the given --effects (auto: chosen on these flights only)."""
    result, _cv, _sel = identify_flights(
        flights,
        base=paper_table_a1(),
        heat_axes=AXES,
        grid=GRID,
        settings=settings,
        terms=terms_of(effects),
        lofo=False,
    )
    return result.params


def segment_rms(log: FlightLog, simulated: np.ndarray) -> dict[str, float]:
    """RMS error (degC) of each flight segment (NaN where the flight has none)."""
    seg = segment_flight(log)
    err = simulated - np.asarray(log["cht_c"])
    return {
        name: float(np.sqrt(np.mean(err[seg.mask(name)] ** 2))) if seg.mask(name).any() else math.nan
        for name in SEGMENT_NAMES
    }


def lofo(flights: Sequence[FlightLog], effects: str, settings: PsoSettings) -> list[tuple[ThermalParams, np.ndarray]]:
    """Leave-one-flight-out: (model fitted on the others, its prediction) for each flight."""
    out = []
    for k, log in enumerate(flights):
        params = fit([f for i, f in enumerate(flights) if i != k], effects, settings)
        out.append((params, simulate_flight(params, log)))
    return out


def rms_c(simulated: np.ndarray, log: FlightLog) -> float:
    """RMS of model - measured CHT, degC."""
    return float(np.sqrt(np.mean((simulated - np.asarray(log["cht_c"])) ** 2)))


def name_of(log: FlightLog) -> str:
    return Path(log.source).stem


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data" / "real", help="real logs")
    parser.add_argument("--quick", action="store_true", help="fewer PSO iterations (a smoke run)")
    parser.add_argument("--variants", help="comma-separated indices of VARIANTS to run (default all)")
    parser.add_argument("--out", type=Path, default=OUT_MD, help="markdown to write (default docs/results/real.md)")
    parser.add_argument(
        "--sections", default="plots,timings,per_cylinder,other_aircraft", help="sections after the table"
    )
    args = parser.parse_args()
    out_md: Path = args.out
    settings = PsoSettings(particles=24, iterations=10 if args.quick else 30, polish_evaluations=100, dt_s=1.0)
    n550 = load_dir(args.data, "ngafid_c172s_n550nd_*.csv")
    if len(n550) < 2:
        print(f"{args.data}: fewer than 2 N550ND flights readable", file=sys.stderr)
        return 2
    PLOTS.mkdir(parents=True, exist_ok=True)
    chosen = [int(v) for v in args.variants.split(",")] if args.variants else list(range(len(VARIANTS)))
    md: list[str] = [
        "# Real engines: identification on Cessna 172S N550ND and other aircraft",
        "",
        "Generated by `nice -n 10 .venv/bin/python benchmarks/bench_real.py --data DIR"
        + (f" --variants {args.variants}" if args.variants else "")
        + "` (DIR: the real G1000 logs),"
        f" PSO {settings.particles} particles x {settings.iterations} iterations, least-squares polish"
        f" {settings.polish_evaluations}, identification step {settings.dt_s:g} s, heat map {AXES[0]} x {AXES[1]}"
        f" {GRID[0]}x{GRID[1]} at the data's quantiles, start: the paper's Table A1.",
        "",
        "Every figure below is **leave-one-flight-out** over the four given N550ND flights: the model is identified"
        " on three flights and predicts the fourth open loop from its first CHT sample, for each of the four."
        " `--effects auto` chooses its terms on the three training flights only (nested), so nothing is"
        " chosen by looking at the held-out flight. Error: model - mean CHT of the four cylinders, degC.",
        "",
        "## Held-out RMS error per flight, before and after each model change",
        "",
        "| model | "
        + " | ".join(name_of(log)[-13:] for log in n550)
        + " | mean | worst | ground | climb | cruise | descent |"
        " fit time (s, CPU) |",
        "|---|" + "---:|" * (len(n550) + 7),
    ]
    best: tuple[float, int, list[tuple[ThermalParams, np.ndarray]]] | None = None
    for index in chosen:
        label, effects = VARIANTS[index]
        started = time.process_time()
        folds = lofo(n550, effects, settings)
        cpu = (time.process_time() - started) / len(n550)
        rms = [rms_c(sim, log) for log, (_p, sim) in zip(n550, folds, strict=True)]
        segs = [segment_rms(log, sim) for log, (_p, sim) in zip(n550, folds, strict=True)]
        seg_mean = {name: float(np.nanmean([s[name] for s in segs])) for name in SEGMENT_NAMES}
        mean = float(np.mean(rms))
        md.append(
            f"| {label} | "
            + " | ".join(f"{v:.2f}" for v in rms)
            + f" | **{mean:.2f}** | {max(rms):.2f} | "
            + " | ".join(f"{seg_mean[n]:.2f}" for n in SEGMENT_NAMES)
            + f" | {cpu:.0f} |"
        )
        print(md[-1], flush=True)
        out_md.write_text("\n".join(md) + "\n", encoding="utf-8")  # partial results survive an interruption
        if effects == "auto":
            md_auto = [
                f"- held out {name_of(log)}: " + ", ".join(n for n in _term_names() if term_is_on(p, n))
                for log, (p, _s) in zip(n550, folds, strict=True)
            ]
        if best is None or mean < best[0]:
            best = (mean, index, folds)
    md += [
        "",
        "Segment columns: RMS error within each segment, mean over the four held-out flights, degC."
        " Fit time: CPU seconds per identification on three flights (the machine is shared; wall time is longer).",
        "",
    ]
    if any(VARIANTS[i][1] == "auto" for i in chosen):
        md += ["Terms `--effects auto` kept in each outer fold (chosen on the other three flights):", "", *md_auto, ""]
    assert best is not None
    mean, index, folds = best
    label, effects = VARIANTS[index]
    sections = set(args.sections.split(","))
    if "plots" in sections:
        md += [f"## Measured vs model per flight ({label})", ""]
        for log, (_params, sim) in zip(n550, folds, strict=True):
            errors = ErrorStats.from_series(sim, np.asarray(log["cht_c"]), np.asarray(log["oat_c"]))
            path = PLOTS / f"lofo_{name_of(log)}.png"
            plot_flight(log, sim, path, f"held out: {name_of(log)} (model identified on the other three)", errors)
            md.append(f"![{name_of(log)}](real/{path.name})")
        md.append("")
    for section in (s for s in (timings, per_cylinder, other_aircraft) if s.__name__ in sections):
        out_md.write_text("\n".join(md) + "\n", encoding="utf-8")
        md += section(args.data, n550, effects, settings, label)
    out_md.write_text("\n".join(md) + "\n", encoding="utf-8")
    print(f"wrote {out_md}")
    return 0


def _term_names() -> tuple[str, ...]:
    from ecu_monitor.identify.select import TERM_NAMES

    return TERM_NAMES


def per_cylinder(_data: Path, n550: list[FlightLog], effects: str, settings: PsoSettings, label: str) -> list[str]:
    """Leave-one-flight-out per cylinder: each cylinder's CHT identified and predicted on its own."""
    columns = [c for c in (f"cht{k}_c" for k in range(1, 9)) if all(log.has(c) for log in n550)]
    if not columns:
        return ["## Per cylinder", "", "The import does not keep the cylinders apart yet (no cht1_c columns).", ""]
    md = [
        f"## Per cylinder ({label})",
        "",
        "Each cylinder's CHT identified and predicted on its own, leave-one-flight-out; held-out RMS, degC.",
        "",
        "| cylinder | mean CHT, degC | " + " | ".join(name_of(log)[-13:] for log in n550) + " | mean | worst |",
        "|---|---:|" + "---:|" * (len(n550) + 2),
    ]
    for column in columns:
        flights = [with_cht(log, column) for log in n550]
        folds = lofo(flights, effects, settings)
        rms = [
            float(np.sqrt(np.mean((sim - log["cht_c"]) ** 2))) for log, (_p, sim) in zip(flights, folds, strict=True)
        ]
        level = float(np.mean([np.mean(log["cht_c"]) for log in flights]))
        md.append(
            f"| {column} | {level:.0f} | "
            + " | ".join(f"{v:.2f}" for v in rms)
            + f" | **{np.mean(rms):.2f}** | {max(rms):.2f} |"
        )
        print(md[-1], flush=True)
    return [*md, ""]


def timings(_data: Path, n550: list[FlightLog], effects: str, settings: PsoSettings, _label: str) -> list[str]:
    """Wall and CPU time of one identification on all four flights (the figure in docs/performance.md)."""
    fixed = effects if effects != "auto" else VARIANTS[4][1]
    form, names = model_form(paper_table_a1(), n550, terms_of(fixed))  # type: ignore[arg-type]
    wall, cpu = time.perf_counter(), time.process_time()
    identify(n550, base=form, heat_axes=AXES, free=names, grid=GRID, settings=settings)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return [
        "## Timing",
        "",
        f"One identification on all four flights with `--effects {fixed}`: {wall:.1f} s wall, {cpu:.1f} s CPU"
        " (shared 2-core machine).",
        "",
    ]


def other_aircraft(data: Path, n550: list[FlightLog], effects: str, settings: PsoSettings, _label: str) -> list[str]:
    """Other aircraft: the N550ND model as is (a different engine), and each flight split in halves."""
    others = load_dir(data, "cafuc_*.csv") + load_dir(data.parent / "g1000", "log_*.csv") + twin_engines(data)
    md = ["## Other aircraft", ""]
    if not others:
        return [*md, "No other aircraft's log could be read.", ""]
    model = fit(n550, effects, settings)
    save_model(model, PLOTS / "n550nd_model.yaml", comment="bench_real.py: identified on the four N550ND flights")
    md += [
        "Two checks per flight: the model identified on all four N550ND flights applied as is (another airframe and"
        " engine: transfer), and a model of the same form identified on the flight's first half predicting its"
        " second half.",
        "",
        "| flight | N550ND model, RMS degC | own first half -> second half, RMS degC |",
        "|---|---:|---:|",
    ]
    for log in others:
        try:
            as_is = float(np.sqrt(np.mean((simulate_flight(model, log) - log["cht_c"]) ** 2)))
            t = np.asarray(log.time_s)
            half = t[0] + 0.5 * (t[-1] - t[0])
            first = log.select(t[0], half)
            second = log.select(half + 1e-6, t[-1])
            own = fit([first], effects if effects != "auto" else VARIANTS[4][1], settings)
            split = float(np.sqrt(np.mean((simulate_flight(own, second) - second["cht_c"]) ** 2)))
            md.append(f"| {name_of(log)} | {as_is:.2f} | {split:.2f} |")
        except EcuMonitorError as exc:
            md.append(f"| {name_of(log)} | failed: {exc} | |")
        print(md[-1], flush=True)
    return [*md, ""]


if __name__ == "__main__":
    sys.exit(main())
