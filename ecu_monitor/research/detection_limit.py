"""The detection limit of the adaptive-baseline CUSUM: which gamma steps the shipped detector turns DEGRADED.

The detector (ecu_monitor.estimation.detection) subtracts from the symptom an exponential baseline
(time constant tau = ``baseline_s``) of the block means older than d = ``baseline_delay_s``. A step
Delta of the symptom at an onset is seen in full for d seconds, then the baseline follows it, so the
statistic gains at most (nominal symptom 0, no noise)::

    G(Delta) = d (Delta - k) + integral_0^inf max(0, Delta exp(-s/tau) - k) ds
             = (d + tau)(Delta - k) - k tau ln(Delta / k)            for Delta > k

and the step is DEGRADED only if G(Delta) >= h: :func:`limit_step` gives Delta*. After that the
baseline has absorbed the step, whatever the degradation still does: a step smaller than Delta* is
never detected later in the flight. The symptom's step is about (gamma_Q - 1) times the heat going
in over the head's heat capacity, so the same gamma_Q is detected at high power and missed at low
power; the time since engine start matters only through the warm-up and the flight phase. With
``baseline_freeze`` the baseline holds while the statistic is above 0, so any step above k keeps
accumulating to h (Delta* = k), at the price the detection docs state.

:func:`detection_case` flies one case on the virtual ECU through the shipped service's estimator and
detector settings; ``benchmarks/bench_detect_limit.py`` runs the grid and writes
docs/results/detection_limit.md.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ecu_monitor.estimation.detection import DetectorSettings

__all__ = ["DetectionCase", "DetectionOutcome", "detection_case", "limit_step", "step_gain"]


def step_gain(step: float, settings: DetectorSettings) -> float:
    """G(Delta): the most a symptom step ``step`` (symptom unit) adds to the statistic (module doc)."""
    k, tau, d = settings.reference, settings.baseline_s, settings.baseline_delay_s
    if step <= k:
        return 0.0
    if tau <= 0.0 or settings.baseline_freeze:
        return math.inf  # the plain test, or a baseline that holds while S > 0: a step above k accumulates
    return (d + tau) * (step - k) - k * tau * math.log(step / k)


def limit_step(settings: DetectorSettings) -> float:
    """Delta*: the smallest symptom step the detector turns DEGRADED (G(Delta*) = h; k without a baseline)."""
    if settings.baseline_s <= 0.0 or settings.baseline_freeze:
        return settings.reference
    lo, hi = settings.reference, 2.0 * settings.reference + settings.threshold
    while step_gain(hi, settings) < settings.threshold:
        lo, hi = hi, 2.0 * hi
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if step_gain(mid, settings) < settings.threshold else (lo, mid)
    return 0.5 * (lo + hi)


class DetectionCase(NamedTuple):
    """One flight: mission seed, gamma_Q step, onset (s after engine start)."""

    seed: int
    gamma_q: float
    onset_s: float


class DetectionOutcome(NamedTuple):
    """delay_s: first alarm - onset (inf: none within 900 s; nan: an alarm before the onset).
    step: the symptom's step at the onset (mean over 60 s after minus 300 s before), degC/s.
    cht_c, throttle_pct: measured at the onset."""

    case: DetectionCase
    delay_s: float
    step: float
    cht_c: float
    throttle_pct: float


def detection_case(case: DetectionCase) -> DetectionOutcome:
    """Fly ``case`` (random mission of onset + 1800 s, the evaluation's residual effects, flown to
    onset + 900 s) and run the shipped service's estimator and detector (example.yaml, its model)."""
    from ecu_monitor.config import DEFAULT_CONFIG, load_config
    from ecu_monitor.estimation import run_estimator
    from ecu_monitor.estimation.detection import cusum_path
    from ecu_monitor.estimation.isolation import run_isolation
    from ecu_monitor.research.evaluation import residual_effects
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
    onset = float(log.time_s[0]) + case.onset_s
    if alarms.size and alarms[0] < onset:
        delay = math.nan
    elif alarms.size and alarms[0] - onset <= 900.0:
        delay = float(alarms[0] - onset)
    else:
        delay = math.inf
    before = (t >= onset - 300.0) & (t < onset)
    after = (t >= onset) & (t < onset + 60.0)
    step = float(np.nanmean(symptom[after]) - np.nanmean(symptom[before]))
    at = min(int(np.searchsorted(log.time_s, onset)), log.time_s.size - 1)
    return DetectionOutcome(case, delay, step, float(log["cht_c"][at]), float(log["throttle_pct"][at]))
