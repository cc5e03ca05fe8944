"""The engine events on real flights (docs/results/events_real.md): each canonical flight CSV replayed with
its aircraft's model, every CHT, EGT and oil temperature it logged mapped, the shipped event limits but
the CHT limit (``--cht-limit``: the engine maker's, the identified models carry the paper's 150 degC).

    nice -n 10 .venv/bin/python benchmarks/bench_events_real.py FLIGHT.csv:MODEL.yaml ... \\
        [--cht-limit 260] [--out-dir DIR] [--plot events_real.png]

Prints a Markdown table (per flight: hours, cylinders, the count of each kind, shock-cooling and divergence
events per flight hour) and writes each flight's events table (``replay --events``' columns) to
``--out-dir``; ``--plot`` draws where each event falls on each flight.
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "ecu_monitor" / "data" / "configs"
#: What each kind's marker looks like on the plot.
MARKERS = {
    "shock_cooling": ("v", "tab:cyan"),
    "cht_divergence": ("D", "tab:olive"),
    "egt_divergence": ("s", "tab:brown"),
    "valve_advisory": ("*", "tab:pink"),
    "cht_exceedance": ("^", "tab:red"),
    "egt_exceedance": ("^", "darkred"),
    "oil_exceedance": ("o", "tab:orange"),
}


def flight_config(log: Any, model: Path | str, cht_limit_c: float | None) -> Any:
    """four_cylinders.yaml with the flight's CHTs (cht_c alone when it has one), its EGTs (as many as CHT
    channels), its oil temperature and manifold pressure when logged, ``model`` (a file, or a preset's name),
    no cross detector, the CHT limit ``cht_limit_c`` (None: the model's)."""
    from ecu_monitor.config import parse_config

    data = yaml.safe_load((CONFIGS / "four_cylinders.yaml").read_text(encoding="utf-8"))
    data = copy.deepcopy(data)
    inputs = data["inputs"]
    cylinders = sorted(n for n in range(1, 5) if log.has(f"cht{n}_c"))
    for n in range(1, 5):
        inputs.pop(f"cht{n}_c")
    temperature = {"unit": "degC", "stale_after_s": 3.0}
    if len(cylinders) > 1:
        for n in cylinders:
            inputs[f"cht{n}_c"] = {"signal": f"ECU_Cht1to4.CHT{n}", **temperature}
            if log.has(f"egt{n}_c"):
                inputs[f"egt{n}_c"] = {"signal": f"ECU_Egt1to4.EGT{n}", **temperature}
    else:
        inputs["cht_c"] = {"signal": "ECU_Slow.CHT", **temperature}
    if log.has("oil_temp_c"):
        inputs["oil_temp_c"] = {"signal": "ECU_Oil.OilTemp", **temperature}
    if log.has("manifold_pressure_kpa"):
        inputs["manifold_pressure_kpa"] = {"signal": "ECU_Slow.ManifoldPressure", "unit": "kPa", "stale_after_s": 3.0}
    data["cylinders"].pop("cross_detector", None)
    data["cylinders"].pop("spread_limit_c", None)
    data["model"] = str(model.resolve()) if isinstance(model, Path) else model
    data["events"] = {} if cht_limit_c is None else {"cht_limit_c": cht_limit_c}
    return parse_config(data, CONFIGS / "four_cylinders.yaml")


def main() -> None:
    from ecu_monitor.bus.canlog import load_flight
    from ecu_monitor.offline.replay import replay_file
    from ecu_monitor.pipeline.events import EVENT_KINDS, events_csv

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("flights", nargs="+", metavar="FLIGHT.csv:MODEL.yaml")
    parser.add_argument("--cht-limit", type=float, default=260.0, help="degC (default 260: 500 degF)")
    parser.add_argument("--out-dir", type=Path, default=Path("events_real"))
    parser.add_argument("--plot", type=Path)
    parser.add_argument(
        "--cost", type=int, default=0, metavar="N",
        help="instead: replay the first flight N times with the events off and on, alternating; print the ratio",
    )  # fmt: skip
    args = parser.parse_args()
    if args.cost:
        _cost(args.flights[0], args.cht_limit, args.cost)
        return
    args.out_dir.mkdir(parents=True, exist_ok=True)
    shown = ("shock_cooling", "cht_divergence", "egt_divergence", "valve_advisory", "cht_exceedance",
             "egt_exceedance", "oil_exceedance")  # fmt: skip
    assert set(shown) == set(EVENT_KINDS)
    print("| flight | hours | CHT channels | " + " | ".join(shown) + " | shock cooling /h | divergence /h |")
    print("|---|---:|---:|" + "---:|" * (len(shown) + 2))
    results: list[tuple[str, float, Any, list[Any]]] = []
    totals = dict.fromkeys(shown, 0)
    hours_total = 0.0
    for item in args.flights:
        flight, model = item.rsplit(":", 1)
        log = load_flight(flight)
        config = flight_config(log, Path(model), args.cht_limit)
        models = config.load_cylinder_params()
        result = replay_file(flight, config, models)
        t = np.asarray(result.columns["time_s"], dtype=float)
        hours = float(t[-1] - t[0]) / 3600.0
        events = list(result.events)
        name = Path(flight).stem
        (args.out_dir / f"{name}_events.csv").write_text(events_csv(events), encoding="utf-8")
        counts = {kind: sum(e.kind == kind for e in events) for kind in shown}
        for kind in shown:
            totals[kind] += counts[kind]
        hours_total += hours
        divergence = counts["cht_divergence"] + counts["egt_divergence"]
        print(f"| {name} | {hours:.2f} | {len(config.cylinder_inputs)} | "
              + " | ".join(str(counts[k]) for k in shown)
              + f" | {counts['shock_cooling'] / hours:.2f} | {divergence / hours:.2f} |")  # fmt: skip
        results.append((name, float(t[0]), hours, events))
    divergence = totals["cht_divergence"] + totals["egt_divergence"]
    print(f"| all | {hours_total:.2f} | | " + " | ".join(str(totals[k]) for k in shown)
          + f" | {totals['shock_cooling'] / hours_total:.2f} | {divergence / hours_total:.2f} |")  # fmt: skip
    print()
    for name, start, _, events in results:
        for e in events:
            if e.kind in ("shock_cooling", "cht_divergence", "egt_divergence", "valve_advisory"):
                print(f"- {name}: {(e.time_s - start) / 60.0:.1f} min, {e.text()}")
    if args.plot:
        _plot(args.plot, results)


def _cost(item: str, cht_limit_c: float, repeats: int) -> None:
    """The replay's CPU time with every event on against off (the same frames, alternating runs)."""
    import time

    import msgspec

    from ecu_monitor.bus.canlog import load_flight
    from ecu_monitor.offline.replay import frames_from_flight, replay_frames
    from ecu_monitor.pipeline.engine import model_input_names

    flight, model = item.rsplit(":", 1)
    log = load_flight(flight)
    on = flight_config(log, Path(model), cht_limit_c)
    off = on.replace(events=msgspec.structs.replace(on.events, enabled=False))
    models = on.load_cylinder_params()
    needed = (*model_input_names(models[0], on.input_names), *on.cylinder_inputs)  # as replay_file
    frames = frames_from_flight(log, on, needed)
    replay_frames(on, models, frames)  # compiled, cached
    spent = {"off": 0.0, "on": 0.0}
    for _ in range(repeats):
        for name, config in (("off", off), ("on", on)):
            started = time.process_time()
            replay_frames(config, models, frames)
            spent[name] += time.process_time() - started
    print(f"{Path(flight).name}: CPU per replay, events off {spent['off'] / repeats:.2f} s, on"
          f" {spent['on'] / repeats:.2f} s: ratio {spent['on'] / spent['off']:.3f} ({repeats} runs each)")  # fmt: skip


def _plot(path: Path, results: list[tuple[str, float, float, list[Any]]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(results), 1, figsize=(12, 1.3 * len(results) + 1.0), sharex=True, squeeze=False)
    seen: set[str] = set()
    for ax, (name, start, hours, events) in zip(axes[:, 0], results, strict=True):
        ax.axvspan(0.0, hours * 60.0, color="0.93", lw=0)
        for e in events:
            marker, colour = MARKERS[e.kind]
            begin = (e.time_s - start) / 60.0
            ax.plot([begin, begin + e.duration_s / 60.0], [e.cylinder, e.cylinder], color=colour, lw=3, alpha=0.6)
            ax.plot(begin, e.cylinder, marker=marker, color=colour, ls="",
                    label=None if e.kind in seen else e.kind.replace("_", " "))  # fmt: skip
            seen.add(e.kind)
        ax.set_ylim(-0.5, 4.5)
        ax.set_yticks(range(5))
        ax.set_ylabel(name, rotation=0, ha="right", va="center", fontsize=7)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time from the first health row (min); y: cylinder (0: the engine)")
    fig.legend(loc="upper right", fontsize=7, ncol=4)
    fig.suptitle("Engine events on the real flights (grey: the flight)")
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
