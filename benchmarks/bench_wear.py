"""Across flights: the maintenance alert on slow wear, virtual ECU and real N550ND flights.

    .venv/bin/python benchmarks/bench_wear.py virtual [--reference 10] [--nominal 100] \\
        [--campaigns 3] [--flights 20] [--step 0.005] [--min-duration 1200] [--max-duration 3600] [--jobs 2]
        [--json OUT.json]
    .venv/bin/python benchmarks/bench_wear.py real FLIGHT.csv ... --mapping g1000 [--heat-axes fuel_flow_lph,rpm] \\
        [--identify-args "..."] [--sequence 30] [--repeats 20] [--k-step 0.01] [--check-k 0.1] [--jobs 2]
        [--json OUT.json]

Each flight's wear index is the one rule of ``ecu_monitor.estimation.wear`` (:class:`FlightWear`) over what
the service's replay feeds its detector (``ReplayResult.reference_feed``: the held CHT, the open-loop
reference model's CHT and OAT where the supervisor is NOMINAL); the CUSUM over flights is
:func:`wear_verdict` with the shipped :class:`WearSettings` (h from one false alert in 2000 nominal flights).

``virtual``: the truth plant carries the residual unmodelled effects of the detection campaigns
(``research.evaluation.residual_effects``, drawn per flight); missions are random
(``random_missions.random_mission``), seeds disjoint between the sets and never tuned:

* reference: ``--reference`` nominal flights -> the engine's reference (mean, sd, flights), as
  ``ecu-monitor calibrate`` stores it;
* nominal: ``--nominal`` more nominal flights in a row: any alert is a false alert;
* wear: ``--campaigns`` campaigns of ``--flights`` flights with gamma_Q = 1 + step x (flight - 1) from engine
  start (``virtual_bus.campaign``): the flight of the alert and its gamma_Q (target: before 1.1).

``real``: identify a model on all but one of the given flights (``ecu-monitor identify``, ``--effects`` as
the commissioning guide) for each flight in turn; each flight's wear index is measured with the model that
never saw it (leave one flight out), nominal and with the overlay CHT + k (CHT - OAT)(1 - exp(-t/240 s))
from engine start (``detection.overlay_degradation``, t0 = 0): the overlaid flight's index is taken from the
nominal replay's reference feed with the overlay applied to its CHT (the overlay changes the CHT only; the
open-loop reference runs from the first reading, which it leaves as it is), checked against full replays of
the overlaid flight for each ``--check-k``. The reference is those held-out nominal
indices (mean, sd, number of flights). A sequence of ``--sequence`` flights is drawn at random (with
replacement) from the given flights: nominal (any alert is false) and with k = k_step x (flight - 1) (the
flight of the alert and its k; target: before k = 0.12).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import multiprocessing
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from ecu_monitor.estimation.wear import FlightWear, WearSettings, reference_from_flights, wear_verdict

ROOT = Path(__file__).resolve().parent.parent


def wear_index(result: Any, settings: WearSettings) -> float | None:
    """A replay's wear index over its reference feed (the one rule, FlightWear)."""
    wear = FlightWear(settings)
    for feed in result.reference_feed:
        wear.add_many(feed.cht_c, feed.model_c, feed.oat_c)
    return wear.index


# --- virtual -----------------------------------------------------------------------------------------


def _virtual_flight(job: tuple[int, float, float]) -> tuple[int, float, float | None, float]:
    """(seed, gamma_Q, duration) -> (seed, gamma_Q, wear index, CPU s)."""
    from ecu_monitor.config import load_config
    from ecu_monitor.offline.replay import frames_from_flight, replay_frames
    from ecu_monitor.pipeline.engine import model_input_names
    from ecu_monitor.research.evaluation import residual_effects
    from ecu_monitor.shipped import DEFAULT_CONFIG
    from virtual_bus.campaign import WearSchedule
    from virtual_bus.plant import fly
    from virtual_bus.random_missions import random_mission

    seed, gamma_q, duration_s = job
    started = time.process_time()
    config = load_config(DEFAULT_CONFIG)
    params = config.load_cylinder_params()[0]
    degradation = WearSchedule("gamma_q", gamma_q - 1.0).degradation(2)  # gamma_q from engine start (none at 1)
    log = fly(
        random_mission(seed, duration_s), params, effects=residual_effects(seed), degradation=degradation, seed=seed
    )
    frames = frames_from_flight(log, config, model_input_names(params, config.input_names))
    result = replay_frames(config, params, frames, keep_reference=True)
    return seed, gamma_q, wear_index(result, config.wear), time.process_time() - started


