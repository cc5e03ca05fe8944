"""``ecu-monitor gap`` end to end on small CSVs, and its one-line errors (exit 2)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ecu_monitor.cli import main
from ecu_monitor.flightlog import write_csv
from ecu_monitor.model import load_model, paper_table_a1, save_model
from ecu_monitor.research.blind import blind_case
from virtual_bus.plant import fly
from virtual_bus.random_missions import random_mission

pytestmark = pytest.mark.slow  # over a minute in all: scheduled first (tests/conftest.py)

SEED = 1
DURATION_S = 1500.0


@pytest.fixture(scope="module")
def flights(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Train/test CSVs of a blind sensor-lag case, a second train and a second test flight of the same
    truth on other missions, and the case's (perturbed) nominal model."""
    case = blind_case(3, SEED, DURATION_S)
    root = tmp_path_factory.mktemp("gapcli")
    write_csv(case.train, root / "train.csv")
    write_csv(case.test, root / "test.csv")
    truth = paper_table_a1().replace(effects=case.effects)
    for name, mission in (("train2", 11), ("test2", 12)):
        log = fly(random_mission(mission, DURATION_S), truth, seed=mission, record_dt_s=1.0)
        write_csv(log, root / f"{name}.csv")
    save_model(case.nominal, root / "nominal.yaml")
    (root / "bad.yaml").write_text("c_w: -3\n", encoding="utf-8")
    return {
        "train": root / "train.csv",
        "test": root / "test.csv",
        "train2": root / "train2.csv",
        "test2": root / "test2.csv",
        "model": root / "nominal.yaml",
        "bad": root / "bad.yaml",
        "root": root,
    }


def test_gap_cli_many_flights_writes_gap_json_report_and_model(
    flights: dict[str, Path], capsys: pytest.CaptureFixture
) -> None:
    out = flights["root"] / "out"
    code = main(
        [
            "gap",
            "--model",
            str(flights["model"]),
            "--train",
            str(flights["train"]),
            str(flights["train2"]),
            "--test",
            str(flights["test"]),
            str(flights["test2"]),
            "--out",
            str(out),
        ]
    )
    assert code == 0
    captured = capsys.readouterr()
    assert "sensor_lag" in captured.out
    refits = [line for line in captured.err.splitlines() if line.startswith("gap: refit")]
    assert any("sensor_lag" in line for line in refits)  # progress on stderr
    doc = json.loads((out / "gap.json").read_text())
    assert doc["flights"]["train"] == [str(flights["train"]), str(flights["train2"])]
    assert doc["flights"]["test"] == [str(flights["test"]), str(flights["test2"])]
    verdict = doc["verdict"]
    assert verdict["effect"] == "sensor_lag"
    assert [e["test_rms_c"] for e in doc["effects"]] == sorted(e["test_rms_c"] for e in doc["effects"])
    # pooled = over both test flights; per flight beside it, each better than the baseline
    rows = doc["per_flight"]
    assert [r["flight"] for r in rows] == doc["flights"]["test"]
    pooled_sq = sum(r["baseline_rms_c"] ** 2 * r["samples"] for r in rows) / sum(r["samples"] for r in rows)
    assert doc["baseline"]["test_rms_c"] == pytest.approx(pooled_sq**0.5, rel=1e-9)
    assert all(r["test_rms_c"] < r["baseline_rms_c"] for r in rows)
    assert verdict["flights_confirming"] == doc["flights"]["test"]
    assert set(verdict["segments_holding"]) <= {"ground", "climb", "cruise", "descent"}
    for r in rows:
        assert {e["id"] for e in r["effects"]} == {e["id"] for e in doc["effects"]}
    model = load_model(out / "model.yaml")
    assert model.effects.sensor_lag is not None
    report = (out / "report.md").read_text()
    assert report.startswith("# Sim-to-real gap diagnosis") and "## Per test flight" in report
    for name in ("residual_time.png", "residual_inputs.png", "spectrum.png", "before_after.png"):
        assert (out / name).stat().st_size > 10_000


def test_gap_cli_leave_one_out_pools_every_held_out_flight(flights: dict[str, Path]) -> None:
    out = flights["root"] / "loo"
    paths = [str(flights[name]) for name in ("train", "train2", "test")]
    args = ["gap", "--model", str(flights["model"]), "--train", *paths, "--leave-one-out"]
    assert main([*args, "--candidates", "sensor_lag,density_cooling", "--out", str(out)]) == 0
    doc = json.loads((out / "gap.json").read_text())
    assert doc["flights"]["cross_validation"] == "leave-one-flight-out"
    assert doc["flights"]["test"] == paths and [r["flight"] for r in doc["per_flight"]] == paths
    assert doc["verdict"]["effect"] == "sensor_lag"
    assert all(r["test_rms_c"] < r["control_rms_c"] for r in doc["per_flight"])
    # model.yaml: the winner refitted on all three flights
    assert load_model(out / "model.yaml").effects.sensor_lag is not None


def test_gap_cli_checks_the_output_before_the_work(flights: dict[str, Path], capsys: pytest.CaptureFixture) -> None:
    blocker = flights["root"] / "a-file"
    blocker.write_text("not a directory\n", encoding="utf-8")
    args = ["gap", "--model", str(flights["model"]), "--train", str(flights["train"]), "--test", str(flights["test"])]
    assert main([*args, "--out", str(blocker / "out")]) == 2
    err = capsys.readouterr().err
    assert "cannot create the directory" in err and "refit" not in err and "Traceback" not in err


