"""Identification benchmark and the measurements behind the choices in docs/results/identification.md.

    .venv/bin/python benchmarks/bench_identify.py                  # main: 1 h flight, PSO vs DE vs numpy loop
    .venv/bin/python benchmarks/bench_identify.py --study dt       # integration step inside identification
    .venv/bin/python benchmarks/bench_identify.py --study variants # PSO variants and DE, several seeds
    .venv/bin/python benchmarks/bench_identify.py --study g1000 --plots docs/results/identification
    nice -n 10 .venv/bin/python benchmarks/bench_identify.py --study plants --seeds 10  # randomised plants
    nice -n 10 .venv/bin/python benchmarks/bench_identify.py --study term-search  # --effects auto vs named terms

Virtual flights: the virtual ECU (virtual_bus.plant.fly) flies random_mission(1) (train) and
random_mission(2) (held out), both about one hour, truth = the paper's Table A1, CHT sampled at 1 Hz
with 0.3 degC noise and the 1 degC quantiser. Identification starts from a deliberately wrong base
(C_w x1.6, R_Ce x0.6, tau_w x2.5, heat map x1.4); alpha_r_e (the scale anchor) and a, b are fixed.
Every figure is printed beside its baseline measured in the same run. Prints markdown tables.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import differential_evolution

from ecu_monitor.bus.canlog import load_flight
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.identify import (
    DEFAULT_FREE,
    ErrorStats,
    ParameterSpace,
    PsoSettings,
    SwarmObjective,
    default_space,
    flight_errors,
    identify,
    polish,
    prepare_flight,
    simulate_flight,
    visited_weight_s,
)
from ecu_monitor.identify.report import plot_cost, plot_flight, plot_heat_map
from ecu_monitor.model import AirspeedCooling, Effects, ThermalParams, coefficients, paper_table_a1, simulate

REPO = Path(__file__).resolve().parents[1]
#: The G1000 flight of the g1000 study: $G1000_LOG, else the data folder beside the checkout (not shipped).
G1000 = Path(os.environ.get("G1000_LOG", REPO.parent / "shared" / "data" / "g1000" / "log_110701_131851_KGFK.csv"))


def virtual_flights(record_dt_s: float = 1.0) -> tuple[FlightLog, FlightLog, ThermalParams]:
    """Train (logged every record_dt_s) and held-out (1 Hz) virtual-ECU flights, about 1 h each, and the truth."""
    from virtual_bus.plant import fly
    from virtual_bus.random_missions import random_mission

    truth = paper_table_a1()
    train = fly(random_mission(1), truth, seed=1, record_dt_s=record_dt_s)
    held_out = fly(random_mission(2), truth, seed=2, record_dt_s=1.0)
    return train, held_out, truth


def wrong_start(truth: ThermalParams) -> ThermalParams:
    """The deliberately wrong starting model."""
    return truth.replace(
        c_w=truth.c_w * 1.6,
        r_ce=truth.r_ce * 0.6,
        tau_w=truth.tau_w * 2.5,
        heat_map=truth.heat_map.with_values(truth.heat_map.values_array() * 1.4),
    )


def fmt_errors(e: ErrorStats) -> str:
    return f"{e.mean_c:.2f} / {e.peak_c:.2f} / {e.rms_c:.2f} | {e.mean_pct:.2f} / {e.peak_pct:.2f}"


def recovery(params: ThermalParams, truth: ThermalParams, space: ParameterSpace, train: FlightLog) -> dict[str, Any]:
    """Relative errors (%) of the identified parameters against the truth."""
    weight = visited_weight_s([train], truth.heat_map)
    got = params.heat_map.values_array()
    want = truth.heat_map.values_array()
    cells = [(i, j, weight[i, j], 100.0 * (got[i, j] / want[i, j] - 1.0)) for i, j in space.heat_cells]
    x, y = train[truth.heat_map.x_axis], train[truth.heat_map.y_axis]
    at_points = 100.0 * np.abs(np.asarray(params.heat_map(x, y)) / np.asarray(truth.heat_map(x, y)) - 1.0)
    return {
        "q_at_points": (float(np.median(at_points)), float(np.quantile(at_points, 0.95))),
        "c_w": 100.0 * (params.c_w / truth.c_w - 1.0),
        "r_ce": 100.0 * (params.r_ce / truth.r_ce - 1.0),
        "tau_w": 100.0 * (params.tau_w / truth.tau_w - 1.0),
        "cells": cells,
    }


def run_de(objective: SwarmObjective, budget: int, particles: int, seed: int) -> tuple[np.ndarray, float, float]:
    """scipy differential_evolution on the same objective and unit cube, population = particles,
    stopped at the same number of particle simulations; returns (best unit point, cost, seconds)."""
    d = objective.space.dimension
    popsize = max(1, particles // d)
    population = popsize * d
    maxiter = max(1, budget // population - 1)

    def cost(x: np.ndarray) -> np.ndarray:
        return objective.costs(np.atleast_2d(x.T))

    start = time.perf_counter()
    result = differential_evolution(
        cost, [(0.0, 1.0)] * d, popsize=popsize, maxiter=maxiter, tol=0.0, atol=0.0, seed=seed,
        vectorized=True, updating="deferred", polish=False, init="latinhypercube",
    )  # fmt: skip
    return np.asarray(result.x), float(result.fun), time.perf_counter() - start


# --------------------------------------------------------------------------------------------------
# main: the benchmark
# --------------------------------------------------------------------------------------------------


def study_main(seed: int, record_dt_s: float) -> None:
    train, held_out, truth = virtual_flights(record_dt_s)
    base = wrong_start(truth)
    settings = PsoSettings(seed=seed)
    print(
        f"train: {train.source}, {train.duration_s / 60:.1f} min; held out: {held_out.source},"
        f" {held_out.duration_s / 60:.1f} min"
    )
    result = identify([train], base=base, settings=settings)
    budget = result.evaluations
    pso_only = settings.particles * (settings.iterations + 1)
    space = result.space
    print(
        f"\nPSO (defaults: {settings.particles} particles x {settings.iterations} iterations,"
        f" dt {settings.dt_s} s, polish)"
    )
    print(
        "| optimiser | wall time s | particle simulations | train cost degC | held-out mean/peak/RMS"
        " degC, mean/peak % |"
    )
    print("|---|---|---|---|---|")
    held = flight_errors(result.params, held_out)
    print(
        f"| PSO + polish | {result.elapsed_s:.2f} | {budget} | {result.best_cost:.4f} (PSO"
        f" alone {result.pso_cost:.4f}) | {fmt_errors(held)} |"
    )
    # DE at the same budget of simulations, same polish afterwards
    objective = SwarmObjective([train], space, settings.dt_s)
    de_unit, de_cost, de_time = run_de(objective, pso_only, settings.particles, seed)
    de_evals = objective.evaluations
    t0 = time.perf_counter()
    pol_unit, pol_cost = polish(objective, de_unit, settings.polish_evaluations)
    de_total = de_time + time.perf_counter() - t0
    de_params = space.to_params(space.from_unit(pol_unit))
    print(
        f"| DE + same polish | {de_total:.2f} | {objective.evaluations} (DE {de_evals}) | {pol_cost:.4f}"
        f" (DE alone {de_cost:.4f}) | {fmt_errors(flight_errors(de_params, held_out))} |"
    )
    rec = recovery(result.params, truth, space, train)
    print(f"\nrecovery (PSO + polish): c_w {rec['c_w']:+.2f} %, r_ce {rec['r_ce']:+.2f} %, tau_w {rec['tau_w']:+.2f} %")
    q50, q95 = rec["q_at_points"]
    print(
        f"heat map Q_SL0 at the train flight's operating points (every sample): |error| median"
        f" {q50:.2f} %, 95th percentile {q95:.2f} %"
    )
    print("| heat-map breakpoint (i, j) | weight in train flight, s | error % |")
    print("|---|---|---|")
    for i, j, w, err in rec["cells"]:
        print(f"| ({i}, {j}) | {w:.0f} | {err:+.1f} |")
    print(f"truth model on the held-out flight (noise + quantiser floor): {fmt_errors(flight_errors(truth, held_out))}")

    # cost of one swarm evaluation: compiled swarm vs numpy particle-by-particle loop
    grid = prepare_flight(train, space.base.heat_axes, settings.dt_s)
    rng = np.random.default_rng(seed)
    unit = rng.random((settings.particles, space.dimension))
    swarm = space.coefficient_arrays(space.from_unit(unit))
    objective.costs(unit)  # warm
    reps = 20
    t0 = time.perf_counter()
    for _ in range(reps):
        objective.costs(unit)
    swarm_s = (time.perf_counter() - t0) / reps
    loop_particles = 3
    t0 = time.perf_counter()
    for p in range(loop_particles):
        single = coefficients(space.to_params(space.from_unit(unit[p])))
        simulate(grid.inputs, single, settings.dt_s, grid.initial_c)
    per_particle = (time.perf_counter() - t0) / loop_particles
    loop_s = per_particle * settings.particles
    steps = int(np.size(grid.inputs.heat_x))
    print(
        f"\ncost of one swarm evaluation ({settings.particles} particles, {steps} steps of"
        f" {settings.dt_s} s = 1 h flight):"
    )
    print("| method | s per swarm evaluation | ratio |")
    print("|---|---|---|")
    print(
        f"| numpy ecu_monitor.model.simulate, particle by particle (measured on {loop_particles},"
        f" x{settings.particles}) | {loop_s:.2f} | 1 |"
    )
    print(
        f"| compiled swarm (simulate_compiled, whole swarm in one call) + cost | {swarm_s:.4f}"
        f" | x{loop_s / swarm_s:.0f} |"
    )
    fine = prepare_flight(train, space.base.heat_axes, 0.02)
    t0 = time.perf_counter()
    from ecu_monitor.model.compiled import simulate_compiled

    simulate_compiled(fine.inputs, swarm, 0.02, fine.initial_c, record_every=fine.record_every)
    print(f"| compiled swarm at dt 0.02 s (reference step) | {time.perf_counter() - t0:.3f} | |")


# --------------------------------------------------------------------------------------------------
# dt study
# --------------------------------------------------------------------------------------------------


def study_dt(seed: int) -> None:
    train, held_out, truth = virtual_flights()
    base = wrong_start(truth)
    print("simulation error of the truth model at step dt vs dt = 0.02 s (1 h train flight):")
    reference = simulate_flight(truth, train, 0.02)
    for dt in (0.1, 0.25, 0.5, 1.0, 2.0):
        print(f"  dt {dt:>4}: max |diff| {np.max(np.abs(simulate_flight(truth, train, dt) - reference)):.2e} degC")
    print(
        "\n| dt s | identification s | failed | train cost at dt | train RMS at 0.02 | held-out"
        " mean/peak/RMS degC, mean/peak % | c_w | r_ce | tau_w |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for dt in (0.02, 0.1, 0.25, 0.5, 1.0, 2.0):
        result = identify([train], base=base, settings=PsoSettings(seed=seed, dt_s=dt))
        p = result.params
        print(
            f"| {dt} | {result.elapsed_s:.1f} | {result.failed_particles} | {result.best_cost:.4f}"
            f" | {result.train_errors[0].rms_c:.4f} |"
            f" {fmt_errors(flight_errors(p, held_out))} | {p.c_w:.1f} | {p.r_ce:.4f} | {p.tau_w:.2f} |"
        )


# --------------------------------------------------------------------------------------------------
# PSO variants
# --------------------------------------------------------------------------------------------------


_INERTIA = {"constriction": False, "cognitive": 1.5, "social": 1.5}
_CLERC = {"constriction": True, "cognitive": 2.05, "social": 2.05}
VARIANTS: dict[str, dict[str, Any]] = {
    "paper: inertia 0.9->0.4, c 2.0, no clamp, no restart": {
        "constriction": False,
        "cognitive": 2.0,
        "social": 2.0,
        "velocity_clamp": None,
        "stagnation_iterations": 0,
    },
    "inertia 0.9->0.4, c 1.5, clamp 0.25, no restart": {**_INERTIA, "velocity_clamp": 0.25, "stagnation_iterations": 0},
    "inertia 0.9->0.4, c 1.5, clamp 0.25, restarts (default)": {**_INERTIA, "velocity_clamp": 0.25},
    "constriction c 2.05, no clamp, no restart": {**_CLERC, "velocity_clamp": None, "stagnation_iterations": 0},
    "constriction c 2.05, clamp 0.25, no restart": {**_CLERC, "velocity_clamp": 0.25, "stagnation_iterations": 0},
    "constriction c 2.05, clamp 0.25, restarts": {**_CLERC, "velocity_clamp": 0.25},
}


def g1000_halves() -> tuple[FlightLog, FlightLog]:
    """The real flight's first and second halves."""
    log = load_flight(G1000, mapping=REPO / "ecu_monitor/data/mappings/g1000.yaml")
    t = log.time_s
    mid = 0.5 * (t[0] + t[-1])
    return log.select(t[0], mid), log.select(mid, t[-1])


