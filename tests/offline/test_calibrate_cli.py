"""``ecu-monitor calibrate``: the detector threshold from the user's own nominal flights.

Two nominal virtual-ECU flights (random missions with the evaluation's residual unmodelled effects,
1.17 h and 1.25 h: 2 whole hours of statistic after the 600 s warm-ups) are written once as .blf CAN
logs (the frames replay makes from their CSVs), so each calibration replays them in about a second.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import math

import can
import numpy as np
import pytest
import yaml

from ecu_monitor.bus.canlog import read_frames
from ecu_monitor.cli import main
from ecu_monitor.commands.replay import DEFAULT_CONFIG
from ecu_monitor.config import load_config
from ecu_monitor.estimation.detection import DetectorSettings, calibrate_threshold, cusum_path
from ecu_monitor.flightlog import write_csv
from ecu_monitor.model import paper_table_a1, save_model
from ecu_monitor.offline.calibration import model_fingerprint
from ecu_monitor.offline.replay import frames_from_flight, replay_file
from ecu_monitor.pipeline.output_table import STATES
from ecu_monitor.research.evaluation import residual_effects
from virtual_bus.plant import fly
from virtual_bus.random_missions import random_mission

pytestmark = pytest.mark.slow  # over a minute in all: scheduled first (tests/conftest.py)

SEEDS = (11, 12)

#: The detector keys of a calibration without an engine reference (too few flights): written off.
NO_REFERENCE = {"nominal_threshold": 0.0, "nominal_mean": (), "nominal_spread": (), "start_fit_mean": (),
                "start_fit_spread": ()}  # fmt: skip


@pytest.fixture(scope="module")
def nominal(tmp_path_factory):
    """Two nominal flights as .blf logs, one as a canonical CSV too (its first 20 min)."""
    folder = tmp_path_factory.mktemp("calibrate")
    config = load_config(DEFAULT_CONFIG)
    paths = []
    for seed in SEEDS:
        log = fly(random_mission(seed, 3600.0), effects=residual_effects(seed), seed=seed)
        frames = frames_from_flight(log, config)
        path = folder / f"nominal_{seed}.blf"
        with can.BLFWriter(str(path)) as writer:
            for msg in frames.messages():
                writer.on_message_received(msg)
        paths.append(path)
        if seed == SEEDS[0]:
            write_csv(log.select(log.time_s[0], log.time_s[0] + 1200.0), folder / "short.csv")
            write_csv(log, folder / "nominal.csv")
    return folder, paths


def _calibrate(args):
    """Run the CLI in process: (exit code, stdout)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(["calibrate", *args])
    return code, out.getvalue()


@pytest.fixture(scope="module")
def calibrated(nominal):
    """``calibrate`` with the default config (true model), fragment + plot; and with --write-config."""
    folder, paths = nominal
    flights = [str(p) for p in paths]
    fragment = folder / "detector.yaml"
    plot = folder / "statistic.png"
    code, printed = _calibrate([*flights, "--out", str(fragment), "--plot", str(plot)])
    written = folder / "service.yaml"
    code_config, _ = _calibrate([*flights, "--write-config", "--out", str(written)])
    return {"code": code, "printed": printed, "fragment": fragment, "plot": plot, "written": written,
            "code_config": code_config, "flights": flights}  # fmt: skip


def test_calibrate_prints_a_table_and_writes_the_fragment(calibrated):
    assert calibrated["code"] == 0 and calibrated["code_config"] == 0
    lines = calibrated["printed"].splitlines()
    assert lines[0].startswith("chosen: 2 flight(s) given, cross-validation needs 3: kept the config's baseline_s 120")
    lines = lines[1:]
    assert lines[0].split()[:5] == ["flight", "hours", "whole", "h", "max"]
    assert "alarms at h=7.77" in lines[0]
    rows = {line.split()[0]: line.split() for line in lines[1:4]}
    assert set(rows) == {"nominal_11.blf", "nominal_12.blf", "total"}
    assert float(rows["nominal_11.blf"][1]) == pytest.approx(1.17, abs=0.01)
    assert rows["total"][2] == "2"  # whole hours of statistic
    assert any(line.startswith("threshold h = ") and "current 7.77" in line for line in lines)
    assert any("fewer than the 100 h of one expected alarm" in line for line in lines)
    fragment = yaml.safe_load(calibrated["fragment"].read_text())
    assert set(fragment) == {"detector"} and fragment["detector"]["symptom"] == "estimator"
    # the whole detector block the threshold holds for: merged into the config it gives the settings used
    shipped = load_config(DEFAULT_CONFIG).detector
    calibrated_settings = {k: v for k, v in fragment["detector"].items() if k not in ("symptom", "calibrated_for")}
    assert fragment["detector"]["calibrated_for"] == model_fingerprint(load_config(DEFAULT_CONFIG).load_params())
    # two flights: no engine reference of their own, and not the shipped virtual ECU's either
    written = dataclasses.replace(shipped, threshold=fragment["detector"]["threshold"], **NO_REFERENCE)
    assert DetectorSettings(**calibrated_settings) == written
    text = calibrated["fragment"].read_text()
    assert "nominal_11.blf" in text and "nominal_12.blf" in text and "# method:" in text
    assert calibrated["plot"].stat().st_size > 10_000


