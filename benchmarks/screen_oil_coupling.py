"""Screen a coupling of the head to a cold engine mass the model lacks (oil, block: a warm-up), leave one out.

    .venv/bin/python benchmarks/screen_oil_coupling.py FLIGHT.csv FLIGHT.csv ... --models WORK
        [--mapping g1000] [--skip 600] [--forms oil] [--tau 60,122,300] [--block-tau 300,600,1200,1800]
        [--window 900]

``WORK`` holds ``model_without_{i}.yaml``, a model identified without flight i (the flights in the same
order; e.g. a ``bench_detect_real.py --work`` folder, or ``ecu-monitor identify`` on the other flights). A
coupling G_w (X - T) of the head to a mass at temperature X in the head's heat balance moves the CHT by
about (G_w / G) x lag(X - T, tau), tau the head's time constant. Per fold, the open-loop residual
(measured - model CHT) of the training flights is regressed (least squares) on that term beside a control
of an intercept and a factor on (model CHT - OAT) (what re-tuning the heat map and R_Ce would absorb; with
``--time-constant`` also C_w R_Ce x lag(d(model CHT)/dt), what re-tuning C_w would absorb); the
held-out flight's residual RMS with the control alone and with the term is printed, over the whole flight
(after ``--skip`` s) and over its first ``--window`` s (after the skip). A physical coupling (the head
pulled towards the mass) has a positive coefficient. Forms (``--forms``, comma-separated):

- ``oil``: X the logged oil temperature (``--tau`` gives the lag's time constants to try, s);
- ``block_cht`` / ``block_oil``: X a hidden block node that follows the model's head with a time constant
  of ``--block-tau`` s, starting at the flight's first CHT / first oil temperature (what a cold soak
  leaves); the lag is the model's own C_w R_Ce;
- ``start``: a warm-up transient not tied to a temperature: (X0 - first CHT) exp(-t/tau_b), X0 the
  training flights' median CHT, decaying with ``--block-tau``.

``--skip 0`` keeps each flight's start (the cold soak is what a warm-up term is for); the default 600 s is
the earlier screen of the oil coupling on steady data. Offline: the service and the model are unchanged.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.flightlog import FlightLog
from ecu_monitor.flightlog.load import load_csv
from ecu_monitor.identify.flights import simulate_flight
from ecu_monitor.model.params import ThermalParams, load_model

FORMS = ("oil", "block_cht", "block_oil", "start")


def lagged(x: np.ndarray, t: np.ndarray, tau_s: float, start: float | None = None) -> np.ndarray:
    """First-order lag of x (time constant tau_s, s) on the log's own sample times, from ``start``
    (default x's first value)."""
    y = np.empty_like(x)
    y[0] = x[0] if start is None else start
    for i in range(1, len(x)):
        y[i] = y[i - 1] + (1.0 - np.exp(-(t[i] - t[i - 1]) / tau_s)) * (x[i] - y[i - 1])
    return y


Term = Callable[[FlightLog, NDArray[np.float64], ThermalParams, float], NDArray[np.float64]]


def _terms(form: str, args: argparse.Namespace) -> list[tuple[str, Term]]:
    """(label, term of a flight given its log, the model CHT, the model and the training median CHT)."""
    if form == "oil":
        return [
            (f"oil, lag {tau:g} s", lambda log, sim, _m, _x0, tau=tau: lagged(log["oil_temp_c"] - sim, log.time_s, tau))
            for tau in args.tau
        ]
    terms: list[tuple[str, Term]] = []
    for tau_b in args.block_tau:
        if form == "start":

            def term(log, sim, model, x0, tau_b=tau_b):
                t = log.time_s - log.time_s[0]
                return lagged((x0 - log["cht_c"][0]) * np.exp(-t / tau_b), log.time_s, model.c_w * model.r_ce)

        else:
            column = "cht_c" if form == "block_cht" else "oil_temp_c"

            def term(log, sim, model, _x0, tau_b=tau_b, column=column):
                block = lagged(sim, log.time_s, tau_b, start=float(log[column][0]))
                return lagged(block - sim, log.time_s, model.c_w * model.r_ce)

        terms.append((f"{form}, block {tau_b:g} s", term))
    return terms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("flights", nargs="+", help="flight CSVs with oil_temp_c, in the models' order")
    parser.add_argument("--models", required=True, help="folder of model_without_{i}.yaml")
    parser.add_argument("--mapping", help="mapping of foreign CSVs (e.g. g1000)")
    parser.add_argument("--skip", type=float, default=600.0, help="start-up seconds left out of every flight")
    parser.add_argument("--forms", default="oil", help=f"terms to try, comma-separated: {', '.join(FORMS)}")
    parser.add_argument("--tau", default="60,122,300", help="oil: lag time constants to try, s")
    parser.add_argument("--block-tau", default="300,600,1200,1800", help="block/start time constants to try, s")
    parser.add_argument(
        "--time-constant", action="store_true", help="the control also re-tunes the head's time constant C_w R_Ce"
    )
    parser.add_argument("--window", type=float, default=900.0, help="the start's window reported apart, s")
    args = parser.parse_args()
    args.tau = [float(text) for text in args.tau.split(",")]
    args.block_tau = [float(text) for text in args.block_tau.split(",")]
    forms = args.forms.split(",")
    for form in forms:
        if form not in FORMS:
            parser.error(f"--forms: unknown form {form!r} (known: {', '.join(FORMS)})")
    logs = [load_csv(path, args.mapping) for path in args.flights]
    for log, path in zip(logs, args.flights, strict=True):
        if not log.has("oil_temp_c"):
            parser.error(f"{path}: no oil_temp_c column")
    models = [load_model(Path(args.models) / f"model_without_{i}.yaml") for i in range(len(logs))]
    # per fold: every flight's model CHT under that fold's model
    sims = [[simulate_flight(model, log) for log in logs] for model in models]
    print(f"held-out RMS, degC: control -> with the term (shrink), first {args.window:g} s | whole flight;"
          f" the term's coefficient (fit on the others); start skipped {args.skip:g} s")  # fmt: skip
    for form in forms:
        for label, term in _terms(form, args):
            print(label)
            for i, path in enumerate(args.flights):
                x0 = float(np.median(np.concatenate([log["cht_c"] for j, log in enumerate(logs) if j != i])))
                parts = []
                for log, sim in zip(logs, sims[i], strict=True):
                    t = log.time_s - log.time_s[0]
                    residual = log["cht_c"] - sim
                    columns = [np.ones_like(t), sim - log["oat_c"]]
                    if args.time_constant:
                        tau = models[i].c_w * models[i].r_ce
                        columns.append(tau * lagged(np.gradient(sim, log.time_s), log.time_s, tau))
                    control = np.column_stack(columns)
                    extra = term(log, sim, models[i], x0)
                    ok = (t >= args.skip) & np.isfinite(residual) & np.isfinite(extra) & np.isfinite(control).all(1)
                    early = t[ok] < args.skip + args.window
                    parts.append((residual[ok], control[ok], np.column_stack([control[ok], extra[ok]]), early))
                train = [p for j, p in enumerate(parts) if j != i]
                e = np.concatenate([p[0] for p in train])
                b0 = np.linalg.lstsq(np.concatenate([p[1] for p in train]), e, rcond=None)[0]
                b1 = np.linalg.lstsq(np.concatenate([p[2] for p in train]), e, rcond=None)[0]
                e_test, c_test, x_test, early = parts[i]
                r0, r1 = e_test - c_test @ b0, e_test - x_test @ b1
                cells = []
                for mask in (early, np.ones_like(early)):
                    rms0, rms1 = (float(np.sqrt(np.mean(r[mask] ** 2))) for r in (r0, r1))
                    cells.append(f"{rms0:5.2f} -> {rms1:5.2f} ({100 * (1 - rms1 / rms0):+5.1f} %)")
                print(f"  {Path(path).stem}: {' | '.join(cells)}  {b1[-1]:+.4f}")


if __name__ == "__main__":
    main()
