"""config.py: the shipped configs load; every error path is a ConfigError naming file and key."""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from ecu_monitor.config import load_config
from ecu_monitor.errors import ConfigError
from tests.helpers import REPO

EXAMPLE = REPO / "ecu_monitor" / "data" / "configs" / "example.yaml"
RUSEFI = REPO / "ecu_monitor" / "data" / "configs" / "rusefi.yaml"


def _base() -> dict[str, Any]:
    data = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))
    data["dbc"] = [str(REPO / "ecu_monitor" / "data" / "dbc" / "engine.dbc")]
    data["health_dbc"] = str(REPO / "ecu_monitor" / "data" / "dbc" / "health.dbc")
    return data


def test_example_config_loads_with_every_input_and_default_rates() -> None:
    config = load_config(EXAMPLE)
    assert config.engine_serial == "UAV-ENG-0001"
    assert set(config.input_names) == {"rpm", "throttle_pct", "fuel_flow_lph", "cht_c", "oat_c", "altitude_m",
                                       "airspeed_mps"}  # fmt: skip
    assert config.input("rpm").message == "ECU_Fast" and config.input("rpm").stale_after_s == 0.5
    assert {h.message: h.rate_hz for h in config.health} == {"Health_Status": 10, "Health_Isolation": 2,
                                                             "Health_Diag": 1}  # fmt: skip
    assert config.dbc_paths == (REPO / "ecu_monitor" / "data" / "dbc" / "engine.dbc",)  # a shipped name
    assert config.estimator_name == "cbekf-au" and config.estimator.dt_s == 0.02
    assert config.sensor_fault.open_values == (3,) and config.sensor_fault.status_signal == "EcuStatus"
    assert config.bus["interface"] == "virtual" and config.load_params().heat_axes == ("throttle_pct", "rpm")


def test_rusefi_config_maps_a_third_party_dbc() -> None:
    config = load_config(RUSEFI)
    assert config.input("cht_c").signal == "AUX1Temp" and config.input("fuel_flow_lph").unit == "g_per_s_gasoline"
    assert config.input("altitude_m").message == "AirData"


def _set(path: str, value: Any) -> Callable[[dict[str, Any]], None]:
    keys = path.split(".")

    def edit(data: dict[str, Any]) -> None:
        node = data
        for key in keys[:-1]:
            node = node[key]
        node[keys[-1]] = value

    return edit


def _drop(path: str) -> Callable[[dict[str, Any]], None]:
    keys = path.split(".")

    def edit(data: dict[str, Any]) -> None:
        node = data
        for key in keys[:-1]:
            node = node[key]
        del node[keys[-1]]

    return edit


ERRORS: list[tuple[str, Callable[[dict[str, Any]], None], str]] = [
    ("missing key", _drop("engine.serial"), "engine.serial: missing"),
    ("missing section", _drop("inputs"), "inputs: missing"),
    ("missing required input", _drop("inputs.oat_c"), "inputs.oat_c: missing"),
    ("unknown top key", _set("colour", "red"), "unknown key 'colour'"),
    (
        "unknown input",
        _set("inputs.coolant_temp_c", {"signal": "ECU_Slow.CHT", "unit": "degC", "stale_after_s": 1}),
        "unknown key 'coolant_temp_c'",
    ),
    ("wrong type", _set("inputs.rpm.stale_after_s", "fast"), "inputs.rpm.stale_after_s: expected a number"),
    ("not positive", _set("inputs.rpm.stale_after_s", 0), "inputs.rpm.stale_after_s: expected a number > 0"),
    ("wrong type bool", _set("stale_predict_limit_s", True), "stale_predict_limit_s: expected a number"),
    ("section not a mapping", _set("bus", ["virtual"]), "bus: expected a mapping"),
    (
        "unknown signal",
        _set("inputs.rpm.signal", "ECU_Fast.Nope"),
        "inputs.rpm.signal: message 'ECU_Fast' has no signal 'Nope'",
    ),
    (
        "unknown message",
        _set("inputs.rpm.signal", "ECU_Turbo.EngineSpeed"),
        "inputs.rpm.signal: no message 'ECU_Turbo'",
    ),
    ("bad signal ref", _set("inputs.rpm.signal", "EngineSpeed"), "inputs.rpm.signal: expected 'Message.Signal'"),
    ("unknown unit", _set("inputs.rpm.unit", "rps"), "inputs.rpm.unit: unknown unit 'rps'"),
    ("unit of wrong quantity", _set("inputs.cht_c.unit", "rpm"), "inputs.cht_c.unit: unit 'rpm' is not a temperature"),
    ("missing dbc file", _set("dbc", ["/nonexistent/engine.dbc"]), "dbc[0]: /nonexistent/engine.dbc: no such DBC file"),
    ("empty dbc list", _set("dbc", []), "dbc: expected a DBC file path or a non-empty list"),
    (
        "bad health message",
        _set("health.Health_Extra", {"rate_hz": 1}),
        "health.Health_Extra: unknown key 'Health_Extra'",
    ),
    ("rate off the step", _set("health.Health_Isolation.rate_hz", 3), "health.Health_Isolation.rate_hz: period"),
    ("estimator name", _set("estimator.name", "kalman9000"), "estimator.name: unknown estimator 'kalman9000'"),
    ("estimator field", _set("estimator.gain", 3), "estimator.gain: unknown key 'gain'"),
    ("estimator value", _set("estimator.dt_s", -1), "estimator.dt_s: expected a positive number"),
    ("model file", _set("model", "missing-model.yaml"), "model: no such model file"),
    ("backoff", _set("reopen_backoff_s.max", 0.1), "reopen_backoff_s.max: expected a number >= 0.5"),
    ("status without values", _drop("sensor_fault.open_values"), "sensor_fault.open_values: missing"),
    ("sensor range", _set("sensor_fault.max_c", -50), "sensor_fault.max_c: expected a number > -40"),
    ("status signal", _set("sensor_fault.status_signal", "ECU_Slow.Status"), "sensor_fault.status_signal: message"),
    ("calibrated_for", _set("detector.calibrated_for", "model.yaml"), "detector.calibrated_for: expected 16 hex"),
]


