"""The fleet: a virtual fleet's ranking, throughput, the speed-up of two workers over one, memory per worker;
the real flights as a fleet.

    nice -n 10 .venv/bin/python benchmarks/bench_fleet.py virtual [--fleet DIR] [--engines 20] [--flights 200]
        [--seed 0] [--json OUT.json]
    nice -n 10 .venv/bin/python benchmarks/bench_fleet.py real [--data ../shared/data] [--out DIR]
        [--screenshot docs/fleet_report.png]

``virtual``: the fleet of ``ecu-monitor fleet demo`` (fleet/demo.py: 20 engines, 200 short random missions of
the virtual ECU with residual unmodelled effects, three engines wearing at gamma_Q +0.03, +0.02, +0.015 a
flight; ``--fleet DIR`` reuses one made before, else it is made here). Targets: the three degrading engines
ranked 1-3 with their alerts and no other engine alerted. Then the same logs are run by ``fleet run`` on a local
Dask cluster of one worker process and of two (each into a fresh folder; every worker first loads the kernels
from the on-disk cache, so compiling is not timed): flights per core-minute, the speed-up of two workers over
one (target >= 1.7), each worker's peak resident memory (target < 1 GB). The machine's load average is printed
before and after: the machine is shared, and a loaded machine lowers the speed-up.

``real``: the flights of ../shared/data (real/ and g1000/) as a fleet, one engine per airframe (each engine of
the PA-44 twin its own), each replayed with the model identified on its airframe's flights in
docs/results/gap/ (the gap diagnosis's nominal models; fuel flow and rpm, or fuel flow and manifold pressure
for the PA-44): processed, the report written (``--screenshot``: Chromium's picture of it).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


def _peak_rss_mb() -> float:
    """This process's peak resident memory, MB (Linux ru_maxrss is in kB)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _warm(log: str) -> float:
    """Load the kernels on this worker (one reference flight summarised); its wall time, s."""
    from ecu_monitor.fleet.spec import EngineSettings, LogJob
    from ecu_monitor.fleet.summary import summarise_log
    from ecu_monitor.shipped import DEFAULT_CONFIG

    started = time.perf_counter()
    engine = EngineSettings("warm", Path(DEFAULT_CONFIG), None, None, None, None, None, 0.0)
    summarise_log(LogJob("warm", Path(log), Path(log).name, 0, "warm"), engine)
    return time.perf_counter() - started


def _timed_run(fleet_file: Path, out: Path, workers: int, warm_log: Path) -> dict[str, Any]:
    from ecu_monitor.fleet.run import open_client, run_fleet

    client = open_client(None, workers)
    try:
        client.run(_warm, str(warm_log))
        started = time.perf_counter()
        run = run_fleet(fleet_file, out, client=client, say=lambda line: print(f"  [{workers}w] {line}", flush=True))
        wall = time.perf_counter() - started
        peaks = client.run(_peak_rss_mb)
    finally:
        cluster = client.cluster
        client.close()
        cluster.close()
    return {"workers": workers, "wall_s": wall, "flights": run.processed, "failed": len(run.failed),
            "task_cpu_s": run.task_cpu_s, "peak_rss_mb": sorted(peaks.values()),
            "flights_per_core_min": run.processed / (wall * workers / 60.0), "engines": run.engines}  # fmt: skip


def run_virtual(args: argparse.Namespace) -> dict[str, Any]:
    from ecu_monitor.fleet.demo import make_virtual_fleet
    from ecu_monitor.fleet.run import open_client

    load_before = os.getloadavg()
    if args.fleet:
        root = Path(args.fleet)
    else:
        root = Path(tempfile.mkdtemp(prefix="bench-fleet-")) / "fleet"
        client = open_client(None, 2)
        try:
            make_virtual_fleet(root, client, engines=args.engines, flights=args.flights, seed=args.seed)
        finally:
            cluster = client.cluster
            client.close()
            cluster.close()
    truth = json.loads((root / "truth.json").read_text())["degrading"]
    warm_log = sorted((root / "reference").iterdir())[0]
    runs = []
    for workers in (1, 2):
        out = root / f"bench-out-{workers}"
        shutil.rmtree(out, ignore_errors=True)
        runs.append(_timed_run(root / "FLEET.yaml", out, workers, warm_log))
    engines = runs[1]["engines"]
    ranked = [(e["rank"], e["serial"], e["alert"], e["alert_flight"], e["flights"]) for e in engines]
    top = {e["serial"] for e in engines[: len(truth)]}
    alerted = {e["serial"] for e in engines if e["alert"]}
    one, two = runs
    result = {
        "fleet": str(root),
        "degrading": truth,
        "ranked": ranked,
        "targets": {
            "degrading_ranked_first": top == set(truth),
            "alerts_exactly_the_degrading": alerted == set(truth),
            "speedup_two_over_one": one["wall_s"] / two["wall_s"],
            "max_worker_rss_mb": max(one["peak_rss_mb"] + two["peak_rss_mb"]),
        },
        "runs": [{k: v for k, v in r.items() if k != "engines"} for r in runs],
        "load_average_before": load_before,
        "load_average_after": os.getloadavg(),
        "cores": os.cpu_count(),
    }
    return result


