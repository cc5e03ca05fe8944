"""Outputs of a gap diagnosis: DIR/gap.json (docs/contracts.md section 3), DIR/report.md, plots, DIR/model.yaml.

gap.json holds the contract's four keys (baseline, where, effects, verdict) and, beside them, the
other breakdowns (segments, regions, correlation, lag_signature, spectrum, innovation_whiteness),
the control refit, the settings and the leave-one-out's screen. In ``effects`` each entry's
``significant`` is the decision (bootstrap-significant AND material vs the control); ``p_value``, ``material`` and
``shrink_vs_reference_pct`` show the parts of it. A pair's id is "first+second"; ``verdict.effect``
is then the first (the best single effect) and ``verdict.effects`` lists both; every effect's
``params`` is ``{effect id: {parameter: value}}`` with ``params_std`` beside it.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from ecu_monitor.errors import ConfigError
from ecu_monitor.gap.diagnosis import EffectScore, GapDiagnosis
from ecu_monitor.gap.localise import LagSignature
from ecu_monitor.gap.segments import SEGMENT_NAMES
from ecu_monitor.model import save_model
from ecu_monitor.userfiles import save_figure, write_output_bytes

__all__ = ["PLOT_FILES", "gap_json", "write_report"]

PLOT_FILES = ("residual_time.png", "residual_inputs.png", "spectrum.png", "before_after.png")
_COLOURS = {"ground": "tab:brown", "climb": "tab:red", "cruise": "tab:blue", "descent": "tab:green"}


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _clean(obj: Any) -> Any:
    """JSON-safe copy: numpy scalars to Python, non-finite floats to None."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    if isinstance(obj, bool | np.bool_):
        return bool(obj)
    if isinstance(obj, int | np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        return _finite(float(obj))
    return obj


def _effect_entry(score: EffectScore) -> dict[str, Any]:
    v = score.versus
    return {
        "id": score.label,
        "test_rms_c": score.test_rms_c,
        "test_peak_c": score.test_peak_c,
        "shrink_pct": score.shrink_pct,
        "significant": score.counts,
        "params": score.fit.values,
        "params_std": {k: {p: _finite(s) for p, s in d.items()} for k, d in score.fit.std.items()},
        "nominal_factors": {k: _finite(x) for k, x in score.fit.nominal_factors.items()},
        "train_rms_c": score.fit.train_rms_c,
        "role": score.role,
        "compared_with": "control" if score.role in ("single", "pair_vs_control") else "+".join(score.fit.ids[:1]),
        "shrink_vs_reference_pct": v.shrink_pct if v else None,
        "p_value": v.p_value if v else None,
        "test_level": v.level if v else None,
        "bootstrap_significant": v.significant if v else None,
        "material": v.material if v else None,
        "converged": score.fit.converged,
        "failed_evaluations": score.fit.failed_evaluations,
    }


def _lead_entry(diag: GapDiagnosis) -> dict[str, Any] | None:
    """verdict.lead: with no winner, the candidate that still shrinks the held-out error (not confirmed)."""
    lead = diag.lead
    if lead is None:
        return None
    return {
        "id": lead.label,
        "shrink_pct": lead.shrink_pct,
        "shrink_vs_control_pct": lead.versus.shrink_pct if lead.versus else None,
        "p_value": lead.versus.p_value if lead.versus else None,
        "test_rms_c": lead.test_rms_c,
        "confirmed": False,
        "text": diag.lead_sentence(),
    }


def gap_json(diag: GapDiagnosis) -> dict[str, Any]:
    """The gap.json document of a diagnosis (docs/contracts.md section 3, plus extra keys beside)."""
    base_test = diag.baseline_test_residual
    base_train = diag.baseline_train_residual
    winner = diag.winner
    detail = diag.flight_detail()
    verdict: dict[str, Any] = {
        "effect": winner.fit.ids[0] if winner is not None else None,
        "shrink_pct": winner.shrink_pct if winner is not None else 0.0,
        "effects": list(winner.fit.ids) if winner is not None else [],
        "label": winner.label if winner is not None else "unexplained",
        "segment": diag.winner_segment,
        "test_rms_c": winner.test_rms_c if winner is not None else float(np.sqrt(np.mean(base_test**2))),
        "test_peak_c": winner.test_peak_c if winner is not None else float(np.max(np.abs(base_test))),
        "segment_gain_share": diag.segment_gain,
        "lead": _lead_entry(diag),
        "flights_confirming": [row["flight"] for row in detail if row.get("shrink_vs_control_pct", 0.0) > 0.0],
        "segments_holding": _segments_holding(detail),
        "per_flight": [
            {k: row[k] for k in ("flight", "test_rms_c", "shrink_pct", "shrink_vs_control_pct") if k in row}
            for row in detail
        ],
    }
    effects = [_effect_entry(s) for s in diag.effects]
    if diag.chosen_by is not None:  # the decision was the train flights' leave-one-out, not this test
        for entry in effects:
            entry["significant"] = winner is not None and entry["id"] == winner.label
    return _clean(
        {
            "chosen_by": _chosen_by_entry(diag),
            "baseline": {
                "train_rms_c": float(np.sqrt(np.mean(base_train**2))),
                "test_rms_c": float(np.sqrt(np.mean(base_test**2))),
                "test_peak_c": float(np.max(np.abs(base_test))),
                "train_peak_c": float(np.max(np.abs(base_train))),
                "test_mean_c": float(np.mean(base_test)),
            },
            "where": [s.to_dict() for s in diag.where],
            "effects": effects,
            "verdict": verdict,
            "control": _effect_entry(diag.control),
            "segments": [
                {"flight": t.name, "segment": s.name, "start_s": s.start_s, "stop_s": s.stop_s}
                for t in diag.tests
                for s in t.segmentation.segments
            ],
            "regions": diag.regions,
            "correlation": diag.correlation,
            "lag_signature": diag.lag.to_dict(),
            "spectrum": diag.spectrum.to_dict(),
            "innovation_whiteness": diag.whiteness,
            "heat_map_coverage": diag.coverage,
            "references": diag.references,
            "settings": {
                "candidates": list(diag.settings.candidates),
                "refit_mode": diag.settings.refit_mode,
                "pair_threshold_c": diag.settings.pair_threshold_c,
                "pair_min_shrink_pct": diag.settings.pair_min_shrink_pct,
                "dt_s": diag.settings.refit.dt_s,
                "block_s": diag.settings.significance.block_s,
                "alpha": diag.settings.significance.alpha,
                "min_shrink_pct": diag.settings.significance.min_shrink_pct,
                "min_rms_drop_c": diag.settings.significance.min_rms_drop_c,
            },
            "screen": _screen_entry(diag),
            "flights": {
                "train": [f.log.source for f in diag.trains],
                "test": [t.name for t in diag.tests],
                "cross_validation": "leave-one-flight-out" if diag.folds > 1 else None,
            },
            "per_flight": [
                {
                    **row,
                    "effects": [
                        {"id": s.label, "test_rms_c": s.flight_rms_c[k], "shrink_pct": _shrink(row, s.flight_rms_c[k])}
                        for s in diag.effects
                    ],
                }
                for k, row in enumerate(detail)
            ],
        }
    )


def _screen_entry(diag: GapDiagnosis) -> dict[str, Any] | None:
    """The leave-one-out's screen: each candidate's train RMS shrink vs the control, both fitted once on every
    flight, the bar, and the candidates it kept out of the folds (None: no screen)."""
    if not diag.screen:
        return None
    return {
        "rule": "fitted once on every flight; the folds refit a candidate only if it shrinks the control's train RMS"
        " by min_shrink_pct",
        "min_shrink_pct": diag.settings.screen_min_shrink_pct,
        "train_shrink_pct": diag.screen,
        "not_refitted": list(diag.screened_out),
    }


def _chosen_by_entry(diag: GapDiagnosis) -> dict[str, Any] | None:
    """With enough train flights: the leave-one-flight-out over them that chose the verdict (what it
    named, its pooled held-out shrink over the train flights, each candidate's pooled held-out RMS)."""
    inner = diag.chosen_by
    if inner is None:
        return None
    return {
        "rule": f"leave-one-flight-out over the {len(inner.tests)} train flights",
        "label": inner.winner.label if inner.winner is not None else "unexplained",
        "lead": inner.lead.label if inner.lead is not None else None,
        "baseline_rms_c": float(np.sqrt(np.mean(inner.baseline_test_residual**2))),
        "control_rms_c": inner.control.test_rms_c,
        "effects": [
            {"id": s.label, "held_out_rms_c": s.test_rms_c, "shrink_pct": s.shrink_pct, "significant": s.counts}
            for s in inner.effects
        ],
        "screen": _screen_entry(inner),
    }


def _shrink(row: dict[str, Any], rms_c: float) -> float:
    base = row["baseline_rms_c"]
    return 100.0 * (1.0 - rms_c / base) if base > 0 else 0.0


def _segments_holding(detail: list[dict[str, Any]]) -> dict[str, list[str]]:
    """Segment -> the test flights on which the winner's RMS there is below the control's and the baseline's."""
    out: dict[str, list[str]] = {}
    for name in SEGMENT_NAMES:
        flights = [row["flight"] for row in detail if row.get("segments", {}).get(name, {}).get("holds")]
        if flights:
            out[name] = flights
    return out


def _segment_colours(labels: np.ndarray) -> list[str]:
    return [_COLOURS[SEGMENT_NAMES[i]] for i in labels]


def _short(name: str) -> str:
    return Path(name).name


def _legend(ax: Any, present: set[str]) -> None:
    handles = [
        plt.Line2D([], [], marker="o", linestyle="", color=_COLOURS[n], label=n) for n in SEGMENT_NAMES if n in present
    ]
    ax.legend(handles=handles, loc="best", fontsize=8)


def _plot_residual_time(diag: GapDiagnosis, path: Path) -> None:
    rows = len(diag.tests)
    fig, axes = plt.subplots(2 * rows, 1, figsize=(11, 5.5 * rows), squeeze=False, height_ratios=(1.2, 1) * rows)
    for k, test in enumerate(diag.tests):
        top, bottom = axes[2 * k, 0], axes[2 * k + 1, 0]
        t = test.flight.log.time_s / 60.0
        present = {SEGMENT_NAMES[i] for i in np.unique(test.segmentation.labels)}
        top.plot(t, test.flight.cht_c, color="black", lw=1.0, label="measured")
        top.plot(t, test.baseline_model_c, color="tab:orange", lw=1.0, label="nominal model (open loop)")
        top.set_ylabel("CHT, degC")
        top.legend(loc="best", fontsize=8)
        top.set_title(
            f"Test flight {_short(test.name)}: measured vs nominal model (RMS {test.baseline_rms_c:.2f} degC)"
        )
        bottom.scatter(t, test.baseline_residual, c=_segment_colours(test.segmentation.labels), s=3)
        bottom.axhline(0.0, color="grey", lw=0.7)
        bottom.set_ylabel("meas - model, degC")
        bottom.set_xlabel("time, min")
        _legend(bottom, present)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    plt.close(fig)


def _plot_residual_inputs(diag: GapDiagnosis, path: Path) -> None:
    names = [n for n in diag.correlation if n != "model_dTdt" and all(t.flight.log.has(n) for t in diag.tests)]
    panels = [*names, "model_dTdt"]
    labels = np.concatenate([t.segmentation.labels for t in diag.tests])
    rate = np.concatenate([t.model_rate_c_per_s for t in diag.tests])
    cols = 3
    rows = math.ceil(len(panels) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(12, 3.4 * rows), squeeze=False)
    colours = _segment_colours(labels)
    for ax, name in zip(axes.flat, panels, strict=False):
        x = rate if name == "model_dTdt" else np.concatenate([np.asarray(t.flight.log[name]) for t in diag.tests])
        ax.scatter(x, diag.baseline_test_residual, c=colours, s=2)
        ax.axhline(0.0, color="grey", lw=0.7)
        label = "model dT/dt, degC/s" if name == "model_dTdt" else name
        ax.set_xlabel(label)
        ax.set_ylabel("residual, degC")
        ax.set_title(f"r = {diag.correlation[name]:+.2f}", fontsize=9)
    for ax in list(axes.flat)[len(panels) :]:
        ax.axis("off")
    _legend(axes.flat[0], {SEGMENT_NAMES[i] for i in np.unique(labels)})
    fig.suptitle(f"Residual of the nominal model against each input ({len(diag.tests)} test flight(s) pooled)")
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    plt.close(fig)


def _plot_spectrum(diag: GapDiagnosis, path: Path) -> None:
    spec = diag.spectrum
    fig, ax = plt.subplots(figsize=(8, 4.5))
    f, p = spec.frequency_hz[1:], spec.power_c2_per_hz[1:]
    ax.loglog(f, p, color="tab:purple", label="residual (nominal model)")
    if diag.winner is not None:
        from scipy import signal

        n = diag.winner.test_residual.size
        fw, pw = signal.welch(
            diag.winner.test_residual, fs=1.0 / diag.tests[0].flight.dt_s, nperseg=int(min(1024, n)), detrend="linear"
        )
        ax.loglog(fw[1:], pw[1:], color="tab:green", label=f"residual with {diag.winner.label}")
    for period in (600.0, 60.0):
        ax.axvline(1.0 / period, color="grey", lw=0.6, ls=":")
    ax.set_xlabel("frequency, Hz (dotted: 10 min and 1 min periods)")
    ax.set_ylabel("PSD, degC^2/Hz")
    lag = f"lag signature tau = {diag.lag.tau_s:.1f} s" if diag.lag.tau_s > 0.0 else "no lag signature"
    ax.set_title(f"Residual spectrum ({lag}, r = {diag.lag.correlation:+.2f})")
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    plt.close(fig)


def _plot_before_after(diag: GapDiagnosis, path: Path) -> None:
    after = diag.winner if diag.winner is not None else diag.control
    label = after.label if diag.winner is not None else "control (R_Ce, heat re-tuned; not significant)"
    rows = len(diag.tests)
    fig, axes = plt.subplots(2 * rows, 1, figsize=(11, 5.5 * rows), squeeze=False)
    for k, test in enumerate(diag.tests):
        top, bottom = axes[2 * k, 0], axes[2 * k + 1, 0]
        t = test.flight.log.time_s / 60.0
        residual = after.flight_residuals[k]
        top.plot(t, test.flight.cht_c, color="black", lw=1.0, label="measured")
        top.plot(t, test.baseline_model_c, color="tab:orange", lw=1.0, label="before: nominal")
        top.plot(t, test.flight.cht_c - residual, color="tab:green", lw=1.0, label=f"after: {label}")
        top.set_ylabel("CHT, degC")
        top.legend(loc="best", fontsize=8)
        top.set_title(f"Held-out {_short(test.name)}, before and after (refitted on the train flights only)")
        after_rms = float(np.sqrt(np.mean(residual**2)))
        bottom.plot(
            t, test.baseline_residual, color="tab:orange", lw=0.8, label=f"before, RMS {test.baseline_rms_c:.2f}"
        )
        bottom.plot(t, residual, color="tab:green", lw=0.8, label=f"after, RMS {after_rms:.2f} degC")
        bottom.axhline(0.0, color="grey", lw=0.7)
        bottom.set_ylabel("meas - model, degC")
        bottom.set_xlabel("time, min")
        bottom.legend(loc="best", fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    plt.close(fig)


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.{digits}g}" if math.isfinite(value) else "inf"
    return str(value)


def _sigma_text(sigma: float) -> str:
    """``+- sigma``, or "(not identifiable)" for the inf that refit.identifiable_std gives."""
    return f"+- {_fmt(sigma, 2)}" if math.isfinite(sigma) else "(not identifiable)"


def _lag_text(lag: LagSignature) -> str:
    """The lag signature as a sentence; a fit with tau <= 0 is a lead, not a lag, and is said so."""
    if lag.tau_s <= 0.0:
        return (
            f"Lag signature: none (the fit r(t) ~ -tau dT/dt gives no positive tau; correlation "
            f"{lag.correlation:+.2f})."
        )
    return (
        f"Lag signature: r(t) ~ -tau dT/dt gives tau = {lag.tau_s:.1f} s with correlation {lag.correlation:+.2f} "
        f"({100 * lag.explained:.0f} % of the residual variance)."
    )


def _params_text(score: EffectScore) -> str:
    parts = []
    for cid, values in score.fit.values.items():
        for name, value in values.items():
            parts.append(f"{name} = {_fmt(value)} {_sigma_text(score.fit.std[cid][name])}")
    f = score.fit.nominal_factors
    parts.append(f"R_Ce x {f['r_ce_factor']:.3f}, heat x {f['heat_factor']:.3f}")
    return "; ".join(parts)


def _flight_table(diag: GapDiagnosis, doc: dict[str, Any]) -> list[str]:
    """Per test flight: baseline, control and winner RMS; winner shrink by segment."""
    name = diag.winner.label if diag.winner is not None else None
    head = "| flight | baseline RMS | control RMS |"
    rule = "|---|---|---|"
    if name:
        head += f" {name} RMS | shrink vs baseline | vs control | shrink by segment (vs baseline; * = holds) |"
        rule += "---|---|---|---|"
    lines = [head, rule]
    for row in doc["per_flight"]:
        line = f"| {_short(row['flight'])} | {row['baseline_rms_c']:.2f} | {row['control_rms_c']:.2f} |"
        if name:
            segs = ", ".join(
                f"{seg} {v['shrink_pct']:+.0f} %{'*' if v['holds'] else ''}" for seg, v in row["segments"].items()
            )
            line += (
                f" {row['test_rms_c']:.2f} | {row['shrink_pct']:+.0f} % | {row['shrink_vs_control_pct']:+.0f} %"
                f" | {segs} |"
            )
        lines.append(line)
    return lines


def _markdown(diag: GapDiagnosis, doc: dict[str, Any], command: str | None) -> str:
    base = doc["baseline"]
    verdict = doc["verdict"]
    lines = ["# Sim-to-real gap diagnosis", ""]
    trains = ", ".join(f"`{f.log.source}`" for f in diag.trains)
    tests = ", ".join(f"`{t.name}`" for t in diag.tests)
    if diag.folds > 1:
        lines.append(
            f"Leave-one-flight-out over {trains}: each flight held out in turn, every candidate refitted on the "
            "other flights (from a nominal model that has not seen it) and scored on it; pooled over all of them."
        )
    else:
        lines.append(f"Train flight(s) (refits): {trains}; test flight(s) (held out): {tests}.")
    chosen = doc["chosen_by"]
    if chosen is not None:
        lines += [
            "",
            f"The verdict was chosen by a {chosen['rule']} (each held out in turn, pooled: "
            f"{chosen['label']}; baseline {chosen['baseline_rms_c']:.2f} degC, control {chosen['control_rms_c']:.2f}, "
            + ", ".join(f"{e['id']} {e['held_out_rms_c']:.2f}" for e in chosen["effects"][:6])
            + "), then refitted on every train flight and scored on the test flight(s): the test flights measure "
            "the choice and take no part in it.",
        ]
    if command:
        lines += ["", f"Command: `{command}`"]
    lines += ["", "## Verdict", ""]
    if diag.winner is not None:
        lines.append(
            f"**{verdict['label']}** explains the gap: held-out RMS {base['test_rms_c']:.2f} -> "
            f"{verdict['test_rms_c']:.2f} degC (shrink {verdict['shrink_pct']:.0f} %), "
            f"peak {base['test_peak_c']:.1f} -> "
            f"{verdict['test_peak_c']:.1f} degC. Most of the gain is in the **{verdict['segment']}** segment. "
            f"Fitted: {_params_text(diag.winner)}. The improved model is in model.yaml."
        )
        confirming = verdict["flights_confirming"]
        lines.append("")
        lines.append(
            f"Held-out flights on which it beats the control: {len(confirming)} of {len(diag.tests)}. "
            "Segments where it holds (RMS below the control's and the baseline's): "
            + ("; ".join(f"{seg} on {len(fl)} flight(s)" for seg, fl in verdict["segments_holding"].items()) or "none")
            + "."
        )
    else:
        top = diag.where[0]
        lead = diag.lead_sentence()
        lines.append(
            (f"**Not confirmed: {lead}.** " if lead else "**Unexplained.** ")
            + "No candidate effect improves the held-out test flight significantly and materially "
            f"over the re-tuned nominal model; none is named. The residual lies mostly in the **{top.segment}** "
            f"segment ({100 * top.share:.0f} % of the squared error, RMS {top.rms_c:.2f} degC, mean "
            f"{top.mean_c:+.2f} degC). model.yaml is the nominal model unchanged."
        )
    lines += [
        "",
        "## Baseline (nominal model, open loop)",
        "",
        "| flight | RMS, degC | peak, degC |",
        "|---|---|---|",
        f"| train ({len(diag.trains)} flight(s) end to end) | {base['train_rms_c']:.2f} | {base['train_peak_c']:.2f} |",
        f"| test ({len(diag.tests)} flight(s) pooled) | {base['test_rms_c']:.2f} | {base['test_peak_c']:.2f} |",
        "",
        "## Per test flight",
        "",
        *_flight_table(diag, doc),
        "",
        "## Where (test flights pooled)",
        "",
        "| segment | share of squared error | RMS, degC | mean, degC | duration, s |",
        "|---|---|---|---|---|",
    ]
    for s in diag.where:
        lines.append(f"| {s.segment} | {s.share:.2f} | {s.rms_c:.2f} | {s.mean_c:+.2f} | {s.duration_s:.0f} |")
    lines += ["", "Correlation of the residual with each input and with the model's dT/dt:", ""]
    lines.append("| " + " | ".join(diag.correlation) + " |")
    lines.append("|" + "---|" * len(diag.correlation))
    lines.append("| " + " | ".join(f"{v:+.2f}" for v in diag.correlation.values()) + " |")
    lines += ["", "By operating region (quantile bins of each input; RMS / mean residual, degC):", ""]
    for name, rows in diag.regions.items():
        cells = ", ".join(f"[{r['low']:.4g}, {r['high']:.4g}]: {r['rms_c']:.2f} / {r['mean_c']:+.2f}" for r in rows)
        lines.append(f"- {name}: {cells}")
    lag = diag.lag
    bands = diag.spectrum.band_share
    lines += [
        "",
        _lag_text(lag),
        "Spectrum: share of residual power with periods > 10 min "
        f"{bands['period_over_600s']:.2f}, 1-10 min {bands['period_60_600s']:.2f}, "
        f"< 1 min {bands['period_under_60s']:.2f}; dominant period "
        f"{diag.spectrum.dominant_period_s:.0f} s.",
    ]
    w = diag.whiteness
    if w.get("estimator"):
        lines.append(
            f"Innovations of the {w['estimator']} filter on the nominal model: Ljung-Box Q = {w['q']:.0f} over "
            f"{w['lags']:.0f} lags (p = {w['p_value']:.2g}), lag-1 autocorrelation {w['acf1']:+.2f}, RMS "
            f"{w['innovation_rms_c']:.2f} degC ({'white' if w['p_value'] > 0.05 else 'not white'})."
        )
    cov = diag.coverage
    lines.append(
        f"Heat-map coverage: {100 * cov['unvisited_time_share']:.0f} % of the test flight is in heat-map cells the "
        f"train flight never visited (< {cov['min_visit_s']:.0f} s); they hold "
        f"{100 * cov['unvisited_error_share']:.0f} % of the squared residual (RMS {cov['unvisited_rms_c']:.2f} degC "
        f"there, {cov['visited_rms_c']:.2f} degC in visited cells)."
    )
    lines += [
        "",
        "## Candidate effects (refitted on the train flights, scored on the test flights)",
        "",
        f"Control (no effect, R_Ce and heat scale re-tuned): test RMS {diag.control.test_rms_c:.2f} degC. "
        "A candidate counts when its held-out gain over its reference (the control for a single effect, the "
        "single effect for a pair, the control for a pair tried when no single effect counts) is significant "
        "in a bootstrap that resamples whole test flights and blocks "
        "within them "
        f"({diag.settings.significance.block_s:.0f} s blocks, family-wise alpha {diag.settings.significance.alpha}: "
        "half of it to the single effect that fits the train flights best, the rest shared by the others) "
        f"and material (>= {diag.settings.significance.min_shrink_pct:.0f} % and "
        f">= {diag.settings.significance.min_rms_drop_c} degC).",
        "",
        "| effect | test RMS, degC | peak, degC | shrink vs baseline | vs reference | p / level | counts"
        " | parameters (+- 1 sigma) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for score in diag.effects:
        v = score.versus
        label = score.label + (" (vs control)" if score.role == "pair_vs_control" else "")
        lines.append(
            f"| {label} | {score.test_rms_c:.2f} | {score.test_peak_c:.1f} | {score.shrink_pct:+.0f} % | "
            f"{(v.shrink_pct if v else 0.0):+.0f} % | {_fmt(v.p_value if v else None, 2)}"
            f"{f' / {v.level:.2g}' if v else ''} | "
            f"{'yes' if score.counts else 'no'} | {_params_text(score)} |"
        )
    if diag.screened_out:
        bar = diag.settings.screen_min_shrink_pct
        lines += [
            "",
            f"Not refitted in the folds (the screen: fitted once on every flight, under {bar:g} % train RMS shrink"
            " against the control there): "
            + ", ".join(f"{cid} {diag.screen[cid]:.0f} %" for cid in diag.screened_out)
            + ".",
        ]
    lines += ["", "## Plots", ""]
    for name in PLOT_FILES:
        lines.append(f"![{name}]({name})")
    return "\n".join(lines) + "\n"


def write_report(diag: GapDiagnosis, out_dir: str | Path, command: str | None = None) -> dict[str, Any]:
    """Write gap.json, report.md, the plots and model.yaml into ``out_dir``; returns the gap.json dict."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{out}: cannot create the output directory ({exc.strerror})") from None
    doc = gap_json(diag)
    write_output_bytes(out / "gap.json", (json.dumps(doc, indent=2, allow_nan=False) + "\n").encode(), ConfigError)
    _plot_residual_time(diag, out / PLOT_FILES[0])
    _plot_residual_inputs(diag, out / PLOT_FILES[1])
    _plot_spectrum(diag, out / PLOT_FILES[2])
    _plot_before_after(diag, out / PLOT_FILES[3])
    write_output_bytes(out / "report.md", _markdown(diag, doc, command).encode("utf-8"), ConfigError)
    label = diag.winner.label if diag.winner is not None else "none (unexplained): nominal model unchanged"
    save_model(diag.model, out / "model.yaml", comment=f"ecu-monitor gap: winning effect {label}")
    return doc
