"""Property: random flight CSVs, model files and CAN logs fed to `import`, `simulate`, `replay` and
`calibrate` give exit 0 or 2, never a traceback or an internal error (exit 1), and never leave an
output file half-written: after exit 2 the output is absent, after exit 0 it is a whole CSV/YAML.

The suite runs a few examples per entry point (``ECU_FUZZ_EXAMPLES``, default 3); the full search is
run by hand: ``ECU_FUZZ_EXAMPLES=500 .venv/bin/python -m pytest -q tests/cli/test_bad_input_fuzz.py``.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import pytest
import yaml

from ecu_monitor.cli import main
from ecu_monitor.model import paper_table_a1

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from tests.helpers import REPO  # noqa: E402
from tests.helpers.fuzz import EXAMPLES, check_cli_outcome, fuzz_settings  # noqa: E402

FUZZ = fuzz_settings(EXAMPLES)
#: row time steps for the commands that replay a flight at 10 Hz (a long hole is H2's replay row)
REPLAY_STEPS = (0.1, 1.0, 0.0, -1.0, 30.0)
COLUMNS = ("time_s", "throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c", "cht_c")

_cell = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=32).map(repr),
    st.sampled_from(["", "nan", "abc", "1e999", "-0", "  ", '"', "1,2"]),
    st.integers(-100000, 100000).map(str),
)


def _plausible_row(t: float) -> list[str]:
    return [f"{t:.1f}", "60", "5500", "1000", "40", "15", "150"]


@st.composite
def flight_csvs(draw: st.DrawFn, steps: tuple[float, ...] = (0.1, 1.0, 0.0, -1.0, 5000.0)) -> bytes:
    """A canonical CSV that is mostly right: plausible rows, some cells, columns or rows spoiled, cut.
    ``steps``: time steps between rows (the 5000 s hole makes a 55 h flight: not for the replays)."""
    header = list(COLUMNS)
    if draw(st.booleans()):
        header = draw(st.permutations(header))
    if draw(st.integers(0, 4)) == 0:
        header = [draw(st.sampled_from([*COLUMNS, "bogus", "", "time_s"])) for _ in header]
    n = draw(st.integers(0, 40))
    step = draw(st.sampled_from(steps))
    rows = []
    for i in range(n):
        row = dict(zip(COLUMNS, _plausible_row(i * step), strict=True))
        line = [row.get(name, "0") for name in header]
        if draw(st.integers(0, 5)) == 0:
            line[draw(st.integers(0, len(line) - 1))] = draw(_cell)
        if draw(st.integers(0, 15)) == 0:
            line = line[: draw(st.integers(0, len(line)))]
        rows.append(",".join(line))
    text = "\n".join([",".join(header), *rows]) + "\n"
    data = text.encode()
    if draw(st.integers(0, 4)) == 0:
        data = data[: draw(st.integers(0, len(data)))]
    if draw(st.integers(0, 10)) == 0:
        data = draw(st.binary(max_size=200))
    return data


@st.composite
def model_files(draw: st.DrawFn) -> bytes:
    """The paper's model.yaml with keys dropped, retyped, repeated or made ragged, or random text."""
    data = paper_table_a1().to_dict()
    for _ in range(draw(st.integers(0, 3))):
        key = draw(st.sampled_from(sorted(data)))
        action = draw(st.sampled_from(["drop", "value", "ragged", "nested"]))
        if action == "drop":
            data.pop(key, None)
        elif action == "value":
            data[key] = draw(st.one_of(st.floats(allow_nan=True), st.text(max_size=5), st.none(), st.booleans()))
        elif action == "ragged" and isinstance(data.get("heat_map"), dict) and "values_w" in data["heat_map"]:
            rows = data["heat_map"]["values_w"]
            rows[draw(st.integers(0, len(rows) - 1))] = draw(st.lists(st.floats(0, 5000), max_size=8))
        elif action == "nested":
            data[key] = {"x": draw(st.integers())}
    text = yaml.safe_dump(data, sort_keys=False)
    if draw(st.integers(0, 6)) == 0:
        text += f"{draw(st.sampled_from(sorted(paper_table_a1().to_dict())))}: 1\n"  # a duplicate key
    raw = text.encode()
    if draw(st.integers(0, 6)) == 0:
        raw = raw[: draw(st.integers(0, len(raw)))]
    if draw(st.integers(0, 12)) == 0:
        raw = draw(st.binary(max_size=120))
    return raw


