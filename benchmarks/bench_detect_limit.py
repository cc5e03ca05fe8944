"""Detection limit of the shipped detector: probability of DEGRADED vs gamma_Q and time since engine start.

    nice -n 10 .venv/bin/python benchmarks/bench_detect_limit.py [--seeds 3] [--gammas 1.05,1.1,1.15,1.2,1.3]
        [--onsets 900,1800,3600,7200] [--workers 2] [--out docs/results]

Each case (:func:`ecu_monitor.research.detection_limit.detection_case`): a virtual-ECU random mission with
the evaluation's residual effects, gamma_Q stepped at ``onset`` s after engine start, flown to onset +
900 s, through the shipped service's estimator and detector (example.yaml on the paper's Table A1
model). Detected: DEGRADED within 900 s of the onset. Also recorded: the symptom's step at the onset,
against Delta* (:func:`~ecu_monitor.research.detection_limit.limit_step`, the smallest step the
adaptive baseline lets through). Prints a Markdown report; with --out writes it to
DIR/detection_limit.md and the plot to DIR/detection/detect_limit.png.
"""

from __future__ import annotations

import argparse
import math
import multiprocessing
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from ecu_monitor.research.detection_limit import DetectionCase, DetectionOutcome, detection_case, limit_step


def report(outcomes: list[DetectionOutcome], gammas: list[float], onsets: list[float], command: str,
           wall_s: float) -> str:  # fmt: skip
    from ecu_monitor.config import DEFAULT_CONFIG, load_config

    detector = load_config(DEFAULT_CONFIG).detector
    star = limit_step(detector)
    lines = [
        "# Detection limit: gamma_Q steps vs time since engine start (shipped detector)",
        "",
        f"Regenerate: `{command}` ({wall_s / 60:.1f} min on this machine, 2 shared cores).",
        "",
        f"The shipped detector (example.yaml: h {detector.threshold:g} degC, k {detector.reference:g} degC/s,"
        f" adaptive baseline {detector.baseline_s:g} s after a {detector.baseline_delay_s:g} s delay, warm-up"
        f" {detector.warmup_s:g} s) turns a clean symptom step DEGRADED only above **Delta* = {star:.3f} degC/s**"
        " (`ecu_monitor/research/detection_limit.py`: the baseline follows the step after the delay, so the"
        " statistic gains at most (d + tau)(Delta - k) - k tau ln(Delta/k)). The symptom's step is about"
        " (gamma_Q - 1) times the heat going in, so a gamma_Q step is caught at high power and missed at low"
        " power; once the baseline has absorbed it, only a later rise of the power (a further step of the symptom)"
        " can still bring it over. Delta* is a bound for a clean step: noise and power changes after the onset"
        " carry some smaller steps over (below).",
        "",
        "The 16 h replay of `benchmarks/bench_replay.py` (gamma_Q = 1.15 at 30 000 s, at a low-power point: CHT"
        " about 70 degC) is such a miss: its symptom steps by 0.104 degC/s, below Delta*; the statistic reaches"
        " SUSPECT (208 s) and the baseline then absorbs the step, although the isolation filter's gamma_Q converges"
        " to 1.15. Not a defect of the code: the price of the adaptive baseline that keeps real engines free of false"
        " alarms. With `detector.baseline_freeze: true` (the baseline holds while S > 0; `ecu-monitor calibrate`"
        " cross-validates it) any step above k accumulates to h (Delta* = k): the same replay is DEGRADED 125 s after"
        " the onset (`ecu-monitor replay flight16h.blf --config example.yaml with baseline_freeze: true`).",
        "",
        "Each case: `random_mission(seed, onset + 1800 s)` with the evaluation's residual effects, gamma_Q stepped"
        " at the onset, flown to onset + 900 s; detected = DEGRADED within 900 s of the onset.",
        "",
        "| gamma_Q | " + " | ".join(f"onset {o / 60:.0f} min" for o in onsets) + " | all | symptom step, median"
        " (min-max) degC/s |",
        "|---|" + "---|" * (len(onsets) + 2),
    ]
    for g in gammas:
        cells = []
        for o in onsets:
            mine = [r for r in outcomes if r.case.gamma_q == g and r.case.onset_s == o]
            cells.append(f"{sum(math.isfinite(r.delay_s) for r in mine)}/{len(mine)}")
        mine = [r for r in outcomes if r.case.gamma_q == g]
        steps = np.array([r.step for r in mine])
        hits = sum(math.isfinite(r.delay_s) for r in mine)
        lines.append(f"| {g:g} | " + " | ".join(cells) + f" | **{hits}/{len(mine)}** |"
                     f" {np.median(steps):.3f} ({steps.min():.3f}-{steps.max():.3f}) |")  # fmt: skip
    above = [r for r in outcomes if r.step >= star]
    below = [r for r in outcomes if r.step < star]
    early = sum(math.isnan(r.delay_s) for r in outcomes)
    lines += [
        "",
        f"By the symptom's step: detected {sum(math.isfinite(r.delay_s) for r in above)}/{len(above)} with a step"
        f" >= Delta*, {sum(math.isfinite(r.delay_s) for r in below)}/{len(below)} below it (noise can push a step"
        f" near Delta* over); alarms before the onset: {early}.",
        "",
        "![detection probability and the symptom step](detection/detect_limit.png)",
        "",
    ]
    return "\n".join(lines)


def plot(outcomes: list[DetectionOutcome], gammas: list[float], onsets: list[float], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ecu_monitor.config import DEFAULT_CONFIG, load_config

    star = limit_step(load_config(DEFAULT_CONFIG).detector)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for o in onsets:
        share = [
            np.mean([math.isfinite(r.delay_s) for r in outcomes if r.case.gamma_q == g and r.case.onset_s == o])
            for g in gammas
        ]
        left.plot(gammas, share, marker="o", label=f"onset {o / 60:.0f} min after engine start")
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
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--gammas", default="1.05,1.1,1.15,1.2,1.3")
    parser.add_argument("--onsets", default="900,1800,3600,7200")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, help="folder for detection_limit.md and detection/detect_limit.png")
    args = parser.parse_args()
    gammas = [float(g) for g in args.gammas.split(",")]
    onsets = [float(s) for s in args.onsets.split(",")]
    cases = [DetectionCase(1000 + s, g, o) for g in gammas for o in onsets for s in range(args.seeds)]
    started = time.perf_counter()
    with multiprocessing.get_context("fork").Pool(args.workers) as pool:
        outcomes = pool.map(detection_case, cases, chunksize=1)
    command = "nice -n 10 .venv/bin/python benchmarks/bench_detect_limit.py " + " ".join(map(shlex.quote, sys.argv[1:]))
    text = report(outcomes, gammas, onsets, command.strip(), time.perf_counter() - started)
    print(text)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "detection_limit.md").write_text(text, encoding="utf-8")
        plot(outcomes, gammas, onsets, args.out / "detection" / "detect_limit.png")
        print(f"wrote {args.out / 'detection_limit.md'}, {args.out / 'detection' / 'detect_limit.png'}")


if __name__ == "__main__":
    main()