def study_variants(seeds: int, data: str) -> None:
    if data == "g1000":
        train, held_out = g1000_halves()
        base = None
        space = default_space([train], heat_axes=("fuel_flow_lph", "rpm"))
        print("g1000: train on the first half, held out = second half")
    else:
        train, held_out, truth = virtual_flights()
        base = wrong_start(truth)
        space = default_space([train], base=base)
    print(
        f"{space.dimension} coordinates; median over seeds 0..{seeds - 1}; 48 particles x 120"
        f" iterations (5808 simulations)"
    )
    print(
        "| optimiser | cost alone (median, worst) | after polish (median, worst) | held-out"
        " RMS after polish (median) | s (median) |"
    )
    print("|---|---|---|---|---|")
    for label, changes in VARIANTS.items():
        alone, final, held, secs = [], [], [], []
        for seed in range(seeds):
            settings = replace(PsoSettings(seed=seed), **changes)
            r = identify([train], space=space, settings=settings)
            alone.append(r.pso_cost)
            final.append(r.best_cost)
            held.append(flight_errors(r.params, held_out).rms_c)
            secs.append(r.elapsed_s)
        print(
            f"| PSO {label} | {statistics.median(alone):.4f}, {max(alone):.4f} | {statistics.median(final):.4f},"
            f" {max(final):.4f} | {statistics.median(held):.4f} | {statistics.median(secs):.1f}"
            f" |"
        )
    alone, final, held, secs = [], [], [], []
    settings = PsoSettings()
    for seed in range(seeds):
        objective = SwarmObjective([train], space, settings.dt_s)
        unit, cost, seconds = run_de(
            objective, settings.particles * (settings.iterations + 1), settings.particles, seed
        )
        t0 = time.perf_counter()
        pol_unit, pol_cost = polish(objective, unit, settings.polish_evaluations)
        alone.append(cost)
        final.append(pol_cost)
        held.append(flight_errors(space.to_params(space.from_unit(pol_unit)), held_out).rms_c)
        secs.append(seconds + time.perf_counter() - t0)
    print(
        f"| scipy differential_evolution, same budget | {statistics.median(alone):.4f}, {max(alone):.4f}"
        f" | {statistics.median(final):.4f}, {max(final):.4f} | {statistics.median(held):.4f}"
        f" | {statistics.median(secs):.1f} |"
    )
    objective = SwarmObjective([train], space, settings.dt_s)
    unit, cost = polish(objective, space.to_unit(space.from_params(space.base)), 200)
    held_rms = flight_errors(space.to_params(space.from_unit(unit)), held_out).rms_c
    print(f"| least squares alone from the wrong start (200 evaluations) | - | {cost:.4f} | {held_rms:.4f} | - |")