def test_threshold_is_calibrate_threshold_on_the_services_own_statistic(calibrated):
    """The statistic is recomputed here from the replay's detector input with cusum_path (no alarm),
    then calibrate_threshold: the command's threshold is that one (written rounded up to 1e-4)."""
    config = load_config(DEFAULT_CONFIG)
    params = config.load_params()
    unbounded = dataclasses.replace(config.detector, threshold=1e300)
    paths = []
    for flight in calibrated["flights"]:
        result = replay_file(flight, config, params, keep_feeds=True)
        assert len(result.detector_feed) == 1  # one clock segment
        time_s, symptom = result.detector_feed[0]
        paths.append(cusum_path(time_s, symptom, unbounded)[1])
    expected = calibrate_threshold(paths, 1.0, sample_period_s=config.detector.block_s)
    assert expected.hours == 2
    threshold = yaml.safe_load(calibrated["fragment"].read_text())["detector"]["threshold"]
    assert threshold == pytest.approx(expected.threshold, abs=1.01e-4) and threshold >= expected.threshold
    assert f"threshold h = {expected.threshold:.3f}" in calibrated["printed"]
    # the flights never come near the shipped 7.77 (the reference model is the monitor's model here)
    assert expected.threshold < config.detector.threshold


def test_written_config_loads_and_replay_uses_the_new_threshold(calibrated, tmp_path, capsys):
    written = calibrated["written"]
    config = load_config(written)
    threshold = yaml.safe_load(calibrated["fragment"].read_text())["detector"]["threshold"]
    assert config.detector.threshold == threshold
    original = load_config(DEFAULT_CONFIG)
    assert config.detector == dataclasses.replace(original.detector, threshold=threshold, **NO_REFERENCE)
    assert config.dbc_paths[0].resolve() == original.dbc_paths[0].resolve()  # relative paths made absolute
    for flight in calibrated["flights"]:
        assert main(["replay", flight, "--config", str(written), "--out", str(tmp_path / "health.csv")]) == 0
        summary = capsys.readouterr().out
        assert "DEGRADED" not in summary and "SUSPECT" in summary  # the statistic passes h/2, never h
        assert "not calibrated for this model" not in summary  # the copy records the model it holds for


def test_the_statistic_is_the_one_the_service_alarms_on(calibrated):
    """With h below the flight's peak statistic, replay goes DEGRADED where the calibration path first
    crosses h (the row after the crossing: rows every 0.1 s)."""
    config = load_config(calibrated["written"])
    params = config.load_params()
    flight = calibrated["flights"][0]
    time_s, symptom = replay_file(flight, config, params, keep_feeds=True).detector_feed[0]
    ends, stat, _ = cusum_path(time_s, symptom, dataclasses.replace(config.detector, threshold=1e300))
    low = 0.6 * float(stat.max())
    crossing = float(ends[np.argmax(stat >= low)])
    lowered = config.replace(detector=dataclasses.replace(config.detector, threshold=low))
    columns = replay_file(flight, lowered, params).columns
    degraded = np.flatnonzero(columns["state"] == STATES.index("DEGRADED"))
    assert degraded.size and crossing <= columns["time_s"][degraded[0]] <= crossing + 0.1 + 1e-6


