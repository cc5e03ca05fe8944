"""mixture_index on the fuel/air ratio: the fuel per unit of fresh air from the fuel flow, rpm, manifold pressure,
OAT and altitude, read as its log so that the heat per unit of fuel follows a power of the ratio."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ecu_monitor.errors import ParameterError
from ecu_monitor.model import InputSeries, MixtureIndex, coefficients, compute_drive, paper_table_a1
from ecu_monitor.model.atmosphere import air_density_kg_m3, isa_pressure_pa
from ecu_monitor.model.effects import Effects, fuel_air_index, mixture_index, volumetric_efficiency
from ecu_monitor.model.kernels import njit
from tests.helpers.columns import NamedColumns

COLUMNS = ("fuel_flow_lph", "rpm", "manifold_pressure_kpa", "oat_c", "altitude_m")


@njit()
def compiled(fuel: float, rpm: float, manifold: float, oat: float, altitude: float) -> float:
    """The index as the live step computes it (compiled, scalars)."""
    return fuel_air_index(fuel, rpm, manifold, oat, altitude)


def _index(**columns: float) -> float:
    return float(mixture_index("fuel_air", {name: np.array([columns[name]]) for name in COLUMNS})[0])


def test_the_index_is_the_log_of_fuel_per_unit_of_fresh_air() -> None:
    """Full throttle at sea level (the manifold at the ambient pressure): every swept litre is fresh air at the
    intake's density; at part throttle the burnt gas left at the exhaust's pressure takes a share of it."""
    open_throttle = _index(fuel_flow_lph=36.0, rpm=2400.0, manifold_pressure_kpa=101.325, oat_c=15.0, altitude_m=0.0)
    per_rev = 36.0 * 1000.0 / 60.0 / 2400.0
    assert volumetric_efficiency(1.0) == pytest.approx(1.0, rel=1e-12)
    assert open_throttle == pytest.approx(math.log(per_rev / float(air_density_kg_m3(101325.0, 15.0))), rel=1e-12)
    # the same fuel into half the manifold pressure: twice the ratio over the charge, more over the residual gas
    half = _index(fuel_flow_lph=36.0, rpm=2400.0, manifold_pressure_kpa=50.6625, oat_c=15.0, altitude_m=0.0)
    assert half - open_throttle == pytest.approx(math.log(2.0) - math.log(float(volumetric_efficiency(2.0))))
    assert 0.85 < volumetric_efficiency(2.0) < 0.95
    # at altitude the exhaust pushes against less: with the manifold at the ambient pressure, again all fresh
    ambient_kpa = float(isa_pressure_pa(3000.0)) / 1000.0
    high = _index(fuel_flow_lph=36.0, rpm=2400.0, manifold_pressure_kpa=ambient_kpa, oat_c=-4.5, altitude_m=3000.0)
    rho = float(air_density_kg_m3(ambient_kpa * 1000.0, -4.5))
    assert high == pytest.approx(math.log(per_rev / rho), rel=1e-9)
    # no fuel (the engine stopped): not an index, so the effect's factor is 1
    assert math.isnan(_index(fuel_flow_lph=0.0, rpm=0.0, manifold_pressure_kpa=95.0, oat_c=15.0, altitude_m=0.0))


def test_the_heat_follows_a_power_of_the_ratio_and_the_compiled_index_agrees() -> None:
    ratio_ref = -1.0
    effect = MixtureIndex("fuel_air", gain=-1.2, reference=ratio_ref)
    on = coefficients(paper_table_a1().replace(effects=Effects(mixture_index=effect)))
    cruise = InputSeries(40.0, 2400.0, 1000.0, 50.0, 5.0)
    richer = compute_drive(cruise._replace(mixture_index=ratio_ref + math.log(1.25)), on).heat_gain
    assert richer == pytest.approx(1.25**-1.2, rel=1e-12)  # 25 % more fuel per unit of air: 24 % less heat per fuel
    stopped = compute_drive(cruise._replace(mixture_index=-math.inf), on).heat_gain
    assert stopped == compute_drive(cruise, coefficients(paper_table_a1())).heat_gain
    with pytest.raises(ParameterError, match="gain"):
        MixtureIndex("fuel_air", gain=-8.0, reference=ratio_ref)  # |gain| x the index's swing <= 3

    values = (50.0, 2300.0, 70.0, 3.0, 1500.0)
    expected = mixture_index("fuel_air", {name: np.array([v]) for name, v in zip(COLUMNS, values, strict=True)})[0]
    assert compiled(*values) == pytest.approx(expected, rel=1e-12)
    assert compiled(0.0, 0.0, 95.0, 15.0, 0.0) == -math.inf


def test_the_start_reads_the_fuel_air_ratio_where_the_manifold_pressure_is_logged() -> None:
    columns = {
        "fuel_flow_lph": np.array([40.0, 50.0, 60.0]),
        "rpm": np.array([2300.0, 2400.0, 2400.0]),
        "manifold_pressure_kpa": np.array([70.0, 80.0, 95.0]),
        "oat_c": np.array([10.0, 12.0, 15.0]),
        "altitude_m": np.array([1000.0, 500.0, 0.0]),
        "egt_c": np.array([700.0, 720.0, 690.0]),
    }
    start = MixtureIndex.start([NamedColumns(columns)])
    assert start.source == "fuel_air" and start.gain == 0.0
    assert start.reference == pytest.approx(float(np.median(mixture_index("fuel_air", columns))), rel=1e-12)
    without = {name: values for name, values in columns.items() if name != "manifold_pressure_kpa"}
    assert MixtureIndex.start([NamedColumns(without)]).source == "egt_rise"
