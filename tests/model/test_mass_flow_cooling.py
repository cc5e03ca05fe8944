"""mass_flow_cooling: the ram air cools by its mass flow, density x airspeed; the engine-speed conductance adds to
the ram air's; the mixture index read as the EGT's rise over the intake air."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ecu_monitor.errors import ParameterError
from ecu_monitor.model import (
    AirspeedCooling,
    EngineSpeedCooling,
    InputSeries,
    MassFlowCooling,
    MixtureIndex,
    coefficients,
    compute_drive,
    paper_table_a1,
)
from ecu_monitor.model.atmosphere import air_density_kg_m3, isa_pressure_pa
from ecu_monitor.model.effects import Effects, mixture_index
from tests.helpers.columns import NamedColumns

AIRSPEED = AirspeedCooling(gain_per_mps=0.02, reference_mps=40.0, floor=0.05, prop_wash_mps=10.0)


def _conductance(effects: Effects, inputs: InputSeries) -> np.ndarray:
    params = paper_table_a1().replace(effects=effects)
    return np.asarray(compute_drive(inputs, coefficients(params)).conductance_w_per_c) * params.r_ce


def _inputs(altitude_m: np.ndarray, airspeed_mps: np.ndarray, rpm: np.ndarray | None = None) -> InputSeries:
    n = altitude_m.size
    rpm = np.full(n, 2400.0) if rpm is None else rpm
    return InputSeries(np.full(n, 50.0), rpm, altitude_m, airspeed_mps, np.full(n, 15.0), np.full(n, np.nan))


def test_the_ram_air_term_reads_density_times_airspeed() -> None:
    """Exponent 1: the airspeed_cooling factor at the airspeed scaled by rho/rho_ref; at the reference density
    nothing changes, and the wash floor is scaled with it (it is a flow of the same air)."""
    altitude = np.array([0.0, 1500.0, 3000.0, 3000.0])
    airspeed = np.array([40.0, 40.0, 40.0, 0.0])
    rho = np.asarray(air_density_kg_m3(isa_pressure_pa(altitude), np.full(4, 15.0)))
    mass = MassFlowCooling(exponent=1.0, reference_kg_m3=float(rho[0]))
    got = _conductance(Effects(airspeed_cooling=AIRSPEED, mass_flow_cooling=mass), _inputs(altitude, airspeed))
    flow = np.maximum(airspeed, AIRSPEED.prop_wash_mps) * rho / rho[0]
    expected = np.maximum(AIRSPEED.floor, 1.0 + AIRSPEED.gain_per_mps * (flow - AIRSPEED.reference_mps))
    assert got == pytest.approx(expected, rel=1e-12)
    assert got[0] == pytest.approx(1.0) and got[2] < got[1] < got[0]  # thinner air cools less
    # exponent 0: exactly airspeed_cooling alone
    alone = _conductance(Effects(airspeed_cooling=AIRSPEED), _inputs(altitude, airspeed))
    neutral = Effects(airspeed_cooling=AIRSPEED, mass_flow_cooling=MassFlowCooling(exponent=0.0))
    assert np.array_equal(_conductance(neutral, _inputs(altitude, airspeed)), alone)


def test_needs_airspeed_cooling_and_starts_at_the_median_density() -> None:
    with pytest.raises(ParameterError, match=r"mass_flow_cooling: .*airspeed_cooling"):
        Effects(mass_flow_cooling=MassFlowCooling())
    with pytest.raises(ParameterError, match=r"mass_flow_cooling\.exponent"):
        MassFlowCooling(exponent=5.0)
    columns = {"altitude_m": np.array([0.0, 1000.0, 2000.0]), "oat_c": np.array([15.0, 8.0, 2.0])}

    start = MassFlowCooling.start([NamedColumns(columns)])
    rho = air_density_kg_m3(isa_pressure_pa(1000.0), 8.0)
    assert start.exponent == 1.0 and math.isclose(start.reference_kg_m3, float(rho), rel_tol=1e-12)


def test_engine_speed_adds_a_conductance_beside_the_ram_air() -> None:
    """The two air flows add: airspeed factor + gain (rpm/ref - 1), not their product; on the ground (no ram
    air beyond the wash) the engine speed alone moves the conductance."""
    speed = EngineSpeedCooling(gain=0.6, reference_rpm=2400.0)
    altitude = np.zeros(4)
    airspeed = np.array([0.0, 0.0, 40.0, 60.0])
    rpm = np.array([1000.0, 2400.0, 2400.0, 2700.0])
    got = _conductance(Effects(airspeed_cooling=AIRSPEED, engine_speed_cooling=speed), _inputs(altitude, airspeed, rpm))
    ram = np.maximum(AIRSPEED.floor, 1.0 + AIRSPEED.gain_per_mps * (np.maximum(airspeed, 10.0) - 40.0))
    assert got == pytest.approx(ram + 0.6 * (rpm / 2400.0 - 1.0), rel=1e-12)
    assert got[1] - got[0] == pytest.approx(0.6 * 1400.0 / 2400.0)


def test_the_egt_rise_index_is_the_exhaust_over_the_intake_air() -> None:
    columns = {"egt_c": np.array([700.0, 650.0]), "oat_c": np.array([20.0, -10.0])}
    assert np.array_equal(mixture_index("egt_rise", columns), [680.0, 660.0])

    start = MixtureIndex.start([NamedColumns(columns)])
    assert start.source == "egt_rise" and start.reference == 670.0 and start.gain == 0.0
