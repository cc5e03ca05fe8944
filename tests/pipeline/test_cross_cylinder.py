"""The cross-cylinder symptom (pipeline/step.py ``cross_step``): each cylinder's symptom minus the median
of the other cylinders' usable ones (``median_of_others``), unusable cylinders left out."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ecu_monitor.pipeline.step import median_of_others


def _cross(symptoms: list[float]) -> list[float]:
    """What cross_step feeds each cylinder's cross detector (nan: the cylinder's own symptom is not usable)."""
    own = np.array(symptoms, dtype=float)
    scratch = np.empty(own.size)
    return [float(own[i] - median_of_others(own, i, scratch)) for i in range(own.size)]


def test_each_cylinder_minus_the_median_of_the_others() -> None:
    assert _cross([0.1, 0.2, 0.4, 1.0]) == pytest.approx([0.1 - 0.4, 0.2 - 0.4, 0.4 - 0.2, 1.0 - 0.2])
    # a common offset cancels: only what differs from the others is left
    assert _cross([5.1, 5.2, 5.4, 6.0]) == pytest.approx([-0.3, -0.2, 0.2, 0.8])
    # two others: their mean; one other: that one; none: nan
    assert _cross([1.0, math.nan, 0.5, 0.0]) == pytest.approx([0.75, math.nan, 0.0, -0.75], nan_ok=True)
    assert _cross([1.0, 0.25]) == [0.75, -0.75]
    assert all(math.isnan(x) for x in _cross([1.0, math.nan, math.nan]))


def test_the_median_of_the_others_equals_numpys() -> None:
    rng = np.random.default_rng(4)
    for count in (2, 3, 4, 6):
        values = rng.normal(0.05, 0.1, (200, count))
        values[rng.uniform(size=values.shape) < 0.2] = np.nan
        scratch = np.empty(count)
        for row in values:
            for i in range(count):
                others = np.delete(row, i)
                expected = np.nanmedian(others) if np.isfinite(others).any() else math.nan
                assert median_of_others(row, i, scratch) == pytest.approx(expected, nan_ok=True, rel=0, abs=0)
                assert median_of_others.py_func(row, i, scratch) == pytest.approx(expected, nan_ok=True, rel=0, abs=0)


def test_calibrate_keeps_a_cylinders_cross_detector_only_if_no_held_out_flight_alarms() -> None:
    from ecu_monitor.config import load_config
    from ecu_monitor.offline.calibration_cross import calibrate_cross, leave_one_out
    from ecu_monitor.offline.calibration_replays import FlightFeeds

    config = load_config("four_cylinders.yaml")
    rng = np.random.default_rng(8)
    t = np.arange(0.0, 2.5 * 3600.0, 1.0)
    feeds: list[list[FlightFeeds]] = [[], []]
    for flight in range(3):
        for cylinder in range(2):
            symptom = rng.normal(0.0, 0.02, t.size)
            if cylinder == 1 and flight == 2:  # an excursion the other flights never show
                symptom[4000:4300] += 0.3
            feed = ((t, symptom),)
            feeds[cylinder].append(FlightFeeds(f"f{flight}", feed, 0.0, float(t[-1]), math.nan, ()))
    checks = leave_one_out(feeds, config, 1.0)
    assert sum(checks[0].false_alarms) == 0 and checks[1].false_alarms[:2] == (0, 0) and checks[1].false_alarms[2] > 0
    kept, dropped = calibrate_cross(feeds, config, 1.0)
    assert dropped is None and kept is not None
    assert kept.calibration.threshold >= 1.0 and kept.current == config.cross_detector(1)
