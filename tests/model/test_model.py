"""The thermal model: steady state, RK4 accuracy, vectorisation, parameters and YAML."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ecu_monitor.errors import ConfigError, ParameterError
from ecu_monitor.model import (
    AirspeedCooling,
    DensityCooling,
    Drive,
    Effects,
    InputSeries,
    MixtureCooling,
    SensorLag,
    coefficients,
    compute_drive,
    derivatives,
    initial_pade_state,
    isa_pressure_pa,
    load_model,
    paper_table_a1,
    rk4_step,
    save_model,
    sensor_step,
    simulate,
    stack_coefficients,
    steady_state_cht,
)

CRUISE = InputSeries(50.0, 6000.0, 1500.0, 23.0, 5.0)


def test_isa_pressure_matches_standard_table():
    assert isa_pressure_pa(0.0) == pytest.approx(101325.0)
    assert isa_pressure_pa(1000.0) == pytest.approx(89874.6, rel=1e-4)
    assert isa_pressure_pa(4000.0) == pytest.approx(61640.2, rel=1e-4)


def test_steady_state_without_radiation_matches_closed_form():
    params = paper_table_a1().replace(alpha_r_e=math.inf)
    c = coefficients(params)
    d = compute_drive(CRUISE, c)
    expected = 5.0 + 1.1 * 1.2 * d.altitude_gain * d.q_sl0_w * params.r_ce
    assert steady_state_cht(d, c, gamma_q=1.1, gamma_d=1.2) == pytest.approx(expected, rel=1e-12)


def test_steady_state_stops_at_its_first_iterate_below_a_bound():
    """With ``below`` Newton returns its first iterate under it (its iterates fall onto the steady state from
    above); a bound under the steady state changes nothing. One operating point and arrays alike."""
    c = coefficients(paper_table_a1())
    scalar = Drive(*(float(v) for v in compute_drive(CRUISE, c)))
    arrays = Drive(*(np.full(3, v) for v in scalar))
    for drive in (scalar, arrays):
        full = np.asarray(steady_state_cht(drive, c, gamma_q=1.1, gamma_d=1.2))
        first = np.asarray(steady_state_cht(drive, c, gamma_q=1.1, gamma_d=1.2, iterations=1))
        assert np.all(first > full + 1e-3)  # one step is not converged: the bound can stop it early
        early = np.asarray(steady_state_cht(drive, c, gamma_q=1.1, gamma_d=1.2, below=float(first.max()) + 1e-9))
        assert np.array_equal(early, first)
        assert np.array_equal(np.asarray(steady_state_cht(drive, c, gamma_q=1.1, gamma_d=1.2, below=-50.0)), full)


@pytest.mark.parametrize("kelvin", [False, True])
def test_model_settles_to_its_heat_balance(kelvin):
    params = paper_table_a1()
    if kelvin:
        params = params.replace(radiation_in_kelvin=True, alpha_r_e=4.4e8)
    c = coefficients(params)
    d = compute_drive(CRUISE, c)
    steady = steady_state_cht(d, c)
    t_k, e_k = steady + c.radiation_offset_c, 5.0 + c.radiation_offset_c
    balance = d.q_sl0_w * d.altitude_gain - (steady - 5.0) / params.r_ce - (t_k**4 - e_k**4) / params.alpha_r_e
    assert abs(balance) < 1e-8
    cht, pade = 20.0, initial_pade_state(d)
    for _ in range(2000):  # 2000 s at 1 s steps
        cht, pade = rk4_step(cht, pade, d, c, 1.0)
    assert cht == pytest.approx(steady, abs=1e-6)
    dt, _ = derivatives(steady, initial_pade_state(d), d, c)
    assert abs(dt) < 1e-10


def test_rk4_converges_to_fine_reference_at_fourth_order():
    c = coefficients(paper_table_a1())
    rng = np.random.default_rng(1)
    drives = [compute_drive(InputSeries(th, 2000 + 70 * th, 500.0, 20.0, 10.0), c) for th in rng.uniform(10, 100, 6)]

    def run(dt: float) -> float:
        cht, pade = 60.0, initial_pade_state(drives[0])
        steps = round(10.0 / dt)
        for d in drives:  # six 10 s segments with throttle steps
            for _ in range(steps):
                cht, pade = rk4_step(cht, pade, d, c, dt)
        return cht

    reference = run(0.001)
    err_coarse = abs(run(0.5) - reference)
    err_fine = abs(run(0.25) - reference)
    assert abs(run(0.02) - reference) < 1e-7
    assert err_fine < err_coarse / 10  # fourth order: ~16x per halving


def test_swarm_step_equals_scalar_steps():
    base = paper_table_a1()
    swarm = [base, base.replace(c_w=700.0, tau_w=3.0), base.replace(r_ce=0.2, a=1.0, b=1.5)]
    swarm.append(base.replace(heat_map=base.heat_map.with_values(base.heat_map.values_array() * 1.3)))
    stacked = stack_coefficients(swarm)
    d_swarm = compute_drive(CRUISE, stacked)
    cht = np.array([90.0, 95.0, 100.0, 105.0])
    pade = np.array([1500.0, 1600.0, 1700.0, 1800.0])
    new_cht, new_pade = rk4_step(cht, pade, d_swarm, stacked, 0.02, gamma_q=1.1, gamma_d=1.05)
    for i, params in enumerate(swarm):
        c = coefficients(params)
        t1, w1 = rk4_step(float(cht[i]), float(pade[i]), compute_drive(CRUISE, c), c, 0.02, 1.1, 1.05)
        assert new_cht[i] == pytest.approx(t1, rel=1e-13)
        assert new_pade[i] == pytest.approx(w1, rel=1e-13)


def test_simulate_swarm_equals_each_member():
    base = paper_table_a1().replace(effects=Effects(airspeed_cooling=AirspeedCooling()))
    swarm = [base, base.replace(c_w=450.0), base.replace(tau_w=12.0, a=1.2)]
    n = 300
    t = np.arange(n)
    series = InputSeries(
        40 + 30 * np.sin(t / 40), 5000 + 2000 * np.sin(t / 40), 10 * t, 20 + 0 * t, 15 - 0.0065 * 10 * t
    )
    together, _ = simulate(series, stack_coefficients(swarm), 1.0, 80.0)
    for i, params in enumerate(swarm):
        alone, _ = simulate(series, coefficients(params), 1.0, 80.0)
        np.testing.assert_allclose(together[:, i], alone, rtol=1e-12)


def test_degradation_factors_raise_the_temperature():
    c = coefficients(paper_table_a1())
    d = compute_drive(CRUISE, c)
    nominal = steady_state_cht(d, c)
    assert steady_state_cht(d, c, gamma_q=1.1) > nominal + 5
    assert steady_state_cht(d, c, gamma_d=1.1) > nominal + 5


def test_effects_change_the_drive_as_documented():
    base = paper_table_a1()
    fx = Effects(
        airspeed_cooling=AirspeedCooling(gain_per_mps=0.02, reference_mps=23.0, floor=0.3),
        density_cooling=DensityCooling(exponent=0.6),
        mixture_cooling=MixtureCooling(fraction=0.2, onset=0.5),
    )
    c0, c1 = coefficients(base), coefficients(base.replace(effects=fx))
    slow = InputSeries(100.0, 9000.0, 3000.0, 13.0, -5.0)
    d0, d1 = compute_drive(slow, c0), compute_drive(slow, c1)
    rho = 0.9093 / 1.225  # ISA pressure at 3000 m with -5 degC
    assert d1.conductance_w_per_c / d0.conductance_w_per_c == pytest.approx((1 - 0.2) * rho**0.6, rel=2e-3)
    assert d1.heat_gain == pytest.approx(0.8)
    assert d0.heat_gain == pytest.approx(1.0)


def test_sensor_lag_is_first_order():
    c = coefficients(paper_table_a1().replace(effects=Effects(sensor_lag=SensorLag(10.0))))
    probe = 0.0
    for _ in range(500):  # 10 s at 0.02 s
        probe = sensor_step(probe, 100.0, c, 0.02)
    assert probe == pytest.approx(100 * (1 - math.exp(-1)), rel=1e-9)
    assert sensor_step(0.0, 100.0, coefficients(paper_table_a1()), 0.02) == 100.0


def test_yaml_round_trip(tmp_path):
    params = paper_table_a1().replace(
        c_w=612.5,
        radiation_in_kelvin=True,
        alpha_r_e=math.inf,
        effects=Effects(sensor_lag=SensorLag(7.5), density_cooling=DensityCooling(0.7, 1.2)),
    )
    path = tmp_path / "model.yaml"
    save_model(params, path, comment="test model")
    assert load_model(path) == params
    assert load_model(path).to_dict() == params.to_dict()


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("c_w: -5\n", "c_w"),
        ("c_w: abc\n", "c_w"),
        ("bogus: 1\n", "bogus"),
        ("effects: {warp_drive: {}}\n", "warp_drive"),
        ("effects: {sensor_lag: {time_constant_s: -1}}\n", "time_constant_s"),
        (
            "heat_map: {x_axis: a, y_axis: b, x_breakpoints: [0, 1], y_breakpoints: [0, 1], values_w: [[1, 2]]}\n",
            "values_w",
        ),
        ("[1, 2\n", "YAML"),
    ],
)
def test_bad_model_yaml_names_the_key(tmp_path, text, needle):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_model(path)
    message = str(info.value)
    assert str(path) in message and needle in message and "\n" not in message


def test_params_are_frozen_and_validated():
    params = paper_table_a1()
    with pytest.raises(AttributeError):
        params.c_w = 1.0  # type: ignore[misc]
    with pytest.raises(ParameterError):
        params.replace(tau_w=0.0)


def test_scalar_drive_path_equals_numpy_path():
    params = paper_table_a1().replace(
        effects=Effects(
            airspeed_cooling=AirspeedCooling(),
            density_cooling=DensityCooling(),
            mixture_cooling=MixtureCooling(0.2, 0.5),
        )
    )
    c = coefficients(params)
    rng = np.random.default_rng(3)
    for _ in range(200):
        values = (rng.uniform(-10, 110), rng.uniform(1000, 10000), rng.uniform(-300, 5000), rng.uniform(-2, 40))
        oat = rng.uniform(-30, 45)
        scalar = compute_drive(InputSeries(*values, oat), c)  # floats: the math-module path
        vector = compute_drive(InputSeries(*(np.array([v]) for v in values), np.array([oat])), c)
        assert isinstance(scalar.q_sl0_w, float)
        for got, want in zip(scalar, vector, strict=True):
            assert got == pytest.approx(float(np.asarray(want)[0]), rel=1e-12, abs=1e-12)


def test_save_model_to_unwritable_place_is_a_one_line_error(tmp_path):
    with pytest.raises(ConfigError, match=r"model\.yaml: cannot write"):
        save_model(paper_table_a1(), tmp_path / "missing-dir" / "model.yaml")


def _model_text(**changes: object) -> str:
    """The paper's model.yaml with some top-level keys changed (None: the key left out)."""
    import yaml

    data = paper_table_a1().to_dict()
    for key, value in changes.items():
        if value is None:
            data.pop(key)
        else:
            data[key] = value
    return yaml.safe_dump(data, sort_keys=False)


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        (_model_text(c_w=None), "c_w: missing"),
        (_model_text(heat_map=None), "heat_map: missing"),
        (_model_text(version=None), "version: missing"),
        (_model_text(version=2), "version: expected 1"),
        (_model_text(a=-1.55), "a: expected a value in [0, 10]"),
        (_model_text(b=-2.0), "b: expected a value in [0, 10]"),
        (_model_text(colour="red"), "colour: unknown key"),
        (_model_text() + "c_w: 600\n", "c_w: duplicate key (line"),
        (_model_text(effects={"sensor_lag": {"time_constant_s": 5, "time_constant_s ": 1}}), "time_constant_s"),
    ],
)
def test_model_yaml_refuses_missing_unknown_duplicate_and_version(tmp_path, text, needle):
    path = tmp_path / "model.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_model(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and needle in message and "\n" not in message


