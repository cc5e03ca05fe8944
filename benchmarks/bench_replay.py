"""Replay benchmark (issue 5 item 8): a 16-hour .blf through the full pipeline against a naive baseline.

    .venv/bin/python benchmarks/bench_replay.py [--log PATH] [--baseline-minutes 30]

The log (50 Hz ECU_Fast, 10 Hz ECU_Slow and AirData: about 4.0 M frames) is made once by the virtual
ECU's recorder (a 16 h random mission, gamma_Q = 1.15 from 30000 s) into $ECU_MONITOR_BENCH_DIR or
/tmp/ecu-monitor-bench, never into the repository. Measured in one run:

* read only: python-can's LogReader over the whole file (Message objects, nothing else), and the
  service's array reader (:func:`ecu_monitor.bus.canlog.read_frames`);
* full pipeline: ``replay_file`` (read, decode with every check, fixed-step inputs, supervision,
  estimator, open-loop reference, isolation filter, detector, headroom) writing health.csv as it
  runs (a second thread formats the rows the loop has written), as ``ecu-monitor replay`` does; the
  target is the whole of it within 3x the array read, both measured in this run; also the pipeline
  without health.csv, health.csv written alone on one thread, and health.parquet (pyarrow installed);
* naive baseline: python-can LogReader, cantools ``decode_message`` per frame, and a filterpy
  ``ExtendedKalmanFilter`` stepped every 20 ms on the model (RK4 prediction, sigmoid sensor update on
  each CHT frame), over the first ``--baseline-minutes`` of the same log; its cost per second of log
  is scaled to the whole log (it would take several minutes to run it all).

The target's ratio is first measured in fresh processes (``--pairs``, 5 by default): the array read and
the replay with health.csv each in a process of its own, alternating, so that both pay for fresh memory as
a user's ``ecu-monitor replay`` does; each pair's ratio and their median are printed. (The read varies
most between processes: its arrays' page faults.)

Prints a table and the ratio baseline / pipeline. The numba kernels are compiled (or loaded from the
cache) on a short warm-up replay first and that time is reported apart.
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HOURS = 16.0


def bench_dir() -> Path:
    """Where the generated log lives (not the repository)."""
    return Path(os.environ.get("ECU_MONITOR_BENCH_DIR", Path(tempfile.gettempdir()) / "ecu-monitor-bench"))


def ensure_log(path: Path) -> None:
    """Record the 16 h flight once with the virtual ECU."""
    if path.exists():
        return
    from ecu_monitor.model import paper_table_a1
    from virtual_bus.plant import Degradation
    from virtual_bus.random_missions import random_mission
    from virtual_bus.recorder import record

    path.parent.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    print(f"recording {HOURS:g} h flight to {path} (once) ...", flush=True)
    partial = path.with_suffix(".part.blf")
    record(random_mission(7, duration_s=HOURS * 3600.0), [partial], paper_table_a1(),
           degradation=[Degradation.parse("gamma_q=1.15@30000")], seed=7)  # fmt: skip
    partial.rename(path)
    print(f"  recorded in {time.perf_counter() - started:.0f} s", flush=True)


def naive_baseline(path: Path, minutes: float) -> tuple[float, float, int, int]:
    """(wall s, log seconds covered, frames, steps) of the naive replay over the first minutes."""
    import can
    import cantools
    from filterpy.kalman import ExtendedKalmanFilter

    from ecu_monitor.estimation.quantiser import sensor_model, sensor_slope
    from ecu_monitor.model import InputSeries, coefficients, compute_drive, paper_table_a1, rk4_step

    root = Path(__file__).resolve().parents[1]
    db: Any = cantools.database.load_file(str(root / "ecu_monitor" / "data" / "dbc" / "engine.dbc"))
    coeffs = coefficients(paper_table_a1())
    signals = {"EngineSpeed": "rpm", "ThrottlePos": "throttle_pct", "CHT": "cht_c", "OAT": "oat_c",
               "PressureAltitude": "altitude_m", "CalibratedAirspeed": "airspeed_mps"}  # fmt: skip
    held: dict[str, float] = {}
    dt = 0.02
    ekf = ExtendedKalmanFilter(dim_x=1, dim_z=1)
    ekf.Q = np.array([[1e-4]])
    ekf.R = np.array([[1.0 / 12.0 + 0.04]])
    state: dict[str, Any] = {"w": None, "next": None, "new_z": False}

    def slope(v: np.ndarray) -> np.ndarray:
        return np.array([[sensor_slope(float(v[0, 0]), 100.0, 0.5, 1.0)]])

    def level(v: np.ndarray) -> np.ndarray:
        return np.array([[sensor_model(float(v[0, 0]), 100.0, 0.5, 1.0)]])

    def drive() -> Any:
        return compute_drive(InputSeries(held["throttle_pct"], held["rpm"], held["altitude_m"], held["airspeed_mps"],
                                         held["oat_c"]), coeffs)  # fmt: skip

    frames = steps = 0
    first = last = math.nan
    started = time.perf_counter()
    with can.LogReader(str(path)) as reader:
        for msg in reader:
            if math.isnan(first):
                first = msg.timestamp
            if msg.timestamp - first > minutes * 60.0:
                break
            last = msg.timestamp
            while state["next"] is not None and state["next"] <= msg.timestamp:
                d = drive()
                x = float(ekf.x[0, 0])
                x_next, w_next = rk4_step(x, state["w"], d, coeffs, dt)
                x_eps, _ = rk4_step(x + 1e-6, state["w"], d, coeffs, dt)
                ekf.F = np.array([[(float(x_eps) - float(x_next)) / 1e-6]])
                ekf.x = np.array([[float(x_next)]])
                ekf.P = ekf.F @ ekf.P @ ekf.F.T + ekf.Q
                state["w"] = float(w_next)
                if state["new_z"]:
                    ekf.update(np.array([[held["cht_c"]]]), slope, level)
                    state["new_z"] = False
                state["next"] += dt
                steps += 1
            frames += 1
            try:
                decoded = db.decode_message(msg.arbitration_id, msg.data)
            except (KeyError, ValueError, cantools.database.DecodeError):
                continue
            for signal, value in decoded.items():
                if signal in signals:
                    held[signals[signal]] = float(value)
                    if signal == "CHT":
                        state["new_z"] = True
            if state["next"] is None and len(held) == len(signals):
                ekf.x = np.array([[held["cht_c"]]])
                state["w"] = 2.0 * float(drive().q_sl0_w)
                state["next"] = msg.timestamp + dt
    return time.perf_counter() - started, last - first, frames, steps


def phases(log: Path) -> None:
    """Read, replay and health.csv in a fresh process without a warm-up (numba's import and cache loads
    fall in the replay, as in ``ecu-monitor replay``): CPU user + system of each phase."""
    from ecu_monitor.bus.canlog import read_frames
    from ecu_monitor.config import load_config
    from ecu_monitor.offline.replay import replay_frames

    root = Path(__file__).resolve().parents[1]
    config = load_config(root / "ecu_monitor" / "data" / "configs" / "example.yaml")
    params = config.load_cylinder_params()
    marks = [os.times()]
    frames = read_frames(log)
    marks.append(os.times())
    replay_frames(config, params, frames, out=bench_dir() / "health16h_phases.csv")
    marks.append(os.times())
    cpu = [(b.user - a.user, b.system - a.system) for a, b in itertools.pairwise(marks)]
    for name, (user, system) in zip(("read_frames", "replay_frames + health.csv"), cpu, strict=True):
        print(f"{name:14s} CPU {user:.2f} + {system:.2f} = {user + system:.2f} s")
    total = sum(u + s for u, s in cpu)
    print(f"read + replay + health.csv over read: {total / sum(cpu[0]):.2f}x CPU")


def ensure_warmup_log(log: Path) -> Path:
    """The log's first 30,000 frames as a small .blf (once): a fresh process's numba warm-up that leaves
    the big arrays' memory untouched."""
    small = log.with_name(log.stem + "_warmup.blf")
    if not small.exists():
        import can

        partial = small.with_suffix(".part.blf")
        with can.LogReader(str(log)) as reader, can.Logger(str(partial)) as writer:
            for msg in itertools.islice(reader, 30000):
                writer(msg)
        partial.rename(small)
    return small


