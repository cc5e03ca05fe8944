"""``fleet run`` on a real dask.distributed scheduler and two workers, each a separate process on 127.0.0.1.

A tiny fleet of short virtual flights: engine NOM-1 nominal (canonical CSVs, one bad log), engine DEG-2 with
gamma_Q = 1.3 from engine start (CAN logs on the UNIX clock). The wear reference is a stored one (as
``calibrate`` writes it), far from both: the degraded engine alerts and ranks first, the nominal one does not.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from ecu_monitor.fleet.run import run_fleet
from ecu_monitor.fleet.store import FleetStore
from ecu_monitor.model import paper_table_a1
from tests.helpers import run_cli
from virtual_bus.faults import Degradation
from virtual_bus.missions import Climb, Cruise, Descent, GroundRun, Landing, Mission, Takeoff
from virtual_bus.recorder import record

pytestmark = [pytest.mark.process, pytest.mark.timeout(600)]  # a cold numba cache compiles on both workers

_DASK = Path(sys.executable).parent / "dask"


def _short_mission(number: int) -> Mission:
    """About 8 minutes: ground run, take-off, climb 300 m, cruise, descent, landing."""
    return Mission(
        name=f"short-{number}",
        description="a short test flight",
        segments=(
            GroundRun(duration_s=60.0, throttle_pct=30.0),
            Takeoff(),
            Climb(target_altitude_m=300.0, climb_rate_mps=3.0, throttle_pct=90.0),
            Cruise(duration_s=150.0 + 20.0 * number, throttle_pct=55.0),
            Descent(target_altitude_m=100.0, rate_mps=3.0),
            Landing(idle_s=20.0),
        ),
    )


def _fly(path: Path, number: int, gamma_q: float = 1.0) -> None:
    degradation = (Degradation("gamma_q", gamma_q, 0.0),) if gamma_q != 1.0 else ()
    record(_short_mission(number), [path], paper_table_a1(), degradation=degradation, seed=number,
           start_time_s=1.7e9 + 86400.0 * number)  # fmt: skip


@pytest.fixture(scope="module")
def fleet_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("fleet")
    (root / "nom").mkdir()
    (root / "deg").mkdir()
    for n in (1, 2):
        _fly(root / "nom" / f"flight_{n}.csv", n)
    for n in (4, 5):
        _fly(root / "deg" / f"flight_{n}.blf", n, gamma_q=1.3)
    (root / "nom" / "broken.csv").write_text("time_s,rpm\nabc,1\n")
    (root / "detector.yaml").write_text("wear:\n  reference: {mean: 0.0, sd: 0.01, flights: 20}\n")
    (root / "FLEET.yaml").write_text(
        "defaults: {detector: detector.yaml}\n"
        "engines:\n"
        "  - {serial: NOM-1, logs: ['nom/*.csv'], tbo_hours: 2000, overhaul_hours: 100}\n"
        "  - {serial: DEG-2, logs: ['deg/*.blf']}\n"
    )
    return root / "FLEET.yaml"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def scheduler() -> Iterator[str]:
    """A dask scheduler and two workers, three processes; their address."""
    from dask.distributed import Client

    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    procs = [subprocess.Popen([str(_DASK), "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--no-dashboard"], **quiet)]  # fmt: skip
    procs += [subprocess.Popen([str(_DASK), "worker", address, "--nthreads", "1", "--no-dashboard",
                                "--name", f"w{i}"], **quiet) for i in (1, 2)]  # fmt: skip
    try:
        with Client(address, timeout="60s") as client:
            client.wait_for_workers(2, timeout=60)
        yield address
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in procs:
            proc.wait(timeout=30)


@pytest.fixture(scope="module")
def first_run(fleet_file: Path, scheduler: str, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    out = tmp_path_factory.mktemp("out") / "fleet-out"
    return out, run_fleet(fleet_file, out, scheduler=scheduler, say=lambda _: None)


def test_every_log_is_summarised_the_bad_one_is_a_failure_row(first_run: tuple[Path, object]) -> None:
    out, run = first_run
    assert run.workers == 2
    assert run.processed == 4 and [log for log, _ in run.failed] == ["nom/broken.csv"]
    store = FleetStore(out)
    failures = store.table("failures").to_pylist()
    assert [(f["serial"], f["log"], f["internal"]) for f in failures] == [("NOM-1", "nom/broken.csv", False)]
    assert "broken.csv" in failures[0]["reason"] and "\n" not in failures[0]["reason"]
    flights = store.table("flights").to_pylist()
    assert sorted(f["log"] for f in flights) == ["deg/flight_4.blf", "deg/flight_5.blf", "nom/flight_1.csv",
                                                 "nom/flight_2.csv"]  # fmt: skip
    for f in flights:
        assert 300.0 < f["duration_s"] < 1200.0 and f["max_cht_c"] > 80.0 and f["wear_index"] is not None
        regions = f["ground_s"] + f["low_power_s"] + f["cruise_power_s"] + f["high_power_s"]
        assert f["cruise_power_s"] > 0.0 and regions <= f["duration_s"] + 1.0 and len(f["max_cht_cyl_c"]) == 1
        assert (f["start_utc"] is not None) == f["log"].endswith(".blf")  # only CAN logs carry a UNIX clock
    by_engine = {f["log"]: f for f in flights}
    assert by_engine["deg/flight_4.blf"]["wear_index"] > 0.05 > abs(by_engine["nom/flight_1.csv"]["wear_index"])


def test_the_degraded_engine_alerts_and_ranks_first(first_run: tuple[Path, object]) -> None:
    out, _ = first_run
    rows = pq.read_table(out / "engines.parquet").to_pylist()
    assert [(r["serial"], r["rank"], r["alert"]) for r in rows] == [("DEG-2", 1, True), ("NOM-1", 2, False)]
    deg, nom = rows
    assert deg["alert_flight"] == 1 and deg["reason"].startswith("ALERT at flight 1 (deg/flight_4.blf)")
    assert nom["flights"] == 2 and nom["failures"] == 1 and nom["cusum"] < nom["threshold"]
    assert nom["hours_to_overhaul"] == pytest.approx(2000 - 100 - nom["hours"])
    page = (out / "report.html").read_text()
    assert "DEG-2" in page and "ALERT" in page and "nom/broken.csv" in page and "data:image/png;base64," in page


def test_duckdb_and_pandas_read_the_datasets(first_run: tuple[Path, object]) -> None:
    import pandas as pd

    out, _ = first_run
    done = run_cli("fleet", "query", out, "SELECT serial, count(*) AS n FROM flights GROUP BY serial ORDER BY serial",
                   cwd=out)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["serial\tn", "DEG-2\t2", "NOM-1\t2"]
    con = FleetStore(out).connect()
    assert con.execute("SELECT count(*) FROM events JOIN engines USING (serial)").fetchone()[0] >= 0
    assert con.execute("SELECT log FROM failures").fetchall() == [("nom/broken.csv",)]
    frame = pd.read_parquet(out / "flights")
    assert sorted(frame["serial"].astype(str).unique()) == ["DEG-2", "NOM-1"] and len(frame) == 4
    bad = run_cli("fleet", "query", out, "SELEC 1", cwd=out)
    assert bad.returncode == 2 and bad.stderr.startswith("ecu-monitor: error: query: Parser Error")


def test_a_rerun_processes_only_unseen_logs(fleet_file: Path, scheduler: str, tmp_path: Path) -> None:
    root = tmp_path / "fleet"
    shutil.copytree(fleet_file.parent, root)
    out = tmp_path / "out"
    first = run_fleet(root / "FLEET.yaml", out, scheduler=scheduler, say=lambda _: None)
    again = run_fleet(root / "FLEET.yaml", out, scheduler=scheduler, say=lambda _: None)
    assert (first.processed, again.processed, again.skipped) == (4, 0, 5)
    shutil.copy(root / "nom" / "flight_1.csv", root / "nom" / "copy_of_1.csv")  # same content: seen
    _fly(root / "nom" / "flight_9.csv", 9)
    (root / "nom" / "flight_2.csv").unlink()
    third = run_fleet(root / "FLEET.yaml", out, scheduler=scheduler, say=lambda _: None)
    assert (third.processed, third.removed) == (1, 2)  # flight_9; flight_2's flights and events files gone
    logs = sorted(f["log"] for f in FleetStore(out).table("flights").to_pylist() if f["serial"] == "NOM-1")
    assert logs == ["nom/flight_1.csv", "nom/flight_9.csv"]
    assert next(r for r in third.engines if r["serial"] == "NOM-1")["flights"] == 2


def test_a_run_killed_at_any_moment_leaves_whole_files_and_resumes(
    fleet_file: Path, scheduler: str, first_run: tuple[Path, object], tmp_path: Path
) -> None:
    out = tmp_path / "out"
    cli = [sys.executable, "-m", "ecu_monitor.cli", "fleet", "run", str(fleet_file), "--out", str(out),
           "--scheduler", scheduler]  # fmt: skip
    proc = subprocess.Popen(cli, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 120.0
    while time.monotonic() < deadline and proc.poll() is None and not list(out.glob("flights/*/*.parquet")):
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    store = FleetStore(out)
    for path in out.rglob("*.parquet"):
        pq.read_table(path)  # every file the readers see is whole
    flights, events = (set(p.stem for p in out.glob(f"{name}/*/*.parquet")) for name in ("flights", "events"))
    assert flights <= events  # events first: a log counts as done only with both
    # a kill between a log's two files and inside a write (what a kill at another moment leaves)
    (out / "events" / "serial=NOM-1").mkdir(parents=True, exist_ok=True)
    (out / "events" / "serial=NOM-1" / ".0123.parquet.part").write_bytes(b"PAR1 half")
    resumed = run_fleet(fleet_file, out, scheduler=scheduler, say=lambda _: None)
    assert resumed.processed == 4 - len(flights)
    assert not list(out.rglob(".*.part"))
    assert sorted(f["log"] for f in store.table("flights").to_pylist()) == sorted(
        f["log"] for f in FleetStore(first_run[0]).table("flights").to_pylist()
    )