def test_model_yaml_duplicate_key_in_a_nested_mapping_is_refused(tmp_path):
    text = _model_text().replace("  x_axis:", "  y_axis: rpm\n  x_axis:", 1)
    path = tmp_path / "model.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=r"y_axis: duplicate key"):
        load_model(path)


@pytest.mark.parametrize(
    ("values", "needle"),
    [
        ("[[1, 2], [3]]", "row 2: expected 2 values"),
        ("[[1, 2], [3, 4, 5]]", "row 2: expected 2 values"),
        ("[[1, 2]]", "expected 2 rows"),
        ("[[1, 2], 7]", "row 2: expected 2 values"),
    ],
)
def test_heat_map_row_of_the_wrong_length_names_the_row(tmp_path, values, needle):
    text = _model_text(heat_map=None) + (
        "heat_map: {x_axis: rpm, y_axis: throttle_pct, x_breakpoints: [0, 1], y_breakpoints: [0, 1], "
        f"values_w: {values}}}\n"
    )
    path = tmp_path / "model.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_model(path)
    assert "heat_map.values_w: " in str(info.value) and needle in str(info.value)


def test_a_binary_model_file_is_one_line(tmp_path):
    """Found by tests/cli/test_bad_input_fuzz.py: a non-UTF-8 model file was a UnicodeDecodeError (exit 1)."""
    path = tmp_path / "model.yaml"
    path.write_bytes(b"\x80\x00c_w: 1\n")
    with pytest.raises(ConfigError, match=r"model\.yaml: not a model file \(not UTF-8"):
        load_model(path)
