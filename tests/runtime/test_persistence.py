"""Flight history database: flight detection from rpm, aggregates, rainflow cycles, crash recovery, kill -9."""

from __future__ import annotations

import math
import random
import re
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import rainflow

from ecu_monitor.errors import ConfigError
from ecu_monitor.runtime.flight_recorder import FlightRecorder
from ecu_monitor.runtime.persistence import (
    DATABASE_NAME,
    FlightRules,
    FlightSample,
    ReversalFilter,
    StateStore,
    count_cycles,
)
from tests.helpers.history import write_old_flight_database

SERIAL = "UAV-ENG-TEST"
LIMIT_C = 200.0
RULES = FlightRules(running_rpm=1000.0, min_flight_s=60.0, end_after_s=10.0, checkpoint_every_s=30.0)


def _sample(t: float, rpm: float | None, cht: float, gamma_q: float = 1.0, state: str = "NOMINAL") -> FlightSample:
    trends = {"gamma_q": gamma_q, "gamma_d": 1.0}
    return FlightSample(time_s=t, wall_time_s=1.7e9 + t, rpm=rpm, cht_c=cht, trends=trends, state=state)


def _feed(
    recorder: FlightRecorder, t0: float, duration_s: float, rpm: float | None, cht, gamma_q=None, state="NOMINAL"
):
    """Samples at 10 Hz from t0 for duration_s; cht and gamma_q are functions of time since t0."""
    n = round(duration_s * 10)
    for i in range(n):
        t = t0 + i * 0.1
        q = 1.0 if gamma_q is None else gamma_q(t - t0)
        recorder.add(_sample(t, rpm, cht(t - t0), q, state))
    return t0 + n * 0.1


def test_astm_e1049_example_counts() -> None:
    # ASTM E1049-85 (2017) section 5.4.4 / Fig. 6 example: ranges 3 (0.5), 4 (1.5), 6 (0.5), 8 (1.0), 9 (0.5).
    series = [-2.0, 1.0, -3.0, 5.0, -1.0, 3.0, -4.0, 4.0, -2.0]
    reversals = ReversalFilter(hysteresis=0.5)
    for value in series:
        reversals.add(value)
    assert reversals.points() == series
    counted = {rng: count for rng, count in rainflow.count_cycles(reversals.points())}
    assert counted == {3.0: 0.5, 4.0: 1.5, 6.0: 0.5, 8.0: 1.0, 9.0: 0.5}
    total, histogram = count_cycles([10.0 * value for value in reversals.points()])  # degC x 10: 30..90
    assert total == pytest.approx(4.0)
    assert histogram["20-50"] == pytest.approx(2.0)  # ranges 30 (0.5) and 40 (1.5)
    assert histogram["50-100"] == pytest.approx(2.0)  # ranges 60 (0.5), 80 (1.0) and 90 (0.5)


def test_reversal_filter_drops_quantisation_noise_keeps_big_cycles() -> None:
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 2000.0, 0.1)
    clean = 150.0 + 40.0 * np.sin(2 * np.pi * t / 200.0)  # 10 cycles of 80 degC range
    noisy = np.round(clean + rng.normal(0.0, 0.4, t.size))  # 1 degC quantised sensor with noise
    reversals = ReversalFilter(hysteresis=5.0)
    for value in noisy:
        reversals.add(float(value))
    points = reversals.points()
    assert len(points) < 40  # the noise produced thousands of raw reversals, none kept
    assert sum(1 for _ in rainflow.reversals(noisy.tolist())) > 1000
    total, histogram = count_cycles(points)
    assert histogram["50-100"] == pytest.approx(10.0, abs=0.5)
    assert total == pytest.approx(10.0, abs=0.6)
    reference = sum(c for r, c in rainflow.count_cycles(clean.tolist()) if r >= 50.0)
    assert histogram["50-100"] == pytest.approx(reference, abs=0.5)


