"""Held-out improvement test: does a refitted candidate beat the control on the TEST flight?

The statistic is the mean of the per-sample difference of squared errors on the test flight,
``d_t = e_control(t)^2 - e_candidate(t)^2`` (> 0 where the candidate is better). The open-loop
residuals are strongly autocorrelated (a thermal time constant of minutes), so the samples are not
independent: the spread of the mean comes from a moving-block bootstrap (circular blocks of
``block_s`` seconds, several thermal time constants long, resampled with replacement).

A candidate counts only when it is both

- *significant*: the one-sided lower confidence bound of mean(d) at level ``alpha / n_tests``
  (Bonferroni over the candidates tried) is above zero, and
- *material*: it shrinks the test RMS relative to the control by at least ``min_shrink_pct`` and by
  at least ``min_rms_drop_c`` degC in absolute terms (a tenth of the 1 degC quantisation step would
  not change any decision an engineer makes).

The thresholds were calibrated on the blind cases (docs/results/gap.md) so that no-effect and
out-of-library cases stay null.
"""

from __future__ import annotations

import math
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

    @property
    def counts(self) -> bool:
        """True when the improvement is both significant and material."""
        return self.significant and self.material


def improvement_test(
    reference_residual: np.ndarray,
    candidate_residual: np.ndarray,
    dt_s: float,
    n_tests: int = 1,
    settings: SignificanceSettings | None = None,
) -> ImprovementTest:
    """Block-bootstrap test that ``candidate_residual`` beats ``reference_residual`` (both (N,), degC)."""
    settings = settings or SignificanceSettings()
    ref = np.asarray(reference_residual, dtype=float)
    cand = np.asarray(candidate_residual, dtype=float)
    if ref.shape != cand.shape or ref.ndim != 1 or ref.size < 2:
        raise ParameterError("improvement_test: residuals must be 1-D arrays of equal length >= 2")
    gain = ref**2 - cand**2
    n = gain.size
    block = int(min(max(1, round(settings.block_s / dt_s)), n))
    n_blocks = math.ceil(n / block)
    rng = np.random.default_rng(settings.seed)
    starts = rng.integers(0, n, size=(settings.resamples, n_blocks))
    index = (starts[:, :, None] + np.arange(block)[None, None, :]) % n
    index = index.reshape(settings.resamples, -1)[:, :n]
    means = gain[index].mean(axis=1)
    level = settings.alpha / max(n_tests, 1)
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
    )