def run_virtual(args: argparse.Namespace) -> dict[str, Any]:
    settings = WearSettings()
    rng = np.random.default_rng(args.seed)
    duration = lambda: float(rng.uniform(args.min_duration, args.max_duration))  # noqa: E731 - randomised lengths
    jobs: list[tuple[str, int, tuple[int, float, float]]] = []
    base = 700_000 + 10_000 * args.seed
    for i in range(args.reference):
        jobs.append(("reference", i, (base + i, 1.0, duration())))
    for c in range(args.campaigns):
        for n in range(1, args.flights + 1):
            jobs.append((f"wear{c}", n, (base + 5000 + 100 * c + n, 1.0 + args.step * (n - 1), duration())))
    for i in range(args.nominal):
        jobs.append(("nominal", i, (base + 1000 + i, 1.0, duration())))
    started = time.perf_counter()
    with multiprocessing.get_context("spawn").Pool(args.jobs) as pool:
        results = []
        for done, out in enumerate(pool.imap(_virtual_flight, [j[2] for j in jobs]), 1):
            results.append(out)
            if args.partial:  # each flight as it comes: a long run stopped early keeps what it measured
                with open(args.partial, "a") as stream:
                    stream.write(json.dumps({"set": jobs[done - 1][0], "seed": out[0], "gamma_q": out[1],
                                             "index": out[2]}) + "\n")  # fmt: skip
            if done % 10 == 0 or done == len(jobs):
                print(
                    f"  {done}/{len(jobs)} flights, {time.perf_counter() - started:.0f} s", file=sys.stderr, flush=True
                )
    by_set: dict[str, list[tuple[int, float, float | None]]] = {}
    cpu = 0.0
    for (name, _, _), (seed, gamma, index, cpu_s) in zip(jobs, results, strict=True):
        by_set.setdefault(name, []).append((seed, gamma, index))
        cpu += cpu_s
    reference = reference_from_flights([i for _, _, i in by_set["reference"]])
    if reference is None:
        raise SystemExit("reference: fewer than 3 flights with a wear index")
    nominal = [i for _, _, i in by_set.get("nominal", [])]
    verdict = wear_verdict(nominal, settings, reference)
    peak = max((s for s in verdict.statistic if s is not None), default=0.0)
    out: dict[str, Any] = {
        "reference": {
            "mean": reference.mean,
            "sd": reference.sd,
            "flights": reference.flights,
            "sd_upper": reference.sd_upper(settings.spread_confidence),
        },
        "threshold": verdict.threshold,
        "nominal": {"flights": len(nominal), "alert_at": verdict.alert_at, "max_statistic": peak, "indices": nominal},
        "campaigns": [],
        "cpu_s": cpu,
        "wall_s": time.perf_counter() - started,
    }
    print(
        f"reference: {reference.flights} nominal flights, wear index mean {reference.mean:+.4f}, sd {reference.sd:.4f}"
        f" (upper bound used {reference.sd_upper(settings.spread_confidence):.4f}); h = {verdict.threshold:.2f}"
    )
    alert = "none" if verdict.alert_at is None else f"at nominal flight {verdict.alert_at + 1}"
    print(
        f"nominal: {len(nominal)} flights, alert {alert}, largest CUSUM {peak:.2f} (h {verdict.threshold:.2f});"
        f" index mean {np.mean(nominal):+.4f}, sd {np.std(nominal, ddof=1):.4f}"
    )
    for c in range(args.campaigns):
        flights = by_set[f"wear{c}"]
        v = wear_verdict([i for _, _, i in flights], settings, reference)
        at = v.alert_at
        gamma = None if at is None else flights[at][1]
        out["campaigns"].append(
            {
                "alert_flight": None if at is None else at + 1,
                "alert_gamma_q": gamma,
                "indices": [i for _, _, i in flights],
                "statistic": list(v.statistic),
            }
        )
        said = "no alert" if at is None else f"alert after flight {at + 1} (gamma_Q {gamma:.3f})"
        print(f"wear campaign {c + 1}: gamma_Q +{args.step:g} a flight from 1.0: {said}")
    print(f"CPU {cpu:.0f} s over {len(jobs)} flights, wall {out['wall_s']:.0f} s")
    return out


