"""Across flights: slow wear and the maintenance alert (a one-sided CUSUM over one number per flight).

Each flight is summarised by its **wear index**: how much hotter the head ran than the nominal model says,
relative to the model's temperature rise over the outside air::

    x = mean over the flight's samples with CHT_model - OAT >= min_rise_c of (CHT - CHT_model) / (CHT_model - OAT)

CHT_model is the pipeline's open-loop reference (the nominal model run from the first CHT reading of the
flight), so nothing learnt during the flight can absorb a fault that is there from engine start. Both
degradations raise it: gamma_Q > 1 puts more heat in, gamma_D > 1 takes less out; the overlay
CHT + k (CHT - OAT) raises it by about k. Samples with a small rise (ground idle, power-off glides) carry
more sensor quantisation than signal and are left out.

The reference is the index's mean and spread over nominal flights of this engine (:class:`WearReference`:
``ecu-monitor calibrate`` stores it, or the engine's own first ``baseline_flights`` flights in its history
give it). Its spread is known from a few flights only, so the test uses an upper confidence bound on it
(chi-square, ``spread_confidence``; Wilson-Hilferty's approximation of the quantile): a reference from few
flights alerts later, never more often. Then, flight after flight::

    z_i = (x_i - mean) / sd_upper        S_i = max(0, S_(i-1) + z_i - k)        alert when S_i >= h

k (``allowance``, in units of the nominal spread) is half the smallest shift worth an alert; h is chosen for
the asked false-alert rate: one alert in ``false_alert_flights`` nominal flights on average (Siegmund's
approximation of the CUSUM's in-control run length, solved for h). The alert latches until maintenance
clears it (the history keeps it; the daemon publishes it at each start).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ecu_monitor.errors import ConfigError

__all__ = [
    "FlightWear",
    "WearReference",
    "WearSettings",
    "WearVerdict",
    "cusum_threshold",
    "reference_from_flights",
    "wear_ratios",
    "wear_verdict",
]


@dataclass(frozen=True)
class WearSettings:
    """The across-flight detector's settings (module docstring)."""

    allowance: float = 0.5  # k, in units of the nominal spread across flights
    false_alert_flights: float = 2000.0  # nominal flights per false alert, on average (sets h)
    spread_confidence: float = 0.9  # one-sided confidence of the upper bound on the nominal spread
    min_rise_c: float = 40.0  # degC: samples whose model CHT is less above OAT are left out
    min_samples: int = 60  # a flight with fewer kept samples has no wear index
    baseline_flights: int = 10  # without a stored reference: the engine's first flights give it

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
                raise ConfigError(f"wear.{item.name}: expected a finite number >= 0, got {value!r}")
        if self.false_alert_flights <= 1.0:
            raise ConfigError(f"wear.false_alert_flights: expected > 1, got {self.false_alert_flights!r}")
        if not 0.5 <= self.spread_confidence < 1.0:
            raise ConfigError(f"wear.spread_confidence: expected 0.5 <= value < 1, got {self.spread_confidence!r}")
        if self.baseline_flights < 3:
            raise ConfigError(f"wear.baseline_flights: expected at least 3, got {self.baseline_flights!r}")

    @property
    def threshold(self) -> float:
        """h for :attr:`false_alert_flights` (:func:`cusum_threshold`)."""
        return cusum_threshold(self.false_alert_flights, self.allowance)


@dataclass(frozen=True)
class WearReference:
    """The wear index over nominal flights of this engine: mean, sample standard deviation, how many flights."""

    mean: float
    sd: float
    flights: int

    def __post_init__(self) -> None:
        if not (math.isfinite(self.mean) and math.isfinite(self.sd) and self.sd > 0.0):
            raise ConfigError(f"wear reference: expected a finite mean and sd > 0, got {self.mean!r}, {self.sd!r}")
        if self.flights < 2:
            raise ConfigError(f"wear reference: expected at least 2 flights, got {self.flights!r}")

    def sd_upper(self, confidence: float) -> float:
        """Upper confidence bound of the spread: sd * sqrt(df / chi2_(1 - confidence)(df)), df = flights - 1."""
        df = self.flights - 1
        z = statistics.NormalDist().inv_cdf(1.0 - confidence)
        c = 2.0 / (9.0 * df)
        quantile = df * max(1.0 - c + z * math.sqrt(c), 0.05) ** 3  # Wilson-Hilferty; floored for tiny df
        return self.sd * math.sqrt(df / quantile)


def reference_from_flights(indices: Sequence[float | None]) -> WearReference | None:
    """The reference of nominal flights' wear indices (None ones skipped); None with fewer than 3."""
    values = [float(v) for v in indices if v is not None and math.isfinite(v)]
    if len(values) < 3:
        return None
    sd = statistics.stdev(values)
    return WearReference(statistics.fmean(values), max(sd, 1e-6), len(values))


