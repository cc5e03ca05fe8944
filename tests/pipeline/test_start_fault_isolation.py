"""The isolation of a fault present from engine start (pipeline/step.py, ``start_fault_call``): the ratio of the
start's excess symptom to the airborne one, against the ratios the heat in and the heat out would give."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ecu_monitor.pipeline.step import (
    CYLINDER_STATE,
    START_CALL_HEAT,
    START_CALL_LOSS,
    START_CALL_NOT_FROM_START,
    START_CALL_UNTOLD,
    start_fault_call,
)

# heat in and heat out over C_w (degC/s): at the start the head is cold, the heat out is half the heat in;
# airborne they balance
START_HEAT, START_LOSS = 1.0, 0.5
AIR_HEAT, AIR_LOSS = 1.5, 1.5
MARGIN = 0.05  # 2 spreads of the nominal start means, degC/s


def _state(start_excess: float, air_excess: float, n: float = 300.0, air_margin: float = 0.04) -> np.void:
    st = np.zeros(1, dtype=CYLINDER_STATE)[0]
    st["start_sums"][:] = (n, n * start_excess, n * START_HEAT, n * START_LOSS, np.nan)
    st["air_sums"][:] = (n, n * air_excess, n * AIR_HEAT, n * AIR_LOSS, n * air_margin)
    # the start's first half: the same excess per heat or loss as the whole start (a fault there throughout)
    st["early_sums"][:] = 0.5 * st["start_sums"]
    return st


@pytest.mark.parametrize("call", [start_fault_call, start_fault_call.py_func])
def test_the_heat_pattern_names_gamma_q_and_the_loss_pattern_gamma_d(call) -> None:
    a, b = 0.15, 0.12  # gamma_Q - 1; 1 - 1/gamma_D
    assert call(_state(a * START_HEAT, a * AIR_HEAT), MARGIN) == START_CALL_HEAT
    assert call(_state(b * START_LOSS, b * AIR_LOSS), MARGIN) == START_CALL_LOSS
    faint_early = _state(a * START_HEAT, a * AIR_HEAT)  # the first half's excess less than half the heat's pattern
    faint_early["early_sums"][1] *= 0.4
    faint_early["start_sums"][1] -= 0.6 * 0.5 * faint_early["start_sums"][1]
    assert call(faint_early, MARGIN) == START_CALL_NOT_FROM_START  # the filter decides
    noise = 0.01  # a nominal excess on top of either still names it
    assert call(_state(a * START_HEAT - noise, a * AIR_HEAT + noise), MARGIN) == START_CALL_HEAT
    assert call(_state(b * START_LOSS + noise, b * AIR_LOSS - noise), MARGIN) == START_CALL_LOSS


@pytest.mark.parametrize("call", [start_fault_call, start_fault_call.py_func])
def test_not_from_start_untold_and_unknown(call) -> None:
    assert call(_state(0.02, 0.2), MARGIN) == START_CALL_NOT_FROM_START  # a mid-flight onset: the filter's split
    # a start that ran warm (above the margin), then an onset: far less than either pattern predicts
    assert call(_state(0.06, 0.4), MARGIN) == START_CALL_NOT_FROM_START
    assert call(_state(0.2, 0.2), math.nan) == START_CALL_NOT_FROM_START  # no reference at the start
    assert call(_state(0.2, 0.2, n=0.0), MARGIN) == START_CALL_NOT_FROM_START  # nothing seen yet
    late_onset = _state(0.15, 0.2)  # an onset within the start region: its first half holds no excess
    late_onset["early_sums"][1] = 0.0
    late_onset["start_sums"][1] *= 0.5
    assert call(late_onset, MARGIN) == START_CALL_NOT_FROM_START
    assert call(_state(0.2, -0.01), MARGIN) == START_CALL_NOT_FROM_START  # no airborne excess after the start
    assert call(_state(0.2, 0.05), MARGIN) == START_CALL_NOT_FROM_START  # 4x the airborne: neither pattern
    # both excesses within the nominal spreads (a reference with tiny spreads, noise in either pattern)
    assert call(_state(0.03, 0.045, air_margin=0.05), MARGIN) == START_CALL_NOT_FROM_START
    same = _state(0.2, 0.2)
    same["start_sums"][3] = same["start_sums"][2]  # heat out as large as heat in at the start too
    same["air_sums"][3] = same["air_sums"][2]
    assert call(same, MARGIN) == START_CALL_UNTOLD
