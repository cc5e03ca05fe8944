"""Truth forms outside the gap library (virtual_bus.plant.TruthForm) and the non-circular blind cases."""

from __future__ import annotations

import numpy as np
import pytest

from ecu_monitor.errors import ParameterError
from ecu_monitor.gap import GapSettings
from ecu_monitor.model import paper_table_a1
from ecu_monitor.research.blind_forms import FORM_CASE_KINDS, form_case, run_form_case
from virtual_bus.plant import TRUTH_FORM_KINDS, TruthForm, fly, random_truth_form
from virtual_bus.random_missions import random_mission


def test_stateless_truth_forms_follow_their_laws() -> None:
    t = np.array([0.0, 600.0, 6000.0])
    v = np.array([0.0, 23.0, 46.0])
    throttle = np.array([20.0, 65.0, 100.0])
    power = TruthForm("airspeed_power", (("exponent", 0.8), ("slipstream_mps", 15.0), ("reference_mps", 23.0)))
    q, d = power.factors(t, v, throttle)
    assert q == 1.0
    # dissipation x (max(v, 15)/23)^0.8, i.e. gamma_D is its inverse
    assert np.asarray(d) == pytest.approx((np.maximum(v, 15.0) / 23.0) ** -0.8)
    sigmoid = TruthForm("mixture_sigmoid", (("fraction", 0.2), ("centre", 0.65), ("width", 0.05)))
    q, d = sigmoid.factors(t, v, throttle)
    assert d == 1.0 and q[1] == pytest.approx(0.9) and q[0] > 0.99 and q[2] < 0.801
    drift = TruthForm("cooling_drift", (("size", 0.2), ("time_constant_s", 600.0)))
    _, d = drift.factors(t, v, throttle)
    assert np.asarray(d) == pytest.approx([1.0, 1.0 + 0.2 * (1 - np.exp(-1.0)), 1.0 + 0.2 * (1 - np.exp(-10.0))])
    with pytest.raises(ParameterError):
        TruthForm("airspeed_power", (("exponent", 0.8),))
    with pytest.raises(ParameterError):
        random_truth_form(0, "warp_drive")
    assert set(FORM_CASE_KINDS) == {*TRUTH_FORM_KINDS, "library", "none"}


def test_oil_coupling_heats_the_head_slowly() -> None:
    form = TruthForm("oil_coupling", (("coupling", 0.3), ("time_constant_s", 600.0)))
    log = fly(random_mission(4, 1200.0), paper_table_a1(), seed=4, record_dt_s=1.0, truth_forms=(form,))
    gamma_d = np.asarray(log["form_gamma_d"])
    assert gamma_d[0] == pytest.approx(1.0)
    assert np.all(log["form_gamma_q"] == 1.0)
    # the oil follows the head with a 600 s lag: the dissipation loss grows while the engine warms
    warm = float(np.max(np.asarray(log["cht_true_c"])) - log["cht_true_c"][0])
    assert warm > 20.0 and gamma_d.max() > 1.0 + 0.3 * 0.2 * warm / 100.0
    assert np.argmax(gamma_d) > np.argmax(np.diff(np.asarray(log["cht_true_c"])))


def test_form_case_scores_by_the_oracle_rule() -> None:
    settings = GapSettings(whiteness_estimator=None)
    none = FORM_CASE_KINDS.index("none")
    case = form_case(none, seed=2, duration_s=1200.0, settings=settings)
    assert case.kind == "none" and case.form is None and case.contribution_rms_c == 0.0
    assert not case.train.has("cht_true_c") and not case.train.has("form_gamma_d")
    assert set(case.oracle) == set(settings.candidates) and case.nearest in settings.candidates
    # nothing in the truth: refitted from the true nominal model, no candidate shrinks the held-out error
    assert case.expected == () and max(case.oracle.values()) < 20.0
    result = run_form_case(case, settings)
    assert result.right == (result.verdict == ())