# --------------------------------------------------------------------------------------------------
# the real g1000 flight
# --------------------------------------------------------------------------------------------------


def study_g1000(seed: int, plots: Path | None) -> None:
    log = load_flight(G1000, mapping=REPO / "ecu_monitor/data/mappings/g1000.yaml")
    axes = ("fuel_flow_lph", "rpm")
    settings = PsoSettings(seed=seed)
    t = log.time_s
    mid = 0.5 * (t[0] + t[-1])
    first, second = log.select(t[0], mid), log.select(mid, t[-1])
    print(
        f"{G1000.name}: {len(log)} samples, {log.duration_s / 60:.1f} min; heat map {axes[0]}"
        f" x {axes[1]} 4x4 from the train data"
    )
    print("| split | train | held out | train RMS degC | held-out mean/peak/RMS degC, mean/peak % | s | failed |")
    print("|---|---|---|---|---|---|---|")
    results = {}
    for label, train, test in (
        ("first half -> second half", [first], second),
        ("second half -> first half", [second], first),
    ):
        r = identify(train, heat_axes=axes, settings=settings)
        results[label] = (r, train, test)
        print(
            f"| {label} | {train[0].duration_s / 60:.0f} min | {test.duration_s / 60:.0f} min |"
            f" {r.train_errors[0].rms_c:.2f} | {fmt_errors(flight_errors(r.params, test))} | {r.elapsed_s:.1f}"
            f" | {r.failed_particles} |"
        )
    edges = np.linspace(t[0], t[-1], 5)
    blocks = [log.select(edges[k], edges[k + 1] - 1e-6 if k < 3 else edges[k + 1]) for k in range(4)]
    held_stats = []
    for k in range(4):
        train = [b for m, b in enumerate(blocks) if m != k]
        r = identify(train, heat_axes=axes, settings=settings)
        e = flight_errors(r.params, blocks[k])
        held_stats.append(e)
        rms_train = math.sqrt(np.mean([x.rms_c**2 for x in r.train_errors]))
        print(
            f"| leave block {k + 1} of 4 out | 3 blocks | {blocks[k].duration_s / 60:.0f} min (from"
            f" {blocks[k].time_s[0] / 60:.0f} min) | {rms_train:.2f} | {fmt_errors(e)} | {r.elapsed_s:.1f}"
            f" | {r.failed_particles} |"
        )
    whole = identify([log], heat_axes=axes, settings=settings)
    p = whole.params
    print(
        f"| whole flight (train error only) | {log.duration_s / 60:.0f} min | - | {whole.train_errors[0].rms_c:.2f}"
        f" | train: {fmt_errors(whole.train_errors[0])} | {whole.elapsed_s:.1f} | {whole.failed_particles}"
        f" |"
    )
    print(
        f"\nwhole-flight model: c_w {p.c_w:.0f} J/degC, r_ce {p.r_ce:.4f} degC/W, C_w R_Ce"
        f" {p.c_w * p.r_ce:.0f} s, tau_w {p.tau_w:.1f} s,"
        f" {len(whole.space.heat_cells)}/16 breakpoints visited; x {p.heat_map.x_breakpoints};"
        f" y {p.heat_map.y_breakpoints}"
    )
    print(np.round(p.heat_map.values_array()))
    if plots is not None:
        plots.mkdir(parents=True, exist_ok=True)
        plot_flight(
            log,
            simulate_flight(p, log),
            plots / "g1000_whole_fit.png",
            "g1000, whole flight: fit (train error)",
            whole.train_errors[0],
        )
        plot_cost(
            whole.cost_history,
            plots / "g1000_cost.png",
            "g1000 whole flight: PSO best cost per iteration",
            whole.polish_cost,
        )
        ident = np.zeros(p.heat_map.shape, dtype=bool)
        for i, j in whole.space.heat_cells:
            ident[i, j] = True
        plot_heat_map(p, ident, plots / "g1000_heat_map.png", "g1000: identified Q_SL0 on fuel flow x rpm")
        r, train, test = results["first half -> second half"]
        plot_flight(
            test,
            simulate_flight(r.params, test),
            plots / "g1000_first_to_second.png",
            "g1000: trained on the first half, held-out second half",
            flight_errors(r.params, test),
        )
        r, train, test = results["second half -> first half"]
        plot_flight(
            test,
            simulate_flight(r.params, test),
            plots / "g1000_second_to_first.png",
            "g1000: trained on the second half, held-out first half",
            flight_errors(r.params, test),
        )
        print(f"plots -> {plots}")


