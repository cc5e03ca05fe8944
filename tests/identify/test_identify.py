"""ecu_monitor.identify: the PSO itself, the parameter space, the swarm cost and identification on a
synthetic flight whose truth is known."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ecu_monitor.errors import FlightLogError, ParameterError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.identify import (
    ErrorStats,
    PsoSettings,
    SwarmObjective,
    constriction_factor,
    default_space,
    flight_errors,
    heat_map_breakpoints,
    identify,
    minimise,
    model_inputs,
    simulate_flight,
    visited_weight_s,
)
from ecu_monitor.model import InputSeries, coefficients, paper_table_a1
from ecu_monitor.model.compiled import simulate_compiled


def _synthetic_flight(
    seed: int, duration_s: int = 1500, order: tuple[float, ...] = (30, 80, 55, 95, 40, 70, 20)
) -> FlightLog:
    """A flight of throttle steps (rpm following the throttle), CHT from the paper's model at 0.02 s,
    sampled at 1 Hz with 0.3 degC noise and a 1 degC quantiser: the truth is paper_table_a1()."""
    rng = np.random.default_rng(seed)
    fine_dt = 0.02
    t_fine = np.arange(0.0, duration_s + fine_dt / 2, fine_dt)
    steps_per_level = round(duration_s / len(order)) * round(1.0 / fine_dt)  # levels change on whole seconds
    level = np.minimum(np.arange(t_fine.size) // steps_per_level, len(order) - 1)
    throttle = np.asarray(order, dtype=float)[level]
    rpm = 2000.0 + 70.0 * throttle
    altitude = 300.0 + 0.5 * t_fine
    airspeed = np.full_like(t_fine, 23.0)
    oat = 15.0 - 0.0065 * altitude
    truth = paper_table_a1()
    series = InputSeries(throttle, rpm, altitude, airspeed, oat)
    cht = simulate_compiled(series, coefficients(truth), fine_dt, 60.0).probe_c
    every = round(1.0 / fine_dt)
    keep = slice(0, None, every)
    measured = np.round(cht[keep] + 0.3 * rng.standard_normal(cht[keep].size))
    return FlightLog(
        {
            "time_s": t_fine[keep],
            "throttle_pct": throttle[keep],
            "rpm": rpm[keep],
            "altitude_m": altitude[keep],
            "airspeed_mps": airspeed[keep],
            "oat_c": oat[keep],
            "cht_c": measured,
            "cht_true_c": cht[keep],
        },
        source=f"synthetic-{seed}",
    )


# --------------------------------------------------------------------------------------------------
# PSO on known functions
# --------------------------------------------------------------------------------------------------


def _shifted_sphere(points: np.ndarray) -> np.ndarray:
    return np.sum((points - np.linspace(0.2, 0.8, points.shape[1])) ** 2, axis=1)


def test_constriction_factor_is_clerc_value():
    assert constriction_factor(2.05, 2.05) == pytest.approx(0.72984, abs=1e-5)


@pytest.mark.parametrize("constriction", [True, False])
def test_pso_finds_minimum_of_a_known_function(constriction: bool):
    settings = PsoSettings(
        particles=30,
        iterations=150,
        seed=3,
        constriction=constriction,
        cognitive=2.05 if constriction else 1.5,
        social=2.05 if constriction else 1.5,
    )
    run = minimise(_shifted_sphere, 5, settings)
    np.testing.assert_allclose(run.best_unit, np.linspace(0.2, 0.8, 5), atol=2e-3)
    assert run.best_cost < 1e-5
    assert run.evaluations == 30 * 151
    assert run.failed == 0
    assert len(run.history) == 151 and all(np.diff(run.history) <= 0)  # best never gets worse


def test_pso_is_reproducible_for_a_seed_and_varies_with_it():
    def rastrigin(points: np.ndarray) -> np.ndarray:
        z = 10.0 * (points - 0.37)
        return np.sum(z * z - 10.0 * np.cos(2 * math.pi * z) + 10.0, axis=1)

    a = minimise(rastrigin, 4, PsoSettings(particles=20, iterations=60, seed=11))
    b = minimise(rastrigin, 4, PsoSettings(particles=20, iterations=60, seed=11))
    c = minimise(rastrigin, 4, PsoSettings(particles=20, iterations=60, seed=12))
    assert a.history == b.history
    np.testing.assert_array_equal(a.best_unit, b.best_unit)
    assert a.history != c.history


def test_pso_counts_failed_particles_and_never_picks_them():
    def half_fails(points: np.ndarray) -> np.ndarray:
        cost = _shifted_sphere(points)
        return np.where(points[:, 0] < 0.5, np.nan, cost)  # the true minimum (x0 = 0.2) is in the failing half

    run = minimise(half_fails, 3, PsoSettings(particles=20, iterations=40, seed=1))
    assert run.failed > 0
    assert math.isfinite(run.best_cost)
    assert run.best_unit[0] >= 0.5
    assert run.best_cost == pytest.approx(0.3**2, abs=1e-3)  # best feasible: x0 on the 0.5 edge


def test_pso_restarts_on_stagnation():
    run = minimise(
        _shifted_sphere, 2, PsoSettings(particles=10, iterations=80, seed=0, stagnation_iterations=5, max_restarts=3)
    )
    assert run.restarts == 3


@pytest.mark.parametrize(
    "kwargs",
    [
        {"particles": 1},
        {"iterations": -1},
        {"constriction": True, "cognitive": 1.0, "social": 1.0},
        {"dt_s": 0.0},
        {"velocity_clamp": 2.0},
    ],
)
def test_pso_settings_are_validated(kwargs):
    with pytest.raises(ParameterError):
        PsoSettings(**kwargs)


# --------------------------------------------------------------------------------------------------
# Problem: inputs, simulation, errors, space
# --------------------------------------------------------------------------------------------------


def test_model_inputs_names_the_missing_column():
    log = _synthetic_flight(0, 300)
    with pytest.raises(FlightLogError, match="fuel_flow_lph"):
        model_inputs(log, ("fuel_flow_lph", "rpm"))


def test_error_stats_by_hand():
    e = ErrorStats.from_series(np.array([101.0, 99.0, 100.0, 104.0]), np.array([100.0, 100.0, 100.0, 100.0]))
    assert (e.mean_c, e.peak_c, e.rms_c) == (1.5, 4.0, pytest.approx(math.sqrt(18 / 4)))
    assert (e.mean_pct, e.peak_pct) == (pytest.approx(1.5), pytest.approx(4.0))
    assert math.isnan(e.peak_rise_pct)
    # against the rise above OAT: mean CHT - OAT = 80 degC, so 1.5 / 80 and 4 / 80
    r = ErrorStats.from_series(np.array([101.0, 99.0, 100.0, 104.0]), np.full(4, 100.0), np.full(4, 20.0))
    assert (r.mean_rise_pct, r.peak_rise_pct) == (pytest.approx(1.875), pytest.approx(5.0))


def test_simulate_flight_matches_the_truth_and_steps_converge():
    log = _synthetic_flight(0, 600)
    truth = paper_table_a1()
    fine = simulate_flight(truth, log)
    np.testing.assert_allclose(fine, log["cht_true_c"], atol=0.02)  # same model, inputs held between samples
    coarse = simulate_flight(truth, log, dt_s=0.5)
    assert np.max(np.abs(coarse - fine)) < 0.01
    assert flight_errors(truth, log).rms_c < 0.5  # quantiser + noise only


def test_swarm_cost_equals_single_simulation_and_reports_failures():
    log = _synthetic_flight(1, 600)
    space = default_space([log])
    objective = SwarmObjective([log], space, dt_s=0.5)
    truth_unit = space.to_unit(space.from_params(paper_table_a1()))
    rng = np.random.default_rng(0)
    swarm = np.vstack([truth_unit, rng.random((5, space.dimension))])
    costs = objective.costs(swarm)
    for k in range(swarm.shape[0]):
        params = space.to_params(space.from_unit(swarm[k]))
        mse = np.mean((simulate_flight(params, log, dt_s=0.5) - log["cht_c"]) ** 2)
        prior = space.prior_penalty(space.from_unit(swarm[k])[None, :])[0]
        assert costs[k] == pytest.approx(math.sqrt(mse + prior), rel=1e-9)
    assert objective.evaluations == 6 and objective.failed == 0


def test_space_round_trip_and_scale_degeneracy_refused():
    log = _synthetic_flight(2, 600)
    space = default_space([log])
    truth = paper_table_a1()
    vector = space.from_params(truth)
    back = space.to_params(vector)
    assert back.c_w == pytest.approx(truth.c_w) and back.r_ce == pytest.approx(truth.r_ce)
    assert back.alpha_r_e == pytest.approx(truth.alpha_r_e)
    assert set(space.names) >= {"time_constant_s", "radiation_fraction", "tau_w"} and "r_ce" not in space.names
    for i, j in space.heat_cells:
        assert back.heat_map.values_array()[i, j] == pytest.approx(truth.heat_map.values_array()[i, j])
    np.testing.assert_allclose(space.from_unit(space.to_unit(vector)), vector, rtol=1e-12)
    with pytest.raises(ParameterError, match="scale"):
        default_space([log], free=("c_w", "r_ce", "alpha_r_e", "heat_map"))
    with pytest.raises(ParameterError, match="unknown"):
        default_space([log], free=("c_w", "volume"))
    with pytest.raises(ParameterError, match="effect is off"):
        default_space([log], free=("c_w", "effects.sensor_lag.time_constant_s"))


def test_altitude_exponents_get_a_prior_when_freed():
    log = _synthetic_flight(2, 600)
    space = default_space([log], free=("c_w", "r_ce", "a", "b"))
    vector = space.from_params(paper_table_a1())
    assert space.prior_penalty(vector[None, :])[0] == pytest.approx(0.0)
    moved = vector.copy()
    moved[space.names.index("a")] += 0.5  # one prior sigma
    assert space.prior_penalty(moved[None, :])[0] == pytest.approx(1.0)


def test_heat_map_grid_from_data_quantiles_and_visits():
    log = _synthetic_flight(3, 700)
    xb, yb = heat_map_breakpoints([log], ("throttle_pct", "rpm"), (3, 4))
    assert len(xb) == 3 and len(yb) == 4
    assert xb[0] >= 20.0 and xb[-1] <= 95.0
    space = default_space([log], grid=(3, 3))
    assert space.base.heat_map.x_breakpoints == heat_map_breakpoints([log], ("throttle_pct", "rpm"), (3, 3))[0]
    weight = visited_weight_s([log], space.base.heat_map)
    assert weight.sum() == pytest.approx(log.duration_s + 1.0)  # every sample carries its interval
    with pytest.raises(ParameterError):
        heat_map_breakpoints([log], ("throttle_pct", "rpm"), (0, 3))
    # one breakpoint on an axis: the heat does not depend on it; the map keeps two, identified as one value
    tied = default_space([log], grid=(3, 1))
    assert tied.base.heat_map.shape == (3, 2) and sorted(tied.heat_cells) == [(0, 0), (1, 0), (2, 0)]
    vector = tied.from_params(tied.base)
    vector[tied.names.index("heat_rise_c[1,0]")] *= 1.5
    heat = tied.coefficient_arrays(vector[None, :]).heat_values_w[0]
    assert np.array_equal(heat[:, 0], heat[:, 1]) and len(set(heat[:, 0])) == 3
    # a fuel-flow axis of two breakpoints (heat linear in fuel) spans from no fuel to beyond the largest
    # flow: the line carries on past one flight; a finer one keeps its quantiles
    fuel = np.asarray(log["throttle_pct"]) * 0.4
    fueled = log.with_columns(fuel_flow_lph=fuel)
    xb, _ = heat_map_breakpoints([fueled], ("fuel_flow_lph", "rpm"), (2, 2))
    assert xb == (0.0, pytest.approx(1.25 * fuel.max(), abs=1e-6))
    xb, _ = heat_map_breakpoints([fueled], ("fuel_flow_lph", "rpm"), (3, 2))
    assert xb == pytest.approx(tuple(np.quantile(fuel, [0.01, 0.5, 0.99])), abs=1e-6)


def test_the_radiation_term_is_switched_off_only_when_named():
    """-radiation: the T^4 term off (terms_off) and alpha_r_e no longer fitted; the term search leaves it."""
    from ecu_monitor.identify.select import AUTO_TERMS, model_form, parse_terms, term_is_on

    log = _synthetic_flight(3, 300)
    dark, free = model_form(paper_table_a1(), [log], parse_terms("-radiation,airspeed_cooling"))
    assert not dark.term_on("radiation") and not term_is_on(dark, "radiation")
    assert "alpha_r_e" not in free and "effects.airspeed_cooling.gain_per_mps" in free
    lit, free = model_form(dark, [log], {"radiation": True})
    assert lit.term_on("radiation") and "alpha_r_e" in free
    assert "radiation" not in AUTO_TERMS and "radiation_kelvin" in AUTO_TERMS


# --------------------------------------------------------------------------------------------------
# Identification on a flight with a known truth
# --------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def identified():
    train = _synthetic_flight(10, 1500)
    truth = paper_table_a1()
    start = truth.replace(
        c_w=900.0, r_ce=0.09, tau_w=15.0, heat_map=truth.heat_map.with_values(truth.heat_map.values_array() * 1.4)
    )
    result = identify([train], base=start, settings=PsoSettings(particles=32, iterations=60, seed=4))
    return train, truth, result


def test_identification_recovers_the_main_parameters(identified):
    _train, truth, result = identified
    p = result.params
    # the common scale is not observable (module doc of identify.problem): r_ce stays at the start
    # value and the scale-free quantities are compared with the truth
    assert p.r_ce == 0.09
    assert p.c_w * p.r_ce == pytest.approx(truth.c_w * truth.r_ce, rel=0.05)
    share = result.space.radiation_share
    assert share(p) == pytest.approx(share(truth), abs=0.05)
    # throttle and rpm move together on this flight, so the data fix the heat map along the flown line
    # (at the operating points), not every breakpoint: off-line breakpoints follow the prior
    levels = np.unique(_train["throttle_pct"])
    rpm = 2000.0 + 70.0 * levels
    np.testing.assert_allclose(p.heat_map(levels, rpm) * p.r_ce, truth.heat_map(levels, rpm) * truth.r_ce, rtol=0.05)
    assert result.at_bounds == ()
    assert p.tau_w == pytest.approx(truth.tau_w, rel=0.15)
    # particles with a time constant far below the step diverge; they are counted and never chosen
    assert result.failed_particles < 0.05 * result.evaluations
    assert result.evaluations > 32 * 61


def test_identified_model_predicts_a_held_out_flight(identified):
    _train, _truth, result = identified
    held_out = _synthetic_flight(11, 1400, order=(20, 70, 40, 95, 55, 80, 30))  # same levels, other order
    e = flight_errors(result.params, held_out)
    assert e.mean_pct < 1.0 and e.peak_pct < 5.0
    assert result.train_errors[0].rms_c < 0.5
    assert result.cost_history[-1] <= result.cost_history[0]


def test_identification_counts_diverging_particles():
    log = _synthetic_flight(5, 400, order=(40, 80))
    result = identify([log], settings=PsoSettings(particles=16, iterations=5, seed=0, dt_s=5.0, polish=False))
    assert result.failed_particles > 0  # RK4 at 5 s is unstable for a short heat-path delay tau_w
    assert math.isfinite(result.cost_history[-1])
    assert result.params.tau_w > 2.0 * 5.0 / 2.79  # the best particle is one whose RK4 is stable


def test_effect_parameters_can_be_freed_by_name():
    from ecu_monitor.model import Effects, SensorLag

    log = _synthetic_flight(6, 600)
    base = paper_table_a1().replace(effects=Effects(sensor_lag=SensorLag(8.0)))
    space = default_space([log], base=base, free=("c_w", "r_ce", "heat_map", "effects.sensor_lag.time_constant_s"))
    vector = space.from_params(base)
    k = space.names.index("effects.sensor_lag.time_constant_s")
    assert vector[k] == 8.0
    vector[k] = 20.0
    params = space.to_params(vector)
    assert params.effects.sensor_lag == SensorLag(20.0)
    np.testing.assert_array_equal(space.coefficient_arrays(vector[None, :]).sensor_lag_s, [20.0])


# --------------------------------------------------------------------------------------------------
# Scale anchor, heat-map prior, bounds, terms
# --------------------------------------------------------------------------------------------------


def test_radiation_share_coordinate_is_scale_free_and_kelvin_aware():
    log = _synthetic_flight(7, 600)
    for kelvin in (False, True):
        base = paper_table_a1().replace(radiation_in_kelvin=kelvin)
        space = default_space([log], base=base)
        vector = space.from_params(base)
        k = space.names.index("radiation_fraction")
        assert 0.0 < vector[k] < 1.0
        vector[k] = 0.25
        params = space.to_params(vector)
        assert space.radiation_share(params) == pytest.approx(0.25)
        # the same share in a model of twice the scale (C_w, Q, 1/R_Ce, 1/alpha R_e all doubled)
        double = params.replace(
            c_w=2 * params.c_w,
            r_ce=params.r_ce / 2,
            alpha_r_e=params.alpha_r_e / 2,
            heat_map=params.heat_map.with_values(2 * params.heat_map.values_array()),
        )
        assert space.radiation_share(double) == pytest.approx(0.25)
        vector[k] = 0.0
        assert math.isinf(space.to_params(vector).alpha_r_e)


def test_heat_map_prior_penalises_curvature_and_a_fall_with_power():
    log = _synthetic_flight(8, 600)
    space = default_space([log], grid=(3, 3))
    assert len(space.heat_cells) == 9  # every breakpoint is free under the prior
    vector = space.from_params(space.base)
    cells = {c: space.names.index(f"heat_rise_c[{c[0]},{c[1]}]") for c in space.heat_cells}
    vector[list(cells.values())] = 60.0
    assert space.prior_penalty(vector[None, :])[0] == pytest.approx(0.0)  # a flat map
    falling = vector.copy()
    falling[cells[(2, 1)]] -= 2.0 * space.heat_monotone_sigma_c  # less heat at more power
    bumped = vector.copy()
    bumped[cells[(2, 1)]] += space.heat_smooth_sigma_c  # a bump at full power: curvature along both axes
    assert space.prior_penalty(falling[None, :])[0] > 4.0
    assert space.prior_penalty(bumped[None, :])[0] == pytest.approx(1.0 + 4.0, rel=1e-9)
    rising = vector.copy()
    for (i, _j), k in cells.items():
        rising[k] += 10.0 * i  # linear in power: no curvature, no fall
    assert space.prior_penalty(rising[None, :])[0] == pytest.approx(0.0, abs=1e-12)


def test_bounds_within_one_percent_are_reported():
    log = _synthetic_flight(9, 600)
    space = default_space([log])
    vector = space.from_params(paper_table_a1())
    assert space.at_bounds(vector) == []
    k = space.names.index("time_constant_s")
    vector[k] = space.upper[k]
    lines = space.at_bounds(vector)
    assert len(lines) == 1 and "time_constant_s" in lines[0] and "upper bound" in lines[0]


def test_terms_switch_on_and_off_and_parse():
    from ecu_monitor.identify.select import model_form, parse_terms, split_halves, term_is_on

    log = _synthetic_flight(12, 1300)
    assert parse_terms("airspeed_cooling,-altitude_factor") == {"airspeed_cooling": True, "altitude_factor": False}
    with pytest.raises(ParameterError, match="unknown term"):
        parse_terms("warp_drive")
    form, free = model_form(paper_table_a1(), [log], {"airspeed_cooling": True, "altitude_factor": False})
    assert term_is_on(form, "airspeed_cooling") and not term_is_on(form, "altitude_factor")
    assert "effects.airspeed_cooling.gain_per_mps" in free and "heat_map" in free
    kelvin, _ = model_form(paper_table_a1(), [log], {"radiation_kelvin": True})
    space = default_space([log], base=paper_table_a1())
    # the switch keeps the radiated share at the data's reference point
    assert space.radiation_share(kelvin) == pytest.approx(space.radiation_share(paper_table_a1()), rel=1e-9)
    first, second = split_halves(log)
    assert len(first) + len(second) == len(log) and first.time_s[-1] < second.time_s[0]
    # the mixture index switched on for a fuel-flow heat map starting from a throttle-axis base (the
    # base's axes are not the flight's: the index reads only its own columns)
    fuel = log.with_columns(fuel_flow_lph=0.3 * np.asarray(log["throttle_pct"]), egt_c=600.0 + log["throttle_pct"])
    fuel = fuel.with_columns(throttle_pct=np.full(len(log), np.nan))
    mixed, names = model_form(paper_table_a1(), [fuel], {"mixture_index": True})
    mixture = mixed.effects.mixture_index
    assert mixture is not None and mixture.source == "egt_rise" and "effects.mixture_index.gain" in names
    assert mixture.reference == pytest.approx(float(np.median(fuel["egt_c"] - np.asarray(fuel["oat_c"]))))
    with pytest.raises(ParameterError, match="needs"):
        split_halves(_synthetic_flight(13, 600))


def test_to_params_keeps_altitude_exponents_when_the_term_is_off():
    log = _synthetic_flight(14, 600)
    base = paper_table_a1().replace(terms_off=("altitude_scaling",))
    space = default_space([log], base=base)
    params = space.to_params(space.from_params(space.base))
    assert (params.a, params.b) == (base.a, base.b) and params.terms_off == ("altitude_scaling",)


def test_a_time_scale_at_its_bound_is_flagged_for_a_second_search():
    from ecu_monitor.identify.fit import _time_scale_at_bound
    from ecu_monitor.identify.select import model_form

    log = _synthetic_flight(15, 600)
    form, names = model_form(paper_table_a1(), [log], {"sensor_lag": True})
    space = default_space([log], base=form, free=names)
    unit = space.to_unit(space.from_params(space.base))
    k_tc, k_lag = space.names.index("time_constant_s"), space.names.index("effects.sensor_lag.time_constant_s")
    inside = unit.copy()
    inside[k_tc], inside[k_lag] = 0.5, 0.5
    assert not _time_scale_at_bound(space, inside)
    no_lag = inside.copy()
    no_lag[k_lag] = 0.0  # a probe without lag is an answer, not a wrong basin
    assert not _time_scale_at_bound(space, no_lag)
    for k, edge in ((k_tc, 0.0), (k_tc, 1.0), (k_lag, 1.0)):
        hit = inside.copy()
        hit[k] = edge
        assert _time_scale_at_bound(space, hit)


def test_least_squares_runs_blas_on_one_thread_and_gives_the_threads_back():
    """The polish's SVD runs on one BLAS thread (faster than two, docs/results/gap_real.md); outside it numpy's and
    scipy's BLAS keep the threads they had (two here: the suite itself runs one per worker)."""
    from threadpoolctl import threadpool_info, threadpool_limits

    from ecu_monitor.identify.fit import one_blas_thread

    def blas_threads() -> set[int]:
        return {info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"}

    with threadpool_limits(limits=2, user_api="blas"):
        assert blas_threads() == {2}
        with one_blas_thread():
            assert blas_threads() == {1}
        assert blas_threads() == {2}
