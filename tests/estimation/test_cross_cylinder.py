"""The cross-cylinder symptom (estimation/cross_cylinder.py): the live step equals the compiled batch
form, the median of the others, unusable cylinders left out."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ecu_monitor.errors import ParameterError
from ecu_monitor.estimation.cross_cylinder import cross_cylinder_step, cross_cylinder_symptoms


def test_each_cylinder_minus_the_median_of_the_others() -> None:
    assert cross_cylinder_step([0.1, 0.2, 0.4, 1.0]) == pytest.approx([0.1 - 0.4, 0.2 - 0.4, 0.4 - 0.2, 1.0 - 0.2])
    # a common offset cancels: only what differs from the others is left
    assert cross_cylinder_step([5.1, 5.2, 5.4, 6.0]) == pytest.approx([-0.3, -0.2, 0.2, 0.8])
    # two others: their mean; one other: that one; none: nan
    assert cross_cylinder_step([1.0, math.nan, 0.5, 0.0]) == pytest.approx([0.75, math.nan, 0.0, -0.75], nan_ok=True)
    assert cross_cylinder_step([1.0, 0.25]) == [0.75, -0.75]
    assert all(math.isnan(x) for x in cross_cylinder_step([1.0, math.nan, math.nan]))


def test_the_batch_form_equals_the_live_step_bit_for_bit() -> None:
    rng = np.random.default_rng(4)
    for count in (2, 3, 4, 6):
        values = rng.normal(0.05, 0.1, (count, 500))
        values[rng.uniform(size=values.shape) < 0.2] = np.nan
        batch = cross_cylinder_symptoms(values)
        live = np.array([cross_cylinder_step(values[:, k].tolist()) for k in range(values.shape[1])]).T
        assert np.array_equal(np.isnan(batch), np.isnan(live))
        assert np.array_equal(batch[np.isfinite(batch)], live[np.isfinite(live)])
    with pytest.raises(ParameterError, match="cylinders, steps"):
        cross_cylinder_symptoms(np.zeros(3))


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
