"""Where the model departs: the open-loop residual (measured minus simulated CHT) broken down.

- by segment (ground/climb/cruise/descent): each segment's share of the squared error, RMS, mean;
- by operating region: quantile bins of each input (heat axes, airspeed, altitude, OAT);
- correlation of the residual with each input and with the model's dT/dt;
- the lag signature: a probe (or heat-path) lag the model lacks leaves ``r(t) ~ -tau dT/dt``, so the
  least-squares tau of that regression and its correlation say whether a lag is plausible;
- the spectrum (Welch) and the share of residual power by band of period;
- whiteness (Ljung-Box) of a sequence such as the filtered innovations;
- heat-map coverage: the share of the test residual in cells of the heat map the train flight never
  visited (there the identified map is an extrapolation, whatever effect is added).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import signal, stats

from ecu_monitor.flightlog import FlightLog
from ecu_monitor.gap.segments import SEGMENT_NAMES, Segmentation

__all__ = [
    "LagSignature",
    "SegmentShare",
    "Spectrum",
    "correlations",
    "heat_map_coverage",
    "lag_signature",
    "ljung_box",
    "region_breakdown",
    "residual_spectrum",
    "segment_breakdown",
]


@dataclass(frozen=True)
class SegmentShare:
    """One segment's part of the residual: share of the total squared error, RMS and mean (degC)."""

    segment: str
    share: float
    rms_c: float
    mean_c: float
    duration_s: float

    def to_dict(self) -> dict[str, Any]:
        """The gap.json ``where`` entry (segment, share, rms_c) plus mean_c and duration_s."""
        return {
            "segment": self.segment,
            "share": self.share,
            "rms_c": self.rms_c,
            "mean_c": self.mean_c,
            "duration_s": self.duration_s,
        }


def segment_breakdown(residual: np.ndarray, segmentation: Segmentation, dt_s: float) -> list[SegmentShare]:
    """Per-segment share of the squared residual, sorted by share (descending); shares sum to 1."""
    r = np.asarray(residual, dtype=float)
    total = float(np.sum(r**2))
    out = []
    for index, name in enumerate(SEGMENT_NAMES):
        mask = segmentation.labels == index
        if not np.any(mask):
            continue
        part = r[mask]
        share = float(np.sum(part**2)) / total if total > 0 else float(np.mean(mask))
        out.append(
            SegmentShare(name, share, float(np.sqrt(np.mean(part**2))), float(np.mean(part)), float(mask.sum()) * dt_s)
        )
    norm = sum(s.share for s in out)
    out = [SegmentShare(s.segment, s.share / norm, s.rms_c, s.mean_c, s.duration_s) for s in out]
    return sorted(out, key=lambda s: (-s.share, s.segment))


def region_breakdown(
    residual: np.ndarray, log: FlightLog, columns: Sequence[str], n_bins: int = 4
) -> dict[str, list[dict[str, float]]]:
    """Residual RMS and mean in quantile bins of each column (bins of equal sample count)."""
    r = np.asarray(residual, dtype=float)
    total = float(np.sum(r**2)) or 1.0
    out: dict[str, list[dict[str, float]]] = {}
    for name in columns:
        if not log.has(name):
            continue
        x = np.asarray(log[name], dtype=float)
        edges = np.unique(np.quantile(x, np.linspace(0.0, 1.0, n_bins + 1)))
        if edges.size < 2:
            continue
        which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, edges.size - 2)
        rows = []
        for b in range(edges.size - 1):
            mask = which == b
            if not np.any(mask):
                continue
            part = r[mask]
            rows.append(
                {
                    "low": float(edges[b]),
                    "high": float(edges[b + 1]),
                    "samples": int(mask.sum()),
                    "share": float(np.sum(part**2)) / total,
                    "rms_c": float(np.sqrt(np.mean(part**2))),
                    "mean_c": float(np.mean(part)),
                }
            )
        out[name] = rows
    return out


def _pearson(x: np.ndarray, y: np.ndarray) -> float:
    if np.std(x) == 0 or np.std(y) == 0:
        return 0.0
    return float(np.corrcoef(x, y)[0, 1])


def correlations(
    residual: np.ndarray, log: FlightLog, columns: Sequence[str], model_rate_c_per_s: np.ndarray
) -> dict[str, float]:
    """Pearson correlation of the residual with each column and with the model's dT/dt."""
    r = np.asarray(residual, dtype=float)
    out = {name: _pearson(r, np.asarray(log[name], dtype=float)) for name in columns if log.has(name)}
    out["model_dTdt"] = _pearson(r, np.asarray(model_rate_c_per_s, dtype=float))
    return out


@dataclass(frozen=True)
class LagSignature:
    """Fit of ``r ~ -tau * dT/dt`` (demeaned): tau_s (s), its correlation and variance explained."""

    tau_s: float
    correlation: float
    explained: float

    def to_dict(self) -> dict[str, float]:
        """Plain dict for gap.json."""
        return {"tau_s": self.tau_s, "correlation": self.correlation, "explained": self.explained}


