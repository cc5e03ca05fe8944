"""Detection: the one-sided CUSUM over whole flights and the threshold calibration (the live step's detector:
tests/pipeline/test_detector_step.py)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ecu_monitor.errors import ConfigError
from ecu_monitor.estimation.detection import (
    DetectorSettings,
    block_means,
    calibrate_threshold,
    count_alarms,
    cusum_path,
    hourly_maxima,
    scale_blocks,
)

HOUR = 3600.0


def _ar1(rng: np.random.Generator, n: int, sigma: float, phi: float) -> np.ndarray:
    from scipy.signal import lfilter

    return lfilter([1.0], [1.0, -phi], rng.standard_normal(n) * sigma * math.sqrt(1.0 - phi * phi))


def test_cusum_detects_a_step_and_not_noise_at_the_calibrated_threshold() -> None:
    rng = np.random.default_rng(1)
    rate = 10.0  # Hz
    base = DetectorSettings(threshold=1e300, reference=0.04, warmup_s=60.0, block_s=1.0, baseline_s=0.0)
    # 30 nominal hours of correlated noise (std 0.03 degC/s, 20 s correlation) to calibrate on
    cal_paths = []
    for _ in range(10):
        n = int((3 * HOUR + 61.0) * rate)
        t = np.arange(n) / rate
        cal_paths.append(cusum_path(t, _ar1(rng, n, 0.03, math.exp(-1.0 / (rate * 20.0))), base)[1])
    cal = calibrate_threshold(cal_paths, 1.0)
    assert cal.hours == 30
    detector = DetectorSettings(threshold=cal.threshold, reference=0.04, warmup_s=60.0, block_s=1.0, baseline_s=0.0)
    # fresh noise: almost no alarm in 30 h. A threshold for 1 per 100 h fitted on 30 h is itself uncertain
    # (on this noise, repeated 30 h calibrations score 0-5 per 100 h), so allow up to 3 here (10 per 100 h)
    fresh = []
    for _ in range(10):
        n = int((3 * HOUR + 61.0) * rate)
        fresh.append((np.arange(n) / rate, _ar1(rng, n, 0.03, math.exp(-1.0 / (rate * 20.0)))))
    alarms, hours = count_alarms(fresh, detector)
    assert hours == pytest.approx(30.17, rel=1e-3)
    assert alarms <= 3
    # the same noise with a step of +0.12 at 1800 s: detected, about h / (0.12 - k) seconds later
    t, x = fresh[0]
    stepped = x + np.where(t >= 1800.0, 0.12, 0.0)
    _, _, alarm_times = cusum_path(t, stepped, detector)
    assert alarm_times.size == 1
    delay = alarm_times[0] - 1800.0
    expected = cal.threshold / (0.12 - 0.04)
    assert 0.0 < delay < 2.0 * expected + 30.0


def test_baseline_absorbs_a_constant_offset_but_not_a_step() -> None:
    t = np.arange(0.0, 4000.0, 1.0)
    offset = np.full(t.size, 0.2)  # a steady model error: the plain test alarms, the baseline test does not
    plain = DetectorSettings(threshold=10.0, reference=0.05, warmup_s=0.0, baseline_s=0.0)
    adaptive = DetectorSettings(threshold=10.0, reference=0.05, warmup_s=0.0, baseline_s=300.0, baseline_delay_s=0.0)
    delayed = DetectorSettings(threshold=10.0, reference=0.05, warmup_s=0.0, baseline_s=300.0, baseline_delay_s=60.0)
    assert cusum_path(t, offset, plain)[2].size == 1
    assert cusum_path(t, offset, adaptive)[2].size == 0
    step = offset + np.where(t >= 2000.0, 0.15, 0.0)
    alarm = cusum_path(t, step, adaptive)[2]
    assert alarm.size == 1
    # the excess over the adapting baseline decays as 0.15 exp(-t/300): S(t) = 45 (1 - e^(-t/300)) - 0.05 t
    # reaches h = 10 at t = 145 s
    assert alarm[0] - 2000.0 == pytest.approx(145.0, abs=5.0)
    # with a 60 s delay line the whole step counts for 60 s (S = 6), then decays: h reached at ~105 s
    assert cusum_path(t, offset, delayed)[2].size == 0
    alarm = cusum_path(t, step, delayed)[2]
    assert alarm.size == 1
    assert alarm[0] - 2000.0 == pytest.approx(105.0, abs=5.0)
    # a small step (0.02 above the allowance): the adapting baseline absorbs it (S peaks near 1 at
    # ~100 s); a baseline frozen while S > 0 never learns it, S climbs 0.02 per s: h at ~500 s
    small = offset + np.where(t >= 2000.0, 0.07, 0.0)
    assert cusum_path(t, small, adaptive)[2].size == 0
    frozen = dataclasses.replace(adaptive, baseline_freeze=True)
    assert cusum_path(t, offset, frozen)[2].size == 0
    alarm = cusum_path(t, small, frozen)[2]
    assert alarm.size == 1
    assert alarm[0] - 2000.0 == pytest.approx(500.0, abs=5.0)


def test_self_normalised_excess_is_weighed_by_floor_over_the_spread() -> None:
    """scale_s on: the excess counts floor / spread of its size when the symptom's running spread about its
    baseline is above the floor, in full at or below it; the spread does not learn while S > 0."""
    t = np.arange(0.0, 4000.0, 1.0)
    rough = np.where(t.astype(int) % 2 == 0, 0.04, -0.04)  # |x - baseline| = 0.04 every block
    step = rough + np.where(t >= 2000.0, 0.15, 0.0)
    frozen = DetectorSettings(threshold=20.0, reference=0.05, warmup_s=0.0, baseline_s=600.0, baseline_delay_s=0.0,
                              baseline_freeze=True)  # fmt: skip
    plain_alarm = cusum_path(t, step, frozen)[2]
    weighed = dataclasses.replace(frozen, scale_s=600.0, scale_floor=0.02)
    spread = scale_blocks(block_means(t, step, weighed)[1], weighed)
    assert spread[1500] == pytest.approx(0.04, rel=0.05)
    assert spread[2400] == pytest.approx(spread[1990], rel=0.05)  # frozen while the step is tested
    half_alarm = cusum_path(t, step, weighed)[2]
    assert plain_alarm.size == half_alarm.size == 1
    # the step's excess 0.10 (0.15 - k) counts 0.05 per s: h = 20 in ~400 s instead of ~200 s
    assert plain_alarm[0] - 2000.0 == pytest.approx(200.0, abs=15.0)
    assert half_alarm[0] - 2000.0 == pytest.approx(400.0, abs=30.0)
    at_floor = dataclasses.replace(weighed, scale_floor=0.05)  # the spread under the floor: counted in full
    assert np.array_equal(cusum_path(t, step, at_floor)[1], cusum_path(t, step, frozen)[1])
    with pytest.raises(ConfigError, match="scale_floor"):
        DetectorSettings(scale_s=600.0)


def test_calibration_gives_the_intended_rate_on_synthetic_data() -> None:
    rng = np.random.default_rng(3)
    settings = DetectorSettings(threshold=1e300, reference=0.03, warmup_s=0.0, block_s=1.0)
    phi = math.exp(-1.0 / 30.0)

    def paths(hours: int) -> list[np.ndarray]:
        out = []
        for _ in range(hours // 10):
            n = int(10 * HOUR)
            out.append(cusum_path(np.arange(n, dtype=float), _ar1(rng, n, 0.04, phi), settings)[1])
        return out

    target = 10.0  # per 100 h, so that 400 scoring hours hold ~40 alarms to count
    cal = calibrate_threshold(paths(400), target)
    scoring = paths(400)
    rate = 100.0 * float(np.mean(hourly_maxima(scoring, 1.0) >= cal.threshold))
    assert 5.0 <= rate <= 20.0
    assert cal.gumbel_scale > 0.0


def test_calibration_on_few_hours_stays_above_what_was_seen() -> None:
    paths = [np.linspace(0.0, 3.0, 7200), np.linspace(0.0, 1.0, 7200)]
    cal = calibrate_threshold(paths, 1.0, margin=1.2)
    assert cal.threshold >= 1.2 * 3.0 - 1e-9
    # flights whose statistic peaks in the last part-hour (landing): h stays above that peak too
    landing = [np.concatenate([np.zeros(3600), np.linspace(0.0, 6.0, 1200)]) for _ in range(3)]
    cal = calibrate_threshold(landing, 1.0)
    assert cal.hours == 3
    assert cal.threshold >= 1.1 * 6.0 - 1e-9


def test_enough_hours_use_the_part_hours_in_the_empirical_quantile() -> None:
    # 400 flights of 1 h 20 min, flat in the whole hour, 5.0 in the last 20 min of 16 of them
    paths = [np.concatenate([np.full(3600, 0.5), np.full(1200, 5.0 if i < 16 else 0.5)]) for i in range(400)]
    assert hourly_maxima(paths, 1.0).max() == 0.5
    assert hourly_maxima(paths, 1.0, part_hours=True).size == 800
    cal = calibrate_threshold(paths, 1.5)  # 16 of 800 maxima (2 %) above the 98.5 % quantile
    assert cal.threshold == pytest.approx(5.0)
    with pytest.raises(ConfigError):
        calibrate_threshold([np.zeros(100)], 1.0)
    with pytest.raises(ConfigError):
        calibrate_threshold(paths, 0.0)


def test_settings_are_validated() -> None:
    with pytest.raises(ConfigError):
        DetectorSettings(threshold=-1.0)
    with pytest.raises(ConfigError):
        DetectorSettings(suspect_fraction=1.5)
    with pytest.raises(ConfigError):
        DetectorSettings(baseline_s=0.5, block_s=1.0)
    with pytest.raises(ConfigError, match="baseline_freeze"):
        DetectorSettings(baseline_freeze="yes")  # type: ignore[arg-type]


def test_evaluation_plan_and_one_simulated_flight() -> None:
    from ecu_monitor.model import paper_table_a1
    from ecu_monitor.research.evaluation import (
        SYMPTOMS,
        EvaluationConfig,
        FlightCase,
        plan_cases,
        residual_effects,
        simulate_case,
    )

    config = EvaluationConfig(hours=3.0, degraded_seeds=1, full_size_hours=1.0)
    cases = plan_cases(config)
    assert cases == plan_cases(config)  # deterministic
    for role in ("calibration", "scoring", "full_size"):
        hours = sum(c.duration_s for c in cases if c.role == role) / HOUR
        assert hours >= (1.0 if role == "full_size" else 3.0)
    seeds = [c.seed for c in cases]
    assert len(seeds) == len(set(seeds))  # disjoint sets
    assert residual_effects(5) == residual_effects(5)
    case = FlightCase("degraded", 123, 1200.0, "gamma_d", 1.3, 650.0)
    result = simulate_case(case, paper_table_a1(), config)
    assert set(result.symptoms) == set(SYMPTOMS)
    n = result.time_s.size
    assert n > 1000 and all(v.size == n for v in result.symptoms.values())
    after = result.time_s > case.onset_s + 200.0
    before = (result.time_s > 400.0) & (result.time_s < case.onset_s)
    # the degradation raises the symptom and the gamma_D estimate
    assert np.mean(result.symptoms["cbekf"][after]) > np.mean(result.symptoms["cbekf"][before]) + 0.03
    assert np.mean(result.gamma_d[after]) > np.mean(result.gamma_d[before]) + 0.05
    assert all(math.isfinite(v) and v < 3.0 for v in result.cht_rms_c.values())


def test_evaluate_command_rejects_bad_arguments() -> None:
    from ecu_monitor.cli import main

    assert main(["evaluate", "--hours", "0"]) == 2
    assert main(["evaluate", "--target", "150"]) == 2


def test_steady_gate_holds_the_test_after_a_throttle_change_and_on_the_ground() -> None:
    from ecu_monitor.estimation.steady_gate import GateSettings, SteadyGate, steady_mask

    t = np.arange(0.0, 1000.0, 0.5)
    throttle = np.where(t < 400.0, 50.0, 90.0) + 0.2 * np.sin(t)
    airspeed = np.where(t < 50.0, 0.0, 23.0)
    settings = GateSettings(throttle_change_pct=10.0, window_s=120.0, min_airspeed_mps=10.0)
    mask = steady_mask(t, throttle, airspeed, settings)
    assert not mask[t < 50.0].any()  # on the ground
    assert mask[(t > 60.0) & (t < 400.0)].all()
    assert not mask[(t >= 400.0) & (t < 519.0)].any()  # within 120 s of the 40 % step
    assert mask[t > 521.0].all()
    gate = SteadyGate(settings)
    assert [gate.update(float(a), float(b), float(c)) for a, b, c in zip(t, throttle, airspeed, strict=True)] == list(
        mask
    )
    # a symptom excursion right after the power change does not count; the same after the hold does
    symptom = np.where((t >= 400.0) & (t < 500.0), 0.3, 0.0)
    detector = DetectorSettings(threshold=5.0, reference=0.05, warmup_s=0.0, baseline_s=0.0)
    assert cusum_path(t, symptom, detector)[2].size == 1
    assert cusum_path(t, symptom, detector, steady=mask)[2].size == 0
    late = np.where((t >= 600.0) & (t < 700.0), 0.3, 0.0)
    assert cusum_path(t, late, detector, steady=mask)[2].size == 1


def test_overlay_degradation_follows_the_first_order_rise_of_cht_minus_oat() -> None:
    from ecu_monitor.errors import ParameterError
    from ecu_monitor.estimation.detection import overlay_degradation

    t = np.arange(0.0, 3000.0, 1.0) + 500.0  # a clock that does not start at 0
    cht = 150.0 + 20.0 * np.sin(t / 300.0)
    oat = np.full(t.size, 10.0)
    cht[5] = np.nan  # a missing reading before the onset stays missing
    out = overlay_degradation(t, cht, oat, onset_s=1500.0, gain=0.2, time_constant_s=240.0)
    before = t < 1500.0
    np.testing.assert_array_equal(out[before], cht[before])  # untouched before the onset (nan included)
    after = ~before
    expected = cht[after] + 0.2 * (cht[after] - oat[after]) * (1.0 - np.exp(-(t[after] - 1500.0) / 240.0))
    np.testing.assert_allclose(out[after], expected, rtol=0, atol=1e-12)
    # one time constant after the onset: 63 % of the final rise; long after: (CHT - OAT) x 1.2
    i = int(np.searchsorted(t, 1740.0))
    assert out[i] - cht[i] == pytest.approx(0.2 * (cht[i] - 10.0) * (1.0 - math.exp(-1.0)), rel=1e-9)
    assert (out[-1] - 10.0) / (cht[-1] - 10.0) == pytest.approx(1.2, abs=1e-3)
    assert np.all(np.isnan(out) == np.isnan(cht))
    with pytest.raises(ParameterError, match="gain"):
        overlay_degradation(t, cht, oat, onset_s=1500.0, gain=-0.1)
    with pytest.raises(ParameterError, match="time_constant_s"):
        overlay_degradation(t, cht, oat, onset_s=1500.0, gain=0.1, time_constant_s=0.0)
    with pytest.raises(ParameterError, match="one length"):
        overlay_degradation(t, cht[:-1], oat, onset_s=1500.0, gain=0.1)
