"""Compile the kernels most tests share, besides the step (``python -m tests.helpers.warm_kernels``).

tests/conftest.py runs this in a second process while the controller compiles the live step, so a fresh
clone's first tests find these in numba's cache too instead of each compiling them in the middle of the
run (numba compiles on one core: the two warm-ups use both). Every call is a small run of the real code
on a two-minute virtual flight: the plant, a short identification, the estimators, the detector.
"""

from __future__ import annotations

from ecu_monitor.estimation import make_estimator
from ecu_monitor.estimation.detection import DetectorSettings, cusum_path
from ecu_monitor.estimation.isolation import run_isolation
from ecu_monitor.estimation.runner import run_estimator
from ecu_monitor.identify import identify
from ecu_monitor.identify.pso import PsoSettings
from ecu_monitor.model import InputSeries, paper_table_a1
from virtual_bus.missions import mission_from_dict
from virtual_bus.plant import fly

SHORT = {"name": "warm", "segments": [{"kind": "ground_run", "duration_s": 40, "throttle_pct": 40},
                                      {"kind": "cruise", "duration_s": 80, "throttle_pct": 60}]}  # fmt: skip

INPUTS = ("throttle_pct", "rpm", "altitude_m", "airspeed_mps", "oat_c")


def main() -> None:
    params = paper_table_a1()
    log = fly(mission_from_dict(SHORT), params, seed=1)
    identify([log], settings=PsoSettings(particles=4, iterations=1))
    trace = run_estimator(log, params, "cbekf-au")
    run_isolation(log, params)
    cusum_path(trace.time_s, trace.cht_est_c - trace.cht_meas_c, DetectorSettings())
    inputs = [InputSeries(*(float(log[c][k]) for c in INPUTS)) for k in range(3)]
    for name in ("cbekf-au", "cbekf-iso"):  # the live filters, a call per period
        live = make_estimator(name, params)
        live.initialise(float(log.time_s[0]), inputs[0], float(log["cht_c"][0]))
        for k in (1, 2):
            live.estimate(float(log.time_s[k]), inputs[k], float(log["cht_c"][k]))


if __name__ == "__main__":
    main()
