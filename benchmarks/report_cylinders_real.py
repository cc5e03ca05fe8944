"""Every cylinder on real flights (issue 14): CHT spread and hottest cylinder per flight phase, and the
service's per-cylinder replay.

    nice -n 10 .venv/bin/python benchmarks/report_cylinders_real.py FLIGHT.csv [...] --models M1.yaml M2.yaml ...

FLIGHT.csv: canonical flight CSVs with per-cylinder columns ``cht1_c .. chtN_c`` (``ecu-monitor import``
of G1000 / NGAFID exports). ``--models``: one model per cylinder (``ecu-monitor identify --cylinder all``).

Per flight and phase (ground, climb, cruise, descent: ``ecu_monitor.gap.segments.segment_flight``):

* measured: the median and the maximum CHT spread (hottest minus coldest cylinder reading, per row) and
  the hottest cylinder (the one hottest in most rows, with its share of the rows);
* replayed: the same from the service's health.csv (``cht_spread_c``, ``hottest_cylinder``: the
  per-cylinder CHT estimates), by the batch replay with ``four_cylinders.yaml`` and the given models;

then, per cylinder, the replay's states (share of NOMINAL rows among those with an estimate, any
DEGRADED) and its gamma_Q estimate (median over the cruise). Prints Markdown tables.
"""

from __future__ import annotations

import argparse
import collections
from pathlib import Path

import numpy as np


def _hottest(which: np.ndarray) -> str:
    which = which[which > 0]
    if not which.size:
        return "-"
    number, count = collections.Counter(which.tolist()).most_common(1)[0]
    return f"{number} ({100.0 * count / which.size:.0f} %)"


def _spread(values: np.ndarray) -> str:
    values = values[np.isfinite(values)]
    return "-" if not values.size else f"{np.median(values):.1f} / {values.max():.1f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("flights", nargs="+", metavar="FLIGHT.csv")
    parser.add_argument("--models", nargs="+", required=True, metavar="MODEL.yaml")
    parser.add_argument("--spread-limit", type=float, default=None, metavar="C")
    args = parser.parse_args()

    from ecu_monitor.config import load_config
    from ecu_monitor.flightlog import cylinder_columns, read_csv
    from ecu_monitor.gap.segments import SEGMENT_NAMES, segment_flight
    from ecu_monitor.model import load_model
    from ecu_monitor.offline.replay import frames_from_flight, replay_frames
    from ecu_monitor.pipeline.output_table import STATES

    models = tuple(load_model(m) for m in args.models)
    config = load_config("four_cylinders.yaml").replace(spread_limit_c=args.spread_limit)
    phase_rows = []
    cylinder_rows = []
    for path in args.flights:
        log = read_csv(path)
        columns = cylinder_columns(log, "cht")
        if len(columns) != len(models):
            raise SystemExit(f"{path}: {len(columns)} cylinders, {len(models)} models given")
        heads = np.vstack([np.asarray(log[c], dtype=float) for c in columns])
        name = Path(path).stem.split("_", 3)[-1]
        segments = segment_flight(log)
        result = replay_frames(config, models, frames_from_flight(log, config, (*models[0].heat_axes, "altitude_m",
                               "airspeed_mps", "oat_c", *config.cylinder_inputs)))  # fmt: skip
        c = result.columns
        # the phase of each health row: the label of the latest log row at or before it
        at = np.clip(np.searchsorted(log.time_s, c["time_s"], side="right") - 1, 0, len(log) - 1)
        row_phase = segments.labels[at]
        with np.errstate(invalid="ignore"):
            measured_spread = np.nanmax(heads, axis=0) - np.nanmin(heads, axis=0)
        valid = np.all(np.isfinite(heads), axis=0)
        measured_hottest = np.where(valid, np.argmax(np.where(np.isfinite(heads), heads, -np.inf), axis=0) + 1, 0)
        for k, phase in enumerate(SEGMENT_NAMES):
            rows = segments.mask(phase)
            health = row_phase == k
            if not rows.any():
                continue
            minutes = float(np.sum(np.diff(log.time_s, append=log.time_s[-1])[rows])) / 60.0
            phase_rows.append(
                f"| {name} | {phase} | {minutes:.1f} | {_spread(measured_spread[rows])} |"
                f" {_hottest(measured_hottest[rows])} | {_spread(c['cht_spread_c'][health])} |"
                f" {_hottest(c['hottest_cylinder'][health])} |"
            )
        cruise = row_phase == SEGMENT_NAMES.index("cruise")
        for n in range(1, len(models) + 1):
            state = c[f"cyl{n}_state"]
            estimating = np.isfinite(c[f"cyl{n}_cht_est_c"])
            nominal = np.mean(state[estimating] == STATES.index("NOMINAL")) if estimating.any() else float("nan")
            degraded = np.flatnonzero(state == STATES.index("DEGRADED"))
            first = f"from {c['time_s'][degraded[0]] - c['time_s'][0]:.0f} s" if degraded.size else "none"
            gq = c[f"cyl{n}_gamma_q"][cruise & estimating]
            rms = float(np.sqrt(np.nanmean((c[f"cyl{n}_cht_est_c"] - c[f"cyl{n}_cht_meas_c"]) ** 2)))
            cylinder_rows.append(
                f"| {name} | {n} | {100.0 * nominal:.1f} | {first} | {np.median(gq) if gq.size else float('nan'):.3f} |"
                f" {rms:.2f} |"
            )
    print("| flight | phase | minutes | measured spread median / max, degC | measured hottest cylinder (share) |"
          " replayed spread median / max, degC | replayed hottest cylinder (share) |")  # fmt: skip
    print("|---|---|---:|---:|---|---:|---|")
    print("\n".join(phase_rows))
    print()
    print("| flight | cylinder | NOMINAL, % of rows with an estimate | DEGRADED | gamma_Q median in cruise |"
          " estimate - reading RMS, degC |")  # fmt: skip
    print("|---|---:|---:|---|---:|---:|")
    print("\n".join(cylinder_rows))


if __name__ == "__main__":
    main()
