"""Detection limit of the shipped detector: probability of DEGRADED vs gamma_Q and time since engine start.

    nice -n 10 .venv/bin/python benchmarks/bench_detect_limit.py [--seeds 4] [--gammas 1.05,1.1,1.15,1.2,1.3]
        [--onsets 900,1800,3600,7200] [--workers 2] [--out docs/results/detection]

Each case: a virtual-ECU random mission (``random_mission(seed, onset + 1800 s)``; the truth plant with
the residual effects of ``ecu-monitor evaluate``), gamma_Q stepped to the given value at ``onset`` s
after engine start, flown to onset + 900 s. The monitor is the shipped service's: the config
example.yaml (its estimator and symptom, the detector settings and threshold it ships) on the paper's
Table A1 model; the CUSUM runs as the live detector does (``cusum_path``, latched). Detected: DEGRADED
within 900 s of the onset (an alarm before the onset counts as a false alarm, not a detection).

Per case it also records the symptom's step: the mean symptom over the 60 s after the onset minus the
mean over the 300 s before (degC/s). With the adaptive baseline (time constant tau, delay d) a step
Delta of the symptom adds to the statistic at most

    G(Delta) = (d + tau) (Delta - k) - k tau ln(Delta / k)     (Delta > k; the baseline follows after d)

so a step is detected (without help from noise) only when G(Delta) >= h: Delta* solves G = h. The
report prints Delta* for the shipped settings and plots detection against the measured Delta: the
limit is the symptom's size, which is gamma_Q - 1 times the heat going in at the onset (low power:
small), not the time since start (beyond the warm-up).

Writes a Markdown table (printed) and, with --out, ``detect_limit.png`` there.
"""

from __future__ import annotations

import argparse
import math
import multiprocessing
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np


class Case(NamedTuple):
    seed: int
    gamma_q: float
    onset_s: float


class Outcome(NamedTuple):
    case: Case
    delay_s: float  # inf: not detected within 900 s; nan: false alarm before the onset
    step: float  # symptom step at the onset, degC/s
    cht_c: float  # measured CHT at the onset, degC
    throttle_pct: float


def limit_step(h: float, k: float, tau: float, delay: float) -> float:
    """Delta* solving (delay + tau)(Delta - k) - k tau ln(Delta/k) = h (bisection; tau = 0: h/delay + k)."""
    if tau <= 0.0:
        return math.inf
    lo, hi = k, 100.0 * k + h
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        gain = (delay + tau) * (mid - k) - k * tau * math.log(mid / k)
        lo, hi = (mid, hi) if gain < h else (lo, mid)
    return 0.5 * (lo + hi)