def test_detector_calibrated_for_is_kept(tmp_path: Path) -> None:
    data = _base()
    data["detector"] = {"calibrated_for": "0123456789abcdef"}  # in place of the shipped detector file
    path = tmp_path / "calibrated.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    assert load_config(path).detector_calibrated_for == "0123456789abcdef"
    assert load_config(RUSEFI).detector_calibrated_for is None  # example.yaml carries the shipped mark


@pytest.mark.parametrize(("case", "edit", "expected"), ERRORS, ids=[e[0] for e in ERRORS])
def test_every_error_names_file_and_key(tmp_path: Path, case: str, edit: Callable[..., None], expected: str) -> None:
    data = copy.deepcopy(_base())
    edit(data)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert message.startswith(f"{path}: "), message
    assert expected in message, message
    assert "\n" not in message


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (None, "no such config file"),
        (b"engine: {serial: [unclosed\n", "not valid YAML at line"),
        (b"- just\n- a list\n", "top level: expected a mapping, got a list"),
        (b"\xff\xfe\x00garbage", "not a config file (not UTF-8 text"),
        (b"", "top level: expected a mapping, got nothing"),
        (
            b"time_s,rpm,cht_c\n" + b"1.0,2400,180\n" * 5000,
            "got str 'time_s,rpm,cht_c 1.0,2400,180 1.0,2400,180 1.0,24... (",
        ),
    ],
    ids=["missing", "bad-yaml", "list", "binary", "empty", "a-flight-csv"],
)
def test_bad_files(tmp_path: Path, content: bytes | None, expected: str) -> None:
    path = tmp_path / "bad.yaml"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value).startswith(str(path)) and expected in str(info.value)
    assert len(str(info.value)) < len(str(path)) + 150  # one short line, not the file (a CSV given as --config)


def test_relative_paths_resolve_against_the_config_file(tmp_path: Path) -> None:
    data = _base()
    (tmp_path / "dbc").mkdir()
    (tmp_path / "dbc" / "mine.dbc").write_bytes((REPO / "ecu_monitor" / "data" / "dbc" / "engine.dbc").read_bytes())
    data["dbc"] = "dbc/mine.dbc"
    data["state_dir"] = "state"
    path = tmp_path / "svc.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    config = load_config(path)
    assert config.dbc_paths == (tmp_path / "dbc" / "mine.dbc",) and config.state_dir == tmp_path / "state"


def test_broken_model_file_names_config_and_key(tmp_path: Path) -> None:
    (tmp_path / "model.yaml").write_text("c_w: -3\n", encoding="utf-8")
    data = _base()
    data["model"] = "model.yaml"
    path = tmp_path / "svc.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    config = load_config(path)
    with pytest.raises(ConfigError, match=r"svc\.yaml: model: .*model\.yaml: c_w"):
        config.load_params()


def test_shipped_example_threshold_is_marked_for_the_model_it_names():
    """example.yaml and multicast.yaml carry the shipped threshold calibrated for paper_table_a1: their
    calibrated_for is that model's fingerprint, so replay does not warn on them (and would, rightly,
    once the preset changed without a recalibration)."""
    from ecu_monitor.offline.calibration import model_fingerprint
    from ecu_monitor.shipped import shipped_file

    for name in ("example.yaml", "multicast.yaml"):
        config = load_config(shipped_file("config", name))
        assert config.detector_calibrated_for == model_fingerprint(config.load_params()), name