def study_g1000_effects(seed: int) -> None:
    """Half splits again, with the airspeed-cooling effect switched on and its gain and floor freed."""
    first, second = g1000_halves()
    axes = ("fuel_flow_lph", "rpm")
    effect = AirspeedCooling(gain_per_mps=0.01, reference_mps=50.0, floor=0.3)
    base = paper_table_a1().replace(effects=Effects(airspeed_cooling=effect))
    free = (*DEFAULT_FREE, "effects.airspeed_cooling.gain_per_mps", "effects.airspeed_cooling.floor")
    print("| split | model | train RMS degC | held-out mean/peak/RMS degC, mean/peak % | gain 1/(m/s) | floor |")
    print("|---|---|---|---|---|---|")
    for label, train, test in (("first -> second half", first, second), ("second -> first half", second, first)):
        for name, space in (
            ("nominal", default_space([train], heat_axes=axes)),
            ("+ airspeed_cooling", default_space([train], base=base, heat_axes=axes, free=free)),
        ):
            r = identify([train], space=space, settings=PsoSettings(seed=seed))
            air = r.params.effects.airspeed_cooling
            extra = f"{air.gain_per_mps:.4f} | {air.floor:.3f}" if air else "- | -"
            held = fmt_errors(flight_errors(r.params, test))
            print(f"| {label} | {name} | {r.train_errors[0].rms_c:.2f} | {held} | {extra} |")


