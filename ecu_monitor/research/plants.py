"""Randomised virtual plants: does identification transfer to engines that are not the paper's?

Each plant is drawn from a seed across wide ranges around the paper's Table A1: C_w x0.03-3 and
R_Ce x0.1-30 (log-uniform, independently; a pair whose time constant C_w R_Ce is below
:data:`MIN_TIME_CONSTANT_S` is drawn again), radiation in kelvin or in the paper's degC with its
share of the dissipated heat drawn in 0-50 % at a typical operating point, heat-path delay tau_w
2-20 s, and a heat map of another shape (load and speed exponents and closed-throttle residual drawn,
scaled to a cruise temperature rise of 90-170 degC at 50 % throttle and 6000 rpm, as engines run)
tabulated on a finer 9 x 9 grid than the 5 x 5 map identification fits. The plant flies one random
mission (train) and another (held out) through the virtual ECU (noise, 1 degC quantiser);
identification sees only the train flight, from the paper's Table A1 as the start (the radiation
form, degC or kelvin, chosen by ``--effects auto`` on the flight's two halves), and is scored on the
held-out one. The paper's own criterion: mean error < 1 %, peak < 5 % of the measured CHT, sample by
sample. Near 0 degC that criterion is not defined (a cold start at a few degC makes 1-2 degC of
quantisation and noise tens of percent; the true model itself misses it there), so each outcome also
reports the errors in percent of the flight's mean temperature rise above OAT (one scale per flight:
:class:`ecu_monitor.identify.ErrorStats`) and :attr:`PlantOutcome.passed_rise` applies the same
thresholds to those.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ecu_monitor.identify import ErrorStats, PsoSettings, flight_errors
from ecu_monitor.identify.select import identify_flights
from ecu_monitor.model import HeatMap, ThermalParams, paper_table_a1

__all__ = ["MIN_TIME_CONSTANT_S", "PlantOutcome", "RandomPlant", "draw_plant", "run_plant"]

#: Shortest convective time constant C_w R_Ce of a drawn plant, s. A 1 Hz log cannot resolve a head
#: that settles within seconds: even the true model, driven by the logged 1 Hz inputs, misses such a
#: plant by tens of percent at every throttle change (measured: 37 % at 1.4 s). Real heads take minutes.
MIN_TIME_CONSTANT_S = 20.0
_THROTTLE = tuple(float(v) for v in np.linspace(0.0, 100.0, 9))
_RPM = tuple(float(v) for v in np.linspace(2000.0, 9000.0, 9))


@dataclass(frozen=True)
class RandomPlant:
    """A drawn plant: its truth model, the missions' seeds and what was drawn (for the report)."""

    seed: int
    truth: ThermalParams
    train_mission_seed: int
    test_mission_seed: int
    c_w_factor: float
    r_ce_factor: float
    radiated_share: float


def draw_plant(seed: int) -> RandomPlant:
    """The plant of ``seed`` (deterministic; module doc for the ranges)."""
    rng = np.random.default_rng([seed, 0x9A17])
    paper = paper_table_a1()
    while True:  # redraw heads that settle within seconds (module doc)
        c_w_factor = float(np.exp(rng.uniform(math.log(0.03), math.log(3.0))))
        r_ce_factor = float(np.exp(rng.uniform(math.log(0.1), math.log(30.0))))
        if paper.c_w * c_w_factor * paper.r_ce * r_ce_factor >= MIN_TIME_CONSTANT_S:
            break
    r_ce = paper.r_ce * r_ce_factor
    kelvin = bool(rng.random() < 0.5)
    cruise_rise = float(rng.uniform(90.0, 170.0))  # convective-only rise at the cruise point, degC
    load_exponent = float(rng.uniform(0.5, 1.8))
    speed_exponent = float(rng.uniform(0.2, 1.2))
    residual = float(rng.uniform(0.05, 0.3))

    def shape(th: float, n: float) -> float:
        return (residual + (1.0 - residual) * (th / 100.0) ** load_exponent) * (n / 9000.0) ** speed_exponent

    values = [[cruise_rise / r_ce * shape(th, n) / shape(50.0, 6000.0) for n in _RPM] for th in _THROTTLE]
    heat_map = HeatMap("throttle_pct", "rpm", _THROTTLE, _RPM, tuple(tuple(row) for row in values))
    share = float(rng.uniform(0.0, 0.5))  # radiated share of the heat at 15 degC OAT, 100 degC rise
    offset = 273.15 if kelvin else 0.0
    t4 = (115.0 + offset) ** 4 - (15.0 + offset) ** 4
    alpha = math.inf if share <= 1e-6 else t4 * r_ce * (1.0 - share) / (share * 100.0)
    truth = paper.replace(
        c_w=paper.c_w * c_w_factor,
        r_ce=r_ce,
        alpha_r_e=alpha,
        radiation_in_kelvin=kelvin,
        tau_w=float(np.exp(rng.uniform(math.log(2.0), math.log(20.0)))),
        heat_map=heat_map,
        cht_limit_c=400.0,
    )
    return RandomPlant(
        seed=seed,
        truth=truth,
        train_mission_seed=int(rng.integers(1, 10**6)),
        test_mission_seed=int(rng.integers(1, 10**6)),
        c_w_factor=c_w_factor,
        r_ce_factor=r_ce_factor,
        radiated_share=share,
    )


@dataclass(frozen=True)
class PlantOutcome:
    """Identification of one plant: train and held-out errors, the bounds hit, the time taken."""

    plant: RandomPlant
    train: ErrorStats
    held_out: ErrorStats
    at_bounds: tuple[str, ...]
    elapsed_s: float
    truth_floor: ErrorStats  # the true model on the held-out flight (1 Hz inputs, quantised CHT)
    radiation_kelvin: bool  # the radiation form identification chose

    @property
    def passed(self) -> bool:
        """The paper's criterion on the held-out flight: mean < 1 %, peak < 5 %."""
        return self.held_out.mean_pct < 1.0 and self.held_out.peak_pct < 5.0

    @property
    def passed_rise(self) -> bool:
        """The same thresholds against the flight's mean rise above OAT: mean < 1 %, peak < 5 %."""
        return self.held_out.mean_rise_pct < 1.0 and self.held_out.peak_rise_pct < 5.0


def run_plant(plant: RandomPlant, duration_s: float = 3600.0, settings: PsoSettings | None = None) -> PlantOutcome:
    """Fly the plant's two missions, identify on the first from Table A1, score on the second."""
    from virtual_bus.plant import fly
    from virtual_bus.random_missions import random_mission

    train = fly(random_mission(plant.train_mission_seed, duration_s), plant.truth, seed=plant.seed, record_dt_s=1.0)
    test = fly(random_mission(plant.test_mission_seed, duration_s), plant.truth, seed=plant.seed + 1, record_dt_s=1.0)
    result, _cv, _selection = identify_flights(
        [train],
        base=paper_table_a1(),
        heat_axes=("throttle_pct", "rpm"),
        grid=None,
        settings=settings or PsoSettings(seed=plant.seed),
        terms="auto",
        candidates=("radiation_kelvin",),
    )
    return PlantOutcome(
        plant=plant,
        train=result.train_errors[0],
        held_out=flight_errors(result.params, test),
        at_bounds=result.at_bounds,
        elapsed_s=result.elapsed_s,
        truth_floor=flight_errors(plant.truth, test),
        radiation_kelvin=result.params.radiation_in_kelvin,
    )