def _asc_line(t: float, can_id: int, payload: bytes) -> str:
    return f"   {t:.6f} 1  {can_id:X}             Rx   d {len(payload)} {' '.join(f'{b:02X}' for b in payload)}"


@st.composite
def can_logs(draw: st.DrawFn) -> tuple[str, bytes]:
    """An .asc of the engine DBC's ids with random payloads and times, cut or spoiled; or a random .blf."""
    if draw(st.integers(0, 5)) == 0:
        return ".blf", draw(st.binary(max_size=300))
    lines = ["date Sun Nov 22 12:00:00.000 pm 2026", "base hex  timestamps absolute", "no internal events logged"]
    t = 0.0
    for _ in range(draw(st.integers(0, 60))):
        t += draw(st.sampled_from([0.02, 0.0, 0.5, -0.1, 3600.0]))
        can_id = draw(st.sampled_from([0x100, 0x101, 0x200, 0x300, 0x7FF]))
        payload = draw(st.binary(min_size=0, max_size=8))
        lines.append(_asc_line(max(t, 0.0), can_id, payload))
        if draw(st.integers(0, 20)) == 0:
            lines.append(draw(st.text(max_size=30).filter(lambda s: "\n" not in s and "\r" not in s)))
    raw = ("\n".join(lines) + "\n").encode()
    if draw(st.integers(0, 4)) == 0:
        raw = raw[: draw(st.integers(0, len(raw)))]
    return ".asc", raw


def _run_in_tmp(capsys: pytest.CaptureFixture[str], files: dict[str, bytes], argv: list[str], out: str) -> None:
    with tempfile.TemporaryDirectory(prefix="ecu-fuzz-") as tmp:
        work = Path(tmp)
        for name, data in files.items():
            (work / name).write_bytes(data)
        check_cli_outcome([a.replace("{w}", tmp) for a in argv], work / out, work, capsys)


@FUZZ
@given(csv=flight_csvs())
def test_import_of_random_csvs(capsys: pytest.CaptureFixture[str], csv: bytes) -> None:
    _run_in_tmp(capsys, {"in.csv": csv}, ["import", "{w}/in.csv", "--out", "{w}/out.csv"], "out.csv")


@FUZZ
@given(log=can_logs())
def test_import_of_random_can_logs(capsys: pytest.CaptureFixture[str], log: tuple[str, bytes]) -> None:
    suffix, raw = log
    argv = ["import", f"{{w}}/in{suffix}", "--dbc", "engine.dbc", "--out", "{w}/out.csv"]
    _run_in_tmp(capsys, {f"in{suffix}": raw}, argv, "out.csv")


@FUZZ
@given(csv=flight_csvs(), model=st.one_of(st.none(), model_files()))
def test_simulate_of_random_csvs_and_models(
    capsys: pytest.CaptureFixture[str], csv: bytes, model: bytes | None
) -> None:
    files = {"in.csv": csv} | ({"model.yaml": model} if model is not None else {})
    argv = ["simulate", "{w}/in.csv", "--out", "{w}/sim.csv"] + (["--model", "{w}/model.yaml"] if model else [])
    _run_in_tmp(capsys, files, argv, "sim.csv")


@FUZZ
@given(log=st.one_of(can_logs(), flight_csvs(REPLAY_STEPS).map(lambda raw: (".csv", raw))))
def test_replay_of_random_logs(capsys: pytest.CaptureFixture[str], log: tuple[str, bytes]) -> None:
    suffix, raw = log
    _run_in_tmp(capsys, {f"in{suffix}": raw}, ["replay", f"{{w}}/in{suffix}", "--out", "{w}/health.csv"], "health.csv")


@FUZZ
@given(csvs=st.lists(flight_csvs(REPLAY_STEPS), min_size=1, max_size=2), model=st.one_of(st.none(), model_files()))
def test_calibrate_of_random_flights(
    capsys: pytest.CaptureFixture[str], csvs: list[bytes], model: bytes | None
) -> None:
    files = {f"f{i}.csv": raw for i, raw in enumerate(csvs)} | ({"model.yaml": model} if model is not None else {})
    argv = ["calibrate", *(f"{{w}}/f{i}.csv" for i in range(len(csvs))), "--out", "{w}/detector.yaml"]
    argv += ["--model", "{w}/model.yaml"] if model is not None else []
    _run_in_tmp(capsys, files, argv, "detector.yaml")