def test_a_wrong_model_needs_a_higher_threshold(nominal, calibrated, tmp_path):
    """Heat map 15 % too high: larger residual at every power change, so the statistic and the
    calibrated threshold grow (measured 3.72 -> 22.8 on these flights)."""
    _, paths = nominal
    true = yaml.safe_load(calibrated["fragment"].read_text())["detector"]["threshold"]
    params = paper_table_a1()
    heat = dataclasses.replace(params.heat_map, values_w=np.asarray(params.heat_map.values_w) * 1.15)
    wrong = tmp_path / "wrong.yaml"
    save_model(params.replace(heat_map=heat), wrong)
    out = tmp_path / "wrong_detector.yaml"
    code, _ = _calibrate([*map(str, paths), "--model", str(wrong), "--out", str(out)])
    assert code == 0
    assert yaml.safe_load(out.read_text())["detector"]["threshold"] > 2.0 * true


def test_csv_flights_go_through_the_same_path(nominal):
    """A canonical CSV of the same flight gives the same statistic peak as its .blf (the frames are
    the ones replay makes from the CSV)."""
    folder, paths = nominal
    config = load_config(DEFAULT_CONFIG)
    params = config.load_params()
    blf = replay_file(paths[0], config, params, keep_feeds=True)
    assert len(read_frames(paths[0])) > 100_000
    csv = replay_file(folder / "nominal.csv", config, params, keep_feeds=True)
    assert np.array_equal(blf.columns["state"], csv.columns["state"])
    for (t_a, x_a), (t_b, x_b) in zip(blf.detector_feed, csv.detector_feed, strict=True):
        assert np.allclose(t_a, t_b) and np.allclose(x_a, x_b, equal_nan=True)


def _one_line_exit_2(args, capsys):
    code, _ = _calibrate(args)
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2, err
    assert len(err) == 1 and err[0].startswith("ecu-monitor: error:"), err
    return err[0]


def test_fewer_than_two_hours_exits_2_with_the_hours(nominal, capsys):
    folder, _ = nominal
    line = _one_line_exit_2([str(folder / "short.csv"), "--out", str(folder / "x.yaml")], capsys)
    assert "0.33 flight hours" in line and "0 whole hour" in line and "at least 2" in line
    assert "giving 2 more" in line and "none under 70 min" in line  # how much more, and what counts
    assert not (folder / "x.yaml").exists()


def test_missing_file_exits_2(tmp_path, capsys):
    line = _one_line_exit_2([str(tmp_path / "none.csv"), "--out", str(tmp_path / "x.yaml")], capsys)
    assert "none.csv: no such file" in line


def test_unreadable_flights_exit_2(tmp_path, capsys):
    garbage_blf = tmp_path / "garbage.blf"
    garbage_blf.write_bytes(b"LOGG" + bytes(range(200)))
    assert "garbage.blf" in _one_line_exit_2([str(garbage_blf), "--out", str(tmp_path / "x.yaml")], capsys)
    text_csv = tmp_path / "text.csv"
    text_csv.write_text("time_s,rpm\nfoo,bar\n")
    assert "text.csv" in _one_line_exit_2([str(text_csv), "--out", str(tmp_path / "x.yaml")], capsys)
    assert "not a file" in _one_line_exit_2([str(tmp_path), "--out", str(tmp_path / "x.yaml")], capsys)
    other = tmp_path / "flight.txt"
    other.write_text("not a log\n")
    assert "unknown log" in _one_line_exit_2([str(other), "--out", str(tmp_path / "x.yaml")], capsys)


def test_csv_without_the_models_inputs_exits_2(nominal, tmp_path, capsys):
    folder, _ = nominal
    lines = (folder / "short.csv").read_text().splitlines()
    header = lines[0].split(",")
    drop = header.index("rpm")
    stripped = tmp_path / "no_rpm.csv"
    stripped.write_text("\n".join(",".join(c for i, c in enumerate(r.split(",")) if i != drop) for r in lines) + "\n")
    line = _one_line_exit_2([str(stripped), "--out", str(tmp_path / "x.yaml")], capsys)
    assert "no_rpm.csv" in line and "'rpm': required column missing" in line  # a canonical column
    # a model whose heat map reads the fuel flow (optional in a canonical CSV) on a CSV without it
    drop = header.index("fuel_flow_lph")
    no_fuel = tmp_path / "no_fuel.csv"
    no_fuel.write_text("\n".join(",".join(c for i, c in enumerate(r.split(",")) if i != drop) for r in lines) + "\n")
    params = paper_table_a1()
    heat = dataclasses.replace(params.heat_map, x_axis="fuel_flow_lph", x_breakpoints=(5.0, 10.0, 20.0, 30.0, 40.0))
    model = tmp_path / "fuel.yaml"
    save_model(params.replace(heat_map=heat), model)
    line = _one_line_exit_2([str(no_fuel), "--model", str(model), "--out", str(tmp_path / "x.yaml")], capsys)
    assert "no_fuel.csv: missing column(s) fuel_flow_lph" in line


