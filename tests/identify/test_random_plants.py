"""Randomised virtual plants (issue 10): identification on one flight of a plant far from the paper's
Table A1 transfers to another flight of it. The plant is the benchmark's first draw: the campaign over
ten draws is ``benchmarks/bench_identify.py --study plants`` (a measure of quality, not a test). The
thresholds are the paper's 1 % mean and 5 % peak, on the scale that is defined for a cold start too: the
flight's mean rise above OAT (:mod:`ecu_monitor.research.plants`)."""

from __future__ import annotations

import pytest

from ecu_monitor.research.plants import draw_plant, run_plant


@pytest.mark.slow
def test_identification_transfers_to_a_held_out_flight_of_a_random_plant() -> None:
    outcome = run_plant(draw_plant(0))
    held_out, floor = outcome.held_out, outcome.truth_floor
    assert held_out.mean_rise_pct < 1.0, outcome.plant
    assert held_out.peak_rise_pct < 5.0, outcome.plant
    # no worse than the true model itself driven by the same logged inputs, beyond noise
    assert held_out.rms_c < 1.5 * floor.rms_c + 0.2, (held_out, floor)
    assert outcome.passed_rise
