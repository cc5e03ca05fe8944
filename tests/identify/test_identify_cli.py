"""``ecu-monitor identify`` and ``ecu-monitor simulate`` as a user runs them (in process, small swarms)."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from ecu_monitor.cli import main
from ecu_monitor.flightlog import FlightLog, write_csv
from ecu_monitor.identify import flight_errors
from ecu_monitor.model import InputSeries, coefficients, load_model, paper_table_a1
from ecu_monitor.model.compiled import simulate_compiled


def _flight(seed: int, levels: tuple[float, ...], hold_s: int = 90, with_throttle: bool = True) -> FlightLog:
    """Throttle steps, rpm following; CHT from the paper's model, 1 Hz, noise and 1 degC quantiser."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hold_s * len(levels), 1.0)
    throttle = np.repeat(np.asarray(levels, dtype=float), hold_s)
    rpm = 2000.0 + 70.0 * throttle
    altitude = np.full_like(t, 500.0)
    airspeed = np.full_like(t, 23.0)
    oat = np.full_like(t, 12.0)
    series = InputSeries(throttle, rpm, altitude, airspeed, oat)
    cht = simulate_compiled(series, coefficients(paper_table_a1()), 1.0, 50.0).probe_c
    columns = {
        "time_s": t,
        "rpm": rpm,
        "altitude_m": altitude,
        "airspeed_mps": airspeed,
        "oat_c": oat,
        "cht_c": np.round(cht + 0.3 * rng.standard_normal(t.size)),
    }
    if with_throttle:
        columns["throttle_pct"] = throttle
    else:
        columns["fuel_flow_lph"] = 0.02 * throttle + 0.05
    return FlightLog(columns, source=f"test-{seed}")


