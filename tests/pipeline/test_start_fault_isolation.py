"""The isolation of a fault present from engine start (pipeline/step.py, ``start_fault_call``): the excess
symptoms of the start region's two halves and of the airborne window after it, fitted to the heat-in and the
heat-out patterns with the nominal spreads; a cause named only when one fits better by NOMINAL_SPREAD_Z^2."""

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

# heat in and heat out over C_w (degC/s) in the start region's first half, its second half and airborne: the
# head is cold at first (the heat out a small part of the heat in), airborne they balance
HEAT = (1.0, 1.2, 1.5)
LOSS = (0.3, 0.6, 1.5)
MARGIN = 0.05  # 2 spreads of the nominal start means, degC/s
AIR_MARGIN = 0.04  # 2 spreads of the nominal airborne means, degC/s
DONE_S = 900.0  # s after engine start: the airborne window (300-600 s) is over


def _state(early: float, late: float, air: float, n: float = 150.0, heat=HEAT, loss=LOSS) -> np.void:
    """Sums of ``n`` samples per half and 2 n airborne with these mean excesses (degC/s)."""
    st = np.zeros(1, dtype=CYLINDER_STATE)[0]
    st["early_sums"][:] = (n, n * early, n * heat[0], n * loss[0], np.nan)
    st["start_sums"][:] = st["early_sums"] + np.array((n, n * late, n * heat[1], n * loss[1], np.nan))
    st["air_sums"][:] = (2 * n, 2 * n * air, 2 * n * heat[2], 2 * n * loss[2], 2 * n * AIR_MARGIN)
    return st


def _fault(pattern: tuple[float, float, float], size: float) -> tuple[float, float, float]:
    return tuple(size * p for p in pattern)


@pytest.mark.parametrize("call", [start_fault_call, start_fault_call.py_func])
def test_each_pattern_names_its_cause_once_the_airborne_window_is_over(call) -> None:
    heat_fault, loss_fault = _state(*_fault(HEAT, 0.15)), _state(*_fault(LOSS, 0.2))
    assert call(heat_fault, MARGIN, DONE_S) == START_CALL_HEAT
    assert call(loss_fault, MARGIN, DONE_S) == START_CALL_LOSS
    assert call(heat_fault, MARGIN, 450.0) == START_CALL_UNTOLD  # the airborne window still filling
    noisy = _fault(HEAT, 0.15)  # a nominal excess of a spread on top still names it
    assert call(_state(noisy[0] - 0.025, noisy[1] + 0.025, noisy[2] - 0.02), MARGIN, DONE_S) == START_CALL_HEAT
    # an onset within the start region (the gamma_Q from 120 s): the first half nearly clean, the rest the
    # heat's pattern, which the loss's pattern does not fit
    assert call(_state(0.03, 0.18, 0.225), MARGIN, DONE_S) == START_CALL_HEAT


@pytest.mark.parametrize("call", [start_fault_call, start_fault_call.py_func])
def test_within_the_spread_it_is_untold_never_a_guess(call) -> None:
    # a small heat fault: the loss's pattern fits within the spreads too
    assert call(_state(*_fault(HEAT, 0.05)), MARGIN, DONE_S) == START_CALL_UNTOLD
    # a loss fault whose first half is as faint as a later onset of a heat fault would leave it
    assert call(_state(*_fault(LOSS, 0.12)), MARGIN, DONE_S) == START_CALL_UNTOLD
    # a start excess below the start's margin, yet what a small fault there from start gives: not the filter's
    # (which leans to gamma_D on a fault from start), untold
    assert call(_state(0.02, 0.02, 0.2), MARGIN, DONE_S) == START_CALL_UNTOLD  # the loss's pattern fits that too
    small = _state(*_fault(HEAT, 0.04))
    assert call(small, MARGIN, DONE_S) == START_CALL_UNTOLD
    same = _state(0.2, 0.2, 0.2, heat=HEAT, loss=HEAT)  # the two patterns alike
    assert call(same, MARGIN, DONE_S) == START_CALL_UNTOLD
    # the same excesses with spreads ten times smaller (a reference on an exact model): told apart
    tight = _state(*_fault(HEAT, 0.05))
    tight["air_sums"][4] /= 10.0
    assert call(tight, MARGIN / 10.0, DONE_S) == START_CALL_HEAT


@pytest.mark.parametrize("call", [start_fault_call, start_fault_call.py_func])
def test_not_from_start(call) -> None:
    assert call(_state(0.0, -0.02, 0.4), MARGIN, DONE_S) == START_CALL_NOT_FROM_START  # a later onset
    assert call(_state(0.0, -0.02, 0.4), MARGIN, 450.0) == START_CALL_UNTOLD  # not known before the window ended
    assert call(_state(0.2, 0.2, 0.2), math.nan, DONE_S) == START_CALL_NOT_FROM_START  # no reference at the start
    assert call(_state(0.2, 0.2, 0.2, n=0.0), MARGIN, DONE_S) == START_CALL_NOT_FROM_START  # nothing seen yet
    assert call(_state(0.2, 0.2, 0.01), MARGIN, DONE_S) == START_CALL_NOT_FROM_START  # not there airborne
    nothing_airborne = _state(0.2, 0.2, 0.2)
    nothing_airborne["air_sums"][:] = 0.0
    assert call(nothing_airborne, MARGIN, DONE_S) == START_CALL_NOT_FROM_START
    # a start above its margin in neither pattern (a start that ran warm then an onset, or a fault from start
    # that fits neither): not the filter's (a fault was there at the start), untold
    assert call(_state(0.06, 0.06, 0.6), MARGIN, DONE_S) == START_CALL_UNTOLD
    assert call(_state(0.4, 0.4, 0.3), MARGIN, DONE_S) == START_CALL_UNTOLD