def test_the_strategies_make_valid_inputs_too() -> None:
    """The generators are not all garbage: a plain flight CSV of theirs imports (else the property
    would test only the first error path)."""
    text = "\n".join([",".join(COLUMNS), *(",".join(_plausible_row(i * 1.0)) for i in range(30))]) + "\n"
    assert not math.isnan(float(text.splitlines()[1].split(",")[0]))
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "in.csv").write_text(text, encoding="utf-8")
        assert main(["import", f"{tmp}/in.csv", "--out", f"{tmp}/out.csv"]) == 0


# --- YAML structure (issue 31): nesting, aliases, huge values, in model.yaml and the service config ----

_LEAF = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**30), 10**30),
    st.text(max_size=8),
    st.none(),
    st.booleans(),
    st.sampled_from(["1e9999", "-.inf", ".nan", "~", "0x1F", "1_000", "2026-11-28"]),
)


def _nested(depth: int) -> str:
    return "[" * depth + "1" + "]" * depth


@st.composite
def yaml_structures(draw: st.DrawFn, base: dict[str, object]) -> bytes:
    """``base`` (a valid file's data) re-emitted with a key's value made deep, aliased, huge or odd,
    or an alias bomb, or nesting past any limit put in front."""
    data = dict(base)
    key = draw(st.sampled_from(sorted(data)))
    kind = draw(st.sampled_from(["leaf", "list", "map", "deep", "bomb", "alias", "huge"]))
    text = yaml.safe_dump({k: v for k, v in data.items() if k != key}, sort_keys=False)
    if kind == "leaf":
        text += yaml.safe_dump({key: draw(_LEAF)})
    elif kind == "list":
        text += yaml.safe_dump({key: draw(st.lists(_LEAF, max_size=6))})
    elif kind == "map":
        text += yaml.safe_dump({key: draw(st.dictionaries(st.text(max_size=4), _LEAF, max_size=4))})
    elif kind == "deep":
        text += f"{key}: {_nested(draw(st.sampled_from([2, 63, 65, 1000, 50_000])))}\n"
    elif kind == "bomb":
        levels = draw(st.integers(1, 9))
        bomb = ['l0: &l0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
        bomb += [f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 9)}]" for i in range(1, levels)]
        text = "\n".join(bomb) + f"\n{text}{key}: *l{levels - 1}\n"
    elif kind == "alias":
        value = yaml.safe_dump(base[key], default_flow_style=True).strip().removesuffix("...").strip()
        text = f"anchor_holder: &v {value}\n{text}{key}: *v\n"
    else:
        huge = draw(st.sampled_from(["9" * 5000, "1" + "0" * 400 + ".0", "[" + ", ".join(["1.0"] * 20000) + "]"]))
        text += f"{key}: {huge}\n"
    return text.encode()


_MODEL_DATA = paper_table_a1().to_dict()
_CONFIG_DATA = yaml.safe_load((REPO / "ecu_monitor" / "data" / "configs" / "example.yaml").read_text())


@FUZZ
@given(model=yaml_structures(_MODEL_DATA))
def test_simulate_with_model_yaml_of_any_structure(capsys: pytest.CaptureFixture[str], model: bytes) -> None:
    flight = "\n".join([",".join(COLUMNS), *(",".join(_plausible_row(i * 1.0)) for i in range(30))]) + "\n"
    argv = ["simulate", "{w}/in.csv", "--model", "{w}/model.yaml", "--out", "{w}/sim.csv"]
    _run_in_tmp(capsys, {"in.csv": flight.encode(), "model.yaml": model}, argv, "sim.csv")


@FUZZ
@given(config=yaml_structures(_CONFIG_DATA))
def test_replay_with_config_yaml_of_any_structure(capsys: pytest.CaptureFixture[str], config: bytes) -> None:
    flight = "\n".join([",".join(COLUMNS), *(",".join(_plausible_row(i * 0.1)) for i in range(30))]) + "\n"
    argv = ["replay", "{w}/in.csv", "--config", "{w}/config.yaml", "--out", "{w}/health.csv"]
    _run_in_tmp(capsys, {"in.csv": flight.encode(), "config.yaml": config}, argv, "health.csv")