@pytest.fixture(scope="module")
def flights(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("identify-cli")
    train, held_out = folder / "train.csv", folder / "held_out.csv"
    write_csv(_flight(1, (30, 80, 50, 95, 40, 70)), train)
    write_csv(_flight(2, (70, 40, 95, 50, 80, 30)), held_out)
    return train, held_out


def test_identify_then_simulate(flights, tmp_path, capsys):
    train, held_out = flights
    model = tmp_path / "model.yaml"
    plots = tmp_path / "plots"
    argv = ["identify", str(train), "--validate", str(held_out), "--out", str(model), "--particles", "16"]
    argv += ["--iterations", "15", "--seed", "3", "--plots", str(plots), "--quiet"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "train" in out and "validate" in out and "RMS degC" in out
    params = load_model(model)  # every other command reads it
    assert params.heat_axes == ("throttle_pct", "rpm")
    assert model.read_text().startswith("# Identified by:")
    pngs = sorted(p.name for p in plots.glob("*.png"))
    assert "cost.png" in pngs and "heat_map.png" in pngs and len(pngs) == 4

    sim = tmp_path / "sim.csv"
    assert main(["simulate", "--model", str(model), str(held_out), "--out", str(sim)]) == 0
    printed = capsys.readouterr().out
    assert "RMS" in printed and "peak" in printed
    with sim.open() as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["time_s", "cht_meas_c", "cht_model_c", "error_c"]
    errors = np.array([float(r["error_c"]) for r in rows])
    model_c = np.array([float(r["cht_model_c"]) for r in rows])
    meas_c = np.array([float(r["cht_meas_c"]) for r in rows])
    np.testing.assert_allclose(errors, meas_c - model_c, atol=1e-9)  # the one residual sign
    assert math.sqrt(np.mean(errors**2)) == pytest.approx(
        flight_errors(params, _flight(2, (70, 40, 95, 50, 80, 30))).rms_c
    )


def test_identify_without_throttle_uses_fuel_flow_and_a_data_grid(tmp_path, capsys):
    path = tmp_path / "no_throttle.csv"
    write_csv(_flight(4, (30, 80, 50, 95), with_throttle=False), path)
    model = tmp_path / "m.yaml"
    argv = ["identify", str(path), "--out", str(model), "--grid", "3x3", "--particles", "8", "--iterations", "4"]
    assert main([*argv, "--quiet", "--no-polish"]) == 0
    params = load_model(model)
    assert params.heat_axes == ("fuel_flow_lph", "rpm")
    assert params.heat_map.shape == (3, 3)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--grid", "4by4"], "--grid"),
        (["--grid", "2x0"], "--grid"),
        (["--heat-axes", "rpm"], "--heat-axes"),
        (["--heat-axes", "egt_c,rpm"], "egt_c"),
        (["--particles", "1"], "particles"),
        (["--free", "c_w,volume"], "volume"),
        (["--effects", "turbo_cooling"], "turbo_cooling"),
        (["--cht-limit", "900"], "--cht-limit"),
    ],
)
def test_identify_bad_options_exit_2(flights, tmp_path, capsys, extra, message):
    train, _ = flights
    assert main(["identify", str(train), "--out", str(tmp_path / "m.yaml"), "--quiet", *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not (tmp_path / "m.yaml").exists()


def test_bad_csv_exits_2(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,rpm,cht_c\n0,abc,100\n1,5000,101\n")
    assert main(["identify", str(bad), "--out", str(tmp_path / "m.yaml"), "--quiet"]) == 2
    assert "bad.csv" in capsys.readouterr().err
    assert main(["simulate", str(bad), "--out", str(tmp_path / "s.csv")]) == 2
    assert "bad.csv" in capsys.readouterr().err
    assert (
        main(["simulate", "--model", str(tmp_path / "missing.yaml"), str(bad), "--out", str(tmp_path / "s.csv")]) == 2
    )


def test_unwritable_outputs_exit_2_before_identifying(flights, tmp_path, capsys):
    train, _ = flights
    assert main(["identify", str(train), "--out", str(tmp_path / "no" / "m.yaml"), "--quiet"]) == 2
    assert "no such folder" in capsys.readouterr().err
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main(["identify", str(train), "--out", str(tmp_path / "m.yaml"), "--plots", str(blocker), "--quiet"]) == 2
    assert "--plots" in capsys.readouterr().err


def test_two_flights_make_one_model_with_effects_lofo_limit_and_bounds(flights, tmp_path, capsys):
    """Several flights, named terms, the user's CHT limit: per-flight table with held-out rows, the
    limit in model.yaml and a warning when the data exceed it, the bound report in the header."""
    train, held_out = flights
    model = tmp_path / "model.yaml"
    argv = ["identify", str(train), str(held_out), "--out", str(model), "--particles", "12", "--iterations", "8"]
    argv += ["--effects=-altitude_factor,sensor_lag", "--cht-limit", "90", "--quiet", "--plots", str(tmp_path / "p")]
    assert main(argv) == 0  # --plots with the LOFO rows in the table: one plot per flight (it raised before)
    assert sorted(p.name for p in (tmp_path / "p").glob("cht_*.png")) == [
        "cht_train_1_train.png",
        "cht_train_2_held_out.png",
    ]
    captured = capsys.readouterr()
    assert captured.out.count("held out (LOFO)") == 2 and "leave-one-flight-out held-out RMS" in captured.out
    assert "measured CHT reaches" in captured.err and "above the limit 90" in captured.err
    params = load_model(model)
    assert params.cht_limit_c == 90.0 and params.a == 0.0 and params.b == 0.0
    assert params.effects.sensor_lag is not None
    header = [line for line in model.read_text().splitlines() if line.startswith("#")]
    assert any("bound" in line for line in header)  # either AT BOUND lines or "no parameter ended ..."
    assert any("held out (LOFO)" in line for line in header) and any("warning:" in line for line in header)


def test_identify_refuses_a_flight_given_twice(tmp_path, capsys):
    """A training flight also given as --validate (or twice) is refused in one line, exit 2."""
    from ecu_monitor.cli import main

    flight = tmp_path / "a.csv"
    flight.write_text("time_s,cht_c\n0,20\n1,20\n", encoding="utf-8")
    code = main(["identify", str(flight), "--validate", str(flight), "--out", str(tmp_path / "m.yaml")])
    err = capsys.readouterr().err
    assert code == 2
    assert "given twice" in err
    assert not (tmp_path / "m.yaml").exists()


def test_identify_every_cylinder_writes_one_model_each(tmp_path, capsys):
    """--cylinder all: one model per cylinder column, each fitted on its own cylinder's CHT; --cylinder 2
    fits cylinder 2 alone; a cylinder the flight lacks exits 2."""
    log = _flight(4, (30, 80, 50, 95))
    hot = log.with_columns(cht1_c=log["cht_c"], cht2_c=log["cht_c"] * 1.1 + 5.0)
    path = tmp_path / "two_cylinders.csv"
    write_csv(hot, path)
    model = tmp_path / "m.yaml"
    argv = [
        "identify",
        str(path),
        "--out",
        str(model),
        "--particles",
        "8",
        "--iterations",
        "4",
        "--quiet",
        "--no-polish",
    ]
    assert main([*argv, "--cylinder", "all"]) == 0
    out = capsys.readouterr().out
    assert "== cylinder 2 of 2 ==" in out and f"cylinders: {{models: [{tmp_path / 'm_cyl1.yaml'}," in out
    one, two = load_model(tmp_path / "m_cyl1.yaml"), load_model(tmp_path / "m_cyl2.yaml")
    assert flight_errors(two, hot.with_columns(cht_c=hot["cht2_c"])).rms_c < flight_errors(one, hot.with_columns(
        cht_c=hot["cht2_c"])).rms_c  # fmt: skip
    assert main([*argv, "--cylinder", "3"]) == 2
    assert "cylinder 3 chosen for cht_c" in capsys.readouterr().err
    # a probe dead in every row is dropped on import (cht1_c, cht3_c): the config hint says what is missing
    gap = tmp_path / "dead_probe.csv"
    write_csv(log.with_columns(cht1_c=log["cht_c"], cht3_c=log["cht_c"] + 4.0), gap)
    assert main([*argv[:1], str(gap), *argv[2:], "--cylinder", "all"]) == 0
    out = capsys.readouterr().out
    assert "== cylinder 3 of 3 ==" in out and "no model for cylinder(s) 2:" in out


def test_a_manifold_pressure_heat_axis_identifies_and_replays_with_the_config_that_maps_it(tmp_path, capsys):
    """A constant-speed engine's log (the PA-44's) carries manifold pressure: identify takes it as a heat-map
    axis with no warning; replay names the shipped config that maps it (exit 2), and replays with it."""
    log = _flight(5, (30, 80, 50, 95))
    path = tmp_path / "map.csv"
    write_csv(log.with_columns(manifold_pressure_kpa=40.0 + 0.6 * np.asarray(log["throttle_pct"])), path)
    model = tmp_path / "m.yaml"
    argv = ["identify", str(path), "--out", str(model), "--heat-axes", "manifold_pressure_kpa,rpm", "--grid", "3x3"]
    assert main([*argv, "--particles", "8", "--iterations", "4", "--quiet", "--no-polish"]) == 0
    assert "not an input the service reads" not in capsys.readouterr().err
    assert main(["replay", str(path), "--model", str(model), "--out", str(tmp_path / "h.csv")]) == 2
    [line] = capsys.readouterr().err.strip().splitlines()
    assert "missing manifold_pressure_kpa" in line and "manifold.yaml" in line
    out = tmp_path / "h.csv"
    assert main(["replay", str(path), "--model", str(model), "--config", "manifold.yaml", "--out", str(out)]) == 0
    assert out.read_text().count("\n") > 1000