def run_case(case: Case) -> Outcome:
    from ecu_monitor.estimation import run_estimator
    from ecu_monitor.estimation.detection import cusum_path
    from ecu_monitor.estimation.isolation import run_isolation
    from ecu_monitor.research.evaluation import residual_effects
    from ecu_monitor.service.config import DEFAULT_CONFIG, load_config
    from virtual_bus.plant import Degradation, fly
    from virtual_bus.random_missions import random_mission

    config = load_config(DEFAULT_CONFIG)
    params = config.load_params()
    log = fly(
        random_mission(case.seed, case.onset_s + 1800.0),
        params,
        effects=residual_effects(case.seed),
        degradation=[Degradation("gamma_q", case.gamma_q, case.onset_s)],
        seed=case.seed,
        max_duration_s=case.onset_s + 900.0,
    )
    if config.detector_symptom == "estimator":
        trace = run_estimator(log, params, config.estimator_name, config.estimator)
        t, symptom = trace.time_s, trace.deviation
    else:
        iso = run_isolation(log, params)
        t, symptom = iso.time_s, iso.deviation
    _, _, alarms = cusum_path(t, symptom, config.detector)
    t0 = float(log.time_s[0])
    onset = t0 + case.onset_s
    if alarms.size and alarms[0] < onset:
        delay = math.nan
    elif alarms.size and alarms[0] - onset <= 900.0:
        delay = float(alarms[0] - onset)
    else:
        delay = math.inf
    before = (t >= onset - 300.0) & (t < onset)
    after = (t >= onset) & (t < onset + 60.0)
    step = float(np.nanmean(symptom[after]) - np.nanmean(symptom[before]))
    at = int(np.searchsorted(log.time_s, onset))
    return Outcome(case, delay, step, float(log["cht_c"][at]), float(log["throttle_pct"][at]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--gammas", default="1.05,1.1,1.15,1.2,1.3")
    parser.add_argument("--onsets", default="900,1800,3600,7200")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, help="folder for detect_limit.png")
    args = parser.parse_args()
    from ecu_monitor.service.config import DEFAULT_CONFIG, load_config

    detector = load_config(DEFAULT_CONFIG).detector
    gammas = [float(g) for g in args.gammas.split(",")]
    onsets = [float(s) for s in args.onsets.split(",")]
    cases = [Case(1000 + s, g, o) for g in gammas for o in onsets for s in range(args.seeds)]
    started = time.perf_counter()
    with multiprocessing.get_context("fork").Pool(args.workers) as pool:
        outcomes = pool.map(run_case, cases, chunksize=1)
    wall = time.perf_counter() - started
    star = limit_step(detector.threshold, detector.reference, detector.baseline_s, detector.baseline_delay_s)
    print(f"{len(cases)} flights in {wall:.0f} s; detector h {detector.threshold:g}, k {detector.reference:g},"
          f" baseline {detector.baseline_s:g} s, delay {detector.baseline_delay_s:g} s"
          f" -> Delta* = {star:.3f} degC/s")  # fmt: skip
    print()
    print("| gamma_Q | " + " | ".join(f"onset {o:.0f} s" for o in onsets) + " | all | symptom step, median degC/s |")
    print("|---|" + "---|" * (len(onsets) + 2))
    for g in gammas:
        cells = []
        for o in onsets:
            mine = [r for r in outcomes if r.case.gamma_q == g and r.case.onset_s == o]
            cells.append(f"{sum(math.isfinite(r.delay_s) for r in mine)}/{len(mine)}")
        mine = [r for r in outcomes if r.case.gamma_q == g]
        hits = sum(math.isfinite(r.delay_s) for r in mine)
        steps = np.array([r.step for r in mine])
        print(f"| {g:g} | " + " | ".join(cells) + f" | **{hits}/{len(mine)}** | {np.median(steps):.3f} |")
    false = sum(math.isnan(r.delay_s) for r in outcomes)
    above = [r for r in outcomes if r.step >= star]
    below = [r for r in outcomes if r.step < star]
    print()
    print(f"alarms before the onset: {false}; detected with the step >= Delta*: "
          f"{sum(math.isfinite(r.delay_s) for r in above)}/{len(above)}, below: "
          f"{sum(math.isfinite(r.delay_s) for r in below)}/{len(below)}")  # fmt: skip
    if args.out:
        _plot(outcomes, gammas, onsets, star, args.out)


def _plot(outcomes: list[Outcome], gammas: list[float], onsets: list[float], star: float, folder: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder.mkdir(parents=True, exist_ok=True)
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for o in onsets:
        share = [
            np.mean([math.isfinite(r.delay_s) for r in outcomes if r.case.gamma_q == g and r.case.onset_s == o])
            for g in gammas
        ]
        left.plot(gammas, share, marker="o", label=f"onset {o / 60:.0f} min after start")
    left.set_xlabel("gamma_Q step")
    left.set_ylabel("P(DEGRADED within 900 s)")
    left.set_ylim(-0.05, 1.05)
    left.legend(fontsize=8)
    left.set_title("detection probability, shipped detector")
    hit = np.array([math.isfinite(r.delay_s) for r in outcomes])
    step = np.array([r.step for r in outcomes])
    gam = np.array([r.case.gamma_q for r in outcomes])
    right.scatter(step[hit], gam[hit], marker="o", color="tab:green", label="detected")
    right.scatter(step[~hit], gam[~hit], marker="x", color="tab:red", label="not detected")
    right.axvline(star, color="k", ls="--", lw=1, label=f"Delta* = {star:.3f} degC/s")
    right.set_xlabel("symptom step at the onset, degC/s")
    right.set_ylabel("gamma_Q step")
    right.legend(fontsize=8)
    right.set_title("what decides: the symptom's step")
    fig.tight_layout()
    fig.savefig(folder / "detect_limit.png", dpi=110)
    plt.close(fig)
    print(f"wrote {folder / 'detect_limit.png'}")


if __name__ == "__main__":
    main()