def test_option_errors_exit_2(nominal, tmp_path, capsys):
    folder, _ = nominal
    flight = str(folder / "short.csv")
    assert "--write-config" in _one_line_exit_2([flight, "--write-config"], capsys)
    assert "input config" in _one_line_exit_2(
        [flight, "--write-config", "--config", str(DEFAULT_CONFIG), "--out", str(DEFAULT_CONFIG)], capsys
    )
    assert "--rate" in _one_line_exit_2([flight, "--rate", "0", "--out", str(tmp_path / "x.yaml")], capsys)
    assert "--rate" in _one_line_exit_2([flight, "--rate", "nan", "--out", str(tmp_path / "x.yaml")], capsys)
    assert math.isclose(load_config(DEFAULT_CONFIG).detector.threshold, 7.77)  # the input config is untouched


# --------------------------------------------------------------------------------------------------
# Choosing the baseline by cross-validation (service.calibration.choose_settings)
# --------------------------------------------------------------------------------------------------

SYNTHETIC_S = 4500.0  # 1.25 h: one whole hour of statistic after the 600 s warm-up


def _synthetic_flight(name, rng, bump=0.0, overlay_slope=None):
    """A detector feed at 1 Hz: white noise of 0.02 (well inside the 0.05 allowance) plus, if ``bump``,
    a smooth nominal excursion of that height rising over 750 s from 1500 s and falling back by 3000 s
    (a phase the model misses on this flight only); overlays add a degradation to the symptom: a
    step of 0.3 approached with 240 s (``overlay_slope`` None) or a ramp of that slope, per s."""
    from ecu_monitor.offline.calibration import FlightFeeds, OverlayRun

    t = np.arange(0.0, SYNTHETIC_S, 1.0)
    nominal = rng.normal(0.0, 0.02, t.size) + bump * np.sin(np.pi * np.clip((t - 1500.0) / 1500.0, 0.0, 1.0)) ** 2
    runs = []
    for onset in (1200.0, 2400.0, 3600.0):
        for gain in (0.2, 0.1):
            after = np.maximum(t - onset, 0.0)
            if overlay_slope is None:
                rise = 1.5 * gain * -np.expm1(-after / 240.0)
            else:
                rise = overlay_slope * gain / 0.2 * after
            runs.append(OverlayRun(onset, gain, ((t, nominal + rise),)))
    return FlightFeeds(name, ((t, nominal),), 0.0, float(t[-1]), 0.0, tuple(runs))


def test_choice_excludes_candidates_with_a_false_alarm_on_a_held_out_flight():
    """One flight has a slow nominal excursion (0.15 over 750 s) the others lack. A 120 s baseline
    follows it (lag 0.15/750 x 180 s = 0.036, under the 0.05 allowance); longer ones do not and alarm
    when that flight is held out (h from the other two, on noise only, sits at the 1.0 floor). The
    choice is 120 s, and it detects the k = 0.2 overlays."""
    from ecu_monitor.offline.calibration import choose_settings

    rng = np.random.default_rng(5)
    flights = [_synthetic_flight("a", rng, bump=0.15), _synthetic_flight("b", rng), _synthetic_flight("c", rng)]
    current = dataclasses.replace(DetectorSettings(), baseline_s=600.0)
    choice = choose_settings(flights, current, 1.0, (120.0, 600.0, 1200.0))
    assert choice.cross_validated and choice.settings.baseline_s == 120.0
    assert "by the rule: the fewest false alarms" in choice.reason and "WARNING" not in choice.reason
    plain = [s for s in choice.scores if not s.settings.baseline_freeze and s.settings.baseline_delay_s == 60.0]
    by_baseline = {s.settings.baseline_s: s for s in plain}
    assert by_baseline[120.0].false_alarms == 0
    assert by_baseline[600.0].false_alarms == 1 and by_baseline[1200.0].false_alarms == 1
    assert math.isfinite(by_baseline[1200.0].false_alarm_s[0])  # the flight with the excursion
    assert by_baseline[120.0].hits(0.2) == 9  # the 0.3 step (approached in 240 s) within 300 s at every onset


