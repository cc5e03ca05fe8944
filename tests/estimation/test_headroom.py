"""Thermal headroom against the model integrated at the estimator step with held full throttle."""

from __future__ import annotations

import numpy as np
import pytest

from ecu_monitor.errors import EstimationError
from ecu_monitor.estimation.headroom import thermal_headroom
from ecu_monitor.model import Drive, InputSeries, coefficients, compute_drive, paper_table_a1
from ecu_monitor.model.compiled import simulate_compiled
from ecu_monitor.pipeline.output_table import HEADROOM_CAP_S

FULL_THROTTLE = InputSeries(100.0, 9030.0, 300.0, 23.0, 13.0)


def _truth_time_to_limit(start_c: float, gamma_q: float, limit_c: float) -> float:
    """Time (s) for the model at dt 0.02 s with held full throttle to reach limit_c from start_c."""
    params = paper_table_a1()
    n = 150_000  # 3000 s
    inputs = InputSeries(*(np.full(n, v) for v in FULL_THROTTLE))
    run = simulate_compiled(inputs, coefficients(params), 0.02, start_c, gamma_q)
    over = np.nonzero(run.cht_c >= limit_c)[0]
    assert over.size, "the truth never reaches the limit in this set-up"
    return float(over[0] * 0.02)


@pytest.mark.parametrize(("start_c", "gamma_q"), [(110.0, 1.0), (90.0, 1.2), (140.0, 1.1)])
def test_time_to_limit_matches_the_model_integrated_finely(start_c: float, gamma_q: float) -> None:
    params = paper_table_a1()
    actual = _truth_time_to_limit(start_c, gamma_q, params.cht_limit_c)
    room = thermal_headroom(start_c, None, FULL_THROTTLE, params, gamma_q=gamma_q, cap_s=HEADROOM_CAP_S)
    assert room.limited
    assert room.time_to_limit_s == pytest.approx(actual, rel=0.01, abs=1.0)
    assert room.margin_c == pytest.approx(params.cht_limit_c - start_c)
    assert room.steady_state_cht_c > params.cht_limit_c


def test_not_limited_below_steady_state_and_zero_above_the_limit() -> None:
    params = paper_table_a1()
    cruise = InputSeries(50.0, 6050.0, 1000.0, 23.0, 8.5)
    room = thermal_headroom(95.0, None, cruise, params, cap_s=HEADROOM_CAP_S)
    assert not room.limited
    assert room.time_to_limit_s == HEADROOM_CAP_S
    drive = compute_drive(cruise, coefficients(params))
    assert float(drive.q_sl0_w) > 0.0
    assert room.steady_state_cht_c < params.cht_limit_c
    hot = thermal_headroom(params.cht_limit_c + 1.0, None, FULL_THROTTLE, params, cap_s=HEADROOM_CAP_S)
    assert hot.time_to_limit_s == 0.0 and hot.limited and hot.margin_c == pytest.approx(-1.0)
    # a degradation shortens the headroom
    nominal = thermal_headroom(120.0, None, FULL_THROTTLE, params, cap_s=HEADROOM_CAP_S)
    degraded = thermal_headroom(120.0, None, FULL_THROTTLE, params, gamma_d=1.2, cap_s=HEADROOM_CAP_S)
    assert degraded.time_to_limit_s < nominal.time_to_limit_s
    capped = thermal_headroom(100.0, None, FULL_THROTTLE, params, cap_s=10.0)
    assert capped.time_to_limit_s == 10.0 and not capped.limited
    with pytest.raises(EstimationError):
        thermal_headroom(float("nan"), None, FULL_THROTTLE, params, cap_s=HEADROOM_CAP_S)


def test_time_to_limit_matches_the_virtual_ecu_truth_plant() -> None:
    from virtual_bus.missions import Climb, Cruise, GroundRun, Mission, Takeoff
    from virtual_bus.plant import fly

    params = paper_table_a1()
    mission = Mission(
        name="full-throttle",
        segments=(
            GroundRun(duration_s=60.0),
            Takeoff(),
            Climb(target_altitude_m=300.0, throttle_pct=60.0),
            Cruise(duration_s=1500.0, throttle_pct=100.0, airspeed_mps=23.0),
        ),
    )
    log = fly(mission, params, seed=4)
    t = log.time_s
    high = np.nonzero((log["throttle_pct"] > 95.0) & (t > 150.0))[0]  # after the take-off's full power
    k = int(high[0]) + 50  # 5 s into the full-throttle leg
    crossing = float(t[np.nonzero(log["cht_true_c"] >= params.cht_limit_c)[0][0]])
    u = InputSeries(*(float(log[c][k]) for c in ("throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c")))
    room = thermal_headroom(float(log["cht_true_c"][k]), None, u, params, cap_s=HEADROOM_CAP_S)
    actual = crossing - float(t[k])
    assert actual > 20.0
    assert room.time_to_limit_s == pytest.approx(actual, rel=0.05, abs=5.0)


def test_the_steps_headroom_equals_the_full_headroom() -> None:
    """The one step's compiled headroom (pipeline/step.py: convective bound first, Newton stopped below the
    limit, the march) gives what thermal_headroom gives (Python floats, written separately), at operating
    points on both sides of the limit and at it."""
    from ecu_monitor.model import pack_coefficients
    from ecu_monitor.model.thermal import unpack_coefficients
    from ecu_monitor.pipeline.step import compiled

    params = paper_table_a1()
    coeffs = coefficients(params)
    packed = unpack_coefficients(*pack_coefficients(coeffs))
    headroom = compiled().headroom_s
    rng = np.random.default_rng(13)
    lo = np.array([20.0, 2000.0, 0.0, 10.0, -20.0])
    hi = np.array([100.0, 9500.0, 4000.0, 60.0, 40.0])
    outcomes = set()
    for _ in range(1000):
        u = InputSeries(*(float(v) for v in rng.uniform(lo, hi)))
        cht = float(rng.uniform(60.0, params.cht_limit_c + 10.0))
        gamma_q, gamma_d = (float(v) for v in rng.uniform(0.8, 1.4, size=2))
        full = thermal_headroom(
            cht, None, u, params, gamma_q=gamma_q, gamma_d=gamma_d, coeffs=coeffs, cap_s=HEADROOM_CAP_S
        )
        drive = Drive(*(float(v) for v in compute_drive(u, coeffs)))
        got = headroom(cht, np.array(drive, dtype=float), packed, gamma_q, gamma_d, params.cht_limit_c)
        assert got == pytest.approx(full.time_to_limit_s, rel=0.0, abs=1e-9)
        heat = gamma_q * gamma_d * drive.heat_gain * drive.altitude_gain * drive.q_sl0_w
        bound = drive.ambient_c + heat / drive.conductance_w_per_c
        if full.time_to_limit_s == 0.0:
            outcomes.add("at the limit")
        elif full.limited:
            outcomes.add("limited")
        else:  # not limited: by the convective bound alone, or by Newton (stopped below the limit, or converged)
            outcomes.add("not limited, bound above the limit" if bound >= params.cht_limit_c else "not limited")
    assert outcomes == {"at the limit", "limited", "not limited", "not limited, bound above the limit"}
