"""``ecu-monitor replay``: runs an estimator over a canonical CSV; bad input exits 2 with one line."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from ecu_monitor.cli import main
from ecu_monitor.flightlog import FlightLog, write_csv
from ecu_monitor.model import InputSeries, coefficients, compute_drive, paper_table_a1, save_model, steady_state_cht
from ecu_monitor.model.compiled import simulate_compiled


@pytest.fixture()
def flight_csv(tmp_path):
    """A 120 s cruise at 10 Hz with gamma_Q = 1.2 from 30 s; readings rounded to 1 degC."""
    return _cruise(tmp_path, 120.0, 30.0)


def _cruise(tmp_path, seconds, onset_s):
    """A cruise of ``seconds`` logged at 10 Hz, gamma_Q = 1.2 from ``onset_s``; (flight CSV, model YAML)."""
    params = paper_table_a1()
    coeffs = coefficients(params)
    dt = 0.02
    n = round(seconds / dt) + 1
    t = dt * np.arange(n)
    one = np.ones(n)
    inputs = InputSeries(60.0 * one, 6500.0 * one, 500.0 * one, 23.0 * one, 12.0 * one)
    start = steady_state_cht(compute_drive(InputSeries(60.0, 6500.0, 500.0, 23.0, 12.0), coeffs), coeffs)
    truth = simulate_compiled(inputs, coeffs, dt, start, np.where(t >= onset_s, 1.2, 1.0)).cht_c
    rng = np.random.default_rng(3)
    keep = slice(None, None, 5)
    log = FlightLog(
        {
            "time_s": t[keep],
            "throttle_pct": inputs.heat_x[keep],
            "rpm": inputs.heat_y[keep],
            "altitude_m": inputs.altitude_m[keep],
            "airspeed_mps": inputs.airspeed_mps[keep],
            "oat_c": inputs.oat_c[keep],
            "cht_c": np.round(truth[keep] + 0.3 * rng.standard_normal(truth[keep].size)),
        }
    )
    path = tmp_path / "flight.csv"
    write_csv(log, path)
    model = tmp_path / "model.yaml"
    save_model(params, model)
    return path, model


@pytest.mark.parametrize("estimator", ["ekf", "cbekf", "cbekf-au"])
def test_replay_writes_health_csv(flight_csv, tmp_path, capsys, estimator):
    path, model = flight_csv
    out = tmp_path / "health.csv"
    code = main(["replay", str(path), "--model", str(model), "--estimator", estimator, "--out", str(out)])
    assert code == 0
    summary = capsys.readouterr().out.strip().splitlines()
    assert "rows" in summary[0] and estimator in summary[0]
    assert all(line.startswith("warning: ") for line in summary[1:])
    with open(out, newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert 1150 <= len(rows) <= 1201  # one row per 0.1 s: the input's rate and the health frame's
    assert list(rows[0])[:5] == ["time_s", "cht_meas_c", "cht_est_c", "deviation", "state"]
    states = {"NOMINAL", "SUSPECT", "DEGRADED", "INPUT_STALE", "SENSOR_FAULT", "UNAVAILABLE"}  # health.dbc
    assert {r["state"] for r in rows} <= states
    assert rows[0]["state"] == "NOMINAL"
    assert float(rows[-1]["time_s"]) == pytest.approx(120.0, abs=0.2)
    est = np.array([float(r["cht_est_c"]) for r in rows])
    meas = np.array([float(r["cht_meas_c"]) for r in rows])
    rms = np.sqrt(np.mean((est[-300:] - meas[-300:]) ** 2))
    late = np.array([float(r["deviation"]) for r in rows[-300:]])
    if estimator == "ekf":  # the conventional EKF keeps the degradation's error and has no deviation term
        assert rms > 3.0
        assert np.all(late == 0.0)
    else:
        assert rms < 1.0
        assert np.mean(late) > 0.1  # gamma_Q = 1.2 adds about 0.33 degC/s at this point


def test_replay_warns_when_the_limit_or_the_threshold_does_not_fit(flight_csv, tmp_path, capsys):
    """A CHT limit below what the engine read, a threshold not calibrated for the model and the shipped engine
    reference (the virtual ECU's) left out for it: one line each."""
    import dataclasses

    from ecu_monitor.commands.replay import fit_warnings
    from ecu_monitor.config import DEFAULT_CONFIG, load_config
    from ecu_monitor.flightlog import read_csv
    from ecu_monitor.offline.calibration import model_fingerprint
    from ecu_monitor.offline.replay import replay_file

    path, _ = flight_csv
    flown = read_csv(path)["cht_c"]
    low = dataclasses.replace(paper_table_a1(), cht_limit_c=float(np.median(flown)))
    model = tmp_path / "low_limit.yaml"
    save_model(low, model)
    assert main(["replay", str(path), "--model", str(model), "--out", str(tmp_path / "health.csv")]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    warnings = [line for line in lines if line.startswith("warning: ")]
    assert len(warnings) == 3 and len(lines) == 4
    assert f"CHT limit {low.cht_limit_c:g} degC is below what the engine read (up to {flown.max():.1f}" in warnings[0]
    assert "not calibrated for this model" in warnings[1] and "this model is" in warnings[1]
    assert "engine reference" in warnings[2] and "another model's: its test was off" in warnings[2]

    config = load_config(DEFAULT_CONFIG)
    fits = dataclasses.replace(paper_table_a1(), cht_limit_c=float(flown.max()) + 10.0)
    result = replay_file(path, config, fits)
    assert fit_warnings(config.replace(detector_calibrated_for=model_fingerprint(fits)), fits, result) == []
    other = config.replace(detector_calibrated_for=model_fingerprint(low))
    (line,) = fit_warnings(other, fits, result)
    assert f"calibrated for model {model_fingerprint(low)}, this model is {model_fingerprint(fits)}" in line


def test_replay_without_model_uses_the_paper_preset(flight_csv, tmp_path):
    path, _ = flight_csv
    assert main(["replay", str(path), "--out", str(tmp_path / "h.csv")]) == 0


@pytest.mark.parametrize(
    "content",
    [
        "time_s,throttle_pct,rpm,altitude_m,airspeed_mps,oat_c\n0,50,6000,0,20,10\n1,50,6000,0,20,10\n",
        "time_s,throttle_pct,rpm,altitude_m,airspeed_mps,oat_c,cht_c\n0,50,6000,0,20,10,hot\n1,50,6000,0,20,10,90\n",
        "",
    ],
    ids=["missing-cht", "text-in-number", "empty"],
)
def test_replay_bad_csv_exits_2_with_one_line(tmp_path, capsys, content):
    bad = tmp_path / "bad.csv"
    bad.write_text(content)
    code = main(["replay", str(bad), "--out", str(tmp_path / "h.csv")])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.csv" in err[0]


def test_replay_unknown_estimator_or_missing_file_exits_2(flight_csv, tmp_path, capsys):
    path, _ = flight_csv
    assert main(["replay", str(path), "--estimator", "nope", "--out", str(tmp_path / "h.csv")]) == 2
    assert "known: " in capsys.readouterr().err
    assert main(["replay", str(tmp_path / "absent.csv"), "--out", str(tmp_path / "h.csv")]) == 2


def _csv_rows(path):
    with open(path, newline="", encoding="utf-8") as handle:
        return list(csv.DictReader(handle))


def test_replay_of_a_csv_with_a_long_hole_runs_no_step_inside_it(flight_csv, tmp_path, capsys):
    """Two stretches of the flight 28 h apart: no frame and no row across the hole, the hole reported."""
    from ecu_monitor.flightlog import read_csv

    path, model = flight_csv
    log = read_csv(path)
    hole_s = 28 * 3600.0
    half = len(log) // 2
    t = log.time_s.copy()
    t[half:] += hole_s
    holed = tmp_path / "holed.csv"
    write_csv(log.with_columns(time_s=t), holed)
    out = tmp_path / "h.csv"
    assert main(["replay", str(holed), "--model", str(model), "--out", str(out)]) == 0
    summary = capsys.readouterr().out
    assert "1 hole(s) in time without frames (longest 10080" in summary and "2 segments replayed apart" in summary
    times = np.array([float(r["time_s"]) for r in _csv_rows(out)])
    inside = (times > t[half - 1] + 1.0) & (times < t[half])
    assert not inside.any() and times.size < 1300  # 2 x 60 s at 10 Hz, not 28 h of repeated rows


def test_replay_of_a_one_row_csv_exits_2_as_simulate_does(flight_csv, tmp_path, capsys):
    from ecu_monitor.flightlog import read_csv

    path, model = flight_csv
    one = tmp_path / "one.csv"
    write_csv(read_csv(path).select(0.0, 0.0), one)
    for command in ("simulate", "replay"):
        out = tmp_path / f"{command}.csv"
        assert main([command, str(one), "--model", str(model), "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "one.csv: at least 2" in err[0]
        assert not out.exists()


def test_replay_plot_draws_the_replay_with_its_states(tmp_path, capsys, monkeypatch):
    """--plot: one figure of the replay; the DEGRADED stretch (gamma_Q = 1.2 after the detector's warm-up)
    is shaded and named in the legend; the CSV is written as without --plot."""
    import matplotlib

    monkeypatch.setitem(matplotlib.rcParams, "svg.fonttype", "none")  # text as text, to read the legend
    path, model = _cruise(tmp_path, 1000.0, 700.0)
    out, plot = tmp_path / "health.csv", tmp_path / "replay.svg"
    assert main(["replay", str(path), "--model", str(model), "--out", str(out), "--plot", str(plot)]) == 0
    printed = capsys.readouterr().out.strip().splitlines()
    assert printed[-1] == f"plot: {plot}" and "DEGRADED from" in printed[0], printed
    svg = plot.read_text(encoding="utf-8")
    assert "DEGRADED" in svg and "CHT estimated" in svg and "gamma_Q (heat in)" in svg
    assert out.stat().st_size > 0


@pytest.mark.parametrize("name", ["replay.txt", "absent/replay.png"])
def test_replay_plot_path_is_checked_before_the_replay(flight_csv, tmp_path, capsys, name):
    path, model = flight_csv
    out = tmp_path / "health.csv"
    code = main(["replay", str(path), "--model", str(model), "--out", str(out), "--plot", str(tmp_path / name)])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--plot" in err[0]
    assert not out.exists()
