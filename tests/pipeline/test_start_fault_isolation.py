"""The isolation of a fault present from engine start (pipeline/step.py, ``start_fault_call``): the open-loop
residual fitted to the model's sensitivities to gamma_Q and gamma_D over the cold start, the settle after it and
the flight, against the nominal spreads; a cause named only when the other's prediction misses by
NOMINAL_SPREAD_Z^2 more in chi-square."""

from __future__ import annotations

import math
from functools import cache
from typing import Any

import numpy as np
import pytest

from ecu_monitor.config import load_config
from ecu_monitor.estimation.regions import START_S
from ecu_monitor.offline.replay import frames_from_flight, replay_frames
from ecu_monitor.pipeline.engine import model_input_names
from ecu_monitor.pipeline.step import (
    COLD_START_LOSS_SHARE,
    CYLINDER_SETTINGS,
    CYLINDER_STATE,
    SETTLE_END_S,
    START_CALL_HEAT,
    START_CALL_LOSS,
    START_CALL_NOT_FROM_START,
    START_CALL_UNTOLD,
    _add_sums,
    start_fault_call,
)
from ecu_monitor.shipped import DEFAULT_CONFIG
from virtual_bus.missions import load_mission
from virtual_bus.plant import Degradation, fly

SPREAD = 0.015  # the nominal flights' spread of each fit, gamma - 1
DONE_S = 900.0  # s after engine start: the settle window is over
TIME_S = np.arange(0.0, DONE_S, 1.0)
TAU_S = 80.0  # the head's time constant of this synthetic warm-up, s


def _sensitivities(onset_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A warm-up from cold: the head's rise and its sensitivities to a fault from ``onset_s`` (degC per unit gamma):
    the heat's from the first second, the loss's growing with the head's rise (the dissipation is small while the
    head is near the air); both zero before the onset and settling to the same value."""
    rise = 1.0 - np.exp(-TIME_S / TAU_S)
    heat = 60.0 * rise
    loss = 60.0 * rise**2
    lag = -(100.0 / TAU_S) * np.exp(-TIME_S / TAU_S)  # minus the reference's rate, degC/s
    after = onset_s <= TIME_S
    k = np.argmax(after)
    fade = np.exp(-(TIME_S - TIME_S[k]) / TAU_S)
    return np.where(after, heat - heat[k] * fade, 0.0), np.where(after, loss - loss[k] * fade, 0.0), lag


def _state(gamma_q: float, gamma_d: float, onset_s: float = 0.0, cold_s: float | None = None) -> np.void:
    """The step's fit sums over the synthetic warm-up with these fault sizes (gamma - 1) from ``onset_s``; the cold
    start ends where the loss's sensitivity passes COLD_START_LOSS_SHARE of the heat's (or at ``cold_s``)."""
    s_q, s_d, lag = _sensitivities(0.0)
    f_q, f_d, _ = _sensitivities(onset_s)
    residual = gamma_q * f_q + gamma_d * f_d
    if cold_s is None:
        cold_s = float(TIME_S[np.argmax((s_d > COLD_START_LOSS_SHARE * s_q) & (s_q >= 1.0))])
    st = np.zeros(1, dtype=CYLINDER_STATE)[0]
    sums = st["fit_sums"]
    for t, q, d, lg, r in zip(TIME_S, s_q, s_d, lag, residual, strict=True):
        if 0.0 < t < cold_s:
            _add_sums.py_func(sums[0], q, lg, d, r)
        elif cold_s <= t < SETTLE_END_S:
            _add_sums.py_func(sums[1], d, lg, q, r)
        if t >= START_S:
            _add_sums.py_func(sums[2], q, d, lg, r)
    return st


def _settings(spread: float = SPREAD) -> np.void:
    cfg = np.zeros(1, dtype=CYLINDER_SETTINGS)[0]
    cfg["measurement_var"] = 0.17
    cfg["start_fit_mean"][:] = 0.0
    cfg["start_fit_spread"][:] = spread
    return cfg


@pytest.mark.parametrize("call", [start_fault_call, start_fault_call.py_func])
def test_each_cause_is_named_from_the_cold_start_once_the_settle_is_over(call: Any) -> None:
    cfg = _settings()
    assert call(_state(0.1, 0.0), cfg, DONE_S) == START_CALL_HEAT
    assert call(_state(0.0, 0.15), cfg, DONE_S) == START_CALL_LOSS
    assert call(_state(0.1, 0.0), cfg, SETTLE_END_S - 1.0) == START_CALL_UNTOLD  # not known before the settle's end
    assert call(_state(0.1, 0.0), _settings(math.nan), DONE_S) == START_CALL_NOT_FROM_START  # no reference


@pytest.mark.parametrize("call", [start_fault_call, start_fault_call.py_func])
def test_what_is_not_from_start_or_not_told_apart(call: Any) -> None:
    cfg = _settings()
    assert call(_state(0.0, 0.0), cfg, DONE_S) == START_CALL_NOT_FROM_START  # nominal
    assert call(_state(0.1, 0.0, onset_s=700.0), cfg, DONE_S) == START_CALL_NOT_FROM_START  # after the settle
    # a heat fault from within the settle: the cold start shows nothing, the settle only part of it: not the
    # loss's pattern from start
    assert call(_state(0.15, 0.0, onset_s=250.0), cfg, DONE_S) == START_CALL_UNTOLD
    # both causes at once fit neither alone within the spreads
    assert call(_state(0.1, 0.1), cfg, DONE_S) == START_CALL_UNTOLD
    # a fault within the nominal spreads is not taken as there from start (the filter's split holds)
    assert call(_state(0.0, 0.02), cfg, DONE_S) == START_CALL_NOT_FROM_START
    # a cold start of three seconds (a hot start): its own standard error leaves the heat's fit nothing to tell
    assert call(_state(0.1, 0.0, cold_s=4.0), cfg, DONE_S) == START_CALL_UNTOLD


@cache
def _fits(gamma: str | None) -> np.ndarray:
    """The start fits at the end of short_hop (the truth plant is the monitor's model: no unmodelled effect) with
    ``gamma`` 1.2 from engine start, replayed with the shipped config."""
    degradation = [Degradation(gamma, 1.2, 0.0)] if gamma else []
    log = fly(load_mission("short_hop"), None, degradation=degradation, seed=11, record_dt_s=1.0)
    config = load_config(DEFAULT_CONFIG)
    params = config.load_params()
    frames = frames_from_flight(log, config, (*model_input_names(params, config.input_names), "cht_c"))
    return replay_frames(config, params, frames, keep_feeds=True).start_fits[0]


def test_the_cold_start_reads_a_heat_fault_in_full_and_a_loss_fault_hardly() -> None:
    nominal, heat, loss = _fits(None), _fits("gamma_q"), _fits("gamma_d")
    assert np.all(np.abs(nominal) < 0.02)
    assert heat[0] == pytest.approx(0.2, abs=0.03) and loss[0] < 0.1  # cold_heat
    assert loss[1] == pytest.approx(0.2, abs=0.03)  # settle_loss: a loss fault there in full
    assert heat[2] == pytest.approx(0.2, abs=0.03) and loss[2] == pytest.approx(0.2, abs=0.03)  # flight_product
