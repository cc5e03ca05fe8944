"""Wall time of a whole gap diagnosis on four train and three test flights of about 100 minutes each,
against the same refit on the numpy model in the same run.

    .venv/bin/python benchmarks/bench_gap.py [--duration 6000] [--train 4] [--test 3] [--seed 7]

Seven virtual-ECU flights of about ``--duration`` seconds on different random missions, with a sensor
lag (8 s) and airspeed cooling in the truth (so the greedy pair stage runs too), and a perturbed
nominal model (as in the blind cases); then, timed as ``ecu-monitor gap`` runs them:

* with ``--model`` (local refits): baseline, localisation (incl. the CBEKF-AU innovations on every
  test flight), control, the default candidates, pairs, significance tests (flights and blocks
  resampled); plus writing gap.json, report.md, the plots and model.yaml;
* without ``--model``: PSO identification of the nominal model on the train flights, then every
  candidate refitted jointly with the whole model (``--refit reidentify``, the command's default
  then), and the report;
* without ``--model`` and with ``--leave-one-out`` over the train flights (one identification on all of
  them, each fold's nominal model warm-started from it: :mod:`ecu_monitor.gap.folds`; every candidate
  re-identified jointly per fold), reported as a ratio to the plain run without ``--model`` (a variant:
  ``gap --leave-one-out`` itself keeps a swarm per fold, docs/performance.md says why);
* with ``--model`` and ``--leave-one-out`` over the train flights (each held out in turn, every
  candidate refitted on the others, the refits of all folds and candidates on every core), reported as
  a ratio to the plain ``--model`` run above (issue 28's target: at most 3x);
* the baseline measured in the same run: ONE single-effect refit (sensor_lag) on the first train
  flight with the plain numpy model loop (``RefitSettings(engine="numpy")``) against the same refit
  with the compiled swarm simulator, reported as a ratio.

Compile time is excluded (one warm-up diagnosis on short flights first; numba caches on disk).
Each figure is given as wall time and as the process's CPU time (all threads): on a shared, loaded
machine the wall time mostly measures the other processes, the CPU time what the diagnosis costs.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np

from ecu_monitor.gap import GapSettings, cross_validate, diagnose, write_report
from ecu_monitor.gap.diagnosis import JOINT_REFIT
from ecu_monitor.gap.folds import fold_nominals
from ecu_monitor.identify import identify
from ecu_monitor.identify.library import candidate, candidates_for, flight_references
from ecu_monitor.identify.refit import RefitSettings, prepare_flight, refit
from ecu_monitor.model import AirspeedCooling, Effects, SensorLag, paper_table_a1
from ecu_monitor.research.blind import perturbed_nominal
from virtual_bus.plant import fly
from virtual_bus.random_missions import random_mission


def _cpu_s() -> float:
    """CPU seconds of this process and of its finished children (the forked refit workers)."""
    own = os.times()
    return own.user + own.system + own.children_user + own.children_system


def main() -> None:
    """Run the benchmark and print the table rows."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=6000.0)
    parser.add_argument("--train", type=int, default=4)
    parser.add_argument("--test", type=int, default=3)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    truth = paper_table_a1()
    effects = Effects(sensor_lag=SensorLag(8.0), airspeed_cooling=AirspeedCooling(0.02, floor=0.45))
    nominal = perturbed_nominal(truth, np.random.default_rng(args.seed))
    ids = candidates_for(nominal.heat_axes, [])
    local = GapSettings(candidates=ids)

    warm = [fly(random_mission(s, 900.0), truth, effects=effects, seed=s, record_dt_s=1.0) for s in (1, 2, 3)]
    diagnose(nominal, warm[:2], warm[2:], local)

    flights = [
        fly(random_mission(args.seed + k, args.duration), truth, effects=effects, seed=args.seed + k, record_dt_s=1.0)
        for k in range(args.train + args.test)
    ]
    trains, tests = flights[: args.train], flights[args.train :]
    minutes = [f"{f.duration_s / 60:.0f}" for f in flights]
    print(f"flights: {args.train} train + {args.test} test, {', '.join(minutes)} min, {sum(map(len, flights))} samples")

    started, cpu = time.perf_counter(), _cpu_s()
    diag = diagnose(nominal, trains, tests, local)
    with tempfile.TemporaryDirectory() as out:
        write_report(diag, out)
    local_s, local_cpu = time.perf_counter() - started, _cpu_s() - cpu
    fits = 1 + len(diag.effects)
    verdict = diag.winner.label if diag.winner else "unexplained"
    print(
        f"with --model: {len(ids)} candidates, {fits} refits, report: {local_s:.1f} s wall,"
        f" {local_cpu:.1f} s CPU; verdict {verdict}"
    )

    started, cpu = time.perf_counter(), _cpu_s()
    diag_loo = cross_validate([nominal] * len(trains), trains, nominal, local)
    with tempfile.TemporaryDirectory() as out:
        write_report(diag_loo, out)
    loo_s, loo_cpu = time.perf_counter() - started, _cpu_s() - cpu
    verdict = diag_loo.winner.label if diag_loo.winner else "unexplained"
    print(
        f"with --model --leave-one-out over the {len(trains)} train flights: {loo_s:.1f} s wall, {loo_cpu:.1f} s CPU"
        f" (with the workers); {loo_s / local_s:.2f}x the plain run's wall time; verdict {verdict},"
        f" held-out shrink {diag_loo.winner.shrink_pct if diag_loo.winner else 0.0:.0f} %"
    )

    started, cpu = time.perf_counter(), _cpu_s()
    identified = identify(trains, heat_axes=nominal.heat_axes).params
    identify_s, identify_cpu = time.perf_counter() - started, _cpu_s() - cpu
    joint = GapSettings(candidates=ids, refit_mode="reidentify")
    diag_joint = diagnose(identified, trains, tests, joint)
    with tempfile.TemporaryDirectory() as out:
        write_report(diag_joint, out)
    total_s, total_cpu = time.perf_counter() - started, _cpu_s() - cpu
    verdict = diag_joint.winner.label if diag_joint.winner else "unexplained"
    print(
        f"without --model: identify {identify_s:.1f} s + joint refits and report {total_s - identify_s:.1f} s"
        f" = {total_s:.1f} s wall; CPU {identify_cpu:.1f} + {total_cpu - identify_cpu:.1f}"
        f" = {total_cpu:.1f} s; verdict {verdict}"
    )

    started, cpu = time.perf_counter(), _cpu_s()
    identified_all = identify(trains, heat_axes=nominal.heat_axes).params
    nominals = fold_nominals(trains, identified_all, JOINT_REFIT)
    diag_joint_loo = cross_validate(nominals, trains, identified_all, joint)
    with tempfile.TemporaryDirectory() as out:
        write_report(diag_joint_loo, out)
    joint_loo_s, joint_loo_cpu = time.perf_counter() - started, _cpu_s() - cpu
    winner = diag_joint_loo.winner
    print(
        f"without --model, --leave-one-out over the {len(trains)} train flights (one identification, warm-started"
        f" fold nominals): {joint_loo_s:.1f} s wall, {joint_loo_cpu:.1f} s CPU; {joint_loo_s / total_s:.2f}x wall,"
        f" {joint_loo_cpu / total_cpu:.2f}x CPU of the plain run without --model; verdict"
        f" {winner.label if winner else 'unexplained'}, held-out shrink {winner.shrink_pct if winner else 0.0:.0f} %"
    )

    refs = flight_references(trains[0])
    timings = {}
    for engine in ("compiled", "numpy"):
        rs = RefitSettings(engine=engine)
        flight = prepare_flight(trains[0], nominal.heat_axes, rs.dt_s)
        started = time.perf_counter()
        fit = refit(nominal, flight, [candidate("sensor_lag")], refs, rs)
        timings[engine] = (time.perf_counter() - started, fit.evaluations, fit.values["sensor_lag"]["time_constant_s"])
    comp, nump = timings["compiled"], timings["numpy"]
    print(f"sensor_lag refit, one flight, compiled swarm: {comp[0]:.2f} s ({comp[1]} evaluations, tau {comp[2]:.2f} s)")
    print(
        f"sensor_lag refit, one flight, numpy model loop: {nump[0]:.2f} s ({nump[1]} evaluations, tau {nump[2]:.2f} s)"
    )
    print(f"ratio numpy / compiled: {nump[0] / comp[0]:.0f}x")


if __name__ == "__main__":
    main()