def lag_signature(residual: np.ndarray, model_rate_c_per_s: np.ndarray) -> LagSignature:
    """Least-squares tau of ``r(t) = -tau dT/dt``: a positive tau with high |correlation| means a lag."""
    r = np.asarray(residual, dtype=float) - np.mean(residual)
    d = np.asarray(model_rate_c_per_s, dtype=float) - np.mean(model_rate_c_per_s)
    dd = float(d @ d)
    if dd == 0.0:
        return LagSignature(0.0, 0.0, 0.0)
    tau = -float(r @ d) / dd
    corr = _pearson(r, -d)
    return LagSignature(tau, corr, corr * corr)


@dataclass(frozen=True)
class Spectrum:
    """Welch spectrum of the residual and the share of its power by band of period."""

    frequency_hz: np.ndarray
    power_c2_per_hz: np.ndarray
    dominant_period_s: float
    band_share: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        """Summary for gap.json (the arrays stay in the plots)."""
        return {"dominant_period_s": self.dominant_period_s, "band_share": self.band_share}


def residual_spectrum(residual: np.ndarray, dt_s: float) -> Spectrum:
    """Welch PSD of the residual (segments of up to 1024 samples, linear detrend)."""
    r = np.asarray(residual, dtype=float)
    nper = int(min(1024, r.size))
    freq, psd = signal.welch(r, fs=1.0 / dt_s, nperseg=nper, detrend="linear")
    bands = {"period_over_600s": (0.0, 1.0 / 600.0), "period_60_600s": (1.0 / 600.0, 1.0 / 60.0)}
    bands["period_under_60s"] = (1.0 / 60.0, np.inf)
    total = float(np.sum(psd[1:])) or 1.0
    share = {
        name: float(np.sum(psd[1:][(freq[1:] >= lo) & (freq[1:] < hi)])) / total for name, (lo, hi) in bands.items()
    }
    k = int(np.argmax(psd[1:])) + 1 if psd.size > 1 else 0
    dominant = float(1.0 / freq[k]) if k > 0 and freq[k] > 0 else float("inf")
    return Spectrum(freq, psd, dominant, share)


def ljung_box(values: np.ndarray, lags: int = 20) -> dict[str, float]:
    """Ljung-Box portmanteau test of whiteness: Q statistic, p-value, lag-1 autocorrelation."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    n = x.size
    lags = int(min(lags, max(1, n // 4)))
    x = x - x.mean()
    denom = float(x @ x)
    if n < 4 or denom == 0.0:
        return {"q": 0.0, "p_value": 1.0, "lags": float(lags), "acf1": 0.0}
    acf = np.array([float(x[k:] @ x[:-k]) / denom for k in range(1, lags + 1)])
    q = float(n * (n + 2) * np.sum(acf**2 / (n - np.arange(1, lags + 1))))
    return {"q": q, "p_value": float(stats.chi2.sf(q, lags)), "lags": float(lags), "acf1": float(acf[0])}


def _cells(x: np.ndarray, y: np.ndarray, xb: np.ndarray, yb: np.ndarray) -> np.ndarray:
    i = np.clip(np.searchsorted(xb, x, side="right") - 1, 0, xb.size - 2)
    j = np.clip(np.searchsorted(yb, y, side="right") - 1, 0, yb.size - 2)
    return i * (yb.size - 1) + j


def heat_map_coverage(
    residual: np.ndarray,
    train: FlightLog,
    test: FlightLog,
    axes: tuple[str, str],
    x_breakpoints: Sequence[float],
    y_breakpoints: Sequence[float],
    min_visit_s: float = 30.0,
) -> dict[str, float]:
    """How much of the test residual lies in heat-map cells the train flight never visited.

    A cell (between adjacent breakpoints of the two heat axes; outside the grid counts as the edge
    cell) is *visited* when the train flight spends at least ``min_visit_s`` in it. A gap that sits
    mostly in unvisited cells is a coverage problem of the identification, not a missing effect.
    """
    xb = np.asarray(x_breakpoints, dtype=float)
    yb = np.asarray(y_breakpoints, dtype=float)
    dt_train = float(np.median(np.diff(train.time_s)))
    train_cells = _cells(np.asarray(train[axes[0]]), np.asarray(train[axes[1]]), xb, yb)
    counts = np.bincount(train_cells, minlength=(xb.size - 1) * (yb.size - 1)) * dt_train
    test_cells = _cells(np.asarray(test[axes[0]]), np.asarray(test[axes[1]]), xb, yb)
    unvisited = counts[test_cells] < min_visit_s
    r = np.asarray(residual, dtype=float)
    total = float(np.sum(r**2)) or 1.0
    return {
        "unvisited_time_share": float(np.mean(unvisited)),
        "unvisited_error_share": float(np.sum(r[unvisited] ** 2)) / total,
        "unvisited_rms_c": float(np.sqrt(np.mean(r[unvisited] ** 2))) if np.any(unvisited) else 0.0,
        "visited_rms_c": float(np.sqrt(np.mean(r[~unvisited] ** 2))) if np.any(~unvisited) else 0.0,
        "min_visit_s": float(min_visit_s),
    }
