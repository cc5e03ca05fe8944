"""Tables and plots of an identification: error table, measured vs simulated CHT (the paper's Figure 6),
cost per iteration (Figure A5) and the identified heat map with the visited breakpoints.

Plots are PNG files written with matplotlib's Agg backend (no display needed).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.flightlog import FlightLog
from ecu_monitor.identify.problem import ErrorStats
from ecu_monitor.model import ThermalParams
from ecu_monitor.userfiles import save_figure

__all__ = ["error_table", "plot_cost", "plot_flight", "plot_heat_map"]


def error_table(rows: Sequence[tuple[str, str, ErrorStats]]) -> str:
    """A plain-text table of (role, flight, errors): mean / peak / RMS in degC and mean / peak in %."""
    header = ("role", "flight", "mean degC", "peak degC", "RMS degC", "mean %", "peak %")
    body = [
        (role, name, f"{e.mean_c:.2f}", f"{e.peak_c:.2f}", f"{e.rms_c:.2f}", f"{e.mean_pct:.2f}", f"{e.peak_pct:.2f}")
        for role, name, e in rows
    ]
    widths = [max(len(str(r[k])) for r in (header, *body)) for k in range(len(header))]
    lines = [
        "  ".join(str(c).ljust(w) if k < 2 else str(c).rjust(w) for k, (c, w) in enumerate(zip(r, widths, strict=True)))
        for r in (header, *body)
    ]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_flight(
    log: FlightLog, simulated_c: NDArray[np.float64], path: str | Path, title: str, errors: ErrorStats | None = None
) -> None:
    """Measured vs simulated CHT over time, with the error below (the paper's Figure 6)."""
    plt = _pyplot()
    t_min = (np.asarray(log.time_s) - log.time_s[0]) / 60.0
    measured = np.asarray(log["cht_c"])
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 6), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    top.plot(t_min, measured, color="0.35", lw=1.0, label="measured CHT")
    top.plot(t_min, simulated_c, color="tab:red", lw=1.2, label="model (open loop)")
    if log.has("cht_true_c"):
        top.plot(t_min, log["cht_true_c"], color="tab:blue", lw=0.8, ls="--", label="true CHT (virtual ECU)")
    top.set_ylabel("CHT, degC")
    top.grid(alpha=0.3)
    top.legend(loc="best")
    heading = title
    if errors is not None:
        heading += (
            f"\nmean {errors.mean_c:.2f} degC ({errors.mean_pct:.2f} %), peak {errors.peak_c:.2f} degC"
            f" ({errors.peak_pct:.2f} %), RMS {errors.rms_c:.2f} degC"
        )
    top.set_title(heading, fontsize=10)
    bottom.plot(t_min, measured - simulated_c, color="tab:red", lw=0.8)
    bottom.axhline(0.0, color="0.5", lw=0.6)
    bottom.set_ylabel("meas - model, degC")
    bottom.set_xlabel("time, min")
    bottom.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def plot_cost(history: Sequence[float], path: str | Path, title: str, polish_cost: float | None = None) -> None:
    """Best cost per PSO iteration (the paper's Figure A5), log scale, with the polished cost if any."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    iterations = np.arange(len(history))
    ax.semilogy(iterations, history, color="tab:blue", lw=1.5, label="PSO best cost")
    if polish_cost is not None:
        ax.axhline(
            polish_cost, color="tab:green", ls="--", lw=1.0, label=f"after least-squares polish: {polish_cost:.3f}"
        )
    ax.set_xlabel("iteration")
    ax.set_ylabel("RMS error, degC")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="best")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def plot_heat_map(params: ThermalParams, identified: NDArray[np.bool_], path: str | Path, title: str) -> None:
    """The identified heat map Q_SL0 (W) as lines over the second axis, visited breakpoints filled."""
    plt = _pyplot()
    hm = params.heat_map
    values = hm.values_array()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    colours = plt.cm.viridis(np.linspace(0.0, 0.9, len(hm.x_breakpoints)))
    for i, x in enumerate(hm.x_breakpoints):
        ax.plot(hm.y_breakpoints, values[i], color=colours[i], lw=1.2, label=f"{hm.x_axis} = {x:.3g}")
        seen = np.asarray(identified[i], dtype=bool)
        ax.scatter(np.asarray(hm.y_breakpoints)[seen], values[i][seen], color=colours[i], s=30, zorder=3)
        ax.scatter(
            np.asarray(hm.y_breakpoints)[~seen],
            values[i][~seen],
            facecolor="white",
            edgecolor=colours[i],
            s=30,
            zorder=3,
        )
    ax.set_xlabel(hm.y_axis)
    ax.set_ylabel("Q_SL0, W")
    ax.set_title(title + "\n(filled: identified breakpoints; open: not visited, copied from the nearest)", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)
