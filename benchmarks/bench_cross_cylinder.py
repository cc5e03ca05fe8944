"""The cross-cylinder symptom against each cylinder's own: nominal noise, nominal CUSUM, held-out false
alarms, on real four-cylinder flights (leave one flight out) and on virtual ones (docs/results/cylinders.md).

    nice -n 10 .venv/bin/python benchmarks/bench_cross_cylinder.py real FLIGHT.csv ... --models-dir DIR [--plot P]
    nice -n 10 .venv/bin/python benchmarks/bench_cross_cylinder.py virtual [--flights 4] [--per-cylinder-effects]

``real``: each flight in turn held out; each cylinder's model for that fold is
``DIR/fold_<flight stem>/*_cyl<n>.yaml`` (identified on the other flights: ``identify --cylinder all``
without the held-out one), the config four_cylinders.yaml with the shipped cross-cylinder settings. The
four flights are replayed with the fold's models; ``ecu-monitor calibrate``'s cross-cylinder procedure
(offline/calibration_cross.py: threshold per cylinder from the training flights, kept only where none of
them alarms when held out) runs on the training flights, and the held-out flight's cross-cylinder
statistic is compared with it. Printed per fold and cylinder: the threshold (or off), the held-out
flight's maximum, whether it alarms; and, for comparison, the same for the own symptom with the same
detector settings (not calibrate's choice of baseline).

``virtual``: nominal one-hour four-cylinder flights of the virtual ECU (random missions, seeds 201..,
cylinders differing as in bench_cylinders.py) with the evaluation's residual unmodelled effects in the
truth (``research.evaluation.residual_effects``; the monitor's models are the cylinders' without them);
``--per-cylinder-effects``: each effect's size drawn per cylinder (x 0.7-1.3), not common to all. Printed:
per flight and cylinder the maximum of the CUSUM on the own and on the cross symptom (the shipped
settings, no alarm), the standard deviation of their 1 s block means, and the threshold calibrate's
procedure would set on them.

Both print the median block-mean standard deviation of each symptom: how much of the nominal
symptom is common to the cylinders.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np


def _stem(path: str) -> str:
    return Path(path).stem


def _own_feeds(result: Any, count: int) -> list[Any]:
    """Per cylinder, the own symptom it was fed (the replay's per-cylinder deviation at the health rows,
    where the cylinder's supervisor said NOMINAL)."""
    c = result.columns
    t = c["time_s"]
    out = []
    for n in range(1, count + 1):
        symptom = np.where(c[f"cyl{n}_state"] <= 2, c[f"cyl{n}_deviation"], np.nan)
        out.append(((t, symptom),))
    return out


def _block_sd(feed: Any, settings: Any) -> float:
    from ecu_monitor.estimation.detection import block_means

    values = [block_means(t, x, settings)[1] for t, x in feed]
    joined = np.concatenate(values) if values else np.empty(0)
    return float(np.nanstd(joined)) if np.isfinite(joined).any() else math.nan


def real(args: argparse.Namespace) -> None:
    from ecu_monitor.config import load_config
    from ecu_monitor.model import load_model
    from ecu_monitor.offline.calibration import calibrate_flights
    from ecu_monitor.offline.calibration_cross import calibrate_cross
    from ecu_monitor.offline.calibration_replays import FlightFeeds
    from ecu_monitor.offline.replay import replay_file

    config = load_config("four_cylinders.yaml")
    count = len(config.cylinder_inputs)
    own_settings = config.cylinder_detector(1)
    cross_alarms = own_alarms = 0
    sd_own: list[float] = []
    sd_cross: list[float] = []
    plot_data = None
    print("| held-out flight | cylinder | cross h (train) | cross max held out | cross alarm | own h (train) |"
          " own max held out | own alarm |")  # fmt: skip
    print("|---|---:|---:|---:|---|---:|---:|---|")
    for held in args.held_out or args.flights:
        fold = Path(args.models_dir) / f"fold_{_stem(held).split('_', 3)[-1]}"
        models = [load_model(next(iter(sorted(fold.glob(f"*_cyl{n}.yaml"))))) for n in range(1, count + 1)]
        train = [f for f in args.flights if f != held]
        cross: list[list[FlightFeeds]] = [[] for _ in range(count)]
        own: list[list[FlightFeeds]] = [[] for _ in range(count)]
        for path in [*train, held]:  # one replay per flight: what each cylinder's two detectors are fed
            result = replay_file(path, config, models, keep_feeds=True)
            t = result.columns["time_s"]
            for n, feed in enumerate(_own_feeds(result, count)):
                own[n].append(FlightFeeds(Path(path).name, feed, float(t[0]), float(t[-1]), math.nan, ()))
                cross[n].append(
                    FlightFeeds(Path(path).name, result.cross_feeds[n], float(t[0]), float(t[-1]), math.nan, ())
                )
        results = calibrate_cross([c[:-1] for c in cross], config, args.rate)
        for n in range(count):
            settings = config.cross_detector(n + 1)
            assert settings is not None
            held_cross = cross[n][-1].statistic_for(settings)
            sd_cross.append(_block_sd(cross[n][-1].feed, settings))
            sd_own.append(_block_sd(own[n][-1].feed, own_settings))
            h_cross = results[n].calibration.threshold if results[n] is not None else math.inf
            alarm_cross = held_cross.max_statistic >= h_cross
            own_cal = calibrate_flights([f.statistic_for(own_settings) for f in own[n][:-1]], args.rate, own_settings)
            h_own = own_cal.calibration.threshold
            held_own = own[n][-1].statistic_for(own_settings).max_statistic
            cross_alarms += alarm_cross
            own_alarms += held_own >= h_own
            print(f"| {_stem(held)} | {n + 1} | {'off' if math.isinf(h_cross) else f'{h_cross:.2f}'} |"
                  f" {held_cross.max_statistic:.2f} | {'**yes**' if alarm_cross else 'no'} | {h_own:.2f} |"
                  f" {held_own:.2f} | {'**yes**' if held_own >= h_own else 'no'} |")  # fmt: skip
            if plot_data is None:
                plot_data = (held, own[n][-1], cross[n][-1], own_settings, settings, n + 1)
                if args.plot:  # drawn at once: the first held-out flight, cylinder 1
                    _plot(args.plot, *plot_data)
    print()
    print(f"held-out flights x cylinders: cross-cylinder detector alarms {cross_alarms}, own symptom (same"
          f" settings, h from the training flights) alarms {own_alarms}, of {len(sd_own)};"
          f" median 1 s block-mean SD own {np.nanmedian(sd_own):.4f}, cross {np.nanmedian(sd_cross):.4f}")  # fmt: skip


def _plot(path: str, flight: str, own: Any, cross: Any, own_settings: Any, cross_settings: Any, number: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ecu_monitor.estimation.detection import block_means

    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for label, feed, settings, color in (("own symptom", own, own_settings, "tab:blue"),
                                         ("cross-cylinder symptom", cross, cross_settings, "tab:red")):  # fmt: skip
        (t, x), *_ = feed.feed
        ends, means = block_means(t, x, settings)
        axes[0].plot((ends - t[0]) / 60.0, means, lw=0.6, color=color, label=label)
        stat = feed.statistic_for(settings)
        for ends_s, values in stat.paths:
            axes[1].plot((ends_s - t[0]) / 60.0, values, lw=0.9, color=color, label=label)
    axes[0].set_ylabel("1 s block mean, degC/s")
    axes[0].set_title(f"{Path(flight).stem}, cylinder {number}: nominal symptom and CUSUM (no alarm)")
    axes[0].legend(fontsize=8)
    axes[0].grid(alpha=0.3)
    axes[1].set_ylabel("CUSUM statistic, degC")
    axes[1].set_xlabel("time since the start of the replay (min)")
    axes[1].grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"wrote {path}")


def virtual(args: argparse.Namespace) -> None:
    from ecu_monitor.config import load_config
    from ecu_monitor.errors import ParameterError
    from ecu_monitor.model import paper_table_a1
    from ecu_monitor.offline.calibration import calibrate_flights
    from ecu_monitor.offline.calibration_replays import FlightFeeds
    from ecu_monitor.offline.replay import replay_file
    from ecu_monitor.research.evaluation import residual_effects
    from virtual_bus.cylinders import cylinder_models
    from virtual_bus.random_missions import random_mission
    from virtual_bus.recorder import record

    config = load_config("four_cylinders.yaml")
    folder = Path(os.environ.get("ECU_MONITOR_BENCH_DIR", Path(tempfile.gettempdir()) / "ecu-monitor-bench"))
    folder = folder / "cross-cylinder"
    folder.mkdir(parents=True, exist_ok=True)
    own_settings = config.cylinder_detector(1)
    cross_settings = config.cross_detector(1)
    assert cross_settings is not None
    stats: dict[str, list[list[Any]]] = {"own": [[] for _ in range(4)], "cross": [[] for _ in range(4)]}
    sd: dict[str, list[float]] = {"own": [], "cross": []}
    tag = "v" if args.per_cylinder_effects else ""
    print("| flight (seed) | own max per cylinder | cross max per cylinder |")
    print("|---|---|---|")
    for seed in range(201, 201 + args.flights):
        models = cylinder_models(paper_table_a1(), 4, seed=seed)
        effects = residual_effects(seed)
        truth = tuple(m.replace(effects=_scaled(effects, seed, n) if tag else effects) for n, m in enumerate(models))
        path = folder / f"nominal{tag}_{seed}.blf"
        if not path.exists():
            record(random_mission(seed, duration_s=3600.0), [path], paper_table_a1(), seed=seed, cylinders=truth)
        result = replay_file(path, config, models, keep_feeds=True)
        t = result.columns["time_s"]
        maxima: dict[str, list[float]] = {"own": [], "cross": []}
        for n, feed in enumerate(_own_feeds(result, 4)):
            for kind, f, settings in (("own", feed, own_settings), ("cross", result.cross_feeds[n], cross_settings)):
                feeds = FlightFeeds(path.name, f, float(t[0]), float(t[-1]), math.nan, ())
                stats[kind][n].append(feeds.statistic_for(settings))
                maxima[kind].append(stats[kind][n][-1].max_statistic)
                sd[kind].append(_block_sd(f, settings))
        print(f"| {seed} | {' / '.join(f'{m:.2f}' for m in maxima['own'])} |"
              f" {' / '.join(f'{m:.2f}' for m in maxima['cross'])} |")  # fmt: skip
    print()
    for kind, settings in (("own", own_settings), ("cross", cross_settings)):
        hs = []
        for n in range(4):
            try:
                hs.append(calibrate_flights(stats[kind][n], args.rate, settings).calibration.threshold)
            except ParameterError as exc:  # too few whole hours: say so, keep going
                hs.append(math.nan)
                print(f"{kind} cylinder {n + 1}: {exc}")
        print(f"{kind}: median 1 s block-mean SD {np.nanmedian(sd[kind]):.4f} degC/s; calibrated h per cylinder"
              f" {' / '.join(f'{h:.2f}' for h in hs)} (k = {settings.reference:g})")  # fmt: skip


def _scaled(effects: Any, seed: int, cylinder: int) -> Any:
    """The effects with each size drawn for this cylinder (x 0.7-1.3)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, cylinder, 555]))
    f = rng.uniform(0.7, 1.3, 4)
    changes = {}
    sizes = (("airspeed_cooling", "gain_per_mps"), ("density_cooling", "exponent"), ("sensor_lag", "time_constant_s"),
             ("mixture_cooling", "fraction"))  # fmt: skip
    for i, (name, field) in enumerate(sizes):
        term = getattr(effects, name)
        if term is not None:
            changes[name] = dataclasses.replace(term, **{field: getattr(term, field) * f[i]})
    return dataclasses.replace(effects, **changes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    r = sub.add_parser("real")
    r.add_argument("flights", nargs="+")
    r.add_argument("--models-dir", required=True)
    r.add_argument("--rate", type=float, default=1.0)
    r.add_argument("--plot")
    r.add_argument("--held-out", nargs="+", help="hold out only these flights (default: each in turn)")
    v = sub.add_parser("virtual")
    v.add_argument("--flights", type=int, default=4)
    v.add_argument("--rate", type=float, default=1.0)
    v.add_argument("--per-cylinder-effects", action="store_true")
    args = parser.parse_args()
    real(args) if args.what == "real" else virtual(args)


if __name__ == "__main__":
    main()
