"""offline/replay.py and ``ecu-monitor replay``: the batch path equals the live pipeline; the virtual
ECU's .blf log and its canonical CSV give the same health.csv; bad input exits 2 with one line."""

from __future__ import annotations

import csv
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from ecu_monitor.bus.canlog import FrameArrays, read_frames
from ecu_monitor.cli import main
from ecu_monitor.config import load_config
from ecu_monitor.model import paper_table_a1
from ecu_monitor.offline.replay import replay_file, replay_frames, replay_live
from tests.helpers import REPO, climb_and_cruise

NUMERIC = ("cht_meas_c", "cht_est_c", "deviation", "gamma_q", "gamma_d", "headroom_s")

SHORT_MISSION = climb_and_cruise(
    "short", ground_s=40, climb_to_m=450, climb_throttle_pct=90, cruise_s=120, cruise_mps=23, cruise_throttle_pct=55
)


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A ~5 min virtual-ECU flight with gamma_Q = 1.2 from 150 s, recorded at once as .blf, .asc and CSV,
    and a config whose detector warms up for 60 s (the default 300 s is longer than the flight)."""
    from virtual_bus.missions import mission_from_dict
    from virtual_bus.plant import Degradation
    from virtual_bus.recorder import record

    root = tmp_path_factory.mktemp("flight")
    paths = {suffix: root / f"flight.{suffix}" for suffix in ("blf", "asc", "csv")}
    record(mission_from_dict(SHORT_MISSION), list(paths.values()), paper_table_a1(),
           degradation=[Degradation.parse("gamma_q=1.2@150")], seed=11)  # fmt: skip
    data = yaml.safe_load((REPO / "ecu_monitor" / "data" / "configs" / "example.yaml").read_text(encoding="utf-8"))
    data["dbc"] = [str(REPO / "ecu_monitor" / "data" / "dbc" / "engine.dbc")]
    data["health_dbc"] = str(REPO / "ecu_monitor" / "data" / "dbc" / "health.dbc")
    data["detector"] = {"symptom": "estimator", "warmup_s": 60.0}
    paths["config"] = root / "service.yaml"
    paths["config"].write_text(yaml.safe_dump(data), encoding="utf-8")
    return paths


def _columns(rows: list[Any]) -> dict[str, np.ndarray]:
    return {name: np.array([getattr(r, name) for r in rows], dtype=float) for name in ("time_s", *NUMERIC)}


def test_batch_replay_equals_the_live_pipeline_frame_by_frame(flight: dict[str, Path]) -> None:
    config = load_config(flight["config"])
    params = config.load_params()
    frames = read_frames(flight["blf"])
    # a little garbage on top: frames of unknown ids, a bad checksum, a wrong DLC
    garbage = FrameArrays(
        time_s=np.array([10.001, 20.001, 30.001]),
        arbitration_id=np.array([0x7E0, 0x100, 0x101]),
        is_extended=np.zeros(3, dtype=bool),
        dlc=np.array([8, 8, 5]),
        data=np.full((3, 8), 0x55, dtype=np.uint8),
        ignored=np.zeros(3, dtype=bool),
    )
    parts: list[Any] = [np.concatenate([a, b]) for a, b in zip(frames, garbage, strict=True)]
    order = np.argsort(parts[0], kind="stable")
    merged = FrameArrays(*[a[order] for a in parts])
    batch = replay_frames(config, params, merged)
    live = replay_live(config, params, merged.messages())
    assert len(batch.rows) == len(live.rows) > 2500
    for key in ("frames", "ok", "unknown_id", "malformed", "bad_checksum", "bad_dlc", "steps"):
        assert batch.counters[key] == live.counters[key], key
    assert batch.counters["unknown_id"] == 1 and batch.counters["malformed"] == 2
    b, v = _columns(batch.rows), _columns(live.rows)
    assert np.array_equal(b["time_s"], v["time_s"])
    for name in NUMERIC:
        assert np.array_equal(np.isnan(b[name]), np.isnan(v[name])), name
        assert np.nanmax(np.abs(b[name] - v[name]), initial=0.0) < 1e-9, name  # compiled vs Python floats
    assert [r.state for r in batch.rows] == [r.state for r in live.rows]
    assert [r.stale_inputs for r in batch.rows] == [r.stale_inputs for r in live.rows]
    states = [r.state for r in batch.rows]
    assert "DEGRADED" in states and all(r.state == "NOMINAL" for r in batch.rows if r.time_s < 150.0)


def test_batch_equals_live_with_the_baseline_frozen_while_suspected(flight: dict[str, Path]) -> None:
    """The detector with ``baseline_freeze`` (what calibrate may choose): the batch replay's states equal
    the live pipeline's. With h = 48: the learning baseline (120 s, delay 60 s) absorbs the gamma_Q = 1.2
    step before its statistic gets there (it levels off near 40, ~180 s after the onset, as the step is
    learned), the frozen one keeps the whole step in the test to the end of the flight (near 58). The
    self-normalised detector (``scale_s``) too."""
    import dataclasses

    config = load_config(flight["config"])
    params = config.load_params()
    frames = read_frames(flight["blf"])
    states = {}
    # the self-normalised detector (scale_s on, floor under the symptom's spread so the weighing acts) too
    for freeze, scale_s in ((False, 0.0), (True, 0.0), (True, 600.0)):
        settings = dataclasses.replace(
            config.detector, threshold=48.0, baseline_freeze=freeze, scale_s=scale_s, scale_floor=0.001 * bool(scale_s)
        )
        frozen = dataclasses.replace(config, detector=settings)
        batch = replay_frames(frozen, params, frames)
        live = replay_live(frozen, params, frames.messages())
        states[freeze, scale_s] = [r.state for r in batch.rows]
        assert states[freeze, scale_s] == [r.state for r in live.rows]
    assert "DEGRADED" not in states[False, 0.0] and "DEGRADED" in states[True, 0.0]


def _read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as handle:
        return list(csv.DictReader(handle))


def _num(rows: list[dict[str, str]], name: str) -> np.ndarray:
    return np.array([float(r[name]) if r[name] else math.nan for r in rows])


def test_blf_and_its_canonical_csv_give_the_same_health_csv(flight: dict[str, Path], tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    outputs = {}
    for kind in ("blf", "csv", "asc"):
        out = tmp_path / f"health-{kind}.csv"
        assert main(["replay", str(flight[kind]), "--config", str(flight["config"]), "--out", str(out)]) == 0
        summary = capsys.readouterr().out.strip().splitlines()
        assert "rows" in summary[0] and "DEGRADED from" in summary[0]
        assert all(line.startswith("warning: ") for line in summary[1:])  # settings that do not fit the engine
        outputs[kind] = _read_csv(out)
    blf, flight_csv, asc = outputs["blf"], outputs["csv"], outputs["asc"]
    assert list(blf[0]) == ["time_s", "cht_meas_c", "cht_est_c", "deviation", "state", "gamma_q", "gamma_d",
                            "headroom_s", "stale_inputs", "sensor_fault", "cht_rate_c_per_min", "gamma_q_sd",
                            "gamma_d_sd", "not_isolable", "detector_armed"]  # fmt: skip
    assert asc == blf  # two log formats of the same frames: identical
    assert len(flight_csv) == len(blf)
    assert np.array_equal(_num(flight_csv, "time_s"), _num(blf, "time_s"))
    # the CSV holds the same CHT readings (10 Hz) but the fast inputs only every 100 ms (the .blf: 50 Hz)
    assert np.array_equal(_num(flight_csv, "cht_meas_c"), _num(blf, "cht_meas_c"))
    est = np.abs(_num(flight_csv, "cht_est_c") - _num(blf, "cht_est_c"))
    assert np.nanmax(est) < 0.5 and np.nanmean(est) < 0.02
    for name, tol in (("gamma_q", 0.01), ("gamma_d", 0.01), ("deviation", 0.02)):
        assert np.nanmax(np.abs(_num(flight_csv, name) - _num(blf, name))) < tol, name
    same = np.mean([a["state"] == b["state"] for a, b in zip(flight_csv, blf, strict=True)])
    assert same > 0.995

    def alarm(rows: list[dict[str, str]]) -> float:
        return next(float(r["time_s"]) for r in rows if r["state"] == "DEGRADED")

    assert abs(alarm(flight_csv) - alarm(blf)) <= 1.0 and 150.0 < alarm(blf) < 210.0


def test_replay_in_blocks_of_a_few_rows_gives_the_same_table_and_health_csv(
    flight: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The loop hands its rows over a block at a time and writes the next block over the last: with blocks
    of 7 rows (hundreds of hand-overs), the table and health.csv are those of one block for the whole flight."""
    from ecu_monitor.pipeline import engine

    config = load_config(flight["config"])
    params = config.load_params()
    frames = read_frames(flight["blf"])
    whole = replay_frames(config, params, frames, out=tmp_path / "whole.csv")
    monkeypatch.setattr(engine, "ROW_BLOCK", 7)
    small = replay_frames(config, params, frames, out=tmp_path / "small.csv")
    assert len(whole.rows) > 2500 and len(whole.rows) % 7 != 0
    assert whole.columns.keys() == small.columns.keys()
    for name, column in whole.columns.items():
        assert np.array_equal(column, small.columns[name], equal_nan=column.dtype.kind == "f"), name
    assert (tmp_path / "whole.csv").read_bytes() == (tmp_path / "small.csv").read_bytes()


