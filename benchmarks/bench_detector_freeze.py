"""Cost of the detector's baseline freeze per live step: ``Detector.update`` at 50 Hz over one hour of
symptom (noise, a step at 30 min), the baseline learning always vs frozen while S > 0, alternated
in one run (best of --repeat each); prints both and the ratio.

    nice -n 10 .venv/bin/python benchmarks/bench_detector_freeze.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from ecu_monitor.estimation.detection import Detector, DetectorSettings


def per_step_us(time_s: np.ndarray, symptom: np.ndarray, freeze: bool) -> float:
    """Mean wall time of one Detector.update over the series, microseconds."""
    detector = Detector(DetectorSettings(threshold=1e300, baseline_s=300.0, baseline_freeze=freeze))
    began = time.perf_counter()
    for t, x in zip(time_s.tolist(), symptom.tolist(), strict=True):
        detector.update(t, x)
    return (time.perf_counter() - began) / time_s.size * 1e6


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 3600.0, 0.02)
    x = 0.03 * rng.standard_normal(t.size) + np.where(t > 1800.0, 0.08, 0.0)
    per_step_us(t[:1000], x[:1000], True)  # compile
    times: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(args.repeat):
        for freeze in (False, True):
            times[freeze].append(per_step_us(t, x, freeze))
    always, frozen = min(times[False]), min(times[True])
    print(f"Detector.update per 50 Hz step (best of {args.repeat}): learning always {always:.2f} us,"
          f" frozen while S > 0 {frozen:.2f} us, ratio {frozen / always:.2f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