def test_flight_found_from_rpm_with_aggregates(tmp_path: Path) -> None:
    with StateStore(tmp_path) as store:
        recorder = FlightRecorder(store, SERIAL, LIMIT_C, RULES)
        t = _feed(recorder, 0.0, 30.0, 0.0, lambda s: 20.0)  # on the ground, engine off

        def cht(s: float) -> float:  # 300 s run: above the 200 degC limit from 100 s to 160 s
            return 210.0 if 100.0 <= s < 160.0 else 150.0

        t = _feed(recorder, t, 300.0, 5000.0, cht, gamma_q=lambda s: 1.0 + 0.2 * s / 300.0)
        assert recorder.in_flight
        _feed(recorder, t, 20.0, 0.0, lambda s: 100.0)
        assert not recorder.in_flight
        (flight,) = store.flights(SERIAL)
    assert flight.status == "finished"
    assert flight.end_reason == "engine_stopped"
    assert flight.duration_s == pytest.approx(299.9, abs=0.2)
    assert flight.hours == pytest.approx(299.9 / 3600, rel=1e-3)
    assert flight.end_utc - flight.start_utc == pytest.approx(flight.duration_s)
    assert flight.max_cht_c == pytest.approx(210.0)
    assert flight.time_above_limit_s == pytest.approx(60.0, abs=0.3)
    assert flight.gamma_q_start == pytest.approx(1.0)
    assert flight.gamma_q_end == pytest.approx(1.2, abs=1e-3)
    assert flight.gamma_q_slope_per_h == pytest.approx(0.2 / 300.0 * 3600.0, rel=1e-3)
    assert flight.gamma_d_slope_per_h == pytest.approx(0.0, abs=1e-9)
    assert flight.cycles_total == pytest.approx(1.0)  # one 150 -> 210 -> 150 cycle (two half cycles)
    assert flight.cycles_histogram["50-100"] == pytest.approx(1.0)


def test_short_run_is_not_a_flight_and_stale_rpm_ends_one(tmp_path: Path) -> None:
    with StateStore(tmp_path) as store:
        recorder = FlightRecorder(store, SERIAL, LIMIT_C, RULES)
        t = _feed(recorder, 0.0, 30.0, 4000.0, lambda s: 100.0)  # ground run of 30 s < 60 s
        t = _feed(recorder, t, 15.0, 0.0, lambda s: 100.0)
        assert store.flights(SERIAL, include_running=True) == []
        t = _feed(recorder, t, 90.0, 4000.0, lambda s: 100.0 + s / 10, state="SUSPECT")
        t = _feed(recorder, t, 12.0, None, lambda s: math.nan, state="INPUT_STALE")  # rpm stale
        assert not recorder.in_flight
        (flight,) = store.flights(SERIAL)
    assert flight.duration_s == pytest.approx(89.9, abs=0.2)
    assert flight.worst_state == "SUSPECT"
    assert flight.time_degraded_s == pytest.approx(89.9, abs=0.2)
    assert flight.time_above_limit_s == 0.0


def test_service_stop_keeps_a_flight_in_progress(tmp_path: Path) -> None:
    with StateStore(tmp_path) as store:
        recorder = FlightRecorder(store, SERIAL, LIMIT_C, RULES)
        _feed(recorder, 0.0, 75.0, 6000.0, lambda s: 180.0)
        assert recorder.close("service_stop") is not None
        (flight,) = store.flights(SERIAL)
    assert flight.status == "finished"
    assert flight.end_reason == "service_stop"


def test_crash_recovery_closes_the_running_flight_at_its_checkpoint(tmp_path: Path) -> None:
    store = StateStore(tmp_path)
    recorder = FlightRecorder(store, SERIAL, LIMIT_C, RULES)
    _feed(recorder, 0.0, 100.0, 6000.0, lambda s: 150.0 + 30.0 * math.sin(s / 5.0))  # checkpoints at 30, 60, 90 s
    assert store.flights(SERIAL) == []  # running flights are not listed
    (running,) = store.flights(SERIAL, include_running=True)
    assert running.status == "running"
    store.close()  # the process "dies" without closing the flight
    with StateStore(tmp_path) as store:
        recorder = FlightRecorder(store, SERIAL, LIMIT_C, RULES)
        assert recorder.recovered == [running.id]
        (flight,) = store.flights(SERIAL)
    assert flight.status == "recovered"
    assert flight.end_reason == "service_crashed"
    assert flight.duration_s == pytest.approx(90.0, abs=0.2)
    assert flight.cycles_total > 2  # counted from the checkpointed reversals


