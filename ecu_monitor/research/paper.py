"""The paper's Section 3.2 reproduced on the virtual ECU (``ecu-monitor results``).

Flies the virtual ECU (virtual_bus.plant.fly: the model's own physics, a 1 degC quantised CHT probe
with 0.3 degC noise, readings at 10 Hz) with gamma_Q / gamma_D injected at t = 150 s and runs EKF,
CBEKF and CBEKF-AU (midpoint and boundary reset) with the compiled runner. :func:`generate` writes PNG
figures (the paper's Figures 7-11 and a sweep of our deviation filter's time constant) and
paper_reproduction.md: a table "paper's claim | our figure | verdict" with the numbers measured in
this run.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.estimation import EstimatorSettings, run_estimator
from ecu_monitor.estimation.runner import EstimateTrace, sample_indices
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.model import ThermalParams, paper_table_a1
from ecu_monitor.userfiles import save_figure, write_output_bytes

__all__ = ["INJECT_S", "VARIANTS", "generate", "settle_time", "steady_relative_error"]

#: Time of the degradation injection (the paper's 150 s), s.
INJECT_S = 150.0
#: Estimator variants compared: label -> (registry name, reset mode).
VARIANTS: dict[str, tuple[str, str]] = {
    "EKF": ("ekf", "none"),
    "CBEKF": ("cbekf", "none"),
    "CBEKF-AU midpoint": ("cbekf-au", "midpoint"),
    "CBEKF-AU boundary": ("cbekf-au", "boundary"),
}
_COLOURS = {
    "EKF": "tab:red",
    "CBEKF": "tab:orange",
    "CBEKF-AU midpoint": "tab:purple",
    "CBEKF-AU boundary": "tab:green",
}
#: Settled: the 10 s trailing mean of |estimate - truth| stays below half a quantisation step.
SETTLE_THRESHOLD_C = 0.5
SETTLE_WINDOW_S = 10.0
_CRUISE: dict[str, Any] = {
    "name": "paper-cruise",
    "description": "steady cruise at 60 % throttle, 500 m, 23 m/s (the setting of the paper's Figures 7-11)",
    "field_elevation_m": 500,
    "segments": [{"kind": "cruise", "duration_s": 1200, "altitude_m": 500, "throttle_pct": 60, "airspeed_mps": 23}],
}


# --- measurements --------------------------------------------------------------------------------


def settle_time(time_s: NDArray[np.float64], error_c: NDArray[np.float64], after_s: float) -> float:
    """Seconds after ``after_s`` until the trailing mean |error| (SETTLE_WINDOW_S) stays below
    SETTLE_THRESHOLD_C; inf if it never settles before the end."""
    step = float(np.median(np.diff(time_s)))
    n = max(1, round(SETTLE_WINDOW_S / step))
    mean_abs = np.convolve(np.abs(error_c), np.ones(n) / n, mode="full")[: error_c.size]
    late = np.nonzero((time_s >= after_s) & (mean_abs > SETTLE_THRESHOLD_C))[0]
    if late.size == 0:
        return 0.0
    if time_s[late[-1]] >= time_s[-1] - 2 * step:
        return float("inf")
    return float(time_s[late[-1]] - after_s)


def steady_relative_error(
    time_s: NDArray[np.float64], error_c: NDArray[np.float64], truth_c: NDArray[np.float64]
) -> float:
    """Mean relative error (%) over the last 300 s of the flight."""
    tail = time_s >= time_s[-1] - 300.0
    return float(np.mean(error_c[tail] / truth_c[tail]) * 100.0)


@dataclass(frozen=True)
class Flight:
    """A virtual-ECU flight and the estimates at its sample times."""

    log: FlightLog
    truth_c: NDArray[np.float64]
    traces: dict[str, EstimateTrace]

    @property
    def time_s(self) -> NDArray[np.float64]:
        return np.asarray(self.log.time_s)

    def error(self, label: str) -> NDArray[np.float64]:
        return self.traces[label].cht_est_c - self.truth_c


def _at_samples(log: FlightLog, trace: EstimateTrace, dt_s: float) -> EstimateTrace:
    return trace.take(sample_indices(log.time_s, float(log.time_s[0]), dt_s, len(trace)))


def _estimate(
    log: FlightLog, params: ThermalParams, labels: Sequence[str], settings: EstimatorSettings
) -> dict[str, EstimateTrace]:
    traces = {}
    for label in labels:
        name, reset = VARIANTS[label]
        trace = run_estimator(log, params, name, replace(settings, reset=reset))
        traces[label] = _at_samples(log, trace, settings.dt_s)
    return traces


class _Plant:
    """The virtual ECU flying the paper's steady cruise.

    The emulated aircraft starts at zero throttle and airspeed, so the first SETTLE_S seconds of each
    flight (spool-up and the CHT's recovery) are flown and discarded: the returned log starts in the
    nominal steady cruise at t = 0 and the degradation is injected at t = INJECT_S on that clock.
    """

    SETTLE_S = 200.0

    def __init__(self, params: ThermalParams) -> None:
        from virtual_bus.missions import load_mission, mission_from_dict  # the emulator: only here
        from virtual_bus.plant import Degradation, fly

        self._fly = fly
        self._degradation = Degradation
        self.params = params
        self._from_dict = mission_from_dict
        self.default_mission = load_mission("default")

    def fly(
        self, gamma_q: float, gamma_d: float, seed: int, duration_s: float = 900.0, throttle_pct: float = 60.0
    ) -> FlightLog:
        start = INJECT_S + self.SETTLE_S
        events = [self._degradation("gamma_q", gamma_q, start), self._degradation("gamma_d", gamma_d, start)]
        segment = {**_CRUISE["segments"][0], "throttle_pct": throttle_pct}
        mission = self._from_dict({**_CRUISE, "segments": [segment], "initial_cht_c": 118.0})
        log = self._fly(mission, self.params, degradation=events, seed=seed, max_duration_s=duration_s + self.SETTLE_S)
        log = log.select(self.SETTLE_S, math.inf)
        return log.with_columns(time_s=log.time_s - self.SETTLE_S)

    def fly_default(self, gamma_q: float, seed: int, duration_s: float) -> FlightLog:
        """The shipped default mission (warm-up, step-climb, cruise) with gamma_Q stepped at INJECT_S."""
        events = [self._degradation("gamma_q", gamma_q, INJECT_S)]
        return self._fly(self.default_mission, self.params, degradation=events, seed=seed, max_duration_s=duration_s)


def _flight(
    plant: _Plant,
    gamma_q: float,
    gamma_d: float,
    seed: int,
    settings: EstimatorSettings,
    labels: Sequence[str] = tuple(VARIANTS),
    duration_s: float = 900.0,
    throttle_pct: float = 60.0,
) -> Flight:
    log = plant.fly(gamma_q, gamma_d, seed, duration_s, throttle_pct)
    return Flight(log, np.asarray(log["cht_true_c"]), _estimate(log, plant.params, labels, settings))


def _deviation_rate(flight: Flight, label: str = "CBEKF") -> float:
    """Slope (degC/s per s) of the deviation over the 10 s after the injection (least squares)."""
    t = flight.time_s
    window = (t >= INJECT_S) & (t <= INJECT_S + 10.0)
    return float(np.polyfit(t[window] - INJECT_S, flight.traces[label].deviation[window], 1)[0])


def _literal_reading(log: FlightLog, params: ThermalParams, settings: EstimatorSettings) -> EstimateTrace:
    """The literal reading of Eq. 25 with x_k = the reading: Delta_k = f(z_k) - f(x(k|k)), i.e. the
    prediction restarts from the last reading every step. Only for the comparison in the report."""
    from ecu_monitor.estimation.ekf import predict, update  # the pure core, reused as is
    from ecu_monitor.estimation.runner import fixed_step_flight
    from ecu_monitor.model import Drive, coefficients, compute_drive

    s = settings
    flight = fixed_step_flight(log, params, s.dt_s)
    coeffs = coefficients(params)
    drive_all = [np.asarray(v, dtype=float) for v in compute_drive(flight.inputs, coeffs)]
    n = flight.time_s.size
    x = np.empty(n)
    x[0] = last = float(flight.z_c[0])
    P = s.initial_var
    w = 2.0 * float(drive_all[0][0])
    for k in range(1, n):
        drive = Drive(*(float(col[k - 1]) for col in drive_all))
        from_reading = predict(last, P, drive, coeffs, s.dt_s, s.process_var, 0.0, w)
        prior = predict(float(x[k - 1]), P, drive, coeffs, s.dt_s, s.process_var, 0.0, w)
        delta = from_reading.x - prior.x
        xk, P, w = prior.x + delta, prior.P, prior.pade_w
        if flight.measured[k]:
            last = float(flight.z_c[k])
            corrected = update(xk, P, last, s.measurement_var, s.sigmoid_a, s.sigmoid_b, s.quantum_c)
            xk, P = corrected.x, corrected.P
        x[k] = xk
    zeros = np.zeros(n)
    trace = EstimateTrace(
        "literal",
        flight.time_s,
        flight.z_c,
        x,
        zeros,
        zeros,
        zeros,
        zeros,
        np.zeros(n, dtype=np.bool_),
        flight.measured,
    )
    return _at_samples(log, trace, s.dt_s)


# --- figures -------------------------------------------------------------------------------------


def _figure_transient(flight: Flight, gamma_q: float, path: Path) -> None:
    import matplotlib.pyplot as plt

    t = flight.time_s
    fig, axes = plt.subplots(3, 1, figsize=(10, 10), constrained_layout=True)
    ax = axes[0]
    for label, trace in flight.traces.items():
        ax.plot(t, trace.cht_est_c, lw=0.8, color=_COLOURS[label], label=label, alpha=0.8)
    ax.plot(t, flight.log["cht_c"], ".", ms=1.0, color="0.3", label="reading (1 degC, noise 0.3 degC)", zorder=4)
    ax.plot(t, flight.truth_c, "k-", lw=1.5, label="true CHT", zorder=5)
    ax.axvline(INJECT_S, color="k", ls=":", lw=1)
    ax.set_ylabel("CHT, degC")
    ax.set_title(f"(a) gamma_Q = {gamma_q} injected at t = {INJECT_S:g} s (virtual ECU, steady cruise)")
    ax.legend(fontsize=8, ncol=3, loc="upper left")
    ax = axes[1]
    zoom = (t >= INJECT_S - 40) & (t <= INJECT_S + 120)
    for label, trace in flight.traces.items():
        ax.plot(t[zoom], trace.cht_est_c[zoom], lw=0.9, color=_COLOURS[label], alpha=0.8)
    ax.plot(t[zoom], flight.log["cht_c"][zoom], ".", ms=1.5, color="0.3", zorder=4)
    ax.plot(t[zoom], flight.truth_c[zoom], "k-", lw=1.5, zorder=5)
    ax.axvline(INJECT_S, color="k", ls=":", lw=1)
    ax.set_ylabel("CHT, degC")
    ax.set_title("(b) around the injection")
    ax = axes[2]
    for label in flight.traces:
        ax.plot(t, flight.error(label) / flight.truth_c * 100.0, lw=0.8, color=_COLOURS[label], label=label)
    ax.axvline(INJECT_S, color="k", ls=":", lw=1)
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_ylabel("estimate - truth, % of truth")
    ax.set_xlabel("time, s")
    ax.set_title("(c) relative error")
    ax.legend(fontsize=8, ncol=4)
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def _figure_boxplots(errors: dict[str, dict[float, NDArray[np.float64]]], path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(errors), figsize=(11, 4.5), sharey=True, constrained_layout=True)
    for ax, (label, by_gamma) in zip(np.atleast_1d(axes), errors.items(), strict=True):
        gammas = sorted(by_gamma)
        ax.boxplot([by_gamma[g] for g in gammas], tick_labels=[f"{g:.1f}" for g in gammas], showfliers=False)
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_title(label)
        ax.set_xlabel("gamma_Q (gamma_D = 1)")
    np.atleast_1d(axes)[0].set_ylabel("estimate - truth after injection, % (whiskers 1.5 IQR)")
    fig.suptitle("Figure 9: CBEKF-AU error distribution against the degradation level")
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def _figure_deviation(flights: dict[float, Flight], path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 4.5), constrained_layout=True)
    for (gamma, flight), style in zip(flights.items(), ("-", ":"), strict=False):
        ax.plot(flight.time_s, flight.traces["CBEKF"].deviation, style, lw=1.0, label=f"gamma_Q = {gamma}")
    ax.axvline(INJECT_S, color="k", ls=":", lw=1)
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_xlabel("time, s")
    ax.set_ylabel("model deviation Delta_k / dt, degC/s")
    ax.set_title("Figure 10: model-deviation term (CBEKF), degradation injected at 150 s")
    ax.legend()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def _figure_rate_grid(gq: Sequence[float], gd: Sequence[float], rates: NDArray[np.float64], path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), constrained_layout=True)
    ax = axes[0]
    for j, g_d in enumerate(gd):
        ax.plot(gq, rates[:, j] * 1000.0, "o-", label=f"gamma_D = {g_d:.1f}")
    ax.set_xlabel("gamma_Q")
    ax.set_ylabel("d(Delta/dt)/dt 10 s after injection, 1e-3 degC/s^2")
    ax.legend(fontsize=8)
    ax.set_title("rate of the deviation against severity")
    ax = axes[1]
    image = ax.imshow(
        rates.T * 1000.0,
        origin="lower",
        aspect="auto",
        cmap="viridis",
        extent=(gq[0] - 0.05, gq[-1] + 0.05, gd[0] - 0.05, gd[-1] + 0.05),
    )
    fig.colorbar(image, ax=ax, label="1e-3 degC/s^2")
    ax.set_xlabel("gamma_Q")
    ax.set_ylabel("gamma_D")
    ax.set_title("Figure 11: same, as a grid")
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def _figure_tau_sweep(taus: Sequence[float], settle: Sequence[float], path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4), constrained_layout=True)
    finite = [s if np.isfinite(s) else np.nan for s in settle]
    ax.plot(taus, finite, "o-")
    ax.axhline(300.0, color="k", ls=":", lw=1, label="paper: about 300 s")
    ax.set_xlabel("deviation filter time constant tau_Delta, s")
    ax.set_ylabel("CBEKF settle time after gamma_Q = 1.1, s")
    ax.set_title("CBEKF convergence against the deviation filter")
    ax.legend()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


# --- the report ----------------------------------------------------------------------------------


def _fmt_s(seconds: float) -> str:
    return "never (within the flight)" if not np.isfinite(seconds) else f"{seconds:.0f} s"


def _linear_r2(x: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[float, float]:
    slope, intercept = np.polyfit(x, y, 1)
    fitted = slope * x + intercept
    ss_res = float(np.sum((y - fitted) ** 2))
    ss_tot = float(np.sum((y - np.mean(y)) ** 2))
    return float(slope), (1.0 - ss_res / ss_tot) if ss_tot > 0 else 1.0


def generate(out: Path, seeds: int = 4, progress: Callable[[str], None] = print) -> Path:
    """Fly every experiment, write the figures and paper_reproduction.md into ``out``; returns the md path."""
    import matplotlib

    matplotlib.use("Agg")
    started = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    params = paper_table_a1()
    settings = EstimatorSettings()
    plant = _Plant(params)

    progress("Figures 7-8: gamma_Q = 1.1 and 1.5 at 150 s")
    main = {g: _flight(plant, g, 1.0, 1, settings) for g in (1.1, 1.5)}
    _figure_transient(main[1.1], 1.1, out / "fig7_gamma_q_1.1.png")
    _figure_transient(main[1.5], 1.5, out / "fig8_gamma_q_1.5.png")
    _figure_deviation(main, out / "fig10_deviation.png")
    f11 = main[1.1]
    t = f11.time_s
    settle = {label: settle_time(t, f11.error(label), INJECT_S) for label in VARIANTS}
    steady = {label: steady_relative_error(t, f11.error(label), f11.truth_c) for label in VARIANTS}
    post = t >= INJECT_S
    ekf_range = np.abs(f11.error("EKF")[post] / f11.truth_c[post] * 100.0)
    literal = _literal_reading(f11.log, params, settings)
    literal_error = literal.cht_est_c - f11.truth_c
    literal_settle = settle_time(t, literal_error, INJECT_S)
    literal_rms = float(np.sqrt(np.mean(literal_error[t >= INJECT_S + 300.0] ** 2)))
    f15 = main[1.5]
    after15 = f15.time_s >= INJECT_S + 10.0
    max15 = {label: float(np.max(np.abs(f15.error(label)[after15] / f15.truth_c[after15]))) * 100 for label in VARIANTS}

    progress("default mission (step-climb) with gamma_Q = 1.1 at 150 s")
    log = plant.fly_default(1.1, 1, 1800.0)
    climb = Flight(log, np.asarray(log["cht_true_c"]), _estimate(log, params, tuple(VARIANTS), settings))
    climb_post = climb.time_s >= INJECT_S
    climb_rel = {label: climb.error(label)[climb_post] / climb.truth_c[climb_post] * 100.0 for label in VARIANTS}

    progress("tau_Delta sweep")
    taus = (5.0, 10.0, 20.0, 40.0, 80.0, 120.0, 160.0)
    tau_settle = []
    for tau in taus:
        trace = _estimate(f11.log, params, ["CBEKF"], replace(settings, deviation_time_s=tau))["CBEKF"]
        tau_settle.append(settle_time(t, trace.cht_est_c - f11.truth_c, INJECT_S))
    _figure_tau_sweep(taus, tau_settle, out / "tau_sweep.png")

    progress(f"Figure 9: gamma_Q = 1.0 .. 1.5, {seeds} flights each")
    gammas = (1.0, 1.1, 1.2, 1.3, 1.4, 1.5)
    au_labels = ("CBEKF-AU midpoint", "CBEKF-AU boundary")
    box: dict[str, dict[float, NDArray[np.float64]]] = {label: {} for label in (*au_labels, "CBEKF")}
    rms: dict[str, dict[float, float]] = {label: {} for label in box}
    for g in gammas:
        pooled: dict[str, list[NDArray[np.float64]]] = {label: [] for label in box}
        for seed in range(seeds):
            # each seed cruises at its own throttle (57, 60, 63 ... %): the steady CHT lands at a
            # different place inside its quantisation level, which matters more than the noise draw
            throttle = 57.0 + 3.0 * seed
            flight = (
                main[g]
                if (g in main and seed == 1)
                else _flight(plant, g, 1.0, seed, settings, tuple(box), throttle_pct=throttle)
            )
            keep = flight.time_s >= INJECT_S
            for label in box:
                pooled[label].append(flight.error(label)[keep] / flight.truth_c[keep] * 100.0)
        for label in box:
            box[label][g] = np.concatenate(pooled[label])
            rms[label][g] = float(np.sqrt(np.mean(box[label][g] ** 2)))
    _figure_boxplots({label: box[label] for label in au_labels}, out / "fig9_cbekf_au_boxplots.png")

    progress("Figure 11: rate of Delta 10 s after injection, gamma_Q x gamma_D grid")
    grid_q = (1.0, 1.1, 1.2, 1.3, 1.4, 1.5)
    grid_d = (1.0, 1.1, 1.2, 1.3, 1.4, 1.5)
    rates = np.empty((len(grid_q), len(grid_d)))
    for i, g_q in enumerate(grid_q):
        for j, g_d in enumerate(grid_d):
            short = _flight(plant, g_q, g_d, 1, settings, ("CBEKF",), duration_s=INJECT_S + 30.0)
            rates[i, j] = _deviation_rate(short)
    _figure_rate_grid(grid_q, grid_d, rates, out / "fig11_deviation_rate.png")

    elapsed = time.perf_counter() - started
    md = out / "paper_reproduction.md"
    write_output_bytes(
        md,
        _report(
            settle,
            steady,
            ekf_range,
            climb_rel,
            max15,
            literal_settle,
            literal_rms,
            taus,
            tau_settle,
            gammas,
            box,
            rms,
            grid_q,
            grid_d,
            rates,
            main,
            seeds,
            elapsed,
            settings,
        ).encode("utf-8"),
    )
    return md


def _report(
    settle: dict[str, float],
    steady: dict[str, float],
    ekf_range: NDArray[np.float64],
    climb_rel: dict[str, NDArray[np.float64]],
    max15: dict[str, float],
    literal_settle: float,
    literal_rms: float,
    taus: Sequence[float],
    tau_settle: Sequence[float],
    gammas: Sequence[float],
    box: dict[str, dict[float, NDArray[np.float64]]],
    rms: dict[str, dict[float, float]],
    grid_q: Sequence[float],
    grid_d: Sequence[float],
    rates: NDArray[np.float64],
    main: dict[float, Flight],
    seeds: int,
    elapsed: float,
    settings: EstimatorSettings,
) -> str:
    g = np.asarray(gammas)
    au = "CBEKF-AU boundary"
    mid = "CBEKF-AU midpoint"
    spread = {label: np.array([np.subtract(*np.percentile(box[label][x], [75, 25])) for x in gammas]) for label in box}
    means = {label: np.array([np.mean(box[label][x]) for x in gammas]) for label in box}
    slope_iqr, r2_iqr = _linear_r2(g, spread[au])
    r2_iqr_mid = _linear_r2(g, spread[mid])[1]
    severity = np.array([[q * d for d in grid_d] for q in grid_q]).ravel() - 1.0
    r2_rate = _linear_r2(severity, rates.ravel())[1]
    slope_q, r2_q = _linear_r2(np.asarray(grid_q), rates[:, 0])
    f11, f15 = main[1.1], main[1.5]
    rise15 = float(
        np.mean(f15.truth_c[f15.time_s > 800]) - np.mean(f15.truth_c[(f15.time_s > 100) & (f15.time_s < 150)])
    )
    dev11 = f11.traces["CBEKF"].deviation
    dev15 = f15.traces["CBEKF"].deviation
    t = f11.time_s
    pre = (t > 30.0) & (t < INJECT_S)
    late = t > INJECT_S + 100.0
    reach = {
        gamma: float(
            f.time_s[
                np.argmax(
                    (f.time_s >= INJECT_S)
                    & (
                        f.traces["CBEKF"].deviation
                        > 0.5 * np.mean(f.traces["CBEKF"].deviation[f.time_s > INJECT_S + 100.0])
                    )
                )
            ]
            - INJECT_S
        )
        for gamma, f in main.items()
    }
    paper_tau = next((tau for tau, s in zip(taus, tau_settle, strict=True) if np.isfinite(s) and s >= 250.0), None)
    mean_rms = {label: float(np.mean([rms[label][x] for x in gammas])) for label in (mid, au)}
    wins = sum(rms[au][x] < rms[mid][x] for x in gammas)
    better = au if mean_rms[au] <= mean_rms[mid] else mid
    rows = [
        (
            "Conventional EKF keeps a 1-4 % error after gamma_Q = 1.1",
            f"EKF error after injection ranges {np.min(ekf_range):.1f}-{np.max(ekf_range):.1f} %, mean over the last"
            f" 300 s {steady['EKF']:+.2f} %",
            "reproduced in kind; larger in size in a steady cruise (see note 1)",
        ),
        (
            "(same, on a varying flight)",
            f"default mission (warm-up, step-climb, cruise; 1800 s): EKF abs. error after injection median"
            f" {np.median(np.abs(climb_rel['EKF'])):.1f} %, 95th percentile"
            f" {np.percentile(np.abs(climb_rel['EKF']), 95):.1f}"
            f" %, mean {np.mean(climb_rel['EKF']):+.2f} %; CBEKF {np.mean(climb_rel['CBEKF']):+.2f} %, CBEKF-AU"
            f" boundary {np.mean(climb_rel[au]):+.2f} % (RMS {np.sqrt(np.mean(climb_rel[au] ** 2)):.2f} %)",
            "reproduced: 1-4 % while the CHT moves"
            if 1.0 <= np.percentile(np.abs(climb_rel["EKF"]), 95) <= 4.5
            else "see note 1",
        ),
        (
            "CBEKF converges in about 300 s",
            f"CBEKF settles in {_fmt_s(settle['CBEKF'])} (tau_Delta = {settings.deviation_time_s:g} s); the sweep gives"
            f" {', '.join(f'{_fmt_s(s)} at {tau:g} s' for tau, s in zip(taus, tau_settle, strict=True))}",
            f"converges, faster than the paper; about 300 s for tau_Delta = {paper_tau:g} s"
            if paper_tau is not None
            else "converges, faster than the paper",
        ),
        (
            "CBEKF-AU converges almost at once",
            f"CBEKF-AU settles in {_fmt_s(settle[mid])} (midpoint), {_fmt_s(settle[au])} (boundary)",
            f"midpoint: {'reproduced' if settle[mid] <= 10.0 else 'not reproduced (note 4)'};"
            f" boundary: {'reproduced' if settle[au] <= 10.0 else 'not reproduced (note 4)'}",
        ),
        (
            "gamma_Q = 1.5 (+20 degC): CBEKF-AU error below 1 %",
            f"+{rise15:.1f} degC; max abs. error from 10 s after injection: {max15[mid]:.2f} % (midpoint),"
            f" {max15[au]:.2f} % (boundary),"
            f" {max15['CBEKF']:.2f} % (CBEKF), {max15['EKF']:.1f} % (EKF)",
            f"midpoint: {'reproduced' if max15[mid] < 1.0 else 'not reproduced'};"
            f" boundary: {'reproduced' if max15[au] < 1.0 else 'not reproduced'}",
        ),
        (
            "Fig. 9: CBEKF-AU error spread grows linearly with gamma_Q",
            f"IQR {spread[au][0]:.3f} % at 1.0 to {spread[au][-1]:.3f} % at 1.5 (boundary;"
            f" slope {slope_iqr:.3f} %/unit,"
            f" R^2 {r2_iqr:.2f}); midpoint {spread[mid][0]:.3f} -> {spread[mid][-1]:.3f} % (R^2 {r2_iqr_mid:.2f})",
            "reproduced"
            if r2_iqr > 0.8 and slope_iqr > 0
            else "not reproduced: the spread changes from flight to"
            " flight with where the true CHT sits against a level edge, not with gamma_Q (note 3)",
        ),
        (
            "Fig. 9: mean error drifts above gamma_Q = 1.3",
            "mean error "
            + ", ".join(f"{x:.1f}: {m:+.3f} %" for x, m in zip(gammas, means[au], strict=True))
            + " (boundary)",
            "see note 3",
        ),
        (
            "Fig. 10: Delta_k responds at once and has a non-zero mean after injection",
            f"Delta/dt before: {np.mean(dev11[pre]):+.4f} degC/s (sd {np.std(dev11[pre]):.4f}); after: "
            f"{np.mean(dev11[late]):+.3f} (gamma_Q 1.1), {np.mean(dev15[late]):+.3f} degC/s (1.5); half of it reached"
            f" {reach[1.1]:.1f} s / {reach[1.5]:.1f} s after injection",
            "reproduced (the response has the deviation filter's lag)",
        ),
        (
            "Fig. 11: rate of Delta_k 10 s after injection grows linearly with severity (gamma_Q, gamma_D)",
            f"rate vs gamma_Q (gamma_D 1): slope {slope_q * 1000:.2f}e-3 degC/s^2 per unit, R^2 {r2_q:.3f}; against"
            f" gamma_Q*gamma_D - 1 over the 6 x 6 grid: R^2 {r2_rate:.3f}",
            "reproduced" if r2_q > 0.95 else "partly",
        ),
    ]
    throttles = ", ".join(f"{57 + 3 * k:g}" for k in range(seeds))
    table = "\n".join(f"| {a} | {b} | {c} |" for a, b, c in rows)
    per_gamma = "\n".join(f"| {x:.1f} | {rms['CBEKF'][x]:.3f} | {rms[mid][x]:.3f} | {rms[au][x]:.3f} |" for x in gammas)
    return f"""# The paper's Section 3.2 reproduced on the virtual ECU

Produced by `ecu-monitor results --out docs/results --seeds {seeds}` in {elapsed:.0f} s (numba runner).
Every number below was measured in that run; the figures are beside this file.

Setting: the virtual ECU (`virtual_bus.plant.fly`) flies a steady cruise (60 % throttle, 500 m,
23 m/s; the first {_Plant.SETTLE_S:g} s of spool-up are flown and cut, so t = 0 is the nominal steady
state), with the paper's Table A1 model as the truth plant. The
CHT probe adds 0.3 degC Gaussian noise and rounds to 1 degC; readings arrive at 10 Hz. gamma_Q
(and, for Figure 11, gamma_D) steps at t = {INJECT_S:g} s. The estimators use the same model (no model
error besides the degradation), step 0.02 s, Q = {settings.process_var:g} degC^2/step, R =
{settings.measurement_var:.4f} degC^2 (1/12 + 0.3^2), sigmoid a = {settings.sigmoid_a:g}, b = {settings.sigmoid_b:g},
deviation filter tau_Delta = {settings.deviation_time_s:g} s. "Settled": the 10 s trailing mean of
|estimate - truth| stays below {SETTLE_THRESHOLD_C} degC (half a quantisation step) for the rest of the flight.

| paper's claim | our figure | verdict |
|---|---|---|
{table}

Figures: `fig7_gamma_q_1.1.png`, `fig8_gamma_q_1.5.png` (estimates, zoom, relative error),
`fig9_cbekf_au_boxplots.png` (error distribution after injection, pooled over {seeds} flights per
level, cruising at {throttles} % throttle), `fig10_deviation.png`, `fig11_deviation_rate.png`,
`tau_sweep.png`.

RMS error after injection (%, pooled over {seeds} flights), CBEKF-AU reset modes compared:

| gamma_Q | CBEKF | CBEKF-AU midpoint | CBEKF-AU boundary |
|---|---|---|---|
{per_gamma}

Mean over the levels: midpoint {mean_rms[mid]:.3f} %, boundary {mean_rms[au]:.3f} %; boundary is lower at
{wins} of {len(gammas)} levels. Default reset mode (`EstimatorSettings.reset`): `{settings.reset}`; lower mean RMS in
this run: `{better}`.

## Notes

1. **EKF error size.** In a steady cruise the conventional EKF cannot follow the degradation at all:
   the sigmoid sensor model has zero slope except within ~0.05 degC of a level boundary, so once the
   estimate sits inside a level the filter learns nothing and follows the nominal model; its error is
   the whole degradation offset ({steady["EKF"]:+.1f} % here). The paper's 1-4 % comes from a flight
   whose CHT keeps moving, which sweeps the estimate across boundaries where the update acts: the
   second row measures the same EKF on the shipped default mission (step-climb and cruise).
2. **Our reading of Delta_k** (docs/estimators.md): the low-pass-filtered deviation of the measured
   CHT from the nominal model run from the previous reading, Delta_k = LP[z_k - f(z_(k-1), u)]. The
   literal reading with x_k = the reading, Delta_k = f(z_k) - f(x(k|k)), restarts the prediction
   from the quantised reading every step: the estimate is the reading plus one model step, with the
   reading's own quantisation and noise error (RMS {literal_rms:.2f} degC after 300 s, hovering
   around the 0.5 degC settle threshold: "settled" after {_fmt_s(literal_settle)}), so a reset has
   nothing to add and the paper's 300 s versus "at once" contrast cannot appear; we did not take it.
   With our reading the CBEKF convergence time is set by tau_Delta plus the head's thermal time
   constant; the paper's ~300 s corresponds to a slower deviation filter (tau_sweep.png).
