"""CHT estimators on the thermal model: EKF, CBEKF, CBEKF-AU and the quantised-sensor model.

Start with :func:`make_estimator` (live, one step at a time: ``initialise`` then ``estimate(t, u, z)``)
or :func:`run_estimator` (a whole flight log, compiled). The equations are in :mod:`.ekf`
(docs/estimators.md explains them and our reading of the paper's model-deviation term).
"""

from ecu_monitor.estimation.ekf import (
    RESET_MODES,
    Correction,
    Estimate,
    EstimatorSettings,
    FilterState,
    Prediction,
    ThermalEKF,
    deviation_update,
    filter_step,
    predict,
    update,
)
from ecu_monitor.estimation.quantiser import quantise, sensor_model, sensor_slope
from ecu_monitor.estimation.registry import (
    ESTIMATORS,
    CHTEstimator,
    EstimatorFactory,
    make_estimator,
    register_estimator,
)
from ecu_monitor.estimation.runner import EstimateTrace, FixedStepFlight, fixed_step_flight, run_estimator

__all__ = [
    "ESTIMATORS",
    "RESET_MODES",
    "CHTEstimator",
    "Correction",
    "Estimate",
    "EstimateTrace",
    "EstimatorFactory",
    "EstimatorSettings",
    "FilterState",
    "FixedStepFlight",
    "Prediction",
    "ThermalEKF",
    "deviation_update",
    "filter_step",
    "fixed_step_flight",
    "make_estimator",
    "predict",
    "quantise",
    "register_estimator",
    "run_estimator",
    "sensor_model",
    "sensor_slope",
    "update",
]