def test_state_dir_that_cannot_be_made_is_a_config_error(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(ConfigError, match="state_dir"):
        StateStore(blocker / "sub")
    with pytest.raises(ConfigError, match="no flight database"):
        StateStore(tmp_path / "empty", readonly=True)


def test_rules_are_validated() -> None:
    with pytest.raises(ConfigError, match="min_flight_s"):
        FlightRules(min_flight_s=-1.0)
    with pytest.raises(ConfigError, match="checkpoint_every_s"):
        FlightRules(checkpoint_every_s=0.0)


_WRITER = textwrap.dedent(
    """
    import math, sys
    from ecu_monitor.runtime.flight_recorder import FlightRecorder
    from ecu_monitor.runtime.persistence import FlightRules, FlightSample, StateStore
    rules = FlightRules(min_flight_s=5.0, end_after_s=1.0, checkpoint_every_s=2.0)
    store = StateStore(sys.argv[1])
    recorder = FlightRecorder(store, "UAV-ENG-KILL", 200.0, rules)
    t = float(sys.argv[2])
    sys.stdout.write("ready\\n")
    while True:
        for i in range(120):  # 12 s engine run at 10 Hz, checkpoints every 2 s
            t += 0.1
            cht = 150.0 + 40.0 * math.sin(i / 7.0)
            trends = {"gamma_q": 1.0 + i * 1e-3, "gamma_d": 1.0}
            recorder.add(FlightSample(t, 1.7e9 + t, 5000.0, cht, trends, "NOMINAL"))
        for i in range(15):
            t += 0.1
            recorder.add(FlightSample(t, 1.7e9 + t, 0.0, 100.0, {"gamma_q": 1.0, "gamma_d": 1.0}, "NOMINAL"))
        # printed after the flight's commit, in one write (atomic on a pipe)
        sys.stdout.write(f"finished {recorder.finished[-1]}\\n")
    """
)
#: A promise of the writer: a whole line (a kill -9 may cut the last one anywhere, even mid-number).
_PROMISE = re.compile(r"finished (\d+)\n")


def _promises(out: str) -> set[int]:
    """Flight ids the writer said were committed, from whole lines only."""
    return {int(m.group(1)) for line in out.splitlines(keepends=True) if (m := _PROMISE.fullmatch(line))}


def test_a_cut_promise_line_is_not_a_promise() -> None:
    assert _promises("ready\nfinished 1\nfinished 2\nfinis") == {1, 2}
    assert _promises("finished 1\nfinished 2") == {1}  # "2" may be the start of "23"
    assert _promises("finished") == set()


@pytest.mark.slow
def test_kill_9_at_random_moments_loses_no_finished_flight(tmp_path: Path) -> None:
    """Six writers killed with SIGKILL at random points of their progress: after 1-3 flights they
    promised, plus 0-50 ms into the next (a flight's 135 samples take about that long)."""
    rng = random.Random(1049)
    promised: set[int] = set()
    for round_index in range(6):
        proc = subprocess.Popen(
            [sys.executable, "-u", "-c", _WRITER, str(tmp_path), str(round_index * 1e5)],
            stdout=subprocess.PIPE,
            text=True,
        )
        assert proc.stdout is not None
        try:
            lines = [proc.stdout.readline()]
            assert lines[0] == "ready\n"
            for _ in range(rng.randint(1, 3)):  # progress, not time: a loaded machine only runs slower
                lines.append(proc.stdout.readline())
                assert _PROMISE.fullmatch(lines[-1]), lines
            time.sleep(rng.uniform(0.0, 0.05))  # a random point inside the next flight
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=60)
            out = "".join(lines) + proc.stdout.read()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=10)
            proc.stdout.close()
        assert proc.returncode == -signal.SIGKILL
        promised.update(_promises(out))
        conn = sqlite3.connect(tmp_path / DATABASE_NAME)
        try:
            assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
            finished = {row[0] for row in conn.execute("SELECT id FROM flights WHERE status = 'finished'")}
        finally:
            conn.close()
        assert promised <= finished
    assert len(promised) >= 6  # at least one promised flight per round, by construction
    with StateStore(tmp_path) as store:
        recorder = FlightRecorder(store, "UAV-ENG-KILL", 200.0, FlightRules(min_flight_s=5.0))
        assert store.integrity_ok()
        statuses = {f.status for f in store.flights("UAV-ENG-KILL", include_running=True)}
        assert statuses <= {"finished", "recovered"}
        assert recorder.finished == []


