"""The batch replay's open-loop reference, kept on request (``replay_frames(..., keep_reference=True)``):
the rows are unchanged, and the reference is aligned with what the detector was fed."""

from __future__ import annotations

import numpy as np

from ecu_monitor.commands.replay import DEFAULT_CONFIG
from ecu_monitor.config import load_config
from ecu_monitor.offline.replay import frames_from_flight, replay_frames
from virtual_bus.plant import fly
from virtual_bus.random_missions import random_mission


def test_reference_is_kept_on_request_and_changes_no_row() -> None:
    config = load_config(DEFAULT_CONFIG)
    params = config.load_params()
    log = fly(random_mission(7, 900.0), params, seed=7)  # the plant is the model: a small residual
    frames = frames_from_flight(log, config)
    plain = replay_frames(config, params, frames)
    kept = replay_frames(config, params, frames, keep_reference=True)
    assert plain.reference_feed == ()
    assert plain.columns.keys() == kept.columns.keys()
    for name, column in plain.columns.items():
        assert np.array_equal(column, kept.columns[name], equal_nan=True), name
    assert len(kept.reference_feed) == len(kept.detector_feed) == 1
    (time_s, symptom), reference = kept.detector_feed[0], kept.reference_feed[0]
    assert np.array_equal(reference.time_s, time_s)
    fed = np.isfinite(symptom)
    for values in (reference.cht_c, reference.model_c, reference.oat_c):
        assert np.array_equal(np.isfinite(values), fed)  # nan exactly where the detector is fed nothing
    # the reference starts from the first reading, then runs open loop on the model the plant flies
    assert reference.model_c[0] == reference.cht_c[0]
    residual = reference.cht_c - reference.model_c
    assert np.nanmax(np.abs(residual)) < 3.0  # sensor noise, quantisation and held inputs only
    assert np.nanmax(reference.model_c - reference.cht_c[0]) > 30.0  # and the head warms up: not a constant
    # the held OAT is the logged one at the last frame before each step (as the bus quantises it)
    oat = np.interp(time_s[fed], log.time_s, log["oat_c"])
    assert np.nanmax(np.abs(reference.oat_c[fed] - oat)) < 1.0
