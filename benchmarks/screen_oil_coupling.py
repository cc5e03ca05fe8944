"""Screen an oil-temperature coupling the model lacks: does it explain held-out residuals (leave one out)?

    .venv/bin/python benchmarks/screen_oil_coupling.py FLIGHT.csv FLIGHT.csv ... --models WORK [--tau 60,122,300]

``WORK`` is a ``bench_detect_real.py --work`` folder: ``model_without_{i}.yaml`` identified without flight i
(the flights in the same order). A coupling of the head to the oil, G_oil (T_oil - T) in the head's heat
balance, moves the CHT by about (G_oil / G) x lag(T_oil - T, tau), tau the head's time constant
(C_w R_Ce, ~120 s for these models). Per fold, the open-loop residual (measured - model CHT, after the
first 600 s) of the three training flights is regressed (least squares) on that lag of the logged oil
temperature minus the model CHT, beside a control of an intercept and a factor on (model CHT - OAT) (what
re-tuning the heat map and R_Ce would absorb); the held-out flight's residual RMS with the control alone
and with the oil term is printed. A physical coupling (heat from warm oil into the head) has a positive
coefficient. Offline: the service and the model are unchanged.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ecu_monitor.flightlog.canonical import read_csv
from ecu_monitor.identify.flights import simulate_flight
from ecu_monitor.model.params import load_model

SKIP_S = 600.0  # the start-up transient the model's initial state does not know


def lagged(x: np.ndarray, t: np.ndarray, tau_s: float) -> np.ndarray:
    """First-order lag of x (time constant tau_s, s) on the log's own sample times."""
    y = np.empty_like(x)
    y[0] = x[0]
    for i in range(1, len(x)):
        y[i] = y[i - 1] + (1.0 - np.exp(-(t[i] - t[i - 1]) / tau_s)) * (x[i] - y[i - 1])
    return y


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("flights", nargs="+", help="canonical CSVs with oil_temp_c, in bench_detect_real's order")
    parser.add_argument("--models", required=True, help="bench_detect_real --work folder (model_without_{i}.yaml)")
    parser.add_argument("--tau", default="60,122,300", help="lag time constants to try, s")
    args = parser.parse_args()
    logs = [read_csv(path) for path in args.flights]
    for log, path in zip(logs, args.flights, strict=True):
        if not log.has("oil_temp_c"):
            parser.error(f"{path}: no oil_temp_c column")
    for tau in (float(text) for text in args.tau.split(",")):
        print(f"lag {tau:g} s: held-out RMS, degC (control -> with the oil term), shrink, oil coefficient")
        for i, path in enumerate(args.flights):
            model = load_model(Path(args.models) / f"model_without_{i}.yaml")
            parts = []
            for log in logs:
                t = log.time_s
                sim = simulate_flight(model, log)
                residual = log["cht_c"] - sim
                control = np.column_stack([np.ones_like(t), sim - log["oat_c"]])
                oil = lagged(log["oil_temp_c"] - sim, t, tau)
                ok = (t - t[0] > SKIP_S) & np.isfinite(residual) & np.isfinite(oil) & np.isfinite(control).all(1)
                parts.append((residual[ok], control[ok], np.column_stack([control[ok], oil[ok]])))
            train = [p for j, p in enumerate(parts) if j != i]
            e = np.concatenate([p[0] for p in train])
            b0 = np.linalg.lstsq(np.concatenate([p[1] for p in train]), e, rcond=None)[0]
            b1 = np.linalg.lstsq(np.concatenate([p[2] for p in train]), e, rcond=None)[0]
            e_test, c_test, x_test = parts[i]
            rms0 = float(np.sqrt(np.mean((e_test - c_test @ b0) ** 2)))
            rms1 = float(np.sqrt(np.mean((e_test - x_test @ b1) ** 2)))
            print(f"  {Path(path).stem}: {rms0:.2f} -> {rms1:.2f}  {100 * (1 - rms1 / rms0):+.1f} %  {b1[-1]:+.4f}")


if __name__ == "__main__":
    main()