def _three_flights(state_dir: Path) -> None:
    """Three 10-minute flights with gamma_Q rising 1.00 -> 1.05 -> 1.10 and CHT cycling 120 <-> 215 degC."""
    with StateStore(state_dir) as store:
        recorder = FlightRecorder(store, SERIAL, LIMIT_C, RULES)
        t = 0.0
        for k in range(3):
            gamma = 1.0 + 0.05 * k
            t = _feed(recorder, t, 600.0, 5500.0, lambda s: 167.5 - 47.5 * math.cos(s / 60), lambda s, g=gamma: g)
            t = _feed(recorder, t, 60.0, 0.0, lambda s: 60.0)
            t += 3600.0


def test_history_prints_the_trend_and_plots_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from ecu_monitor.cli import main

    _three_flights(tmp_path)
    out_png = tmp_path / "trend.png"
    assert main(["history", "--state-dir", str(tmp_path), "--plot", str(out_png)]) == 0
    text = capsys.readouterr().out
    assert f"engine {SERIAL}: 3 flights, 0.50 h" in text
    assert "trend: gamma_Q 1.100 (+30.0" in text  # +0.05 per flight of 1/6 h = +30 per 100 engine hours
    assert out_png.stat().st_size > 10_000
    assert main(["history", "--state-dir", str(tmp_path), "--engine", "NOPE"]) == 2
    assert "no engine 'NOPE'" in capsys.readouterr().err
    assert main(["history", "--state-dir", str(tmp_path / "missing")]) == 2


