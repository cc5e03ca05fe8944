"""JSBSim's piston engine, an engine model nobody here wrote: identified on one flight, predicting other
missions of the same aircraft open loop, for several of the jsbsim package's piston aircraft.

    nice -n 10 .venv/bin/python benchmarks/bench_jsbsim.py [--aircraft c172p,c182] [--quick] [--out DIR]

For each aircraft, three missions are flown (``virtual-ecu jsbsim``: cross_country seed 1, step_climb
seed 2, cross_country seed 3: other fields, days, levels, power and mixture). Each flight in turn is the
training flight: ``identify`` on it alone with the form of each row below (heat map on fuel flow x rpm,
4x4, the way a light aircraft's engine monitor is identified), then every other flight is predicted open
loop from its first CHT sample; the figure is that held-out RMS (model - measured CHT, degC), per
ordered pair. Rows: the paper's form; ``--effects auto`` (the terms chosen on the training flight's two
halves); the named form the library's real-data best used (docs/results/real.md); the fuel-flow form (no
altitude factor: the fuel flow carries the charge density; airspeed cooling; the mixture index on EGT);
the same with engine_speed_cooling; the cooling-air form (:data:`COOLING_AIR`, 2 x 2: the ram air's mass
flow and the engine-speed conductance, no T^4 term) with its mixture index on the EGT's rise (the flights'
manifold pressure taken out) and on the fuel/air ratio (the start where the manifold pressure is logged); the
same on a 2 x 1 map (``--grid 2x1``: the heat on the fuel alone, engine speed acting on the cooling only).
Then the gap diagnosis (``ecu-monitor gap --model`` the paper's form identified on flight 1 ``--train``
flight 1 ``--test`` flights 2 and 3: local refits) and its verdict, and the same from the cooling-air form
without its two new terms (:data:`GAP_BASE`), trying them.
Prints markdown tables and the wall time of each identification and
of the gap (the term search runs on every core); ``--forms 3,4`` picks rows; ``--quick`` uses a smaller
swarm; ``--no-gap`` skips the gap. The flights and gap reports stay in ``--out`` (default a temporary folder).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ecu_monitor.flightlog import FlightLog, load_csv
from ecu_monitor.identify import PsoSettings, flight_errors
from ecu_monitor.identify.select import identify_flights, parse_terms

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
AXES = ("fuel_flow_lph", "rpm")
GRID = (4, 4)
MISSIONS = (("cross_country", 1), ("step_climb", 2), ("cross_country", 3))
#: The cooling-air form (docs/jsbsim.md): the ram air's mass flow and the engine-speed conductance added to the
#: fuel-flow form, no T^4 term, on a 2 x 2 map (heat linear in fuel flow and rpm: what one flight can pin).
COOLING_AIR = "-altitude_factor,-radiation,airspeed_cooling,mass_flow_cooling,engine_speed_cooling,mixture_index"
#: Rows: (label, --effects value; "" = the paper's form; the heat-map grid; columns taken out of the flights
#: first: without the manifold pressure the mixture index starts on the EGT's rise, with it on the fuel/air ratio).
FORMS = (
    ("paper form", "", GRID, ()),
    ("--effects auto", "auto", GRID, ()),
    (
        "real-data best (docs/results/real.md)",
        "-altitude_factor,airspeed_cooling,sensor_lag,density_cooling,mixture_index",
        GRID,
        (),
    ),
    ("fuel-flow form", "-altitude_factor,airspeed_cooling,mixture_index", GRID, ()),
    (
        "fuel-flow form + engine_speed_cooling",
        "-altitude_factor,airspeed_cooling,mixture_index,engine_speed_cooling",
        GRID,
        (),
    ),
    ("cooling-air form, 2x2, mixture on the EGT's rise", COOLING_AIR, (2, 2), ("manifold_pressure_kpa",)),
    ("cooling-air form, 2x2, mixture on the fuel/air ratio", COOLING_AIR, (2, 2), ()),
    ("cooling-air form, 2x1: heat on the fuel alone", COOLING_AIR, (2, 1), ()),
)
#: The gap diagnosis's start (``gap --model``): the cooling-air form without its two new terms, and the
#: candidates it tries (the library's defaults and the two cooling-air terms).
GAP_BASE = ("-altitude_factor,-radiation,airspeed_cooling,mixture_index", (2, 2))
GAP_CANDIDATES = "airspeed_cooling,density_cooling,sensor_lag,mixture_cooling,mass_flow_cooling,engine_speed_cooling"
TARGET_C = 3.0


def fly(aircraft: str, out: Path) -> list[Path]:
    """The missions of ``aircraft`` flown to CSVs in ``out`` (the user's command)."""
    paths = []
    for mission, seed in MISSIONS:
        path = out / f"{aircraft}_{mission}_{seed}.csv"
        cmd = [str(BIN / "virtual-ecu"), "jsbsim", "--aircraft", aircraft, "--mission", mission,
               "--seed", str(seed), "--out", str(path)]  # fmt: skip
        subprocess.run(cmd, check=True, capture_output=True, text=True)
        paths.append(path)
    return paths


def held_out(
    flights: list[FlightLog], effects: str, settings: PsoSettings, grid: tuple[int, int] = GRID
) -> tuple[np.ndarray, float]:
    """RMS (degC) of the model identified on flight i predicting flight j (NaN on the diagonal), and the
    identifications' wall time (s; the term search runs on every core)."""
    n = len(flights)
    rms = np.full((n, n), np.nan)
    start = time.perf_counter()
    for i in range(n):
        terms = "auto" if effects == "auto" else (parse_terms(effects) if effects else {})
        result, _cv, _sel = identify_flights(
            [flights[i]], base=_base(), heat_axes=AXES, grid=grid, settings=settings, terms=terms, lofo=False
        )
        for j in range(n):
            if j != i:
                rms[i, j] = flight_errors(result.params, flights[j]).rms_c
    return rms, time.perf_counter() - start


def _without(log: FlightLog, dropped: tuple[str, ...]) -> FlightLog:
    """``log`` without the columns ``dropped`` (a log that never had them)."""
    if not dropped:
        return log
    return FlightLog({k: v for k, v in log.columns.items() if k not in dropped}, log.source, log.notes)


def _base():  # the paper's Table A1, as identify starts from
    from ecu_monitor.model import paper_table_a1

    return paper_table_a1()


def gap_verdict(paths: list[Path], out: Path, effects: str = "", grid: tuple[int, int] = GRID,
                candidates: str = "") -> tuple[str, float]:  # fmt: skip
    """``ecu-monitor gap --train`` the first flight ``--test`` the others, from the form ``effects`` (default the
    paper's) identified on the train flight (``identify``, then the gap's local refits of ``candidates``, default
    the library's): its verdict and wall time (s)."""
    tag = "cooling" if effects else "paper"
    folder = out / f"gap_{tag}_{paths[0].stem}"
    nominal = out / f"nominal_{tag}_{paths[0].stem}.yaml"
    start = time.perf_counter()
    form = [f"--effects={effects}"] if effects else []
    subprocess.run([str(BIN / "ecu-monitor"), "identify", str(paths[0]), "--heat-axes", ",".join(AXES), "--grid",
                    "x".join(map(str, grid)), *form, "--out", str(nominal), "--quiet"], check=True,
                   capture_output=True)  # fmt: skip
    pick = ["--candidates", candidates] if candidates else []
    cmd = [str(BIN / "ecu-monitor"), "gap", "--model", str(nominal), "--train", str(paths[0]), "--test",
           *map(str, paths[1:]), *pick, "--out", str(folder)]  # fmt: skip
    done = subprocess.run(cmd, check=True, capture_output=True, text=True)
    wall = time.perf_counter() - start
    report = json.loads((folder / "gap.json").read_text(encoding="utf-8"))
    verdict = report["verdict"]
    base = report["baseline"]["test_rms_c"]
    best = min(report["effects"], key=lambda e: e["test_rms_c"]) if report["effects"] else None
    lines = [line for line in done.stdout.splitlines() if line.strip()]
    text = (
        f"verdict {verdict['effect'] or 'unexplained'}; baseline held-out {base:.2f} degC"
        + (f", best candidate {best['id']} {best['test_rms_c']:.2f} degC" if best else "")
        + (f" ({lines[-4].strip()})" if len(lines) >= 4 and not verdict["effect"] else "")
    )
    return text, wall


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--aircraft", default="c172p,c182", help="comma-separated aircraft (default c172p,c182)")
    parser.add_argument("--quick", action="store_true", help="a smaller swarm (24 particles, 30 iterations)")
    parser.add_argument("--out", type=Path, help="folder kept for the flights and gap reports (default: temporary)")
    parser.add_argument("--forms", default=",".join(str(k) for k in range(len(FORMS))), help="rows to run (indices)")
    parser.add_argument("--no-gap", action="store_true", help="the held-out tables only, not the gap diagnoses")
    args = parser.parse_args()
    settings = PsoSettings(particles=24, iterations=30) if args.quick else PsoSettings()
    forms = [FORMS[int(k)] for k in args.forms.split(",")]
    with tempfile.TemporaryDirectory(prefix="bench-jsbsim-") as scratch:
        out = args.out or Path(scratch)
        out.mkdir(parents=True, exist_ok=True)
        for aircraft in args.aircraft.split(","):
            start = time.perf_counter()
            paths = fly(aircraft, out)
            flights = [load_csv(p) for p in paths]
            names = [p.stem.removeprefix(f"{aircraft}_") for p in paths]
            minutes = ", ".join(f"{f.duration_s / 60:.0f}" for f in flights)
            print(
                f"\n## {aircraft}: {len(flights)} flights ({minutes} min), flown in {time.perf_counter() - start:.0f} s"
            )
            print("\nheld-out RMS, degC (identified on the row's flight, predicting the column's), mean and worst:\n")
            print("| form | train -> test | " + " | ".join(names) + " | mean | worst |")
            print("|---|---|" + "---|" * (len(names) + 2))
            for label, effects, grid, dropped in forms:
                rms, wall = held_out([_without(f, dropped) for f in flights], effects, settings, grid)
                off = rms[~np.isnan(rms)]
                for i, name in enumerate(names):
                    cells = " | ".join("-" if np.isnan(v) else f"{v:.2f}" for v in rms[i])
                    head = f"{label} ({wall / len(names):.0f} s each)" if i == 0 else ""
                    tail = f"{off.mean():.2f} | {off.max():.2f}" if i == 0 else " | "
                    print(f"| {head} | {name} -> | {cells} | {tail} |")
                print(f"<!-- {label}: mean {off.mean():.2f}, worst {off.max():.2f}, target {TARGET_C} -->")
                sys.stdout.flush()
            if args.no_gap:
                continue
            text, wall = gap_verdict(paths, out)
            print(f"\ngap from the paper's form (train {names[0]}, test the others): {text} ({wall:.0f} s)")
            text, wall = gap_verdict(paths, out, GAP_BASE[0], GAP_BASE[1], GAP_CANDIDATES)
            print(f"\ngap from {GAP_BASE[0]} (train {names[0]}, test the others): {text} ({wall:.0f} s)")
            sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
