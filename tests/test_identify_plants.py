"""Identification transfers to a plant that is not the paper's: one randomised virtual plant per run.

The plant is drawn afresh every run (ecu_monitor.research.plants: C_w x0.03-3, R_Ce x0.1-30, radiation
in kelvin or degC, another heat-map shape, other missions), identified on one flight and scored on
another. The benchmark (``benchmarks/bench_identify.py --study plants``) measures the paper's target on
ten plants; this test guards the property on a random one with a margin, and prints the seed so a
failure can be replayed with ``draw_plant(seed)``.
"""

from __future__ import annotations

import os

import pytest

from ecu_monitor.identify import PsoSettings
from ecu_monitor.research.plants import draw_plant, run_plant


@pytest.mark.slow
def test_a_random_plant_is_identified_on_one_flight_and_predicts_another():
    seed = int.from_bytes(os.urandom(4), "little") % 1_000_000
    plant = draw_plant(seed)
    outcome = run_plant(plant, duration_s=1200.0, settings=PsoSettings(particles=16, iterations=20, seed=seed))
    where = (
        f"plant seed {seed} (C_w x{plant.c_w_factor:.3f}, R_Ce x{plant.r_ce_factor:.2f},"
        f" {'K' if plant.truth.radiation_in_kelvin else 'degC'}, radiated share {plant.radiated_share:.2f}):"
        f" held-out {outcome.held_out}, true model {outcome.truth_floor}, at bounds {outcome.at_bounds}"
    )
    scale_bounds = [line for line in outcome.at_bounds if line.startswith("time_constant_s")]
    assert not scale_bounds, where
    # about as good as the true model itself on the held-out flight (whose % error alone can be large
    # when a cold day puts the CHT near 0 degC): the regression issue 10 found was 5 % and 9.7 degC
    assert outcome.held_out.mean_pct < outcome.truth_floor.mean_pct + MEAN_PCT_MARGIN, where
    assert outcome.held_out.rms_c < outcome.truth_floor.rms_c + RMS_MARGIN_C, where


#: Margins over the true model's own held-out error (the benchmark measures the paper's 1 % / 5 %).
MEAN_PCT_MARGIN = 1.5
RMS_MARGIN_C = 2.0
