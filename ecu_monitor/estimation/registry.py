"""The estimator contract and the registry of estimators by name: one explicit table.

"ekf" (conventional, Delta = 0), "cbekf" (with the model deviation), "cbekf-au" (CBEKF with automatic
reset, ``EstimatorSettings.reset`` chooses midpoint or boundary) and "cbekf-iso" (the gamma_Q /
gamma_D isolation filter of :mod:`.isolation`). Every estimator is in :data:`ESTIMATORS` below; no
module adds itself on import. :func:`register_estimator` exists for callers that add their own.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

from ecu_monitor.errors import ConfigError
from ecu_monitor.estimation.ekf import Estimate, EstimatorSettings, ThermalEKF
from ecu_monitor.estimation.isolation import ESTIMATOR_NAME as ISOLATION_NAME
from ecu_monitor.estimation.isolation import make_isolation_filter
from ecu_monitor.model import InputSeries, ThermalParams

__all__ = [
    "ESTIMATORS",
    "CHTEstimator",
    "EstimatorFactory",
    "make_estimator",
    "register_estimator",
]


@runtime_checkable
class CHTEstimator(Protocol):
    """A fixed-step CHT estimator (progpy's ``estimate(t, u, z)`` manner); the model is passed in."""

    name: str

    def initialise(self, t_s: float, u: InputSeries, z_cht_c: float) -> None:
        """Start at t_s from the first reading z (degC) with inputs u."""
        ...

    def estimate(self, t_s: float, u: InputSeries, z_cht_c: float | None) -> Estimate:
        """One fixed step to t_s with inputs u; z None means no reading at this step."""
        ...


EstimatorFactory = Callable[[ThermalParams, EstimatorSettings], CHTEstimator]


def _ekf(params: ThermalParams, settings: EstimatorSettings) -> CHTEstimator:
    return ThermalEKF(params, settings, name="ekf", use_deviation=False, reset="none")


def _cbekf(params: ThermalParams, settings: EstimatorSettings) -> CHTEstimator:
    return ThermalEKF(params, settings, name="cbekf", use_deviation=True, reset="none")


def _cbekf_au(params: ThermalParams, settings: EstimatorSettings) -> CHTEstimator:
    return ThermalEKF(params, settings, name="cbekf-au", use_deviation=True, reset=settings.reset)


#: Estimator name -> factory(params, settings).
ESTIMATORS: dict[str, EstimatorFactory] = {
    "ekf": _ekf,
    "cbekf": _cbekf,
    "cbekf-au": _cbekf_au,
    ISOLATION_NAME: make_isolation_filter,
}


def register_estimator(name: str, factory: EstimatorFactory) -> None:
    """Add (or replace) an estimator under ``name``."""
    if not name or not isinstance(name, str):
        raise ConfigError(f"estimator name: expected a non-empty string, got {name!r}")
    ESTIMATORS[name] = factory


def make_estimator(name: str, params: ThermalParams, settings: EstimatorSettings | None = None) -> CHTEstimator:
    """A new estimator by name; an unknown name raises ConfigError listing the known ones."""
    factory = ESTIMATORS.get(name)
    if factory is None:
        raise ConfigError(f"estimator: unknown name {name!r} (known: {', '.join(sorted(ESTIMATORS))})")
    return factory(params, settings if settings is not None else EstimatorSettings())
