"""The step's thermal headroom (pipeline/step.py ``headroom_s``) against the model integrated at the
estimator step with held full throttle, and against the virtual ECU's truth plant."""

from __future__ import annotations

import numpy as np
import pytest

from ecu_monitor.model import InputSeries, ThermalParams, coefficients, compute_drive, pack_coefficients, paper_table_a1
from ecu_monitor.model.compiled import simulate_compiled
from ecu_monitor.model.thermal import unpack_coefficients
from ecu_monitor.pipeline.output_table import HEADROOM_CAP_S
from ecu_monitor.pipeline.step import headroom_s

FULL_THROTTLE = InputSeries(100.0, 9030.0, 300.0, 23.0, 13.0)


def _headroom(cht_c: float, inputs: InputSeries, params: ThermalParams, gamma_q: float = 1.0, gamma_d: float = 1.0):
    """The step's headroom (s) at the held ``inputs`` (floats), and the model's drive there."""
    coeffs = coefficients(params)
    drive = np.array([float(v) for v in compute_drive(inputs, coeffs)])
    packed = unpack_coefficients(*pack_coefficients(coeffs))
    return headroom_s(cht_c, drive, packed, gamma_q, gamma_d, params.cht_limit_c), drive


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
    room, _ = _headroom(start_c, FULL_THROTTLE, params, gamma_q=gamma_q)
    assert room < HEADROOM_CAP_S
    assert room == pytest.approx(actual, rel=0.01, abs=1.0)


def test_not_limited_below_steady_state_and_zero_above_the_limit() -> None:
    params = paper_table_a1()
    cruise = InputSeries(50.0, 6050.0, 1000.0, 23.0, 8.5)
    room, drive = _headroom(95.0, cruise, params)
    assert room == HEADROOM_CAP_S and drive[0] > 0.0
    hot, _ = _headroom(params.cht_limit_c + 1.0, FULL_THROTTLE, params)
    assert hot == 0.0
    # a degradation shortens the headroom
    nominal, _ = _headroom(120.0, FULL_THROTTLE, params)
    degraded, _ = _headroom(120.0, FULL_THROTTLE, params, gamma_d=1.2)
    assert degraded < nominal < HEADROOM_CAP_S


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
    room, _ = _headroom(float(log["cht_true_c"][k]), u, params)
    actual = crossing - float(t[k])
    assert actual > 20.0
    assert room == pytest.approx(actual, rel=0.05, abs=5.0)


def test_not_limited_exactly_where_the_models_steady_state_is_below_the_limit() -> None:
    """The step's shortcuts (the convective bound, Newton stopped below the limit) against the model's own
    steady state, at random operating points on both sides of the limit."""
    from ecu_monitor.model import Drive, steady_state_cht

    params = paper_table_a1()
    coeffs = coefficients(params)
    limit = params.cht_limit_c
    rng = np.random.default_rng(13)
    lo = np.array([20.0, 2000.0, 0.0, 10.0, -20.0])
    hi = np.array([100.0, 9500.0, 4000.0, 60.0, 40.0])
    outcomes = set()
    for _ in range(300):
        u = InputSeries(*(float(v) for v in rng.uniform(lo, hi)))
        cht = float(rng.uniform(60.0, limit + 10.0))
        gamma_q, gamma_d = (float(v) for v in rng.uniform(0.8, 1.4, size=2))
        room, drive = _headroom(cht, u, params, gamma_q, gamma_d)
        steady = float(steady_state_cht(Drive(*drive), coeffs, gamma_q, gamma_d))
        bound = drive[2] + gamma_q * gamma_d * drive[4] * drive[1] * drive[0] / drive[3]  # convective only
        if cht >= limit:
            assert room == 0.0
            outcomes.add("at the limit")
        elif steady < limit:
            assert room == HEADROOM_CAP_S
            outcomes.add("not limited, bound above the limit" if bound >= limit else "not limited")
        else:
            assert 0.0 < room <= HEADROOM_CAP_S
            outcomes.add("limited")
    assert outcomes == {"at the limit", "limited", "not limited", "not limited, bound above the limit"}
