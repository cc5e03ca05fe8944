"""engine_speed_cooling: the conductance grows with the engine speed read from the heat map's rpm axis."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ecu_monitor.errors import ParameterError
from ecu_monitor.model import EngineSpeedCooling, InputSeries, coefficients, compute_drive, paper_table_a1
from ecu_monitor.model.effects import running_rpm


def _with(effect: EngineSpeedCooling):
    base = paper_table_a1()
    return base.replace(effects=base.effects.replace("engine_speed_cooling", effect))


def test_conductance_follows_engine_speed_and_is_nominal_at_the_reference() -> None:
    params = _with(EngineSpeedCooling(gain=0.5, reference_rpm=6000.0))
    rpm = np.array([3000.0, 6000.0, 9000.0])
    ones = np.ones(3)
    inputs = InputSeries(50.0 * ones, rpm, 500.0 * ones, 25.0 * ones, 15.0 * ones, np.full(3, np.nan))
    conductance = np.asarray(compute_drive(inputs, coefficients(params)).conductance_w_per_c)
    nominal = 1.0 / params.r_ce
    assert conductance == pytest.approx(nominal * np.array([0.75, 1.0, 1.25]))
    # off: exactly the paper's conductance whatever the speed
    off = np.asarray(compute_drive(inputs, coefficients(paper_table_a1())).conductance_w_per_c)
    assert np.array_equal(off, np.full(3, nominal))


def test_needs_rpm_as_the_second_heat_axis() -> None:
    params = _with(EngineSpeedCooling())
    other = dataclasses.replace(params.heat_map, y_axis="manifold_pressure_kpa")
    with pytest.raises(ParameterError, match="engine_speed_cooling"):
        params.replace(heat_map=other)


def test_reference_is_the_running_median() -> None:
    flight = {"rpm": np.array([0.0, 0.0, 2000.0, 2400.0, 2500.0])}

    class Log:
        def has(self, name: str) -> bool:
            return name in flight

        def __getitem__(self, name: str) -> np.ndarray:
            return flight[name]

    assert running_rpm([Log()]) == 2400.0
    assert EngineSpeedCooling.start([Log()]).reference_rpm == 2400.0
