"""Delta* (research.detection_limit) predicts which symptom steps the detector's own CUSUM turns DEGRADED."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ecu_monitor.estimation.detection import DetectorSettings, cusum_path
from ecu_monitor.research.detection_limit import limit_step, step_gain

SETTINGS = [
    DetectorSettings(),  # the shipped variant: baseline 120 s after 60 s
    DetectorSettings(threshold=20.0, reference=0.02, baseline_s=300.0, baseline_delay_s=0.0),
    DetectorSettings(threshold=3.0, reference=0.1, baseline_s=60.0, baseline_delay_s=120.0, block_s=2.0),
]


def _alarms(step: float, settings: DetectorSettings) -> int:
    """Alarms of the detector over a flight whose symptom steps from 0 to ``step`` at 1200 s (50 Hz)."""
    t = np.arange(0.0, 3600.0, 0.02)
    symptom = np.where(t >= 1200.0, step, 0.0)
    _, _, alarms = cusum_path(t, symptom, settings)
    return int(alarms.size)


@pytest.mark.parametrize("settings", SETTINGS)
def test_steps_above_delta_star_alarm_and_below_do_not(settings: DetectorSettings) -> None:
    star = limit_step(settings)
    assert math.isclose(step_gain(star, settings), settings.threshold, rel_tol=1e-9)
    assert _alarms(0.96 * star, settings) == 0
    assert _alarms(1.04 * star, settings) == 1


@pytest.mark.parametrize(
    "settings",
    [DetectorSettings(baseline_s=0.0, baseline_delay_s=0.0), DetectorSettings(baseline_freeze=True)],
    ids=["no baseline", "frozen while suspected"],
)
def test_without_a_learning_baseline_any_step_above_k_alarms(settings: DetectorSettings) -> None:
    assert limit_step(settings) == settings.reference
    assert _alarms(1.2 * settings.reference, settings) == 1
    assert _alarms(0.9 * settings.reference, settings) == 0