def test_choice_freezes_the_baseline_when_the_degradation_creeps_in():
    """Overlays that ramp up (k = 0.1: 1.5e-4 per s) instead of stepping: a learning baseline follows a
    ramp with a lag of slope x (baseline + delay), 0.1 for 600 s + 60 s, so the excess over the 0.05
    allowance builds up slowly; frozen while S > 0, the whole ramp stays in the test. The choice is a
    frozen baseline, and at 600 s / 60 s the frozen candidate sees more k = 0.1 ramps in time than
    its learning twin."""
    from ecu_monitor.offline.calibration import choose_settings

    rng = np.random.default_rng(8)
    flights = [_synthetic_flight(n, rng, overlay_slope=3e-4) for n in "abc"]
    choice = choose_settings(flights, DetectorSettings(), 1.0, (120.0, 600.0))
    assert choice.cross_validated and choice.settings.baseline_freeze
    assert "frozen while a change is suspected" in choice.reason
    twins = {s.settings.baseline_freeze: s for s in choice.scores if s.settings.baseline_s == 600.0
             and s.settings.baseline_delay_s == 60.0}  # fmt: skip
    assert twins[True].false_alarms == twins[False].false_alarms == 0
    assert twins[True].hits(0.1) > twins[False].hits(0.1)


def test_held_out_verdicts_are_those_of_the_threshold_calibrated_on_the_others():
    """Recomputed here with calibrate_threshold and cusum_path: per fold, h from the other flights'
    nominal statistics, the held-out nominal flight's first alarm, each overlay's delay."""
    from ecu_monitor.offline.calibration import score_candidate

    rng = np.random.default_rng(6)
    flights = [_synthetic_flight(n, rng, bump=b, overlay_slope=3e-4) for n, b in (("a", 0.1), ("b", 0.0), ("c", 0.05))]
    settings = dataclasses.replace(DetectorSettings(), baseline_s=300.0)
    score = score_candidate(flights, settings, 1.0)
    unbounded = dataclasses.replace(settings, threshold=1e300)
    delays = {0.2: [], 0.1: []}
    for i, held in enumerate(flights):
        others = [cusum_path(t, x, unbounded)[1] for j, f in enumerate(flights) if j != i for t, x in f.feed]
        h = calibrate_threshold(others, 1.0, sample_period_s=1.0).threshold
        assert score.thresholds[i] == h
        alarms = cusum_path(*held.feed[0], dataclasses.replace(settings, threshold=h))[2]
        assert (score.false_alarm_s[i] == alarms[0]) if alarms.size else math.isinf(score.false_alarm_s[i])
        for run in held.overlays:
            first = cusum_path(*run.feed[0], dataclasses.replace(settings, threshold=h))[2]
            if not first.size:
                delays[run.gain].append(math.inf)
            elif first[0] < run.onset_s:
                delays[run.gain].append(math.nan)
            else:
                delays[run.gain].append(float(first[0] - run.onset_s))
    for gain in (0.2, 0.1):
        np.testing.assert_array_equal(score.delays[gain], delays[gain])


def test_choice_falls_back_with_too_few_flights_or_too_little_airborne_time():
    from ecu_monitor.offline.calibration import FlightFeeds, choose_settings

    rng = np.random.default_rng(7)
    flights = [_synthetic_flight(n, rng) for n in "abc"]
    current = DetectorSettings()
    two = choose_settings(flights[:2], current, 1.0)
    assert not two.cross_validated and two.settings == current and not two.scores
    assert "2 flight(s) given" in two.reason and "kept the config's baseline_s 120 s" in two.reason
    grounded = dataclasses.replace(flights[2], overlays=())
    assert isinstance(grounded, FlightFeeds)
    short = choose_settings([*flights[:2], grounded], current, 1.0)
    assert not short.cross_validated and short.settings == current
    assert "2 flight(s) with at least 15 min airborne" in short.reason
    t, x = flights[2].feed[0]
    brief = dataclasses.replace(flights[2], feed=((t[:3000], x[:3000]),))  # no whole hour after the warm-up
    fold = choose_settings([*flights[:2], brief], current, 1.0)
    assert not fold.cross_validated and "without a the other flights give 1 whole hour(s)" in fold.reason


def test_onsets_lie_in_the_airborne_part_after_the_warm_up():
    from ecu_monitor.flightlog import FlightLog
    from ecu_monitor.offline.calibration import airborne_onsets

    t = np.arange(0.0, 5000.0, 1.0)
    airspeed = np.where((t > 300.0) & (t < 4500.0), 50.0, 3.0)  # taxi, flight 300-4500 s, taxi
    log = FlightLog({"time_s": t + 1000.0, "airspeed_mps": airspeed})
    onsets = airborne_onsets(log, 600.0)
    assert onsets.size == 3 and onsets[0] >= 600.0 and onsets[-1] <= 4500.0 - 600.0
    assert airborne_onsets(log, 3500.0).size == 0  # 3500 s warm-up: 399 s left before landing - 600 s