def study_virtual_plots(seed: int, plots: Path) -> None:
    train, held_out, truth = virtual_flights()
    result = identify([train], base=wrong_start(truth), settings=PsoSettings(seed=seed))
    plots.mkdir(parents=True, exist_ok=True)
    p = result.params
    plot_flight(
        train,
        simulate_flight(p, train),
        plots / "virtual_train.png",
        "virtual ECU, train (random_mission 1)",
        result.train_errors[0],
    )
    plot_flight(
        held_out,
        simulate_flight(p, held_out),
        plots / "virtual_held_out.png",
        "virtual ECU, held out (random_mission 2)",
        flight_errors(p, held_out),
    )
    plot_cost(
        result.cost_history, plots / "virtual_cost.png", "virtual ECU: PSO best cost per iteration", result.polish_cost
    )
    print(f"plots -> {plots}")


def study_plants(seeds: int, first_seed: int) -> None:
    """Randomised plants (ecu_monitor.research.plants): identified on one mission, scored on another."""
    from ecu_monitor.research.plants import draw_plant, run_plant

    print(f"Randomised plants, seeds {first_seed}..{first_seed + seeds - 1}; errors in % of the measured CHT (the")
    print("paper's metric, sample by sample) and in % of the flight's mean rise above OAT (rise)")
    print()
    print("| seed | C_w x | R_Ce x | radiation (chosen) | radiated share | true model on held-out mean / peak % |"
          " train mean / peak % | held-out mean / peak % | pass | held-out mean / peak, % of rise |"
          " true model, % of rise | pass (rise) | held-out RMS degC | at bounds | time s |")  # fmt: skip
    print("|---:|---:|---:|---|---:|---:|---:|---:|---|---:|---:|---|---:|---|---:|")
    passed = passed_rise = 0
    for seed in range(first_seed, first_seed + seeds):
        plant = draw_plant(seed)
        outcome = run_plant(plant)
        passed += outcome.passed
        passed_rise += outcome.passed_rise
        units = "K" if plant.truth.radiation_in_kelvin else "degC"
        units += " (K)" if outcome.radiation_kelvin else " (degC)"
        floor = outcome.truth_floor
        held = outcome.held_out
        print(
            f"| {seed} | {plant.c_w_factor:.3f} | {plant.r_ce_factor:.2f} | {units} | {plant.radiated_share:.2f} |"
            f" {floor.mean_pct:.2f} / {floor.peak_pct:.2f} |"
            f" {outcome.train.mean_pct:.2f} / {outcome.train.peak_pct:.2f} |"
            f" {held.mean_pct:.2f} / {held.peak_pct:.2f} |"
            f" {'yes' if outcome.passed else 'NO'} |"
            f" {held.mean_rise_pct:.2f} / {held.peak_rise_pct:.2f} |"
            f" {floor.mean_rise_pct:.2f} / {floor.peak_rise_pct:.2f} |"
            f" {'yes' if outcome.passed_rise else 'NO'} | {held.rms_c:.2f} |"
            f" {'; '.join(outcome.at_bounds) or '-'} | {outcome.elapsed_s:.0f} |",
            flush=True,
        )
    print()
    print(f"{passed} of {seeds} plants meet mean < 1 % and peak < 5 % of the measured CHT on the held-out flight")
    print(f"{passed_rise} of {seeds} meet mean < 1 % and peak < 5 % of the flight's mean rise above OAT")


