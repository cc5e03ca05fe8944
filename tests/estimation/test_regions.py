"""The operating-region rule: each region reached at its bounds, unknown inputs, arrays agree with scalars."""

import math

import numpy as np
import pytest

from ecu_monitor.estimation import regions as r


def test_power_fraction_clips_and_refuses_nonsense():
    assert r.power_fraction(50.0, 0.0, 100.0) == pytest.approx(0.5)
    assert r.power_fraction(-5.0, 0.0, 100.0) == 0.0
    assert r.power_fraction(130.0, 0.0, 100.0) == 1.0
    assert r.power_fraction(20.0, 10.0, 30.0) == pytest.approx(0.5)  # fuel flow L/h axis
    assert math.isnan(r.power_fraction(math.nan, 0.0, 100.0))
    assert math.isnan(r.power_fraction(50.0, 100.0, 100.0))


@pytest.mark.parametrize(
    ("elapsed", "airspeed", "power", "expected"),
    [
        (0.0, 40.0, 1.0, r.REGION_START),
        (r.START_S - 1e-6, 40.0, 0.5, r.REGION_START),
        (r.START_S, 0.0, 0.5, r.REGION_GROUND),
        (r.START_S, r.GROUND_AIRSPEED_MPS - 1e-6, 1.0, r.REGION_GROUND),
        (r.START_S, r.GROUND_AIRSPEED_MPS, r.LOW_POWER - 1e-6, r.REGION_LOW),
        (r.START_S, 30.0, r.LOW_POWER, r.REGION_CRUISE),
        (r.START_S, 30.0, r.HIGH_POWER - 1e-6, r.REGION_CRUISE),
        (r.START_S, 30.0, r.HIGH_POWER, r.REGION_HIGH),
        (1e4, math.nan, 0.9, r.REGION_HIGH),  # no airspeed: airborne
        (1e4, 30.0, math.nan, r.REGION_CRUISE),  # no power input: cruise
    ],
)
def test_region_of_bounds(elapsed, airspeed, power, expected):
    assert r.region_of(elapsed, airspeed, power) == expected


def test_every_region_named_and_only_airborne_power_isolable():
    assert len(r.REGION_NAMES) == 5
    assert [r.isolable_region(i) for i in range(5)] == [False, False, False, True, True]


def test_arrays_follow_the_scalar_rule():
    rng = np.random.default_rng(3)
    e = rng.uniform(0, 2 * r.START_S, 500)
    v = rng.uniform(0, 40, 500)
    p = rng.uniform(0, 1, 500)
    got = r.regions_of(e, v, p)
    assert got.tolist() == [r.region_of(a, b, c) for a, b, c in zip(e, v, p, strict=True)]
    assert set(got.tolist()) == set(range(5))
