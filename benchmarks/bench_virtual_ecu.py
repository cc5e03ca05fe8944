"""Benchmark of the virtual ECU: truth plant and frame encoding, each against a baseline of the same run.

    .venv/bin/python benchmarks/bench_virtual_ecu.py [--mission default]

1. Truth plant: ``virtual_bus.plant.fly`` over the whole mission (pilot, airframe, RK4 at 0.02 s,
   sensors, recording every 0.1 s) against the model layer's plain numpy loop
   ``ecu_monitor.model.simulate`` over the same number of steps with the same inputs (the baseline:
   what the plant would cost stepping the model's vectorised functions one step at a time).
2. Frames: ``FrameEncoder.frames`` (sampling, clipping, counter, CRC, can.Message) against a bare
   cantools strict ``Message.encode`` of the same ECU_Fast payloads (the baseline).
3. Recording the whole mission to .blf (plant + frames + python-can writer), reported as frames/s.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from ecu_monitor.model import InputSeries, coefficients, paper_table_a1, simulate
from virtual_bus.emitter import FrameEncoder, load_engine_dbc
from virtual_bus.missions import load_mission
from virtual_bus.plant import fly, iter_steps
from virtual_bus.recorder import record


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mission", default="default")
    args = parser.parse_args()
    mission = load_mission(args.mission)
    params = paper_table_a1()

    start = time.perf_counter()
    log = fly(mission, params)
    plant_s = time.perf_counter() - start
    steps = round(log.duration_s / 0.02) + 1
    fine = log.resample(0.02)
    inputs = InputSeries(fine["throttle_pct"], fine["rpm"], fine["altitude_m"], fine["airspeed_mps"], fine["oat_c"])
    start = time.perf_counter()
    simulate(inputs, coefficients(params), 0.02, float(log["cht_true_c"][0]))
    baseline_s = time.perf_counter() - start
    print(f"mission {mission.name}: {log.duration_s:.0f} s of flight, {steps} steps of 0.02 s")
    print(
        f"truth plant fly(): {plant_s:.2f} s ({plant_s / steps * 1e6:.2f} us/step, {log.duration_s / plant_s:.0f}x real"
        f" time); baseline model.simulate numpy loop: {baseline_s:.2f} s ({baseline_s / len(fine) * 1e6:.2f} us/step);"
        f" ratio baseline/plant {baseline_s / len(fine) / (plant_s / steps):.1f}x"
    )

    blocks = list(iter_steps(mission, params, max_duration_s=600.0))
    encoder = FrameEncoder()
    start = time.perf_counter()
    frames = sum(len(encoder.frames(block)) for block in blocks)
    frames_s = time.perf_counter() - start
    fast = load_engine_dbc().get_message_by_name("ECU_Fast")
    rpm = np.concatenate([b.measured.rpm for b in blocks]).tolist()
    throttle = np.concatenate([b.measured.throttle_pct for b in blocks]).tolist()
    fuel = np.concatenate([b.measured.fuel_flow_lph for b in blocks]).tolist()
    start = time.perf_counter()
    for i, (n, th, ff) in enumerate(zip(rpm, throttle, fuel, strict=True)):
        fast.encode(
            {"EngineSpeed": n, "ThrottlePos": th, "FuelFlow": ff, "FastCounter": i % 16, "FastChecksum": 0},
            strict=True,
        )
    strict_s = time.perf_counter() - start
    per_frame, per_strict = frames_s / frames * 1e6, strict_s / len(rpm) * 1e6
    print(
        f"frames: FrameEncoder {per_frame:.1f} us/frame ({frames} frames); baseline cantools strict encode alone"
        f" {per_strict:.1f} us/frame; ratio encoder/baseline {per_frame / per_strict:.2f}"
    )

    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        summary = record(mission, [Path(tmp) / "flight.blf"], params)
        record_s = time.perf_counter() - start
    print(
        f"record .blf: {summary.frames} frames in {record_s:.2f} s ({summary.frames / record_s:.0f} frames/s,"
        f" {summary.duration_s / record_s:.0f}x real time)"
    )


if __name__ == "__main__":
    main()