#: The terms docs/identify_your_engine.md names for N550ND: the named-term identification of --study term-search.
NAMED_TERMS = "-altitude_factor,airspeed_cooling,sensor_lag,density_cooling,mixture_index"


def _cpu_s() -> float:
    """CPU seconds of this process and of its finished children (the forked fold workers)."""
    own = os.times()
    return own.user + own.system + own.children_user + own.children_system


def study_term_search(minutes: float | None) -> None:
    """``identify --effects auto`` against one identification with the terms named, on the four given
    N550ND flights (1 s step, leave-one-flight-out on both), in one run: wall and CPU time, the ratio,
    the held-out errors and the terms chosen."""
    from ecu_monitor.identify.select import identify_flights, parse_terms

    paths = sorted((REPO.parent / "shared" / "data" / "real").glob("ngafid_c172s_n550nd_*.csv"))
    flights = [load_flight(p, mapping="g1000") for p in paths]
    if minutes:
        flights = [f.select(f.time_s[0], f.time_s[0] + 60.0 * minutes) for f in flights]
    settings = PsoSettings(dt_s=1.0)
    rows = []
    for label, terms in (("named terms", parse_terms(NAMED_TERMS)), ("--effects auto", "auto")):
        wall, cpu = time.perf_counter(), _cpu_s()
        _, cv, selection = identify_flights(
            flights, base=paper_table_a1(), heat_axes=("fuel_flow_lph", "rpm"), grid=None, settings=settings,
            terms=terms, progress=lambda line: print(f"  {line}", flush=True),
        )  # fmt: skip
        wall, cpu = time.perf_counter() - wall, _cpu_s() - cpu
        assert cv is not None
        chosen = ", ".join(f"{'+' if on else '-'}{name}" for name, on in (selection.terms if selection else {}).items())
        rows.append((label, wall, cpu, cv.rms_c, chosen or terms_label(NAMED_TERMS)))
        print(f"{label}: {wall:.0f} s wall, {cpu:.0f} s CPU, held-out {np.round(cv.rms_c, 2)}", flush=True)
    cut = f" (first {minutes:g} min each)" if minutes else ""
    print(f"\nFour N550ND flights{cut}, step 1 s, {os.cpu_count()} cores\n")
    print("| identification | wall, s | CPU, s | wall / named | held-out RMS per flight, degC | mean | terms |")
    print("|---|---|---|---|---|---|---|")
    for label, wall, cpu, rms, chosen in rows:
        per = ", ".join(f"{x:.2f}" for x in rms)
        print(f"| {label} | {wall:.0f} | {cpu:.0f} | {wall / rows[0][1]:.2f} | {per} | {rms.mean():.2f} | {chosen} |")