#: The shipped configs that run the virtual ECU's engine: one detector file, the same detector and reference.
VIRTUAL_ENGINE_CONFIGS = ("example.yaml", "dronecan.yaml", "mavlink.yaml", "multicast.yaml", "manifold.yaml")


@pytest.mark.parametrize("name", VIRTUAL_ENGINE_CONFIGS)
def test_the_virtual_engines_configs_share_one_detector_file(name: str) -> None:
    from ecu_monitor.offline.calibration import model_fingerprint
    from ecu_monitor.shipped import shipped_file

    shared = yaml.safe_load(shipped_file("detector", "virtual_ecu.yaml").read_text(encoding="utf-8"))["detector"]
    config = load_config(shipped_file("config", name))
    assert config.detector.reference_on and list(config.detector.nominal_mean) == shared["nominal_mean"]
    assert config.detector.nominal_threshold == shared["nominal_threshold"]
    assert config.detector_calibrated_for == shared["calibrated_for"] == model_fingerprint(config.load_params())
    raw = yaml.safe_load(shipped_file("config", name).read_text(encoding="utf-8"))["detector"]
    assert raw["file"] == "virtual_ecu.yaml" and not set(raw) & set(shared)  # named, not copied


def test_a_detector_file_beside_the_config_and_its_errors(tmp_path: Path) -> None:
    data = _base()
    data["detector"] = {"symptom": "estimator", "file": "mine.yaml"}
    (tmp_path / "svc.yaml").write_text(yaml.safe_dump(data), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"svc\.yaml: detector\.file: .*mine\.yaml: no such detector file"):
        load_config(tmp_path / "svc.yaml")
    mine = tmp_path / "mine.yaml"
    mine.write_text(yaml.safe_dump({"detector": {"threshold": 3.5, "calibrated_for": "0123456789abcdef"}}), "utf-8")
    config = load_config(tmp_path / "svc.yaml")
    assert config.detector.threshold == 3.5 and config.detector_calibrated_for == "0123456789abcdef"
    mine.write_text(yaml.safe_dump({"detector": {"treshold": 3.5}}), "utf-8")
    with pytest.raises(ConfigError, match=r"mine\.yaml: detector\.treshold: unknown key 'treshold'"):
        load_config(tmp_path / "svc.yaml")
    mine.write_text(yaml.safe_dump({"detector": {"threshold": 3.5}, "model": "x"}), "utf-8")
    with pytest.raises(ConfigError, match=r"mine\.yaml: model: unknown key"):
        load_config(tmp_path / "svc.yaml")
    mine.write_text(yaml.safe_dump({"detector": {"symptom": "isolation"}}), "utf-8")
    with pytest.raises(ConfigError, match=r"svc\.yaml: detector\.symptom: given here and in the detector file"):
        load_config(tmp_path / "svc.yaml")


# --- the schema (msgspec): its errors, in our one-line form, and what it gives back ----------------------

SCHEMA_ERRORS: list[tuple[str, Callable[[dict[str, Any]], None], str]] = [
    (
        "unknown key",
        _set("engine.colour", "red"),
        "engine.colour: unknown key 'colour' (known: serial, overhaul_hours, tbo_hours)",
    ),
    (
        "unknown key of a detector entry",
        _set("cylinders", {"cross_detector": {"treshold": 1.0}}),
        "cylinders.cross_detector.treshold: unknown key 'treshold' (known: calibrated_for, threshold, reference,"
        " warmup_s, suspect_fraction, block_s, baseline_s, baseline_delay_s, baseline_freeze, scale_s, scale_floor,"
        " nominal_threshold, nominal_mean, nominal_spread, start_fit_mean, start_fit_spread)",
    ),
    ("wrong type", _set("detector.threshold", "abc"), "detector.threshold: expected a number, got str 'abc'"),
    ("wrong type in a list", _set("dbc", ["engine.dbc", 3]), "dbc[1]: expected a file path, got int 3"),
    ("wrong type of section", _set("sensor_fault", None), "sensor_fault: expected a mapping, got nothing"),
    (
        "not finite",
        _set("no_frames_warning_s", float("inf")),
        "no_frames_warning_s: expected a number > 0, got float inf",
    ),
    ("out of range", _set("stale_predict_limit_s", -1), "stale_predict_limit_s: expected a number >= 0, got int -1"),
    ("not one of", _set("protocol", "j1939"), "protocol: expected one of dbc, dronecan, mavlink, got str 'j1939'"),
    ("key not a string", _set("bus", {"interface": "virtual", "channel": "x", 3: 1}), "bus: keys must be strings"),
    ("missing required key", _drop("engine.serial"), "engine.serial: missing"),
    ("missing required key of an entry", _drop("inputs.rpm.stale_after_s"), "inputs.rpm.stale_after_s: missing"),
    ("missing bus key", _drop("bus.channel"), "bus.channel: missing"),
]