def test_gap_cli_split_at_runs_on_one_flight(flights: dict[str, Path]) -> None:
    out = flights["root"] / "split"
    args = ["gap", "--model", str(flights["model"]), "--train", str(flights["test"]), "--split-at", "700"]
    assert main([*args, "--candidates", "sensor_lag", "--out", str(out)]) == 0
    doc = json.loads((out / "gap.json").read_text())
    assert [e["id"] for e in doc["effects"]] == ["sensor_lag"]
    assert main([*args, "--test-first", "--candidates", "sensor_lag", "--out", str(out / "reverse")]) == 0
    reverse = json.loads((out / "reverse" / "gap.json").read_text())
    assert reverse["baseline"]["test_rms_c"] != doc["baseline"]["test_rms_c"]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--test", "missing.csv"], "missing.csv"),
        ([], "--test is required"),
        (["--test", "{test}", "--candidates", "warp_drive"], "warp_drive"),
        (["--test", "{test}", "--model", "{bad}"], "c_w"),
        (["--test", "{test}", "--heat-axes", "rpm"], "--heat-axes"),
        (["--split-at", "5"], "--split-at"),
        (["--test", "{test}", "--test-first"], "--test-first"),
        (["--test", "{train}"], "given twice"),
        (["--test", "{test}", "--split-at", "700"], "--split-at"),
        (["--leave-one-out"], "at least two"),
        (["--test", "{test}", "--leave-one-out"], "--leave-one-out"),
        (["--test", "{test}", "--choose-on-train"], "at least three --train"),
    ],
)
def test_gap_cli_bad_input_exits_2(
    flights: dict[str, Path], capsys: pytest.CaptureFixture, extra: list[str], message: str
) -> None:
    args = ["gap", "--train", str(flights["train"]), "--out", str(flights["root"] / "bad-out")]
    if "--model" not in extra:
        args += ["--model", str(flights["model"])]
    filled = [a.format(test=flights["test"], train=flights["train"], bad=flights["bad"]) for a in extra]
    assert main(args + filled) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and "Traceback" not in err[0]


def test_gap_cli_without_model_identifies_then_reidentifies(flights: dict[str, Path]) -> None:
    out = flights["root"] / "no-model"
    args = ["gap", "--train", str(flights["train"]), "--test", str(flights["test"]), "--out", str(out)]
    assert main([*args, "--candidates", "sensor_lag,airspeed_cooling"]) == 0
    doc = json.loads((out / "gap.json").read_text())
    assert doc["settings"]["refit_mode"] == "reidentify"
    # the true effect ranks first and its held-out gain is significant; whether it is also material
    # (>= 0.3 degC absolute) depends on how much of it the identified nominal model already explains
    best = doc["effects"][0]
    assert best["id"] == "sensor_lag" and best["bootstrap_significant"] and best["shrink_pct"] >= 20.0
    if doc["verdict"]["effect"] == "sensor_lag":
        assert load_model(out / "model.yaml").effects.sensor_lag is not None


def test_gap_cli_without_model_takes_fuel_flow_axes_when_no_throttle_is_logged(
    flights: dict[str, Path], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """A G1000-like log (fuel flow, no throttle) identifies on fuel_flow_lph,rpm as ``identify`` does,
    instead of failing on the missing throttle column."""
    import csv

    from ecu_monitor.commands import gap as gap_command
    from ecu_monitor.errors import UserInputError

    paths = []
    for name in ("train", "test"):
        with flights[name].open(newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
        path = flights["root"] / f"{name}-no-throttle.csv"
        with path.open("w", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, [c for c in rows[0] if c != "throttle_pct"], extrasaction="ignore")
            writer.writeheader()
            writer.writerows(rows)
        paths.append(str(path))
    seen: list[tuple[str, str]] = []

    def identify_stub(logs: object, axes: tuple[str, str], label: str) -> None:
        seen.append(axes)
        raise UserInputError("stub: stop before the PSO")

    monkeypatch.setattr(gap_command, "_identify", identify_stub)
    args = ["gap", "--train", paths[0], "--test", paths[1], "--out", str(flights["root"] / "no-throttle")]
    assert main(args) == 2
    assert seen == [("fuel_flow_lph", "rpm")]
    assert "heat map on fuel_flow_lph,rpm" in capsys.readouterr().err


def test_gap_cli_choose_on_train_uses_three_train_flights_not_the_test(flights: dict[str, Path]) -> None:
    """Issue 28: --choose-on-train with three train flights chooses the verdict by a leave-one-flight-out over them; the
    test flight only measures it (one refit of the control and of the chosen effect are scored on it)."""
    out = flights["root"] / "chosen"
    trains = [str(flights[name]) for name in ("train", "train2", "test2")]
    args = ["gap", "--model", str(flights["model"]), "--train", *trains, "--test", str(flights["test"])]
    assert main([*args, "--choose-on-train", "--candidates", "sensor_lag,density_cooling", "--out", str(out)]) == 0
    doc = json.loads((out / "gap.json").read_text())
    chosen = doc["chosen_by"]
    assert chosen["rule"] == "leave-one-flight-out over the 3 train flights" and chosen["label"] == "sensor_lag"
    # every candidate refitted in the folds, or kept out of them by the leave-one-out's screen
    screened = chosen["screen"]["not_refitted"]
    assert {e["id"] for e in chosen["effects"]} | set(screened) >= {"sensor_lag", "density_cooling"}
    assert doc["verdict"]["effect"] == "sensor_lag" and [e["id"] for e in doc["effects"]] == ["sensor_lag"]
    assert doc["per_flight"][0]["test_rms_c"] < doc["per_flight"][0]["control_rms_c"]
    assert "take no part in it" in (out / "report.md").read_text()