def terms_label(text: str) -> str:
    return ", ".join(t if t.startswith("-") else f"+{t}" for t in text.split(","))


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--study",
        choices=("main", "dt", "variants", "g1000", "g1000-effects", "virtual-plots", "plants", "term-search"),
        default="main",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--record-dt", type=float, default=1.0, help="logging interval of the train flight, s (main)")
    parser.add_argument("--seeds", type=int, default=5, help="seeds for --study variants")
    parser.add_argument("--data", choices=("virtual", "g1000"), default="virtual", help="for --study variants")
    parser.add_argument("--plots", type=Path, help="directory for PNGs (g1000, virtual-plots)")
    parser.add_argument("--minutes", type=float, help="term-search: only the first MINUTES of each flight (quick)")
    args = parser.parse_args(argv)
    if args.study == "term-search":
        study_term_search(args.minutes)
        return
    if args.study == "main":
        study_main(args.seed, args.record_dt)
    elif args.study == "dt":
        study_dt(args.seed)
    elif args.study == "variants":
        study_variants(args.seeds, args.data)
    elif args.study == "g1000":
        study_g1000(args.seed, args.plots)
    elif args.study == "g1000-effects":
        study_g1000_effects(args.seed)
    elif args.study == "plants":
        study_plants(args.seeds, args.seed)
    else:
        study_virtual_plots(args.seed, args.plots or REPO / "docs/results/identification")


if __name__ == "__main__":
    main()