@pytest.mark.parametrize(("case", "edit", "expected"), SCHEMA_ERRORS, ids=[e[0] for e in SCHEMA_ERRORS])
def test_schema_errors_are_one_line_naming_file_and_key(
    tmp_path: Path, case: str, edit: Callable[..., None], expected: str
) -> None:
    data = _base()
    edit(data)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value) == f"{path}: {expected}"


def test_a_default_is_the_config_files_and_the_daemon_takes_it(tmp_path: Path) -> None:
    """Keys left out take ConfigFile's defaults, and DaemonSettings' defaults are those same values."""
    from ecu_monitor.commands.run import daemon_settings
    from ecu_monitor.config import config_default
    from ecu_monitor.runtime.daemon import DaemonSettings

    data = _base()
    for key in ("reopen_backoff_s", "no_frames_warning_s", "stale_predict_limit_s"):
        data.pop(key, None)
    path = tmp_path / "defaults.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    config = load_config(path)
    assert config.no_frames_warning_s == config_default("no_frames_warning_s") == 10.0
    assert config.stale_predict_limit_s == config_default("stale_predict_limit_s")
    assert daemon_settings(config, None) == DaemonSettings()


def _calibration(threshold: float) -> Any:
    from ecu_monitor.estimation.detection import DetectorSettings, ThresholdCalibration
    from ecu_monitor.offline.calibration import CalibrationResult

    c = ThresholdCalibration(threshold, threshold, threshold, 1.0, 0.1, 0, 1.0)
    return CalibrationResult(calibration=c, method="test", flights=(), current=DetectorSettings(baseline_s=300.0))


def test_a_config_written_back_by_calibrate_loads_to_the_same_config(tmp_path: Path) -> None:
    """``calibrate --write-config`` re-emits the YAML (calibration.config_copy_yaml): read back from another
    folder it is the same configuration, relative paths resolved as before, with the new detector."""
    from ecu_monitor.offline.calibration import config_copy_yaml

    data = _base()
    (tmp_path / "dbc").mkdir()
    (tmp_path / "dbc" / "mine.dbc").write_bytes((REPO / "ecu_monitor" / "data" / "dbc" / "engine.dbc").read_bytes())
    data.update(dbc="dbc/mine.dbc", health_dbc="health.dbc", state_dir="state")
    source = tmp_path / "svc.yaml"
    source.write_text(yaml.safe_dump(data), encoding="utf-8")
    original = load_config(source)
    (tmp_path / "out").mkdir()
    copy_path = tmp_path / "out" / "copy.yaml"
    text = config_copy_yaml(source, copy_path, _calibration(5.25), 1.0, ["f.csv"], "0123456789abcdef")
    copy_path.write_text(text, "utf-8")
    written = load_config(copy_path)
    assert written.detector.threshold == 5.25 and written.detector.baseline_s == 300.0
    assert written.detector_calibrated_for == "0123456789abcdef"
    # the same files, named from the copy's folder (out/../dbc/mine.dbc)
    assert [p.resolve() for p in written.dbc_paths] == list(original.dbc_paths) == [tmp_path / "dbc" / "mine.dbc"]
    assert written.state_dir.resolve() == original.state_dir == tmp_path / "state"
    same = original.replace(
        source=copy_path,
        detector=written.detector,
        detector_calibrated_for="0123456789abcdef",
        dbc_paths=written.dbc_paths,
        state_dir=written.state_dir,
    )
    assert written == same


def test_a_four_cylinder_config_written_back_keeps_its_cylinders(tmp_path: Path) -> None:
    from ecu_monitor.offline.calibration import config_copy_yaml

    source = REPO / "ecu_monitor" / "data" / "configs" / "four_cylinders.yaml"
    original = load_config(source)
    marks = [f"{n:016x}" for n in range(4)]
    per_cylinder = [(_calibration(2.0 + n), marks[n]) for n in range(4)]
    cross = [(None, ""), *[(_calibration(1.5), marks[n]) for n in range(1, 4)]]
    copy_path = tmp_path / "copy.yaml"
    text = config_copy_yaml(
        source, copy_path, per_cylinder[0][0], 1.0, ["f.csv"], marks[0], cylinders=per_cylinder, cross=cross
    )
    copy_path.write_text(text, encoding="utf-8")
    written = load_config(copy_path)
    assert [d.threshold for d in written.cylinder_detectors] == [2.0, 3.0, 4.0, 5.0]
    assert written.cylinder_calibrated_for == tuple(marks)
    assert written.cross_detectors[0] is None and [d.threshold for d in written.cross_detectors[1:]] == [1.5] * 3
    assert written.cross_calibrated_for == (None, *marks[1:])
    assert written.detector == original.detector and written.spread_limit_c == original.spread_limit_c
    assert written.inputs == original.inputs and written.health == original.health