def test_replay_of_a_csv_runs_the_same_path(flight: dict[str, Path]) -> None:
    config = load_config(flight["config"])
    result = replay_file(flight["csv"], config, config.load_params())
    assert result.counters["malformed"] == 0 and result.counters["ok"] == result.counters["frames"]
    assert {r.state for r in result.rows[:100]} == {"NOMINAL"}


def test_replay_bad_config_exits_2_with_one_line(flight: dict[str, Path], tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    bad = tmp_path / "bad.yaml"
    bad.write_text(flight["config"].read_text(encoding="utf-8").replace("unit: rpm", "unit: rps"), encoding="utf-8")
    code = main(["replay", str(flight["csv"]), "--config", str(bad), "--out", str(tmp_path / "h.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "bad.yaml" in err[0] and "inputs.rpm.unit" in err[0]
    missing = tmp_path / "absent.blf"
    assert main(["replay", str(missing), "--config", str(flight["config"]), "--out", str(tmp_path / "h.csv")]) == 2
    assert "absent.blf" in capsys.readouterr().err
    code = main(["replay", str(flight["csv"]), "--estimator", "nope", "--out", str(tmp_path / "h.csv")])
    assert code == 2 and "known: " in capsys.readouterr().err


def test_fast_blf_reader_equals_python_can(flight: dict[str, Path], tmp_path: Path) -> None:
    from ecu_monitor.bus.canlog import read_blf_arrays

    fast = read_blf_arrays(flight["blf"])
    assert fast is not None
    import can

    with can.LogReader(str(flight["blf"])) as reader:
        messages = list(reader)
    assert len(fast) == len(messages) > 10000
    assert np.allclose(fast.time_s, [m.timestamp for m in messages], rtol=0, atol=1e-6)
    assert fast.arbitration_id.tolist() == [m.arbitration_id for m in messages]
    assert [bytes(row[:n]) for row, n in zip(fast.data, fast.dlc, strict=True)] == [bytes(m.data) for m in messages]
    # a log with an error frame is not all classic frames: python-can's reader takes over
    mixed = tmp_path / "mixed.blf"
    with can.Logger(str(mixed)) as writer:
        writer.on_message_received(can.Message(timestamp=1.0, arbitration_id=0x100, data=bytes(8)))
        writer.on_message_received(can.Message(timestamp=1.1, is_error_frame=True))
    assert read_blf_arrays(mixed) is None
    frames = read_frames(mixed)
    assert len(frames) == 2 and frames.ignored.tolist() == [False, True]


def test_batch_equals_live_across_a_hole_that_restarts_the_clock(flight: dict[str, Path]) -> None:
    """Two stretches of a recorded flight with a 700 s hole between them (longer than MAX_CLOCK_GAP_S):
    both paths restart the clock there, run no step inside the hole and give the same rows."""
    config = load_config(flight["config"])
    params = config.load_params()
    frames = read_frames(flight["blf"])
    t = frames.time_s - frames.time_s[0]
    first, second = frames.take(t < 40.0), frames.take((t >= 150.0) & (t < 190.0))
    moved = FrameArrays(second.time_s + 700.0, *second[1:])
    both = FrameArrays(*[np.concatenate([a, b]) for a, b in zip(first, moved, strict=True)])
    batch = replay_frames(config, params, both)
    live = replay_live(config, params, both.messages())
    assert batch.counters["clock_restarts"] == live.counters["clock_restarts"] == 1
    assert len(batch.gaps) == 1 and 800.0 < batch.gaps[0][1] - batch.gaps[0][0] < 820.0
    b, v = _columns(batch.rows), _columns(live.rows)
    assert np.array_equal(b["time_s"], v["time_s"])
    hole = (b["time_s"] > frames.time_s[0] + 41.0) & (b["time_s"] < frames.time_s[0] + 849.0)
    assert not hole.any()
    for name in NUMERIC:
        assert np.array_equal(np.isnan(b[name]), np.isnan(v[name])), name
        assert np.nanmax(np.abs(b[name] - v[name]), initial=0.0) < 1e-9, name
    assert [r.state for r in batch.rows] == [r.state for r in live.rows]


def test_batch_equals_live_with_a_mixture_index_after_a_restart(flight: dict[str, Path]) -> None:
    """A model with the mixture index (fuel per revolution, from the fuel flow and rpm the config maps)
    over a flight whose second stretch starts after a restart: the batch path cuts each stretch's inputs
    once and gives the live pipeline's rows, and the index is fed (the estimate differs from the same
    model's without the effect)."""
    from ecu_monitor.model import MixtureIndex

    config = load_config(flight["config"])
    base = config.load_params()
    params = replace(base, effects=base.effects.replace("mixture_index", MixtureIndex("fuel_per_rev", 0.5, 0.3)))
    frames = read_frames(flight["blf"])
    t = frames.time_s - frames.time_s[0]
    first, second = frames.take(t < 40.0), frames.take((t >= 150.0) & (t < 190.0))
    moved = FrameArrays(second.time_s + 700.0, *second[1:])
    both = FrameArrays(*[np.concatenate([a, b]) for a, b in zip(first, moved, strict=True)])
    batch = replay_frames(config, params, both)
    live = replay_live(config, params, both.messages())
    b, v = _columns(batch.rows), _columns(live.rows)
    without = _columns(replay_frames(config, base, both).rows)
    assert np.nanmax(np.abs(b["cht_est_c"] - without["cht_est_c"])) > 0.01
    assert np.array_equal(b["time_s"], v["time_s"])
    for name in NUMERIC:
        assert np.array_equal(np.isnan(b[name]), np.isnan(v[name])), name
        assert np.nanmax(np.abs(b[name] - v[name]), initial=0.0) < 1e-9, name


def test_csv_values_outside_a_dbc_signal_range_are_sent_clamped_with_one_warning(
    flight: dict[str, Path], caplog: pytest.LogCaptureFixture
) -> None:
    """engine.dbc's FuelFlow covers the engines users fly (a Lycoming at full power burns ~57 L/h, a big
    Continental ~150): no warning. A value past its range (500 L/h: a cc/min column given as L/h, say) is
    sent clamped, as that ECU would send it, and the replay says so once, naming the column."""
    from ecu_monitor.flightlog import load_csv
    from ecu_monitor.offline.replay import frames_from_flight

    log = load_csv(flight["csv"])
    fuel = np.asarray(log["fuel_flow_lph"], dtype=float)
    config = load_config(REPO / "ecu_monitor" / "data" / "configs" / "example.yaml")
    with caplog.at_level("WARNING", logger="ecu_monitor.offline.flight_frames"):
        frames_from_flight(log, config)
    assert not caplog.records  # the virtual ECU's own flight stays inside its DBC
    lycoming = log.with_columns(fuel_flow_lph=np.where(np.arange(fuel.size) % 10 == 0, 150.0, 57.5))
    with caplog.at_level("WARNING", logger="ecu_monitor.offline.flight_frames"):
        frames = frames_from_flight(lycoming, config)
    assert not caplog.records
    fast = frames.arbitration_id == 0x100  # ECU_Fast: FuelFlow at bit 32, 0.01 L/h
    raw = frames.data[fast][:, 4].astype(int) | (frames.data[fast][:, 5].astype(int) << 8)
    assert raw.max() * 0.01 == pytest.approx(150.0)
    hot = log.with_columns(fuel_flow_lph=np.where(np.arange(fuel.size) % 10 == 0, 575.0, fuel))
    with caplog.at_level("WARNING", logger="ecu_monitor.offline.flight_frames"):
        frames = frames_from_flight(hot, config)
    [record] = caplog.records
    text = record.getMessage()
    assert "fuel_flow_lph" in text and "ECU_Fast.FuelFlow" in text and "[0, 500]" in text and "575" in text
    assert f"in {(fuel.size + 9) // 10} of {fuel.size} rows" in text
    caplog.clear()
    with caplog.at_level("WARNING", logger="ecu_monitor.offline.flight_frames"):
        frames_from_flight(hot, config)  # calibrate replays a flight many times: told once
    assert not caplog.records
    fast = frames.arbitration_id == 0x100  # 500 L/h the largest sent
    raw = frames.data[fast][:, 4].astype(int) | (frames.data[fast][:, 5].astype(int) << 8)
    assert raw.max() * 0.01 == pytest.approx(500.0)


def test_replay_of_a_log_without_throttle_on_a_throttle_model_says_which_model_it_needs(
    flight: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """A G1000 log (fuel flow, no throttle) replayed on the default model (paper heat map on throttle): one
    line naming the column and the way out, exit 2."""
    with flight["csv"].open(newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    path = tmp_path / "no_throttle.csv"
    with path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, [c for c in rows[0] if c != "throttle_pct"], extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    assert main(["replay", str(path), "--out", str(tmp_path / "h.csv")]) == 2
    [line] = capsys.readouterr().err.strip().splitlines()
    assert "missing column(s) throttle_pct" in line and "--heat-axes fuel_flow_lph,rpm" in line


def test_values_by_frame_is_a_stable_sort_by_frame() -> None:
    # the compiled counting sort against numpy's stable argsort: frames with no value, several names and a
    # name with two values in one frame; within a frame the values keep the names' order
    from ecu_monitor.offline.replay import _values_by_frame

    rng = np.random.default_rng(5)
    n = 500
    names = ("a", "b", "c")
    decoded = {}
    for name in names:
        rows = np.sort(rng.choice(n, size=200, replace=True)).astype(np.int64)
        decoded[name] = (rows, rng.normal(size=rows.size))
    first, slots, values = _values_by_frame(names, decoded, n)
    frame = np.concatenate([decoded[name][0] for name in names])
    order = np.argsort(frame, kind="stable")
    assert np.array_equal(first, np.searchsorted(frame[order], np.arange(n + 1)))
    assert np.array_equal(slots, np.repeat(np.arange(3), 200)[order])
    assert np.array_equal(values, np.concatenate([decoded[name][1] for name in names])[order])
