"""The step's detector (pipeline/step.py ``detector_step``, sample by sample) against the CUSUM over a whole
flight (estimation/detection.py ``cusum_path``): the same blocks, statistic and alarm."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ecu_monitor.estimation.detection import DetectorSettings, cusum_path
from ecu_monitor.pipeline.engine import _detector_record
from ecu_monitor.pipeline.step import DETECTOR_SETTINGS, DETECTOR_STATE, _reset_detector, detector_step

_CASES = (  # baseline_s, baseline_delay_s, baseline_freeze, scale_s
    (0.0, 0.0, False, 0.0),
    (200.0, 0.0, False, 0.0),
    (200.0, 30.0, False, 0.0),
    (200.0, 30.0, True, 0.0),
    (200.0, 30.0, True, 300.0),  # self-normalised: the noise's spread (~0.016) above the floor
    (200.0, 30.0, False, 300.0),
)


@pytest.mark.parametrize("case", _CASES)
def test_the_steps_detector_equals_the_whole_flight_cusum(case: tuple[float, float, bool, float]) -> None:
    baseline_s, delay_s, freeze, scale_s = case
    rng = np.random.default_rng(2)
    t = np.arange(0.0, 1500.0, 0.1)
    x = 0.02 * rng.standard_normal(t.size) + np.where(t > 900.0, 0.15, 0.0)
    x[rng.uniform(size=t.size) < 0.05] = np.nan  # skipped samples
    settings = DetectorSettings(
        threshold=5.0, reference=0.05, warmup_s=100.0, block_s=1.0, baseline_s=baseline_s,
        baseline_delay_s=delay_s, baseline_freeze=freeze, scale_s=scale_s, scale_floor=0.01 if scale_s else 0.0,
    )  # fmt: skip
    ends, stat, alarms = cusum_path(t, x, settings)
    config = np.zeros(1, DETECTOR_SETTINGS)
    _detector_record(config[0], settings)
    state = np.zeros(1, DETECTOR_STATE)
    _reset_detector(state[0])
    ring = np.full(settings.delay_blocks + 1, np.nan)
    verdicts = set()
    for ti, xi in zip(t, x, strict=True):
        verdicts.add(detector_step(state[0], config[0], ring, float(ti), float(xi)))
    assert alarms.size == 1 and 900.0 < alarms[0] < 1000.0
    assert state[0]["alarm_s"] == pytest.approx(alarms[0], abs=0.11)  # closed at the next block's first sample
    assert state[0]["statistic"] == pytest.approx(stat[-1], rel=1e-9, abs=1e-12)
    assert verdicts == {0, 1, 2}  # NOMINAL, SUSPECT, DEGRADED (latched)
    assert not math.isnan(state[0]["alarm_s"]) and ends.size == stat.size
