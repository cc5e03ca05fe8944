"""The package as a user installs it: a wheel in a fresh venv finds its shipped files from any folder,
and the daemon's own install does without the ``tools`` extra.

The wheel is built from this checkout (``pip wheel --no-deps``) and installed with ``--no-index
--no-deps`` into a fresh venv; the dependencies come from the test environment through a ``.pth``
line (no network). The commands then run from an empty directory, where no source checkout could
help them. They run with NUMBA_DISABLE_JIT=1: a fresh install compiles its kernels on first use (~30 s
on 2 cores), which tests numba, not the install; the compiled kernels are tested in the other files.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import textwrap
import venv
from pathlib import Path

import pytest
import yaml

from ecu_monitor.errors import TOOLS_MODULES
from ecu_monitor.shipped import KINDS, resolve_file, shipped_dir, shipped_file, shipped_files
from tests.helpers import REPO

#: A 100 s mission: long enough for frames of every message and a health CSV, short to fly.
SHORT_MISSION = {
    "name": "short",
    "segments": [
        {"kind": "ground_run", "duration_s": 30, "throttle_pct": 40},
        {"kind": "cruise", "duration_s": 70, "airspeed_mps": 23, "throttle_pct": 60},
    ],
}


# --- the resolver ---------------------------------------------------------------------------------


def test_every_kind_ships_files_and_a_bare_name_finds_them() -> None:
    for kind in KINDS:
        names = shipped_files(kind)
        assert names, kind
        for name in names:
            path = shipped_file(kind, name)
            assert path is not None and path.is_file() and path.is_relative_to(shipped_dir(kind))
    assert shipped_file("config", "example") == shipped_file("config", "example.yaml")
    assert shipped_file("dbc", "third_party/rusEFI_CAN_verbose.dbc") is not None
    assert shipped_file("dbc", "../configs/example.yaml") is None  # never leaves its folder


def test_an_existing_path_wins_over_a_shipped_name(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    mine = tmp_path / "engine.dbc"
    mine.write_text('VERSION ""\n', encoding="utf-8")
    assert resolve_file("engine.dbc", "dbc", base=tmp_path) == mine
    monkeypatch.chdir(tmp_path)
    assert resolve_file("engine.dbc", "dbc") == Path("engine.dbc")
    assert resolve_file("health.dbc", "dbc") == shipped_file("dbc", "health.dbc")


def test_an_unknown_name_is_one_line_listing_the_shipped_files(tmp_path: Path) -> None:
    from ecu_monitor.errors import ConfigError
    from ecu_monitor.shipped import shipped_files

    listed = r"\(shipped: " + ", ".join(name.replace(".", r"\.") for name in shipped_files("config")) + r"\)"
    assert "example.yaml" in shipped_files("config")
    with pytest.raises(ConfigError, match=r"nope\.yaml: no such config file " + listed):
        resolve_file("nope.yaml", "config", base=tmp_path)


# --- the daemon's lean install --------------------------------------------------------------------

#: Run a command with the tools extra's modules made unimportable (as in ``pip install ecu-monitor``).
_WITHOUT_TOOLS = textwrap.dedent(
    """
    import sys
    for name in {modules!r}:
        sys.modules[name] = None  # import raises ImportError
    from ecu_monitor.cli import main
    sys.exit(main(sys.argv[1:]))
    """
)


def _without_tools(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    code = _WITHOUT_TOOLS.format(modules=sorted(TOOLS_MODULES))
    return subprocess.run(
        [sys.executable, "-c", code, *args], cwd=cwd, capture_output=True, text=True, timeout=300, check=False
    )


@pytest.mark.slow
@pytest.mark.process
def test_replay_demo_and_help_run_without_the_tools_extra(tmp_path: Path) -> None:
    from virtual_bus.missions import mission_from_dict
    from virtual_bus.recorder import record

    log = tmp_path / "flight.blf"
    record(mission_from_dict(SHORT_MISSION), [log], seed=3)
    replay = _without_tools(["replay", str(log), "--out", "health.csv"], tmp_path)
    assert replay.returncode == 0, replay.stderr
    assert (tmp_path / "health.csv").stat().st_size > 1000
    (tmp_path / "short.yaml").write_text(yaml.safe_dump(SHORT_MISSION), encoding="utf-8")
    demo = _without_tools(["demo", "--mission", "short.yaml", "--inject-at", "40", "--out", "d"], tmp_path)
    assert demo.returncode == 0, demo.stderr
    assert "no plots: pip install 'ecu-monitor[tools]'" in demo.stdout and (tmp_path / "d" / "health.csv").exists()
    helped = _without_tools(["--help"], tmp_path)
    assert helped.returncode == 0 and "identify" in helped.stdout, helped.stderr
    identify = _without_tools(["identify", "x.csv", "--out", "m.yaml"], tmp_path)
    lines = identify.stderr.strip().splitlines()
    assert identify.returncode == 1 and len(lines) == 1, identify.stderr
    assert (
        lines[0].startswith("ecu-monitor: error: this command needs ")
        and "pip install 'ecu-monitor[tools]'" in lines[0]
    )


# --- a wheel in a fresh venv ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """bin/ of a fresh venv holding the wheel of this checkout (dependencies from the test venv)."""
    root = tmp_path_factory.mktemp("wheel")
    source, dist = root / "source", root / "dist"
    # built from a copy: setuptools leaves build/ and *.egg-info beside the sources it builds
    shutil.copytree(REPO, source, ignore=shutil.ignore_patterns(".*", "build", "*.egg-info", "__pycache__", "docs"))
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(dist), str(source)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    # setuptools >= 70.1 builds wheels by itself; the test extra has it (pip install -e '.[test]')
    assert built.returncode == 0, built.stderr[-3000:]
    (wheel,) = dist.glob("ecu_monitor-*.whl")
    env_dir = root / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "-q", "--no-index", "--no-deps", str(wheel)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    # the test venv's packages after the fresh venv's own (its editable ecu_monitor hook is not read)
    (Path(purelib) / "test_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n", encoding="utf-8")
    return env_dir / "bin"


def _run(bin_dir: Path, command: str, args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1", "MPLBACKEND": "Agg"}
    env.pop("PYTHONPATH", None)
    return subprocess.run(
        [str(bin_dir / command), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600, check=False
    )


@pytest.mark.slow
@pytest.mark.install
def test_wheel_runs_record_replay_and_demo_from_an_empty_directory(installed: Path, tmp_path: Path) -> None:
    work = tmp_path / "empty"
    work.mkdir()
    where = subprocess.run(
        [str(installed / "python"), "-c", "import ecu_monitor, virtual_bus; print(ecu_monitor.__file__)"],
        cwd=work,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert str(REPO) not in where and str(installed.parent) in where  # the wheel's copy, not this checkout

    listed = _run(installed, "ecu-monitor", ["files"], work)
    assert listed.returncode == 0 and "example.yaml" in listed.stdout and "ecu-monitor.service" in listed.stdout

    (work / "short.yaml").write_text(yaml.safe_dump(SHORT_MISSION), encoding="utf-8")
    recorded = _run(
        installed, "virtual-ecu", ["record", "--mission", "short.yaml", "--out", "f.csv", "--out", "f.blf"], work
    )
    assert recorded.returncode == 0, recorded.stderr

    replayed = _run(installed, "ecu-monitor", ["replay", "f.blf", "--config", "example.yaml", "--out", "h.csv"], work)
    assert replayed.returncode == 0, replayed.stderr
    assert (work / "h.csv").read_text(encoding="utf-8").startswith("time_s,")

    demo = _run(installed, "ecu-monitor", ["demo", "--mission", "short.yaml", "--inject-at", "40", "--out", "d"], work)
    assert demo.returncode == 0, demo.stderr
    assert "0 malformed" in demo.stdout and (work / "d" / "cht.png").stat().st_size > 1000

    missing = _run(installed, "ecu-monitor", ["run", "--config", "nope.yaml"], work)
    assert missing.returncode == 2 and "(shipped: dronecan.yaml, example.yaml" in missing.stderr
