"""ecu_monitor/compile_cache.py: numba's cache directory defaults to ``$XDG_CACHE_HOME/ecu-monitor/numba``
unless the user set NUMBA_CACHE_DIR, both entry points set it before numba loads, and a first run says it
compiles (once: the second run loads the cache and says nothing)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ecu_monitor.compile_cache import (
    CACHE_ENV,
    COMPILING_LINE,
    CompileClock,
    compile_notice,
    default_cache_dir,
    use_cache_dir,
)
from ecu_monitor.flightlog import write_csv
from virtual_bus.missions import mission_from_dict
from virtual_bus.plant import fly

BIN = Path(sys.executable).parent
#: A 100 s mission (as in tests/install/test_install.py): every message's frames and a few hundred health rows.
SHORT_MISSION = {
    "name": "short",
    "segments": [
        {"kind": "ground_run", "duration_s": 30, "throttle_pct": 40},
        {"kind": "cruise", "duration_s": 70, "airspeed_mps": 23, "throttle_pct": 60},
    ],
}


def _env(xdg: Path, **more: str) -> dict[str, str]:
    """This environment without any numba setting of its own, XDG_CACHE_HOME at ``xdg``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env["XDG_CACHE_HOME"] = str(xdg)
    env.update(more)
    return env


# --- the directory --------------------------------------------------------------------------------


def test_default_cache_dir_follows_xdg_cache_home() -> None:
    assert default_cache_dir({"XDG_CACHE_HOME": "/srv/cache"}) == Path("/srv/cache/ecu-monitor/numba")
    home = Path.home() / ".cache" / "ecu-monitor" / "numba"
    assert default_cache_dir({}) == home
    assert default_cache_dir({"XDG_CACHE_HOME": ""}) == home
    assert default_cache_dir({"XDG_CACHE_HOME": "relative/cache"}) == home  # the XDG spec ignores a relative one


def test_use_cache_dir_sets_the_default_only_when_the_user_did_not() -> None:
    env: dict[str, str] = {"XDG_CACHE_HOME": "/srv/cache"}
    assert use_cache_dir(env) == "/srv/cache/ecu-monitor/numba"
    assert env[CACHE_ENV] == "/srv/cache/ecu-monitor/numba"
    mine = {"XDG_CACHE_HOME": "/srv/cache", CACHE_ENV: "/data/kernels"}
    assert use_cache_dir(mine) == "/data/kernels"
    assert mine[CACHE_ENV] == "/data/kernels"
    empty = {CACHE_ENV: ""}  # set, even empty (numba's own default): left alone
    assert use_cache_dir(empty) is None
    assert empty == {CACHE_ENV: ""}


_ENTRY_PROBE = """
import contextlib, io, sys
from {module} import main
with contextlib.redirect_stdout(io.StringIO()):
    main({argv!r})
loaded = "numba" in sys.modules
import numba
print(loaded, numba.config.CACHE_DIR)
"""


