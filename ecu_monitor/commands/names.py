"""Names and defaults the subcommands' ``--help`` shows, in plain Python (stdlib only).

``ecu-monitor --help`` and each subcommand's help build their parsers without importing numpy,
numba, scipy or matplotlib (the command's run imports them). The lists below are copies of the
values their own modules define; tests/cli/test_cli_startup.py checks each copy equals its source, so a
change there fails a test that names this file. Lists that grow often (the gap's candidate effects,
identification's terms) are not copied: their help says an unknown name lists them.
"""

from __future__ import annotations

__all__ = [
    "CALIBRATE_RATE_PER_100H",
    "ESTIMATOR_NAMES",
    "IDENTIFY_DEFAULT_FREE",
    "PSO_DT_S",
    "PSO_ITERATIONS",
    "PSO_PARTICLES",
    "SIMULATE_DT_S",
]

#: ecu_monitor.offline.calibration_channel.DEFAULT_RATE_PER_100H: calibrate's false alarms per 100 flight hours.
CALIBRATE_RATE_PER_100H = 1.0
#: ecu_monitor.estimation.ESTIMATORS (the shipped estimators; register_estimator may add more).
ESTIMATOR_NAMES: tuple[str, ...] = ("ekf", "cbekf", "cbekf-au", "cbekf-iso")
#: ecu_monitor.identify.DEFAULT_FREE.
IDENTIFY_DEFAULT_FREE: tuple[str, ...] = ("c_w", "tau_w", "alpha_r_e", "heat_map")
#: ecu_monitor.identify.PsoSettings() defaults: swarm size, iterations, integration step (s).
PSO_PARTICLES = 48
PSO_ITERATIONS = 120
PSO_DT_S = 0.5
#: ecu_monitor.identify.REFERENCE_DT_S: the open-loop simulation's step, s.
SIMULATE_DT_S = 0.02