def child(what: str, log: Path) -> None:
    """One fresh process's measurement, printed as ``wall user system`` (s): the array read, or the replay
    with health.csv as ``ecu-monitor replay`` runs it. Imports and the compile cache's load come first
    (a replay of the small warm-up log), untimed."""
    from ecu_monitor.bus.canlog import read_frames
    from ecu_monitor.config import load_config
    from ecu_monitor.offline.replay import replay_file

    root = Path(__file__).resolve().parents[1]
    config = load_config(root / "ecu_monitor" / "data" / "configs" / "example.yaml")
    params = config.load_params()
    replay_file(ensure_warmup_log(log), config, params)
    started, split = time.perf_counter(), os.times()
    if what == "read":
        read_frames(log)
    else:
        replay_file(log, config, params, out=bench_dir() / "health16h_fresh.csv")
    wall, end = time.perf_counter() - started, os.times()
    print(f"{wall:.4f} {end.user - split.user:.4f} {end.system - split.system:.4f}")


def fresh_pairs(log: Path, pairs: int) -> None:
    """The target in fresh processes: ``pairs`` times the array read then the replay with health.csv, each
    in a process of its own (both pay for fresh memory, as a user's ``ecu-monitor replay`` does); each
    pair's ratio, and their median."""
    import statistics
    import subprocess
    import sys

    ensure_warmup_log(log)
    ratios = []
    print(f"{'pair':>4s} {'read s':>8s} {'(user+sys)':>11s} {'replay s':>9s} {'(user+sys)':>11s} {'ratio':>6s}")
    for n in range(1, pairs + 1):
        measured = {}
        for what in ("read", "replay"):
            done = subprocess.run([sys.executable, __file__, "--log", str(log), "--child", what],
                                  check=True, capture_output=True, text=True)  # fmt: skip
            measured[what] = [float(v) for v in done.stdout.split()[-3:]]
        ratios.append(measured["replay"][0] / measured["read"][0])
        r, p = measured["read"], measured["replay"]
        print(f"{n:4d} {r[0]:8.2f} {r[1]:5.2f}+{r[2]:.2f} {p[0]:9.2f} {p[1]:5.2f}+{p[2]:.2f} {ratios[-1]:5.2f}x")
    median = statistics.median(ratios)
    print(f"target: replay with health.csv within 3x the array read, fresh processes: median {median:.2f}x"
          f" (range {min(ratios):.2f}-{max(ratios):.2f}x over {pairs} pairs)")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--log", type=Path, default=bench_dir() / "flight16h.blf")
    parser.add_argument("--baseline-minutes", type=float, default=30.0)
    parser.add_argument(
        "--phases",
        action="store_true",
        help="only read, replay, health.csv in a fresh process, no warm-up (as ecu-monitor replay)",
    )
    parser.add_argument("--pairs", type=int, default=5,
                        help="fresh-process pairs (read, replay) for the target's ratio; 0: skip")  # fmt: skip
    parser.add_argument("--child", choices=("read", "replay"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child, args.log)
        return
    ensure_log(args.log)
    if args.phases:
        phases(args.log)
        return
    if args.pairs:
        fresh_pairs(args.log, args.pairs)

    import can

    from ecu_monitor.bus.canlog import read_frames
    from ecu_monitor.config import load_config
    from ecu_monitor.offline.replay import replay_file, replay_frames

    root = Path(__file__).resolve().parents[1]
    config = load_config(root / "ecu_monitor" / "data" / "configs" / "example.yaml")
    params = config.load_params()

    started, cpu, split = time.perf_counter(), time.process_time(), os.times()
    frames = read_frames(args.log)
    t_read_arrays = time.perf_counter() - started
    cpu_read_arrays = time.process_time() - cpu
    read_user, read_sys = os.times().user - split.user, os.times().system - split.system
    span = float(frames.time_s[-1] - frames.time_s[0])
    warm = slice(0, 30000)
    started = time.perf_counter()
    replay_frames(config, params, frames.take(warm))
    t_compile = time.perf_counter() - started
    del frames

    started = time.perf_counter()
    count = 0
    with can.LogReader(str(args.log)) as reader:
        for _ in reader:
            count += 1
    t_read_pycan = time.perf_counter() - started

    out = bench_dir() / "health16h.csv"
    started, cpu, split = time.perf_counter(), time.process_time(), os.times()
    result = replay_file(args.log, config, params, out=out)  # health.csv written by a thread as the loop runs
    t_full = time.perf_counter() - started
    cpu_full = time.process_time() - cpu
    first_user, first_sys = os.times().user - split.user, os.times().system - split.system
    rows = len(result)
    split = os.times()
    replay_file(args.log, config, params, out=out)  # again: the process's memory already mapped
    again_user, again_sys = os.times().user - split.user, os.times().system - split.system
    started = time.perf_counter()
    replay_file(args.log, config, params)
    t_pipeline = time.perf_counter() - started
    started = time.perf_counter()
    result.write_csv(out)
    t_csv = time.perf_counter() - started
    t_parquet = math.nan
    try:
        import pyarrow  # noqa: F401

        started = time.perf_counter()
        result.write_csv(out.with_suffix(".parquet"))
        t_parquet = time.perf_counter() - started
    except ModuleNotFoundError:
        pass

    t_naive, covered, naive_frames, naive_steps = naive_baseline(args.log, args.baseline_minutes)
    t_naive_full = t_naive * span / covered

    times = result.columns["time_s"]
    degraded = np.flatnonzero(result.columns["state"] == 2)  # STATES.index("DEGRADED")
    alarm = float(times[degraded[0]]) if degraded.size else math.nan
    t0 = float(times[0])
    print(f"log: {args.log} ({args.log.stat().st_size / 1e6:.0f} MB), {count} frames, {span / 3600:.2f} h")
    print(f"{'operation':58s} {'wall s':>8s}")
    print(f"{'python-can LogReader, read only (Message objects)':58s} {t_read_pycan:8.2f}")
    print(f"{'service read_frames (arrays)':58s} {t_read_arrays:8.2f}")
    print(f"{'numba compile / cache load (warm-up, once per process)':58s} {t_compile:8.2f}")
    print(f"{'full pipeline: read + decode + steps + filters + detector':58s} {t_pipeline:8.2f}")
    print(f"{'  with health.csv written beside the loop (a second thread)':58s} {t_full:8.2f}")
    print(f"{'health.csv alone, one thread (' + str(rows) + ' rows)':58s} {t_csv:8.2f}")
    print(f"{'health.parquet alone (pyarrow; nan: not installed)':58s} {t_parquet:8.2f}")
    hugepage = os.environ.get("NUMPY_MADVISE_HUGEPAGE", "unset")
    print(f"CPU user + system: read {read_user:.2f} + {read_sys:.2f} s; pipeline + health.csv, first replay"
          f" {first_user:.2f} + {first_sys:.2f} s, second replay {again_user:.2f} + {again_sys:.2f} s"
          f" (system: page faults of fresh arrays; NUMPY_MADVISE_HUGEPAGE={hugepage})")  # fmt: skip
    print(f"target: pipeline + health.csv within 3x the array read: {t_full / t_read_arrays:.2f}x wall,"
          f" {cpu_full / cpu_read_arrays:.2f}x CPU ({cpu_full:.2f} s / {cpu_read_arrays:.2f} s)")  # fmt: skip
    print(f"{'naive baseline, measured over ' + f'{covered / 60:.0f} min ({naive_frames} frames)':58s} {t_naive:8.2f}")
    print(f"{'naive baseline scaled to the whole log':58s} {t_naive_full:8.2f}")
    print(f"ratio naive / pipeline: {t_naive_full / t_pipeline:.1f}x (with health.csv written: "
          f"{t_naive_full / t_full:.1f}x); pipeline {span / t_full:.0f}x faster than real time")  # fmt: skip
    print(f"pipeline: {result.counters['steps']} steps, {rows} health rows, malformed {result.counters['malformed']}, "
          f"DEGRADED from t = {alarm - t0:.0f} s (gamma_Q 1.15 injected at 30000 s)")  # fmt: skip
    from ecu_monitor.research.detection_limit import limit_step

    feed_t, feed_v = replay_file(args.log, config, params, keep_feeds=True).detector_feed[0]  # after the timing
    onset = 30000.0  # the log's gamma_Q step, s after its first frame
    rel = feed_t - t0
    step = float(np.nanmean(feed_v[(rel >= onset) & (rel < onset + 60.0)])
                 - np.nanmean(feed_v[(rel >= onset - 300.0) & (rel < onset)]))  # fmt: skip
    suspect_s = float(np.count_nonzero(result.columns["state"] == 1)) * 0.1  # STATES.index("SUSPECT"), 10 Hz rows
    print(f"detector at the onset: symptom step {step:.3f} degC/s against Delta* {limit_step(config.detector):.3f}"
          f" (research.detection_limit); SUSPECT for {suspect_s:.0f} s in all")  # fmt: skip
    print(f"naive baseline: {naive_steps} filter steps, {t_naive / max(naive_steps, 1) * 1e6:.0f} us per step")


if __name__ == "__main__":
    main()