# --- real --------------------------------------------------------------------------------------------


def _identify(train: list[Path], out: Path, args: argparse.Namespace) -> None:
    command = [
        sys.executable,
        "-m",
        "ecu_monitor.cli",
        "identify",
        *map(str, train),
        "--out",
        str(out),
        "--heat-axes",
        args.heat_axes,
        *args.identify_args.split(),
    ]
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)


def _overlaid_index(result: Any, settings: WearSettings, t0_s: float, k: float) -> float | None:
    """The wear index of the flight with the overlay of gain k from engine start, from its nominal replay's
    reference feed: the overlay changes the CHT only, and the open-loop reference runs from the first reading,
    which the overlay leaves as it is (1 - exp(0) = 0); a full replay of the overlaid flight checks it."""
    from ecu_monitor.estimation.detection import overlay_degradation

    wear = FlightWear(settings)
    for feed in result.reference_feed:
        cht = feed.cht_c if k == 0.0 else overlay_degradation(feed.time_s - t0_s, feed.cht_c, feed.oat_c, 0.0, k)
        wear.add_many(cht, feed.model_c, feed.oat_c)
    return wear.index


def run_real(args: argparse.Namespace) -> dict[str, Any]:
    from ecu_monitor.bus.canlog import load_flight
    from ecu_monitor.config import load_config
    from ecu_monitor.estimation.detection import overlay_degradation
    from ecu_monitor.flightlog import import_mapped_csv, resolve_mapping, write_csv
    from ecu_monitor.model import load_model
    from ecu_monitor.offline.replay import frames_from_flight, replay_frames
    from ecu_monitor.pipeline.engine import model_input_names
    from ecu_monitor.shipped import DEFAULT_CONFIG

    settings = WearSettings()
    config = load_config(DEFAULT_CONFIG)
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="bench_wear_"))
    work.mkdir(parents=True, exist_ok=True)
    canon = []
    for path in map(Path, args.flights):
        log = import_mapped_csv(path, resolve_mapping(args.mapping)) if args.mapping else load_flight(path)
        target = work / f"{path.stem}.csv"
        write_csv(log, target)
        canon.append(target)
    logs = [load_flight(p) for p in canon]
    k_values = sorted({round(args.k_step * n, 6) for n in range(args.sequence)})
    table: dict[int, dict[float, float | None]] = {}
    started = time.perf_counter()
    models = [work / f"model_{held}.yaml" for held in range(len(canon))]
    missing = [held for held, m in enumerate(models) if not m.exists()]  # --work keeps the fold models
    with concurrent.futures.ThreadPoolExecutor(max(1, args.jobs)) as pool:
        list(pool.map(lambda held: _identify([p for i, p in enumerate(canon) if i != held], models[held], args),
                      missing))  # fmt: skip
    print(f"  fold models ready ({time.perf_counter() - started:.0f} s)", file=sys.stderr, flush=True)
    checks: list[tuple[str, float, float | None, float | None]] = []
    for held, path in enumerate(canon):
        params = load_model(models[held])
        needed = model_input_names(params, config.input_names)
        log = logs[held]
        result = replay_frames(config, params, frames_from_flight(log, config, needed), keep_reference=True)
        t0 = float(log["time_s"][0])
        table[held] = {k: _overlaid_index(result, settings, t0, k) for k in k_values}
        for k in args.check_k:  # the shortcut against a full replay of the overlaid flight
            time_s = log["time_s"] - t0
            overlaid = log.with_columns(cht_c=overlay_degradation(time_s, log["cht_c"], log["oat_c"], 0.0, k))
            full = wear_index(replay_frames(config, params, frames_from_flight(overlaid, config, needed),
                                            keep_reference=True), settings)  # fmt: skip
            checks.append((path.stem, k, _overlaid_index(result, settings, t0, k), full))
        print(f"  {path.stem}: nominal index {table[held][0.0]} ({time.perf_counter() - started:.0f} s)",
              file=sys.stderr, flush=True)  # fmt: skip
    for name, k, short, full in checks:
        print(f"  check {name} k {k:g}: index from the nominal replay's feed {short}, from a replay of the overlaid"
              f" flight {full}")  # fmt: skip
    reference = reference_from_flights([table[i][0.0] for i in table])
    if reference is None:
        raise SystemExit("reference: fewer than 3 flights with a wear index")
    rng = np.random.default_rng(args.seed)
    out: dict[str, Any] = {
        "indices": {canon[i].stem: {str(k): v for k, v in table[i].items()} for i in table},
        "reference": {"mean": reference.mean, "sd": reference.sd, "flights": reference.flights},
        "sequences": [],
    }
    print(
        f"reference (held-out nominal indices of {reference.flights} flights): mean {reference.mean:+.4f},"
        f" sd {reference.sd:.4f}, upper bound used {reference.sd_upper(settings.spread_confidence):.4f};"
        f" h = {settings.threshold:.2f}"
    )
    for i in table:
        print(f"  {canon[i].stem}: " + ", ".join(f"k {k:g}: {v:+.4f}" for k, v in table[i].items() if v is not None))
    alerts_nominal = alerts_late = 0
    for s in range(args.repeats):
        draw = rng.integers(0, len(canon), size=args.sequence)
        nominal = [table[int(i)][0.0] for i in draw]
        worn = [table[int(i)][k_values[n]] for n, i in enumerate(draw)]
        vn = wear_verdict(nominal, settings, reference)
        vw = wear_verdict(worn, settings, reference)
        k_alert = None if vw.alert_at is None else k_values[vw.alert_at]
        alerts_nominal += vn.alerted
        alerts_late += k_alert is None or k_alert >= 0.12
        out["sequences"].append(
            {
                "draw": draw.tolist(),
                "nominal_alert_at": vn.alert_at,
                "wear_alert_k": k_alert,
                "nominal_max_statistic": max(x for x in vn.statistic if x is not None),
            }
        )
        said = "no alert" if k_alert is None else f"alert at k = {k_alert:g} (flight {vw.alert_at + 1})"
        print(
            f"sequence {s + 1}: nominal {'ALERT at flight ' + str(vn.alert_at + 1) if vn.alerted else 'no alert'};"
            f" k +{args.k_step:g} a flight: {said}"
        )
    print(
        f"{args.repeats} sequences of {args.sequence}: false alerts {alerts_nominal}, alerts not before k = 0.12"
        f" {alerts_late}; wall {time.perf_counter() - started:.0f} s"
    )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="part", required=True)
    virtual = sub.add_parser("virtual")
    virtual.add_argument("--reference", type=int, default=10)
    virtual.add_argument("--nominal", type=int, default=100)
    virtual.add_argument("--campaigns", type=int, default=3)
    virtual.add_argument("--flights", type=int, default=20)
    virtual.add_argument("--step", type=float, default=0.005)
    virtual.add_argument("--seed", type=int, default=0)
    virtual.add_argument("--min-duration", type=float, default=1200.0, help="random mission length, s: from")
    virtual.add_argument("--max-duration", type=float, default=3600.0, help="to")
    virtual.add_argument("--jobs", type=int, default=2)
    virtual.add_argument("--json")
    virtual.add_argument("--partial", help="append each flight's result here (JSON lines) as it comes")
    real = sub.add_parser("real")
    real.add_argument("flights", nargs="+")
    real.add_argument("--mapping")
    real.add_argument("--heat-axes", default="fuel_flow_lph,rpm")
    real.add_argument("--identify-args", default="", help="more identify options, one string")
    real.add_argument("--sequence", type=int, default=30)
    real.add_argument("--repeats", type=int, default=10, help="random sequences drawn")
    real.add_argument("--k-step", type=float, default=0.01)
    real.add_argument("--seed", type=int, default=0)
    real.add_argument("--jobs", type=int, default=2, help="fold identifications at once")
    real.add_argument("--check-k", type=float, action="append", default=[], help="k checked by a full replay")
    real.add_argument("--work", help="folder for the canonical flights and fold models (kept; reused)")
    real.add_argument("--json")
    args = parser.parse_args()
    out = run_virtual(args) if args.part == "virtual" else run_real(args)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=lambda v: None if v is None else float(v)))


if __name__ == "__main__":
    main()
