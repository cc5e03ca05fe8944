"""Wall time of a whole gap diagnosis on two one-hour flights, against the same refit on the numpy model.

    .venv/bin/python benchmarks/bench_gap.py [--duration 3600] [--seed 7]

Two virtual-ECU flights of about ``--duration`` seconds on different random missions with a sensor
lag (8 s) and airspeed cooling in the truth (so the greedy pair stage runs too), a perturbed nominal
model (as in the blind cases), then:

* the whole diagnosis with every library candidate (``CANDIDATE_IDS``, the opt-in one included):
  baseline, localisation (incl. the CBEKF-AU innovations), control, every single refit, pairs,
  significance tests; plus writing gap.json, report.md, four plots and model.yaml;
* the command's path without ``--model``: PSO identification of the nominal model on the train
  flight, then the diagnosis with every candidate re-identified jointly with the model (PSO each);
* the baseline measured in the same run: ONE single-effect refit (sensor_lag) with the plain numpy
  model loop (``RefitSettings(engine="numpy")``) against the same refit with the compiled swarm
  simulator, reported as a ratio.

Compile time is excluded (one warm-up diagnosis on a short flight first; numba caches on disk).
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np

from ecu_monitor.gap import GapSettings, diagnose, write_report
from ecu_monitor.gap.library import CANDIDATE_IDS, candidate, flight_references
from ecu_monitor.gap.refit import RefitSettings, prepare_flight, refit
from ecu_monitor.identify import identify
from ecu_monitor.model import AirspeedCooling, Effects, SensorLag, paper_table_a1
from ecu_monitor.research.blind import perturbed_nominal
from virtual_bus.missions import random_mission
from virtual_bus.plant import fly


def main() -> None:
    """Run the benchmark and print the table rows."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=3600.0)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    truth = paper_table_a1()
    effects = Effects(sensor_lag=SensorLag(8.0), airspeed_cooling=AirspeedCooling(0.02, floor=0.45))
    nominal = perturbed_nominal(truth, np.random.default_rng(args.seed))
    settings = GapSettings(candidates=CANDIDATE_IDS)

    warm_train = fly(random_mission(1, 900.0), truth, effects=effects, seed=1, record_dt_s=1.0)
    warm_test = fly(random_mission(2, 900.0), truth, effects=effects, seed=2, record_dt_s=1.0)
    diagnose(nominal, warm_train, warm_test, settings)

    train = fly(random_mission(args.seed, args.duration), truth, effects=effects, seed=args.seed, record_dt_s=1.0)
    test = fly(
        random_mission(args.seed + 1, args.duration), truth, effects=effects, seed=args.seed + 1, record_dt_s=1.0
    )
    print(f"flights: train {train.duration_s:.0f} s, test {test.duration_s:.0f} s, {len(train) + len(test)} samples")

    started = time.perf_counter()
    diag = diagnose(nominal, train, test, settings)
    diagnose_s = time.perf_counter() - started
    with tempfile.TemporaryDirectory() as out:
        started = time.perf_counter()
        write_report(diag, out)
        report_s = time.perf_counter() - started
    fits = 1 + len(diag.effects)
    print(f"diagnosis, {len(CANDIDATE_IDS)} candidates, {fits} refits (control + singles + pairs): {diagnose_s:.1f} s")
    print(f"report (gap.json, report.md, 4 plots, model.yaml): {report_s:.1f} s")
    print(f"total: {diagnose_s + report_s:.1f} s; verdict {diag.winner.label if diag.winner else 'unexplained'}")

    started = time.perf_counter()
    nominal_identified = identify([train], heat_axes=nominal.heat_axes).params
    identify_s = time.perf_counter() - started
    started = time.perf_counter()
    diag_pso = diagnose(nominal_identified, train, test, GapSettings(candidates=CANDIDATE_IDS, refit_mode="reidentify"))
    reidentify_s = time.perf_counter() - started
    print(
        f"without --model: identify nominal {identify_s:.1f} s + diagnosis with PSO re-identification per candidate"
        f" {reidentify_s:.1f} s = {identify_s + reidentify_s:.1f} s;"
        f" verdict {diag_pso.winner.label if diag_pso.winner else 'unexplained'}"
    )

    refs = flight_references(train)
    timings = {}
    for engine in ("compiled", "numpy"):
        rs = RefitSettings(engine=engine)
        flight = prepare_flight(train, nominal.heat_axes, rs.dt_s)
        started = time.perf_counter()
        fit = refit(nominal, flight, [candidate("sensor_lag")], refs, rs)
        timings[engine] = (time.perf_counter() - started, fit.evaluations, fit.values["sensor_lag"]["time_constant_s"])
    comp, nump = timings["compiled"], timings["numpy"]
    print(f"sensor_lag refit, compiled swarm: {comp[0]:.2f} s ({comp[1]} evaluations, tau {comp[2]:.2f} s)")
    print(f"sensor_lag refit, numpy model loop: {nump[0]:.2f} s ({nump[1]} evaluations, tau {nump[2]:.2f} s)")
    print(f"ratio numpy / compiled: {nump[0] / comp[0]:.0f}x")


if __name__ == "__main__":
    main()
