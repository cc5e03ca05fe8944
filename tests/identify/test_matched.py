"""matched_rise: airframes compared at the steady operating points they share.

Synthetic airframes: the same schedule of operating points (rpm, fuel flow, airspeed held 10 minutes
each), the CHT approaching a level set by the point, with each airframe's own head offset and time
constant; a third airframe flies points no other holds.
"""

from __future__ import annotations

import numpy as np
import pytest

from ecu_monitor.errors import ParameterError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.identify.matched import matched_rise

POINTS = ((2100.0, 30.0, 45.0), (2450.0, 34.0, 52.0), (2400.0, 57.0, 38.0), (1900.0, 22.0, 40.0))


def _flight(points, offset_c: float, time_constant_s: float, seed: int, oil_c: float | None = None) -> FlightLog:
    """Each point held 600 s; CHT - OAT approaches 0.06 x rpm + fuel flow + offset with the time constant,
    with 0.3 degC noise at 1 Hz; ``oil_c``: an oil temperature logged ``oil_c`` + a third of the CHT rise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 600.0 * len(points), 1.0)
    k = (t // 600.0).astype(int)
    rpm, fuel, airspeed = (np.array([p[i] for p in points])[k] for i in range(3))
    level = 0.06 * rpm + fuel + offset_c
    rise = np.empty_like(t)
    rise[0] = level[0] - 40.0
    for i in range(1, t.size):
        rise[i] = rise[i - 1] + (level[i] - rise[i - 1]) / time_constant_s
    oat = np.full_like(t, 15.0)
    columns = {"time_s": t, "rpm": rpm, "fuel_flow_lph": fuel, "airspeed_mps": airspeed, "oat_c": oat,
               "cht_c": oat + rise + 0.3 * rng.standard_normal(t.size)}  # fmt: skip
    if oil_c is not None:
        columns["oil_temp_c"] = oat + oil_c + rise / 3.0
    return FlightLog(columns, source=f"matched-{seed}")


def test_each_airframe_is_compared_with_the_others_at_shared_steady_points():
    flights = [
        _flight(POINTS, 0.0, 60.0, 1),
        _flight(POINTS[::-1], 0.0, 60.0, 2),
        _flight(POINTS, 8.0, 90.0, 3),  # B: 8 degC hotter at the same inputs, a slower head
        _flight(((1500.0, 12.0, 30.0), (2700.0, 70.0, 60.0)), 0.0, 60.0, 4),  # C: points nobody else flies
    ]
    result = matched_rise(flights, ["A", "A", "B", "C"])
    assert result["B"].offset_c == pytest.approx(8.0, abs=1.0)  # the transients (B's slower) are not compared
    assert result["A"].offset_c == pytest.approx(-8.0, abs=1.0)
    assert result["B"].spread_c < 1.0 and result["B"].bins == len(POINTS)
    assert 0.0 < result["B"].matched_s <= result["B"].steady_s < 600.0 * len(POINTS)
    assert result["C"].bins == 0 and np.isnan(result["C"].offset_c)
    assert np.isnan(result["A"].egt_offset_c) and np.isnan(result["A"].oil_offset_c)  # no EGT, no oil logged


def test_the_oil_temperature_is_compared_where_every_side_logs_it():
    """B's oil runs 5 degC warmer above the air on top of its head's 9 degC (a third of it): 8 degC."""
    flights = [_flight(POINTS, 0.0, 60.0, 1, oil_c=40.0), _flight(POINTS, 9.0, 60.0, 2, oil_c=45.0)]
    result = matched_rise(flights, ["A", "B"])
    assert result["B"].oil_offset_c == pytest.approx(8.0, abs=0.5)
    assert result["A"].oil_offset_c == pytest.approx(-8.0, abs=0.5)
    assert np.isnan(result["B"].egt_offset_c)


def test_one_airframe_is_refused():
    flight = _flight(POINTS, 0.0, 60.0, 1)
    with pytest.raises(ParameterError, match="two airframes"):
        matched_rise([flight, flight], ["A", "A"])


def test_other_inputs_and_one_cylinder_can_set_the_comparison():
    """Binned by rpm alone B is still 8 degC hotter (its points at 2400 and 2450 rev/min in one bin); its
    cylinder 1, 3 degC above the mean, 11; no column to bin by is refused."""
    flights = [
        FlightLog({**log.columns, "cht1_c": log["cht_c"] + above_mean_c}, source=log.source)
        for log, above_mean_c in ((_flight(POINTS, 0.0, 60.0, 1), 0.0), (_flight(POINTS, 8.0, 60.0, 2), 3.0))
    ]
    by_rpm = matched_rise(flights, ["A", "B"], widths={"rpm": 150.0})
    assert by_rpm["B"].offset_c == pytest.approx(8.0, abs=1.0) and by_rpm["B"].bins == 3  # 2400 and 2450 share one
    assert by_rpm["B"].fuel_offset_lph == pytest.approx(0.0, abs=0.1)  # the same fuel flow at the same points
    assert matched_rise(flights, ["A", "B"], cht_column="cht1_c")["B"].offset_c == pytest.approx(11.0, abs=1.0)
    with pytest.raises(ParameterError, match="no column"):
        matched_rise(flights, ["A", "B"], widths={})
