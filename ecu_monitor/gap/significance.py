"""Held-out improvement test: does a refitted candidate beat the control on the TEST flight?

The statistic is the mean of the per-sample difference of squared errors on the test flight(s),
``d_t = e_control(t)^2 - e_candidate(t)^2`` (> 0 where the candidate is better), pooled over every
sample of every test flight. The open-loop residuals are strongly autocorrelated (a thermal time
constant of minutes), so the samples are not independent: the spread of the mean comes from a
moving-block bootstrap (circular blocks of ``block_s`` seconds, several thermal time constants long,
resampled with replacement). With several test flights the bootstrap is two-level: each resample
draws whole flights with replacement (flights differ by day, weather, pilot: the gain on one flight
says little about the next), then blocks within each drawn flight; the resampled statistic is the
pooled mean over the samples drawn. With one test flight it is the plain block bootstrap.

A candidate counts only when it is both

- *significant*: the one-sided lower confidence bound of mean(d) at level ``alpha / n_tests``
  (Bonferroni over the candidates tried; the diagnosis weights the single candidates, half of alpha
  to the one that fits the train flights best, :func:`ecu_monitor.gap.diagnose.train_led_shares`)
  is above zero, and
- *material*: it shrinks the test RMS relative to the control by at least ``min_shrink_pct`` and by
  at least ``min_rms_drop_c`` degC in absolute terms (a tenth of the 1 degC quantisation step would
  not change any decision an engineer makes).

The thresholds were calibrated on the blind cases (docs/results/gap.md) so that no-effect and
out-of-library cases stay null.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ecu_monitor.errors import ParameterError

__all__ = ["ImprovementTest", "SignificanceSettings", "improvement_test"]


@dataclass(frozen=True)
class SignificanceSettings:
    """block_s: bootstrap block length (s); resamples; alpha: family-wise level; min_shrink_pct:
    smallest material shrink of the test RMS vs the control (%); min_rms_drop_c: smallest material
    absolute drop (degC); seed of the bootstrap."""

    block_s: float = 300.0
    resamples: int = 2000
    alpha: float = 0.05
    min_shrink_pct: float = 20.0
    min_rms_drop_c: float = 0.3
    seed: int = 0

    def __post_init__(self) -> None:
        checks = (
            ("block_s", self.block_s, 1.0, 1e5),
            ("resamples", self.resamples, 100, 1e6),
            ("alpha", self.alpha, 1e-6, 0.5),
            ("min_shrink_pct", self.min_shrink_pct, 0.0, 100.0),
            ("min_rms_drop_c", self.min_rms_drop_c, 0.0, 100.0),
        )
        for name, value, low, high in checks:
            if not isinstance(value, int | float) or not math.isfinite(value) or not low <= value <= high:
                raise ParameterError(f"significance.{name}: expected a number in [{low:g}, {high:g}], got {value!r}")


@dataclass(frozen=True)
class ImprovementTest:
    """Outcome of :func:`improvement_test` (RMS in degC, shrink in %)."""

    reference_rms_c: float
    candidate_rms_c: float
    shrink_pct: float
    mean_gain_c2: float  # mean of d_t, degC^2
    lower_bound_c2: float  # one-sided lower confidence bound of mean(d_t)
    p_value: float  # bootstrap share of resampled means <= 0
    significant: bool
    material: bool
    level: float = 0.05  # the one-sided level of this test (alpha over the family's weight)

    @property
    def counts(self) -> bool:
        """True when the improvement is both significant and material."""
        return self.significant and self.material


def _block_sums(gain: np.ndarray, block: int, resamples: int, rng: np.random.Generator) -> np.ndarray:
    """Sums of ``resamples`` circular block-bootstrap copies of ``gain`` (each of the original length)."""
    n = gain.size
    block = int(min(max(1, block), n))
    n_blocks = math.ceil(n / block)
    # prefix sums over the doubled series: a circular block's sum in O(1)
    prefix = np.concatenate([[0.0], np.cumsum(np.concatenate([gain, gain]))])
    starts = rng.integers(0, n, size=(resamples, n_blocks))
    lengths = np.full(n_blocks, block)
    lengths[-1] = n - block * (n_blocks - 1)
    return np.sum(prefix[starts + lengths[None, :]] - prefix[starts], axis=1)


def _as_flights(residual: np.ndarray | Sequence[np.ndarray]) -> list[np.ndarray]:
    if isinstance(residual, np.ndarray) and residual.ndim == 1:
        return [np.asarray(residual, dtype=float)]
    return [np.asarray(r, dtype=float) for r in residual]


def improvement_test(
    reference_residual: np.ndarray | Sequence[np.ndarray],
    candidate_residual: np.ndarray | Sequence[np.ndarray],
    dt_s: float,
    n_tests: float = 1,
    settings: SignificanceSettings | None = None,
) -> ImprovementTest:
    """Bootstrap test that ``candidate_residual`` beats ``reference_residual`` (degC): each one (N,)
    array for one test flight, or a sequence of them, one per test flight (flights and blocks
    resampled, module doc)."""
    settings = settings or SignificanceSettings()
    refs = _as_flights(reference_residual)
    cands = _as_flights(candidate_residual)
    if (
        not refs
        or len(refs) != len(cands)
        or any(r.shape != c.shape or r.ndim != 1 or r.size < 2 for r, c in zip(refs, cands, strict=True))
    ):
        raise ParameterError("improvement_test: residuals must be 1-D arrays of equal length >= 2, flight by flight")
    gains = [r**2 - c**2 for r, c in zip(refs, cands, strict=True)]
    rng = np.random.default_rng(settings.seed)
    block = round(settings.block_s / dt_s)
    sums = np.stack([_block_sums(g, block, settings.resamples, rng) for g in gains])  # (F, R)
    sizes = np.array([g.size for g in gains], dtype=float)
    n_flights = len(gains)
    if n_flights == 1:
        means = sums[0] / sizes[0]
    else:
        drawn = rng.integers(0, n_flights, size=(settings.resamples, n_flights))
        column = rng.integers(0, settings.resamples, size=(settings.resamples, n_flights))
        means = sums[drawn, column].sum(axis=1) / sizes[drawn].sum(axis=1)
    ref = np.concatenate(refs)
    cand = np.concatenate(cands)
    gain = np.concatenate(gains)
    level = settings.alpha / max(float(n_tests), 1.0)
    lower = float(np.quantile(means, level))
    mean_gain = float(gain.mean())
    ref_rms = float(np.sqrt(np.mean(ref**2)))
    cand_rms = float(np.sqrt(np.mean(cand**2)))
    shrink = 100.0 * (1.0 - cand_rms / ref_rms) if ref_rms > 0 else 0.0
    material = shrink >= settings.min_shrink_pct and (ref_rms - cand_rms) >= settings.min_rms_drop_c
    return ImprovementTest(
        reference_rms_c=ref_rms,
        candidate_rms_c=cand_rms,
        shrink_pct=shrink,
        mean_gain_c2=mean_gain,
        lower_bound_c2=lower,
        p_value=float(np.mean(means <= 0.0)),
        significant=lower > 0.0,
        material=material,
        level=level,
    )
