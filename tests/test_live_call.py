"""service/live_call.py: the one compiled call per filter period (reference, supervision, estimator,
isolation filter) gives the pipeline's health rows and frames bit for bit as the three separate filter
calls and the Python supervision do, through every supervisor branch."""

from __future__ import annotations

from typing import Any

import pytest
from test_pipeline import SteadyEcu, _config, _run

from ecu_monitor.model import paper_table_a1
from ecu_monitor.service import live_call
from ecu_monitor.service.pipeline import Pipeline


def _scenario(
    estimator: dict[str, Any], fused: bool, monkeypatch: pytest.MonkeyPatch, rehearse: bool = False
) -> tuple[str, list[Any], int]:
    """A steady engine, a stuck probe, stale air data (predicting, then UNAVAILABLE), recovery, an open probe,
    a clock restart: (repr of every health row, the health frames, filter periods run by LiveCall).
    ``rehearse``: ``Pipeline.rehearse`` before every frame (the daemon does it before some)."""
    calls = [0]
    original_call = live_call.LiveCall.call
    original_advance = Pipeline.advance_to

    def counted(self: live_call.LiveCall, *args: Any) -> Any:
        calls[0] += 1
        return original_call(self, *args)

    def rehearsed(self: Pipeline, t_s: float) -> Any:
        self.rehearse()
        return original_advance(self, t_s)

    with monkeypatch.context() as patch:
        patch.setattr(live_call.LiveCall, "call", counted)
        if not fused:
            patch.setattr(live_call.LiveCall, "of", staticmethod(lambda *args: None))
        if rehearse:
            patch.setattr(Pipeline, "advance_to", rehearsed)
        config = _config(estimator=estimator, stale_predict_limit_s=5.0, sensor_fault__stuck_after_s=10.0,
                         detector={"symptom": "estimator", "warmup_s": 5.0, "block_s": 2.0})  # fmt: skip
        pipeline = Pipeline(config, paper_table_a1())
        ecu = SteadyEcu()
        frames = _run(pipeline, ecu.frames(15.0))
        ecu.values.update(throttle_pct=100.0, rpm=8000.0)  # the model heats up, the reading stays: stuck
        frames += _run(pipeline, ecu.frames(40.0))
        ecu.values["cht_c"] += 7.0  # moving again; the detector sees a deviation
        frames += _run(pipeline, ecu.frames(45.0))
        frames += _run(pipeline, ecu.frames(53.0, silent=("AirData",)))  # stale, then UNAVAILABLE after 5 s
        frames += _run(pipeline, ecu.frames(60.0))  # recovered: initialised again
        ecu.values.update(status=3, cht_c=-40.0)  # probe open
        frames += _run(pipeline, ecu.frames(63.0))
        ecu.values.update(status=0, cht_c=ecu.values["cht_c"] if ecu.values["cht_c"] > 0 else 250.0)
        frames += _run(pipeline, ecu.frames(66.0))
        ecu.next_t = {name: t + 700.0 for name, t in ecu.next_t.items()}  # a jump that restarts the clock
        frames += _run(pipeline, ecu.frames(775.0))
    rows = pipeline.drain_rows()
    assert {r.state for r in rows} >= {"NOMINAL", "SENSOR_FAULT", "INPUT_STALE", "UNAVAILABLE"}
    assert pipeline.counters["clock_restarts"] == 1
    return repr(rows), [(f.arbitration_id, bytes(f.data)) for f in frames], calls[0]


@pytest.mark.parametrize(
    "estimator",
    [
        {"name": "cbekf-au", "dt_s": 0.02},
        {"name": "cbekf-au", "dt_s": 0.02, "reset": "midpoint"},
        {"name": "cbekf", "dt_s": 0.02},
        {"name": "ekf", "dt_s": 0.02},
        {"name": "cbekf-iso", "dt_s": 0.02},  # the isolation filter as estimator: run once for both
    ],
)
def test_one_compiled_call_equals_the_separate_calls_bit_for_bit(
    estimator: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    rows, frames, calls = _scenario(estimator, True, monkeypatch)
    rows_apart, frames_apart, calls_apart = _scenario(estimator, False, monkeypatch)
    assert calls > 500 and calls_apart == 0
    assert len(frames) > 800 and frames == frames_apart
    assert rows == rows_apart  # repr: the shortest round-trip form of every float, so equal means bit-equal


def test_a_rehearsal_before_every_frame_changes_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    """Pipeline.rehearse (the daemon's, shortly before the frame of a Health_Status step) has no effect on
    the rows or the frames, through every supervisor branch, and runs the compiled call on its copy."""
    estimator = {"name": "cbekf-au", "dt_s": 0.02}
    rehearsals = [0]
    original = live_call.LiveCall.rehearse

    def counted(self: live_call.LiveCall, *args: Any) -> None:
        rehearsals[0] += 1
        original(self, *args)

    monkeypatch.setattr(live_call.LiveCall, "rehearse", counted)
    rows, frames, calls = _scenario(estimator, True, monkeypatch, rehearse=True)
    assert rehearsals[0] > 5 * calls > 2500
    assert (rows, frames) == _scenario(estimator, True, monkeypatch)[:2]


def test_an_isolation_filter_unlike_the_pipelines_is_not_folded() -> None:
    """cbekf-iso is run once for estimator and isolation filter only when the two are the same filter."""
    from ecu_monitor.estimation import EstimatorSettings, make_estimator
    from ecu_monitor.estimation.isolation import IsolationFilter, IsolationSettings
    from ecu_monitor.model import InputSeries, coefficients

    params = paper_table_a1()
    u = InputSeries(50.0, 6000.0, 1000.0, 40.0, 15.0)
    reference = make_estimator("ekf", params, EstimatorSettings(dt_s=0.02))
    same = IsolationFilter(params, IsolationSettings(dt_s=0.02))
    other = IsolationFilter(params, IsolationSettings(dt_s=0.02, gamma_max=2.0))
    later = IsolationFilter(params, IsolationSettings(dt_s=0.02))
    isolation = IsolationFilter(params, IsolationSettings(dt_s=0.02))
    for filt in (reference, same, other, later, isolation):
        filt.initialise(0.0, u, 150.0)
    later.estimate(0.1, u, 151.0)
    args = (coefficients(params), 0.0, 5.0, 10.0, 0.5)
    assert live_call.LiveCall.of(reference, same, isolation, *args) is not None
    assert live_call.LiveCall.of(reference, other, isolation, *args) is None
    assert live_call.LiveCall.of(reference, later, isolation, *args) is None