def test_history_shows_the_checkpointed_flight_of_a_killed_daemon(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Killed mid-flight, before the next start: the running row is listed with its checkpoint."""
    from ecu_monitor.cli import main

    store = StateStore(tmp_path)
    recorder = FlightRecorder(store, SERIAL, LIMIT_C, RULES)
    _feed(recorder, 0.0, 100.0, 6000.0, lambda s: 150.0)  # checkpoints at 30, 60, 90 s
    store.close()  # killed: the flight is never closed
    assert main(["history", "--state-dir", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert f"engine {SERIAL}: 1 flights (1 running), 0.03 h" in text  # 90 s to the last checkpoint
    (row,) = [line for line in text.splitlines() if "running (checkpoint" in line]
    assert "cut by a crash" in row


def test_history_plot_has_no_offset_and_no_negative_ticks(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    from ecu_monitor.commands.history import trend_figure

    with StateStore(tmp_path) as store:
        recorder = FlightRecorder(store, SERIAL, LIMIT_C, RULES)
        t = 0.0
        for gamma in (1.0, 1.001, 1.002):  # gamma near 1: matplotlib's default would print "+1" and 0.001
            t = _feed(recorder, t, 120.0, 6000.0, lambda s: 150.0, lambda s, g=gamma: g)  # flat CHT: 0 cycles
            t = _feed(recorder, t, 20.0, 0.0, lambda s: 60.0)
        records = store.flights(SERIAL)
    assert len(records) == 3 and all(r.cycles_total == 0 and r.time_above_limit_s == 0 for r in records)
    fig = trend_figure({SERIAL: records})
    try:
        fig.canvas.draw()
        for ax in fig.axes:
            assert ax.yaxis.get_major_formatter().get_offset() == ""
            low, high = sorted(ax.get_ylim())
            labels = [tick.get_text() for tick in ax.get_yticklabels() if low <= tick.get_position()[1] <= high]
            if ax.get_ylabel().startswith(("thermal cycles", "time above")):
                assert low >= 0.0
                assert not any(text.startswith(("-", "\N{MINUS SIGN}")) for text in labels), labels
    finally:
        plt.close(fig)


def _killed_mid_flight(tmp_path: Path, seconds: float) -> float:
    """A daemon that flew ``seconds`` of a climbing-gamma run and was killed; returns the time reached."""
    store = StateStore(tmp_path)
    recorder = FlightRecorder(store, SERIAL, LIMIT_C, RULES)
    t = _feed(recorder, 0.0, seconds, 6000.0, lambda s: 150.0 + 30.0 * math.sin(s / 5.0), lambda s: 1.0 + s / 3600.0)
    store.close()
    return t


def test_a_restart_mid_run_keeps_one_engine_run_one_flight(tmp_path: Path) -> None:
    """Killed at 100 s (last checkpoint 90 s), restarted 5 s later with the engine still running: the
    run is one flight from its start to its real end, its gamma trend continuous."""
    t = _killed_mid_flight(tmp_path, 100.0)
    with StateStore(tmp_path) as store:
        recorder = FlightRecorder(store, SERIAL, LIMIT_C, RULES)
        (cut,) = recorder.recovered
        t = _feed(recorder, t + 5.0, 200.0, 6000.0, lambda s: 150.0 + 30.0 * math.sin(s / 5.0),
                  lambda s, t0=t + 5.0: 1.0 + t0 / 3600.0 + s / 3600.0)  # fmt: skip
        t = _feed(recorder, t, 20.0, 0.0, lambda s: 60.0)
        (flight,) = store.flights(SERIAL)
    assert recorder.resumed == cut == flight.id
    assert (flight.status, flight.end_reason) == ("finished", "engine_stopped")
    assert flight.duration_s == pytest.approx(305.0, abs=0.3)  # 0 .. 100 + 5 + 200 s, the outage included
    assert flight.gamma_q_start == pytest.approx(1.0, abs=1e-9)
    assert flight.gamma_q_end == pytest.approx(1.0 + 304.9 / 3600.0, abs=1e-6)
    assert flight.gamma_q_slope_per_h == pytest.approx(1.0, rel=0.05)  # d gamma / d hour of the whole run
    assert flight.cycles_total >= 9  # both parts: 90 + 200 s of a 31.4 s period (the second alone: 6.4)


def test_a_restart_after_the_engine_stopped_starts_a_new_flight(tmp_path: Path) -> None:
    t = _killed_mid_flight(tmp_path, 100.0)
    with StateStore(tmp_path) as store:
        recorder = FlightRecorder(store, SERIAL, LIMIT_C, RULES)
        t = _feed(recorder, t + 600.0, 100.0, 6000.0, lambda s: 150.0)  # ten minutes later: another run
        recorder.close()
        first, second = store.flights(SERIAL)
    assert recorder.resumed is None
    assert (first.status, second.status) == ("recovered", "finished")


def _cylinder_sample(t: float, rpm: float, degraded_after_s: float) -> FlightSample:
    """Three cylinders: 2 runs 10 degC hotter than 1, 3 is 5 degC cooler and degrades (gamma_Q rising)."""
    base = 150.0 + 10.0 * math.sin(t / 20.0)
    gamma = 1.0 + max(0.0, t - degraded_after_s) / 1000.0
    state = "DEGRADED" if t >= degraded_after_s + 30.0 else "NOMINAL"
    cylinders = ((base, {"gamma_q": 1.0, "gamma_d": 1.0}, "NOMINAL"),
                 (base + 10.0, {"gamma_q": 1.01, "gamma_d": 1.0}, "NOMINAL"),
                 (base - 5.0, {"gamma_q": gamma, "gamma_d": 1.0}, state))  # fmt: skip
    return FlightSample(t, 1.7e9 + t, rpm, base + 10.0, {"gamma_q": 1.01, "gamma_d": 1.0},
                        state if state == "DEGRADED" else "NOMINAL",
                        cylinders, 15.0 + (t > 100.0), 2, t > 100.0)  # fmt: skip


def test_per_cylinder_aggregates_survive_a_restart_and_old_databases_gain_them(tmp_path: Path) -> None:
    """An engine monitored per cylinder: each cylinder's max CHT, gamma and worst state, the largest spread,
    the alarm time and the hottest cylinder are kept in the flight row, across a restart mid-run; a
    database of schema version 1 gains the column when opened."""
    old = tmp_path / "old"
    old.mkdir()
    write_old_flight_database(old / DATABASE_NAME, version=1)  # a version-1 flights table, without cylinders_json
    with StateStore(old) as store:
        (kept,) = store.flights("OLD")
    assert kept.cylinders == {} and kept.max_cht_c == 150.0
    with StateStore(tmp_path) as store:
        recorder = FlightRecorder(store, SERIAL, LIMIT_C, RULES)
        for i in range(1000):  # 100 s, killed after the checkpoint at 90 s
            recorder.add(_cylinder_sample(i * 0.1, 6000.0, 60.0))
    with StateStore(tmp_path) as store:
        recorder = FlightRecorder(store, SERIAL, LIMIT_C, RULES)
        for i in range(1050, 2050):  # back 5 s later, the engine still running, for 100 s
            recorder.add(_cylinder_sample(i * 0.1, 6000.0, 60.0))
        recorder.close()
        (flight,) = store.flights(SERIAL)
    cyl = flight.cylinders
    one, two, three = cyl["per_cylinder"]
    assert [c["number"] for c in (one, two, three)] == [1, 2, 3]
    assert one["max_cht_c"] == pytest.approx(160.0, abs=0.01) and two["max_cht_c"] == pytest.approx(170.0, abs=0.01)
    assert (one["worst_state"], three["worst_state"]) == ("NOMINAL", "DEGRADED")
    # 90-100 s after the last checkpoint went with the crash, the 5 s outage has no samples: 105-205 s count
    assert three["time_degraded_s"] == pytest.approx(100.0, abs=0.5)
    assert three["gamma_q_start"] == 1.0 and three["gamma_q_end"] == pytest.approx(1.0 + 144.9 / 1000.0)
    assert one["gamma_q_max"] == 1.0 and two["gamma_q_mean"] == pytest.approx(1.01)
    assert cyl["spread_max_c"] == 16.0 and cyl["spread_alarm_s"] == pytest.approx(100.0, abs=0.5)
    assert set(cyl["hottest_s"]) == {"2"} and cyl["hottest_s"]["2"] == pytest.approx(190.0, abs=0.5)


def test_history_prints_and_plots_the_cylinders(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from ecu_monitor.cli import main

    with StateStore(tmp_path) as store:
        recorder = FlightRecorder(store, SERIAL, LIMIT_C, RULES)
        for i in range(1000):
            recorder.add(_cylinder_sample(i * 0.1, 6000.0, 60.0))
        recorder.close()
    plot = tmp_path / "trend.png"
    assert main(["history", "--state-dir", str(tmp_path), "--plot", str(plot)]) == 0
    out = capsys.readouterr().out
    assert "cylinder 3: max CHT 155.0, gQ mean" in out and "worst DEGRADED" in out
    assert "CHT spread max 15.0 degC, spread alarm 0 s; hottest cylinder: 2 100 %" in out
    assert plot.stat().st_size > 10000