def run_real(args: argparse.Namespace) -> dict[str, Any]:
    from ecu_monitor.fleet.run import run_fleet

    data = Path(args.data).resolve()
    models = ROOT / "docs" / "results" / "gap"
    out = Path(args.out or tempfile.mkdtemp(prefix="bench-fleet-real-"))
    out.mkdir(parents=True, exist_ok=True)
    fleet = out / "FLEET.yaml"
    engines = [
        ("N550ND", "real/n550nd_2train_2test", "real/ngafid_c172s_n550nd_*.csv", ""),
        ("C172S-25BA", "real/cafuc_25BA_split", "real/cafuc_c172s_25BA_*.csv", ""),
        ("C172R-2D87", "real/cafuc_2D87_split", "real/cafuc_c172r_2D87_*.csv", ""),
        ("PA44-E1", "real/pa44_e1_split", "real/ngafid_pa44_*.csv", ", config: manifold.yaml, engine: 1"),
        ("PA44-E2", "real/pa44_e2_split", "real/ngafid_pa44_*.csv", ", config: manifold.yaml, engine: 2"),
        ("C172S-KGFK", "g1000", "g1000/*.csv", ""),
    ]
    lines = ["engines:"]
    for serial, model, logs, extra in engines:
        lines.append(
            f"  - {{serial: {serial}, model: '{models / model / 'model.yaml'}', logs: ['{data / logs}']{extra}}}"
        )
    fleet.write_text("\n".join(lines) + "\n")
    started = time.perf_counter()
    run = run_fleet(fleet, out / "out", workers=2, say=lambda line: print(f"  {line}", flush=True))
    result = {
        "fleet": str(fleet),
        "wall_s": time.perf_counter() - started,
        "processed": run.processed,
        "failed": run.failed,
        "engines": [(e["rank"], e["serial"], e["flights"], round(e["hours"], 2), e["reason"]) for e in run.engines],
        "report": str(out / "out" / "report.html"),
    }
    if args.screenshot:
        chromium = shutil.which("chromium") or shutil.which("chromium-browser")
        if chromium is None:
            raise SystemExit("--screenshot: no chromium (apt-get install chromium)")
        _screenshot(chromium, out / "out" / "report.html", Path(args.screenshot), out / "profile")
    return result


def _screenshot(chromium: str, page: Path, png: Path, profile: Path) -> None:
    subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                    f"--user-data-dir={profile}", "--window-size=1280,1500", f"--screenshot={png.resolve()}",
                    page.resolve().as_uri()], check=True, capture_output=True, timeout=120)  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="mode", required=True)
    virtual = sub.add_parser("virtual")
    virtual.add_argument("--fleet", help="a folder made by ecu-monitor fleet demo (default: make one here)")
    virtual.add_argument("--engines", type=int, default=20)
    virtual.add_argument("--flights", type=int, default=200)
    virtual.add_argument("--seed", type=int, default=0)
    virtual.add_argument("--screenshot", help="also Chromium's picture of the two-worker run's report.html")
    virtual.add_argument("--json")
    real = sub.add_parser("real")
    real.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    real.add_argument("--out")
    real.add_argument("--screenshot")
    real.add_argument("--json")
    args = parser.parse_args()
    result = run_virtual(args) if args.mode == "virtual" else run_real(args)
    if args.mode == "virtual" and args.screenshot:
        chromium = shutil.which("chromium") or shutil.which("chromium-browser")
        if chromium is None:
            raise SystemExit("--screenshot: no chromium (apt-get install chromium)")
        fleet = Path(result["fleet"])
        _screenshot(chromium, fleet / "bench-out-2" / "report.html", Path(args.screenshot), fleet / "profile")
    text = json.dumps(result, indent=2, default=str)
    print(text)
    if args.json:
        Path(args.json).write_text(text)
    sys.exit(0)


if __name__ == "__main__":
    main()
