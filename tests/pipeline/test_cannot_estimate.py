"""Issue 31: a step whose filter cannot estimate (its CHT estimate not finite) is never NOMINAL.

model.yaml now refuses a heat map no engine has (params.MAX_STEADY_RISE_C); the model here goes round
that check on purpose, as a model the bounds let through yet the filter cannot follow would."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ecu_monitor.bus.canlog import load_flight
from ecu_monitor.config import load_config
from ecu_monitor.errors import ParameterError
from ecu_monitor.model import paper_table_a1
from ecu_monitor.offline.replay import frames_from_flight, replay_frames
from ecu_monitor.pipeline.engine import model_input_names
from ecu_monitor.pipeline.output_table import STATES

FLIGHT = Path(__file__).resolve().parents[1] / "data" / "flight_small.csv"


def test_a_heat_map_no_engine_has_is_refused() -> None:
    base = paper_table_a1()
    with pytest.raises(ParameterError, match=r"heat_map\.values_w: .* is the heat map in W"):
        base.replace(heat_map=base.heat_map.with_values(np.asarray(base.heat_map.values_w) * 1e6))


def test_no_nominal_state_without_an_estimate() -> None:
    base = paper_table_a1()
    params = base.replace()
    bad_map = base.heat_map.with_values(np.asarray(base.heat_map.values_w) * 1e6)
    object.__setattr__(params, "heat_map", bad_map)  # past the bounds: the step's own rule is tested
    config = load_config("example.yaml")
    needed = (*model_input_names(params, config.input_names), *config.cylinder_inputs)
    frames = frames_from_flight(load_flight(FLIGHT), config, needed)
    result = replay_frames(config, (params,), frames)
    est = np.asarray(result.columns["cht_est_c"])
    states = np.asarray(result.columns["state"])
    no_estimate = ~np.isfinite(est)
    assert no_estimate.any(), "the model should defeat the filter"
    assert not np.any(states[no_estimate] == STATES.index("NOMINAL"))