@pytest.mark.process
@pytest.mark.parametrize(("module", "argv"), [("ecu_monitor.cli", ["files"]), ("virtual_bus.cli", [])])
def test_entry_points_set_the_cache_dir_before_numba_loads(tmp_path: Path, module: str, argv: list[str]) -> None:
    code = _ENTRY_PROBE.format(module=module, argv=argv)
    done = subprocess.run(
        [sys.executable, "-c", code], env=_env(tmp_path), capture_output=True, text=True, timeout=120, check=True
    )
    assert done.stdout.split() == ["False", str(tmp_path / "ecu-monitor" / "numba")]
    mine = tmp_path / "mine"
    done = subprocess.run(
        [sys.executable, "-c", code], env=_env(tmp_path, NUMBA_CACHE_DIR=str(mine)),
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    assert done.stdout.split() == ["False", str(mine)]  # the user's setting wins


# --- the line -------------------------------------------------------------------------------------


def test_clock_says_the_line_once_after_the_compiling_passed_the_limit() -> None:
    said: list[str] = []
    clock = CompileClock(said.append, after_s=0.1)
    clock.start()
    clock.end()  # short: no line, and its timer is cancelled
    clock.start()
    clock.start()  # a kernel compiling a callee counts once
    deadline = time.monotonic() + 5.0
    while not said and time.monotonic() < deadline:
        time.sleep(0.01)
    clock.end()
    clock.end()
    assert said == [COMPILING_LINE]
    assert clock.total_s >= 0.1
    clock.start()  # later compiles: no second line
    clock.end()
    clock.close()
    assert said == [COMPILING_LINE]


def test_clock_says_nothing_when_the_compiling_stays_under_the_limit() -> None:
    said: list[str] = []
    clock = CompileClock(said.append, after_s=0.5)
    for _ in range(3):
        clock.start()
        clock.end()
    clock.end()  # an end whose start came before the listener: ignored
    time.sleep(0.6)
    clock.close()
    assert said == []
    assert clock.total_s < 0.5


def test_compile_notice_hears_numba_compile_and_not_a_loaded_kernel() -> None:
    import numba

    @numba.njit(cache=False)
    def twice(x: float) -> float:
        return 2.0 * x

    said: list[str] = []
    with compile_notice(said.append, after_s=0.0):  # every compile counts
        assert twice(1.5) == 3.0
    assert said[0] == COMPILING_LINE
    assert said[1].startswith("compiled in ") and len(said) == 2
    said.clear()
    with compile_notice(said.append, after_s=0.0):
        assert twice(2.5) == 5.0  # compiled already: no compile event
    assert said == []


# --- end to end -----------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.process
def test_first_replay_says_it_compiles_and_the_second_does_not(tmp_path: Path) -> None:
    """Two ``ecu-monitor replay`` processes on a fresh cache (XDG_CACHE_HOME in tmp_path): the first prints
    the line once and fills $XDG_CACHE_HOME/ecu-monitor/numba, the second loads it and prints neither line."""
    flight = tmp_path / "short.csv"  # flown here, on this process's kernels: only the replays meet the fresh cache
    write_csv(fly(mission_from_dict(SHORT_MISSION)), flight)
    env = _env(tmp_path / "xdg")
    runs = []
    for n in (1, 2):
        done = subprocess.run(
            [str(BIN / "ecu-monitor"), "replay", str(flight), "--out", str(tmp_path / f"health{n}.csv")],
            env=env, capture_output=True, text=True, timeout=240, check=False,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        runs.append(done)
    first, second = (run.stderr.splitlines() for run in runs)
    assert first.count(COMPILING_LINE) == 1, first
    assert [line for line in first if line.startswith("compiled in ")], first
    assert COMPILING_LINE not in second and not [line for line in second if "compil" in line], second
    cache = tmp_path / "xdg" / "ecu-monitor" / "numba"
    assert list(cache.rglob("*.nbi"))  # numba's index files, in the default directory
    assert (tmp_path / "health1.csv").read_bytes() == (tmp_path / "health2.csv").read_bytes()


def test_forked_processes_say_the_line_once_and_their_compiling_is_added_up() -> None:
    # identify and gap fit in forked processes, each hearing its own compiles with a copy of the clock:
    # two of them compiling past the limit give one line, and the parent's total counts theirs
    import multiprocessing

    said = multiprocessing.get_context("fork").Queue()
    clock = CompileClock(said.put, after_s=0.05)

    def compile_for_a_while() -> None:
        clock.start()
        time.sleep(0.3)
        clock.end()
        clock.close()

    workers = [multiprocessing.get_context("fork").Process(target=compile_for_a_while) for _ in range(2)]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join(10)
        assert worker.exitcode == 0
    lines = [said.get(timeout=5)]
    time.sleep(0.2)  # the workers have exited: anything else they said is in the pipe by now
    while not said.empty():
        lines.append(said.get(timeout=1))
    assert lines == [COMPILING_LINE]
    assert clock.said and not clock.announced  # said by a worker, not by this process
    assert clock.processes == 2 and clock.shared_total_s >= 0.6 and clock.total_s == 0.0
