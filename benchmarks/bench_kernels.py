"""CPU time of the model's compiled kernels: the swarm kernel (PSO, gap refits), the EKF runner, the
isolation filter over a flight, and one call of the one-step estimator API (``make_estimator``'s
``estimate``; the service's live path runs the compiled step of ecu_monitor/pipeline/step.py instead).

    .venv/bin/python benchmarks/bench_kernels.py

Each figure is the least CPU time (``time.process_time``, so other processes on a shared machine
count less than in wall time) over several repetitions, beside a baseline measured in the same run:
the numpy reference ``thermal.simulate`` for the swarm, the plain-Python filter for the estimator call.
It uses only the public API, so the same file also runs on an older commit (``git worktree add``)
to compare kernels across commits; docs/performance.md keeps the figures.
"""

from __future__ import annotations

import argparse
import functools
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ecu_monitor.estimation import make_estimator, run_estimator
from ecu_monitor.estimation.ekf import EstimatorSettings, ThermalEKF
from ecu_monitor.estimation.isolation import run_isolation
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.model import (
    AirspeedCooling,
    DensityCooling,
    Effects,
    InputSeries,
    SensorLag,
    coefficients,
    paper_table_a1,
    simulate,
    stack_coefficients,
)
from ecu_monitor.model.compiled import simulate_compiled


def least_cpu_s(run: Callable[[], Any], repeats: int) -> float:
    """Least CPU time of ``run`` over ``repeats`` calls (after one warm-up call), s."""
    run()
    best = float("inf")
    for _ in range(repeats):
        start = time.process_time()
        run()
        best = min(best, time.process_time() - start)
    return best


def held_inputs(rng: np.random.Generator, seconds: int, dt_s: float) -> InputSeries:
    """Random inputs logged at 1 Hz and held on a step of dt_s."""
    n = int(seconds / dt_s) + 1
    k = np.floor(np.arange(n) * dt_s).astype(int)
    ranges = ((20, 100), (3000, 9000), (0, 3000), (0, 40), (-10, 30))
    return InputSeries(*(rng.uniform(lo, hi, seconds + 2)[k] for lo, hi in ranges))


def swarm(rng: np.random.Generator, particles: int, effects: bool) -> Any:
    """A swarm of parameter sets around Table A1, with airspeed, density and probe effects or none."""
    base = paper_table_a1()
    on = Effects(airspeed_cooling=AirspeedCooling(), density_cooling=DensityCooling(), sensor_lag=SensorLag())
    chosen = on if effects else Effects()
    scales = rng.uniform(0.5, 2.0, (particles, 2))
    return stack_coefficients(
        [base.replace(c_w=base.c_w * sc, r_ce=base.r_ce * sr, effects=chosen) for sc, sr in scales]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--particles", type=int, default=48)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    seconds = 3600
    print(f"| kernel ({args.particles} particles, {seconds} s flight, inputs at 1 Hz) | CPU ms | baseline | ratio |")
    print("|---|---|---|---|")
    for dt_s, every in ((0.5, 2), (0.02, 50)):
        for effects in (False, True):
            inputs = held_inputs(rng, seconds, dt_s)
            coeffs = swarm(rng, args.particles, effects)
            run = functools.partial(simulate_compiled, inputs, coeffs, dt_s, 80.0, record_every=every)
            compiled = least_cpu_s(run, args.repeats)
            label = f"swarm kernel, dt {dt_s} s, effects {'on' if effects else 'off'}"
            if dt_s == 0.5:
                numpy_s = least_cpu_s(functools.partial(simulate, inputs, coeffs, dt_s, 80.0), 1)
                baseline = f"numpy simulate {numpy_s * 1e3:.0f} ms | x{numpy_s / compiled:.0f}"
                print(f"| {label} | {compiled * 1e3:.2f} | {baseline} |")
            else:
                print(f"| {label} | {compiled * 1e3:.2f} | | |")
    # filters over a 1 h flight logged at 1 Hz
    params = paper_table_a1()
    inputs = held_inputs(rng, seconds, 1.0)
    truth = simulate_compiled(inputs, coefficients(params), 1.0, 80.0).cht_c
    columns = dict(zip(("throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c"), inputs, strict=False))
    log = FlightLog({"time_s": np.arange(truth.size, dtype=float), **columns, "cht_c": np.round(truth)})
    runner = least_cpu_s(lambda: run_estimator(log, params, "cbekf-au"), max(3, args.repeats // 3))
    print(f"| run_estimator cbekf-au, 1 h at 0.02 s | {runner * 1e3:.1f} | | |")
    isolation = least_cpu_s(lambda: run_isolation(log, params), max(3, args.repeats // 3))
    print(f"| run_isolation, 1 h at 0.02 s | {isolation * 1e3:.1f} | | |")
    # one estimator call (0.1 s of filter = 5 steps of 0.02 s)
    u = InputSeries(60.0, 6500.0, 500.0, 23.0, 12.0)
    settings = EstimatorSettings()
    steps = 2000
    timings = {}
    for compiled in (True, False):
        live = ThermalEKF(params, settings, name="cbekf-au", use_deviation=True, reset="boundary", compiled=compiled)
        live.initialise(0.0, u, 110.0)
        timings[compiled] = least_cpu_s(functools.partial(_live_calls, live, u, steps), 3) / steps
    print(
        f"| ThermalEKF.estimate cbekf-au (5 steps) | {timings[True] * 1e3:.4f} | plain Python "
        f"{timings[False] * 1e3:.3f} ms | x{timings[False] / timings[True]:.1f} |"
    )
    iso = make_estimator("cbekf-iso", params)
    iso.initialise(0.0, u, 110.0)
    iso_s = least_cpu_s(functools.partial(_live_calls, iso, u, steps), 3) / steps
    print(f"| isolation filter estimate, cbekf-iso (5 steps) | {iso_s * 1e3:.4f} | | |")


def _live_calls(filter_: Any, u: InputSeries, calls: int) -> None:
    """``calls`` filter calls 0.1 s apart, continuing from the filter's current time."""
    start = round(filter_._time_s / 0.1)
    for k in range(start + 1, start + calls + 1):
        filter_.estimate(0.1 * k, u, 110.0)


if __name__ == "__main__":
    main()