3. **Figure 9.** With the sensor noise of the virtual ECU the CBEKF-AU error is dominated by the
   quantisation and by resets on noisy level flickers: a flight whose true CHT settles near a level
   edge flickers between two readings and resets often (a wide box), one that settles mid-level
   hardly resets (a narrow box, offset by the last reset). That, not gamma_Q, sets the spread. The
   paper's linear growth and the mean drift above 1.3 are not seen here: our truth plant is exactly
   the filter's model plus gamma_Q, and Delta_k absorbs a constant gamma_Q completely once settled.
   The paper's plant (Simulink with their identified model) and noise settings are not published.
4. **Midpoint vs boundary.** The paper's midpoint reset puts the estimate at the centre of the new
   level, up to 0.5 degC from a truth that has just crossed the boundary; the boundary reset puts it on
   the crossed edge. With noisy readings both also reset on flickers between two levels; when the
   true CHT settles near an edge, midpoint resets throw the estimate 0.5 degC either side of it at
   every flicker (the "settle" metric then never drops below 0.5 degC for long), while boundary
   resets land on the edge, next to the truth. When the truth settles mid-level, midpoint resets are
   the better guess. The RMS table above weighs both situations over flights at several throttles.
   In a steady state both are less accurate than the plain CBEKF (gamma_Q = 1.0 row): after a reset
   the sigmoid update pins the estimate near the level edge (docs/estimators.md).
"""