def cusum_threshold(false_alert_flights: float, allowance: float) -> float:
    """h of a one-sided CUSUM on unit-variance flights with allowance k whose in-control average run length is
    ``false_alert_flights`` (Siegmund: ARL0 = (exp(2kb) - 2kb - 1) / (2k^2), b = h + 1.166; k = 0: b^2)."""
    if allowance <= 0.0:
        return max(math.sqrt(false_alert_flights) - 1.166, 0.0)
    target = false_alert_flights * 2.0 * allowance**2

    def arl(b: float) -> float:
        x = 2.0 * allowance * b
        return math.expm1(x) - x

    low, high = 0.0, 1.0
    while arl(high) < target:
        high *= 2.0
    for _ in range(80):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if arl(mid) < target else (low, mid)
    return max(0.5 * (low + high) - 1.166, 0.0)


def wear_ratios(cht_c: ArrayLike, model_c: ArrayLike, oat_c: ArrayLike, min_rise_c: float) -> NDArray[np.float64]:
    """(CHT - CHT_model) / (CHT_model - OAT) of the samples that count (module docstring), 1-D."""
    cht = np.asarray(cht_c, dtype=np.float64).ravel()
    model = np.asarray(model_c, dtype=np.float64).ravel()
    rise = model - np.asarray(oat_c, dtype=np.float64).ravel()
    keep = np.isfinite(cht) & np.isfinite(rise) & (rise >= min_rise_c)
    return (cht[keep] - model[keep]) / rise[keep]


class FlightWear:
    """A flight's wear index, accumulated online (:meth:`add`) or over arrays (:meth:`add_many`)."""

    def __init__(self, settings: WearSettings | None = None) -> None:
        self.settings = settings or WearSettings()
        self.n = 0
        self.total = 0.0
        self.total_sq = 0.0

    def add(self, cht_c: float, model_c: float, oat_c: float) -> None:
        """One sample: measured (or trusted) CHT, the reference model's CHT and OAT, degC."""
        self.add_many([cht_c], [model_c], [oat_c])

    def add_many(self, cht_c: ArrayLike, model_c: ArrayLike, oat_c: ArrayLike) -> None:
        """Samples as arrays of the same length, degC."""
        ratios = wear_ratios(cht_c, model_c, oat_c, self.settings.min_rise_c)
        self.n += int(ratios.size)
        self.total += float(ratios.sum())
        self.total_sq += float(np.square(ratios).sum())

    def restore(self, n: int, mean: float | None, sd: float | None) -> None:
        """Continue from a stored part (a flight cut by a restart)."""
        if n <= 0 or mean is None:
            return
        spread = sd or 0.0
        self.n += n
        self.total += n * mean
        self.total_sq += n * (spread * spread + mean * mean)

    @property
    def index(self) -> float | None:
        """The wear index, or None with fewer than ``min_samples`` samples."""
        return self.total / self.n if self.n >= max(self.settings.min_samples, 1) else None

    @property
    def spread(self) -> float | None:
        """Standard deviation of the samples' ratios within the flight (None below ``min_samples``)."""
        if self.index is None:
            return None
        mean = self.total / self.n
        return math.sqrt(max(self.total_sq / self.n - mean * mean, 0.0))


@dataclass(frozen=True)
class WearVerdict:
    """The CUSUM over one engine's flights: the statistic after each flight (None: flight without an index or
    inside the baseline), h, the position of the first flight at or above h (None: no alert), the reference."""

    statistic: tuple[float | None, ...]
    threshold: float
    alert_at: int | None
    reference: WearReference | None
    learned: bool  # the reference came from the engine's own first flights

    @property
    def alerted(self) -> bool:
        """An alert was raised."""
        return self.alert_at is not None


def wear_verdict(
    indices: Sequence[float | None], settings: WearSettings, reference: WearReference | None = None
) -> WearVerdict:
    """The CUSUM over flights' wear indices, oldest first (module docstring).

    Without ``reference`` the first ``baseline_flights`` flights with an index give it and the test starts
    after them (fewer: no test yet).
    """
    h = settings.threshold
    start = 0
    learned = reference is None
    if reference is None:
        seen = [i for i, v in enumerate(indices) if v is not None and math.isfinite(v)]
        if len(seen) < settings.baseline_flights:
            return WearVerdict((None,) * len(indices), h, None, None, True)
        start = seen[settings.baseline_flights - 1] + 1
        reference = reference_from_flights([indices[i] for i in seen[: settings.baseline_flights]])
        if reference is None:
            return WearVerdict((None,) * len(indices), h, None, None, True)
    scale = reference.sd_upper(settings.spread_confidence)
    path: list[float | None] = [None] * len(indices)
    s = 0.0
    alert_at = None
    for i in range(start, len(indices)):
        value = indices[i]
        if value is None or not math.isfinite(value):
            path[i] = s
            continue
        s = max(0.0, s + (value - reference.mean) / scale - settings.allowance)
        path[i] = s
        if alert_at is None and s >= h:
            alert_at = i
    return WearVerdict(tuple(path), h, alert_at, reference, learned)