def test_baseline_override_skips_the_choice(nominal, tmp_path):
    _, paths = nominal
    out = tmp_path / "d.yaml"
    code, printed = _calibrate([*map(str, paths), "--baseline-s", "600", "--out", str(out)])
    assert code == 0
    assert printed.splitlines()[0] == "detector settings: baseline_s 600 s given by --baseline-s (no cross-validation)"
    fragment = yaml.safe_load(out.read_text())["detector"]
    assert fragment["baseline_s"] == 600.0
    # the threshold is calibrated for that baseline
    config = load_config(DEFAULT_CONFIG)
    settings = dataclasses.replace(config.detector, baseline_s=600.0, threshold=1e300)
    feeds = [replay_file(p, config, config.load_params(), keep_feeds=True).detector_feed[0] for p in paths]
    expected = calibrate_threshold([cusum_path(t, x, settings)[1] for t, x in feeds], 1.0).threshold
    assert fragment["threshold"] == pytest.approx(expected, abs=1.01e-4)


def test_calibrate_chooses_the_baseline_on_three_flights(nominal, tmp_path):
    """Three flights (the two CAN logs and the CSV of the first, which counts as a third flight here:
    this checks the command's path, test_choice_* the choice): the table per candidate, the rule, and
    the chosen baseline written with its threshold."""
    folder, paths = nominal
    third = folder / "nominal.csv"
    out = tmp_path / "d.yaml"
    code, printed = _calibrate([*map(str, paths), str(third), "--candidates", "120,600", "--out", str(out)])
    assert code == 0
    lines = printed.splitlines()
    assert lines[0].startswith("cross-validation, leave one flight out over 3 flights (9 overlays per gain)")
    assert lines[1].split()[:4] == ["baseline_s", "delay_s", "freeze", "h"]
    rows = [line.split() for line in lines[2:10]]  # 2 lengths x 2 delays x freeze or not
    assert [(float(r[0]), float(r[1]), r[2]) for r in rows] == [
        (b, d, f) for b in (120.0, 600.0) for d in (0.0, 60.0) for f in ("no", "yes")
    ]
    chosen = [r for r in rows if r[-2:] == ["<-", "chosen"]]
    assert len(chosen) == 1
    fragment = yaml.safe_load(out.read_text())["detector"]
    frozen = "frozen while a change is suspected" if chosen[0][2] == "yes" else "always learning"
    assert lines[10].startswith(f"chosen: baseline_s {chosen[0][0]} s, delay {chosen[0][1]} s, {frozen}, by the rule")
    fewest = min(int(r[6]) for r in rows)
    assert int(chosen[0][6]) == fewest  # false alarms
    assert ("WARNING: every candidate raised a false alarm" in lines[10]) == (fewest > 0)
    assert fragment["baseline_s"] == float(chosen[0][0])
    assert fragment["baseline_delay_s"] == float(chosen[0][1])
    assert fragment["baseline_freeze"] == (chosen[0][2] == "yes")
    assert "# detector settings (cross-validated): baseline_s" in out.read_text()


def test_bad_baseline_options_exit_2(nominal, tmp_path, capsys):
    folder, _ = nominal
    flight = str(folder / "short.csv")
    assert "--baseline-s" in _one_line_exit_2([flight, "--baseline-s", "0.5", "--out", str(tmp_path / "x")], capsys)
    assert "--candidates" in _one_line_exit_2([flight, "--candidates", "1,x", "--out", str(tmp_path / "x")], capsys)


def test_calibrate_refuses_the_same_flight_twice(tmp_path, capsys):
    """The same file twice (even spelled differently) would count its hours twice: one line, exit 2."""
    from ecu_monitor.cli import main

    flight = tmp_path / "a.csv"
    flight.write_text("time_s,cht_c\n0,20\n1,20\n", encoding="utf-8")
    other_spelling = tmp_path / "." / "a.csv"
    code = main(["calibrate", str(flight), str(other_spelling), "--out", str(tmp_path / "d.yaml")])
    err = capsys.readouterr().err
    assert code == 2
    assert "given twice" in err and "a.csv" in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "d.yaml").exists()
