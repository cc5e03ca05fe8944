"""The model is written once: every kernel equals the numpy reference (thermal.simulate) with every
effect on, and the model-layer options (mixture index, propeller wash, terms switched off, radiation
in kelvin) behave as documented."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ecu_monitor.errors import FlightLogError, ParameterError
from ecu_monitor.estimation.ekf import EstimatorSettings
from ecu_monitor.estimation.isolation import IsolationSettings, run_isolation
from ecu_monitor.estimation.runner import trace_loop
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.model import (
    EFFECT_COEFFICIENTS,
    EFFECT_NAMES,
    EFFECT_TYPES,
    AirspeedCooling,
    DensityCooling,
    Effects,
    EngineSpeedCooling,
    InputSeries,
    MassFlowCooling,
    MixtureCooling,
    MixtureIndex,
    SensorLag,
    ThermalParams,
    coefficients,
    compute_drive,
    flight_inputs,
    input_columns,
    paper_table_a1,
    rk4_step,
    scalar_coefficients,
    sensor_step,
    simulate,
    stack_coefficients,
)
from ecu_monitor.model.compiled import compute_drive_compiled, simulate_compiled

DT = 0.5


def _random_params(rng: np.random.Generator, kelvin: bool) -> ThermalParams:
    """A parameter set far from Table A1 with every effect on (sizes drawn wide)."""
    base = paper_table_a1()
    effects = Effects(
        airspeed_cooling=AirspeedCooling(
            gain_per_mps=float(rng.uniform(-0.01, 0.04)),
            reference_mps=float(rng.uniform(15, 60)),
            floor=float(rng.uniform(0.1, 0.6)),
            prop_wash_mps=float(rng.uniform(0, 20)),
        ),
        density_cooling=DensityCooling(
            exponent=float(rng.uniform(0.2, 0.9)), reference_kg_m3=float(rng.uniform(1, 1.3))
        ),
        mass_flow_cooling=MassFlowCooling(
            exponent=float(rng.uniform(0.3, 1.2)), reference_kg_m3=float(rng.uniform(0.9, 1.3))
        ),
        engine_speed_cooling=EngineSpeedCooling(
            gain=float(rng.uniform(-0.3, 1.0)), reference_rpm=float(rng.uniform(1500, 6000))
        ),
        sensor_lag=SensorLag(time_constant_s=float(rng.uniform(1, 30))),
        mixture_cooling=MixtureCooling(fraction=float(rng.uniform(0, 0.3)), onset=float(rng.uniform(0.3, 0.9))),
        mixture_index=MixtureIndex(
            "egt_c", gain=float(rng.uniform(-0.002, 0.002)), reference=float(rng.uniform(500, 800))
        ),
    )
    heat = base.heat_map.values_array() * rng.uniform(0.3, 3.0, base.heat_map.shape)
    return base.replace(
        c_w=base.c_w * float(rng.uniform(0.03, 3.0)),
        r_ce=base.r_ce * float(rng.uniform(0.1, 3.0)),
        alpha_r_e=float(rng.uniform(2e8, 2e9)) if kelvin else float(rng.uniform(3e5, 3e6)),
        radiation_in_kelvin=kelvin,
        tau_w=float(rng.uniform(1, 30)),
        a=float(rng.uniform(0.5, 2.5)),
        b=float(rng.uniform(0, 3)),
        heat_map=base.heat_map.with_values(heat),
        effects=effects,
    )


def _random_inputs(rng: np.random.Generator, n: int, hold: int = 4) -> InputSeries:
    """Inputs held over ``hold`` steps (as a 1 Hz log on a 0.5 s grid), the EGT blank now and then."""
    m = n // hold + 1
    k = np.arange(n) // hold
    egt = rng.uniform(450, 850, m)
    egt[rng.random(m) < 0.1] = np.nan  # not logged: the mixture factor is 1
    return InputSeries(
        rng.uniform(-5, 105, m)[k],  # beyond the map's edges too (clamped lookup)
        rng.uniform(1500, 9500, m)[k],
        rng.uniform(0, 4000, m)[k],
        np.where(rng.random(m) < 0.2, 0.0, rng.uniform(0, 60, m))[k],  # ground (prop wash) and flight
        rng.uniform(-20, 35, m)[k],
        egt[k],
    )


@pytest.mark.parametrize("kelvin", [False, True])
def test_every_kernel_equals_the_reference_model(kelvin: bool) -> None:
    rng = np.random.default_rng(12 + kelvin)
    params = [_random_params(rng, kelvin) for _ in range(5)]
    assert set(params[0].effects.active) == set(EFFECT_NAMES)  # a new effect must be added above
    inputs = _random_inputs(rng, 240)
    gamma_q = rng.uniform(1.0, 1.3, 240)
    gamma_d = rng.uniform(1.0, 1.3, 240)
    start = 120.0
    swarm = simulate_compiled(inputs, stack_coefficients(params), DT, start, gamma_q, gamma_d)
    assert not swarm.failed.any()
    for p, param in enumerate(params):
        coeffs = coefficients(param)
        ref_cht, ref_probe = simulate(inputs, coeffs, DT, start, gamma_q, gamma_d)
        scale = max(1.0, float(np.max(np.abs(ref_cht))))
        # the compiled swarm kernel
        assert np.max(np.abs(swarm.cht_c[:, p] - ref_cht)) < 1e-9 * scale
        assert np.max(np.abs(swarm.probe_c[:, p] - ref_probe)) < 1e-9 * scale
        # the scalar float path (math module): one step at a time as the live filter
        cht, pade, probe = (
            start,
            2.0 * compute_drive(InputSeries(*(float(v[0]) for v in inputs)), coeffs).q_sl0_w,
            start,
        )
        for k in range(1, 240):
            drive = compute_drive(InputSeries(*(float(v[k - 1]) for v in inputs)), coeffs)
            assert isinstance(drive.q_sl0_w, float)
            cht, pade = rk4_step(cht, pade, drive, coeffs, DT, float(gamma_q[k - 1]), float(gamma_d[k - 1]))
            probe = sensor_step(probe, cht, coeffs, DT)
            assert cht == pytest.approx(ref_cht[k], abs=1e-9 * scale)
            assert probe == pytest.approx(ref_probe[k], abs=1e-9 * scale)
        # the compiled drive (filters' whole-flight path) equals the numpy drive
        compiled = compute_drive_compiled(inputs, scalar_coefficients(coeffs))
        reference = compute_drive(inputs, coeffs)
        for got, want in zip(compiled, reference, strict=True):
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("kelvin", [False, True])
def test_filter_kernels_predict_with_the_reference_model(kelvin: bool) -> None:
    """Without readings, the EKF loop (compiled and Python) and the isolation filter run the model open loop."""
    rng = np.random.default_rng(40 + kelvin)
    params = _random_params(rng, kelvin).replace(
        effects=_random_params(rng, kelvin).effects.replace("sensor_lag", None)
    )
    inputs = _random_inputs(rng, 400, hold=1)
    coeffs = coefficients(params)
    ref_cht, _ = simulate(inputs, coeffs, DT, 110.0)
    scale = float(np.max(np.abs(ref_cht)))
    # EKF loop: no reading after the first, no deviation term: x follows f
    drive = [np.ascontiguousarray(v) for v in compute_drive_compiled(inputs, scalar_coefficients(coeffs))]
    z = np.full(400, np.nan)
    z[0] = 110.0
    s = EstimatorSettings(dt_s=DT)
    for loop in (trace_loop, trace_loop.py_func):
        outs = [np.empty(400) for _ in range(5)] + [np.zeros(400, dtype=np.bool_)]
        loop(*drive, z, np.isfinite(z), np.ones(400, dtype=np.int64), scalar_coefficients(coeffs), s.initial_var,
             DT, s.process_var, s.measurement_var, s.sigmoid_a, s.sigmoid_b, s.quantum_c, s.deviation_time_s,
             False, 0, *outs)  # fmt: skip
        assert np.max(np.abs(outs[0] - ref_cht)) < 1e-9 * scale
    # isolation filter: readings ignored (huge R), gammas frozen
    columns = {"time_s": DT * np.arange(400), "z": z}
    columns.update(zip(("throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c", "egt_c"), inputs, strict=True))
    log = FlightLog(columns)
    settings = IsolationSettings(dt_s=DT, measurement_var=1e12, gamma_q_process_var=1e-12, gamma_d_process_var=1e-12)
    with pytest.raises(FlightLogError, match="egt_c"):  # a logged EGT must be finite where the model reads it
        run_isolation(log, params, settings, cht_column="z")
    held = FlightLog({**columns, "egt_c": np.nan_to_num(inputs.mixture_index, nan=600.0)})
    trace = run_isolation(held, params, settings, cht_column="z")
    ref_held, _ = simulate(flight_inputs(held, params), coeffs, DT, 110.0)
    assert np.max(np.abs(trace.cht_c - ref_held)) < 1e-9 * scale


def test_every_effect_parameter_reaches_the_equations() -> None:
    for name, kind in EFFECT_TYPES.items():
        for field in dataclasses.fields(kind):
            if field.type not in ("str", str):  # a choice (mixture_index.source) is read by inputs.py
                assert f"{name}.{field.name}" in EFFECT_COEFFICIENTS, f"{name}.{field.name}"
    neutral = coefficients(paper_table_a1())
    for key, (column, value) in EFFECT_COEFFICIENTS.items():
        assert getattr(neutral, column) == value, key


def test_mixture_index_effect() -> None:
    params = paper_table_a1()
    cruise = InputSeries(60.0, 6500.0, 1000.0, 25.0, 10.0)
    fuel = MixtureIndex("fuel_per_rev", gain=-2.0, reference=0.25)
    on = coefficients(params.replace(effects=Effects(mixture_index=fuel)))
    nominal = compute_drive(cruise, coefficients(params))
    # not logged (the default) is neutral; at the reference too; richer (more fuel per rev) cools
    assert compute_drive(cruise, on) == nominal
    assert compute_drive(cruise._replace(mixture_index=0.25), on).heat_gain == pytest.approx(1.0, abs=1e-15)
    richer = compute_drive(cruise._replace(mixture_index=0.35), on).heat_gain
    assert richer == pytest.approx(math.exp(-2.0 * 0.1), rel=1e-12)
    # the one mapping from a flight log: fuel_flow_lph / rpm in mL per revolution
    log = FlightLog(
        {
            "time_s": [0.0, 1.0],
            "throttle_pct": [50.0, 60.0],
            "rpm": [2400.0, 0.0],
            "altitude_m": [0.0, 0.0],
            "airspeed_mps": [0.0, 0.0],
            "oat_c": [15.0, 15.0],
            "fuel_flow_lph": [36.0, 0.0],
        }
    )
    model = params.replace(effects=Effects(mixture_index=fuel))
    assert input_columns(model) == ("throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c", "fuel_flow_lph")
    np.testing.assert_allclose(flight_inputs(log, model).mixture_index, [36000.0 / 60.0 / 2400.0, 0.0])
    assert np.all(np.isnan(flight_inputs(log, params).mixture_index))
    with pytest.raises(FlightLogError, match="no column 'egt_c'"):
        flight_inputs(log, params.replace(effects=Effects(mixture_index=MixtureIndex("egt_c"))))
    # validated like the others, and in model.yaml with its source
    assert "mixture_index" in EFFECT_NAMES
    with pytest.raises(ParameterError, match="source"):
        MixtureIndex("lambda")
    with pytest.raises(ParameterError, match="gain"):
        MixtureIndex("fuel_per_rev", gain=50.0, reference=0.3)
    with pytest.raises(ParameterError, match="reference"):
        MixtureIndex("egt_c", reference=2000.0)
    assert ThermalParams.from_dict(model.to_dict()) == model
    with pytest.raises(ParameterError, match="source"):
        Effects.from_dict({"mixture_index": {"source": 3.0}})


def test_airspeed_cooling_keeps_the_prop_wash_on_the_ground() -> None:
    wash = AirspeedCooling(gain_per_mps=0.02, reference_mps=30.0, floor=0.1, prop_wash_mps=12.0)
    coeffs = coefficients(paper_table_a1().replace(effects=Effects(airspeed_cooling=wash)))
    ground = compute_drive(InputSeries(40.0, 5000.0, 0.0, 0.0, 15.0), coeffs)
    taxi = compute_drive(InputSeries(40.0, 5000.0, 0.0, 8.0, 15.0), coeffs)
    flying = compute_drive(InputSeries(40.0, 5000.0, 0.0, 40.0, 15.0), coeffs)
    base_conductance = 1.0 / 0.15
    assert ground.conductance_w_per_c == pytest.approx(base_conductance * (1.0 + 0.02 * (12.0 - 30.0)), rel=1e-12)
    assert taxi.conductance_w_per_c == ground.conductance_w_per_c  # below the wash speed: the wash cools
    assert flying.conductance_w_per_c == pytest.approx(base_conductance * 1.2, rel=1e-12)
    with pytest.raises(ParameterError, match="prop_wash_mps"):
        AirspeedCooling(prop_wash_mps=-1.0)
    # an older model.yaml without the field loads with no wash (airspeed alone, as before)
    assert Effects.from_dict({"airspeed_cooling": {"gain_per_mps": 0.01}}).airspeed_cooling.prop_wash_mps == 0.0


def test_terms_of_the_paper_can_be_switched_off() -> None:
    params = paper_table_a1()
    high = InputSeries(60.0, 6500.0, 3000.0, 25.0, -5.0)
    no_g = params.replace(terms_off=("altitude_scaling",))
    assert compute_drive(high, coefficients(params)).altitude_gain < 0.9
    assert compute_drive(high, coefficients(no_g)).altitude_gain == 1.0
    no_radiation = coefficients(params.replace(terms_off=["radiation"]))
    assert no_radiation.radiative_conductance == 0.0
    assert ThermalParams.from_dict(no_g.to_dict()) == no_g
    assert "terms_off" not in params.to_dict()  # the paper's model: files unchanged
    with pytest.raises(ParameterError, match="terms_off"):
        params.replace(terms_off=("heat_map",))
    # the compiled swarm honours it too
    inputs = InputSeries(*(np.full(50, v) for v in high))
    both = simulate_compiled(inputs, stack_coefficients([params, no_g]), DT, 100.0)
    for p, model in enumerate((params, no_g)):
        np.testing.assert_allclose(both.cht_c[:, p], simulate(inputs, coefficients(model), DT, 100.0)[0], rtol=1e-12)
    assert both.cht_c[-1, 1] > both.cht_c[-1, 0]  # g(z) < 1 at altitude: without it the head runs hotter


def test_radiation_in_kelvin_is_honoured() -> None:
    params = paper_table_a1()
    kelvin = params.replace(radiation_in_kelvin=True)
    hot = InputSeries(90.0, 8000.0, 0.0, 23.0, 15.0)
    c_c, c_k = coefficients(params), coefficients(kelvin)
    assert c_c.radiation_offset_c == 0.0 and c_k.radiation_offset_c == 273.15
    inputs = InputSeries(*(np.full(100, v) for v in hot))
    runs = [simulate_compiled(inputs, c, DT, 50.0).cht_c for c in (c_c, c_k)]
    # same alpha R_e, hotter T^4 in kelvin: more radiated, a cooler head
    assert runs[1][-1] < runs[0][-1] - 1.0
