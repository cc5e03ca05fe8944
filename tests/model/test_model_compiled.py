"""The compiled simulator is the same model as the numpy one, and reports failed particles."""

from __future__ import annotations

import numpy as np

from ecu_monitor.model import (
    AirspeedCooling,
    DensityCooling,
    Effects,
    InputSeries,
    MixtureCooling,
    SensorLag,
    coefficients,
    paper_table_a1,
    simulate,
    stack_coefficients,
)
from ecu_monitor.model.compiled import simulate_compiled


def _series(n: int) -> InputSeries:
    t = np.arange(n, dtype=float)
    held = np.floor(t / 3)  # inputs held for 3 steps, like 1 Hz data on a finer step
    return InputSeries(
        50 + 45 * np.sin(held / 40),
        5000 + 2000 * np.sin(held / 40),
        5.0 * held,
        20 + 5 * np.sin(held / 100),
        15 - 0.03 * held,
    )


def test_compiled_swarm_equals_numpy_model_with_every_effect():
    base = paper_table_a1().replace(
        effects=Effects(
            airspeed_cooling=AirspeedCooling(),
            density_cooling=DensityCooling(),
            sensor_lag=SensorLag(5.0),
            mixture_cooling=MixtureCooling(0.2, 0.5),
        )
    )
    swarm = stack_coefficients(
        [base, base.replace(c_w=450.0), base.replace(tau_w=12.0, a=1.2, radiation_in_kelvin=False)]
    )
    series = _series(1200)
    gamma_q = np.where(np.arange(1200) > 600, 1.2, 1.0)
    run = simulate_compiled(series, swarm, 0.5, 80.0, gamma_q=gamma_q, gamma_d=1.05)
    cht, probe = simulate(series, swarm, 0.5, 80.0, gamma_q=gamma_q, gamma_d=1.05)
    np.testing.assert_allclose(run.cht_c, cht, rtol=0, atol=1e-9)
    np.testing.assert_allclose(run.probe_c, probe, rtol=0, atol=1e-9)
    assert not run.failed.any()


def test_compiled_single_parameter_set_and_decimation():
    c = coefficients(paper_table_a1())
    series = _series(1000)
    full = simulate_compiled(series, c, 0.2, 60.0)
    every_ten = simulate_compiled(series, c, 0.2, 60.0, record_every=10)
    assert full.cht_c.shape == (1000,) and every_ten.cht_c.shape == (100,)
    np.testing.assert_array_equal(every_ten.cht_c, full.cht_c[::10])
    assert not bool(full.failed)


def test_unstable_particle_is_flagged_not_hidden():
    base = paper_table_a1()
    # tau_w far below the step makes RK4 on the Pade state unstable: that particle must fail
    swarm = stack_coefficients([base, base.replace(tau_w=0.05)])
    run = simulate_compiled(_series(400), swarm, 1.0, 80.0)
    assert list(run.failed) == [False, True]
    assert np.isnan(run.probe_c[-1, 1]) and np.isfinite(run.probe_c[:, 0]).all()


def test_packed_coefficients_unpack_to_the_same_fields_in_python_and_compiled():
    """pack_coefficients / unpack_coefficients (the live filters' compiled calls) lose no field and move none:
    the model's coefficients with every effect on, and distinct values in every scalar slot, compared field by
    field in Python and after numba's unpack."""
    import numba

    from ecu_monitor.model import Coefficients, pack_coefficients, scalar_coefficients, unpack_coefficients

    params = paper_table_a1().replace(
        effects=Effects(
            airspeed_cooling=AirspeedCooling(),
            density_cooling=DensityCooling(),
            sensor_lag=SensorLag(5.0),
            mixture_cooling=MixtureCooling(0.2, 0.5),
        )
    )
    original = scalar_coefficients(coefficients(params))
    packed = pack_coefficients(original)
    assert len(packed.scalars) == len(Coefficients._fields) - 3  # every field but the heat map and its breakpoints
    distinct = packed._replace(scalars=np.arange(len(packed.scalars)) + 0.5)
    compiled = numba.njit(lambda *packed: unpack_coefficients(*packed))
    for unpack in (unpack_coefficients, compiled):
        unpacked = unpack(*packed)
        assert unpacked._fields == original._fields
        for name in original._fields:
            np.testing.assert_array_equal(getattr(unpacked, name), getattr(original, name), err_msg=name)
        slots = unpack(*distinct)
        for index, name in enumerate(Coefficients._fields[: len(packed.scalars)]):
            assert getattr(slots, name) == index + 0.5, name
