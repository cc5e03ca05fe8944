"""The engine's reference from nominal flights: per-region means and spread across flights, the reference
test's threshold from each flight measured against the others, and its refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ecu_monitor.errors import ParameterError
from ecu_monitor.estimation.detection import NOMINAL_SPREAD_Z, DetectorSettings
from ecu_monitor.estimation.regions import REGION_COUNT, REGION_CRUISE, REGION_GROUND, REGION_START, START_S
from ecu_monitor.offline.calibration_reference import (
    calibrate_reference,
    flight_region_means,
    reference_paths,
)
from ecu_monitor.offline.calibration_replays import FlightFeeds


def _flight(name: str, offset: float, seed: int, hours: float = 1.5, step_s: float = 0.1) -> FlightFeeds:
    """A flight fed ``offset`` + noise (degC/s): 300 s start, 300 s ground, then cruise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0, step_s)
    regions = np.where(t < 300.0, REGION_START, np.where(t < 600.0, REGION_GROUND, REGION_CRUISE)).astype(np.int64)
    symptom = offset + 0.02 * rng.standard_normal(t.size)
    symptom[::50] = np.nan  # steps the supervisor did not let through
    return FlightFeeds(name, ((t, symptom),), 0.0, float(t[-1]), 0.0, (), (), (regions,))


def test_region_means_skip_unfed_steps_and_regions_seen_too_briefly() -> None:
    means = flight_region_means(_flight("a", 0.1, 1))
    assert means[REGION_START] == pytest.approx(0.1, abs=0.005)  # learned (the isolation reads it), not tested
    assert means[REGION_GROUND] == pytest.approx(0.1, abs=0.005)
    assert means[REGION_CRUISE] == pytest.approx(0.1, abs=0.002)
    seen = (REGION_START, REGION_GROUND, REGION_CRUISE)
    assert np.isnan(means[[r for r in range(REGION_COUNT) if r not in seen]]).all()


def test_reference_mean_spread_and_a_threshold_that_a_held_out_nominal_flight_stays_under() -> None:
    flights = [_flight(f"f{i}", offset, i) for i, offset in enumerate((0.00, 0.02, 0.04, 0.01))]
    settings = DetectorSettings()
    ref = calibrate_reference(flights, settings, 1.0)
    assert ref.mean[REGION_CRUISE] == pytest.approx(0.0175, abs=0.002)
    assert ref.spread[REGION_CRUISE] == pytest.approx(np.std([0.0, 0.02, 0.04, 0.01], ddof=1), abs=0.003)
    assert math.isnan(ref.mean[4])
    tuned = ref.settings(settings)
    assert tuned.reference_on and tuned.nominal_threshold >= ref.calibration.threshold
    levels = tuned.nominal_levels()
    assert math.isfinite(ref.mean[REGION_START]) and math.isnan(levels[REGION_START])  # learned, not tested
    assert levels[REGION_CRUISE] == pytest.approx(
        ref.mean[REGION_CRUISE] + NOMINAL_SPREAD_Z * ref.spread[REGION_CRUISE]
    )
    new = _flight("new", 0.03, 99)
    assert max(stat.max() for _, stat in reference_paths(new, levels, tuned)) < tuned.nominal_threshold
    faulty = _flight("faulty", 0.2, 98)  # a fault from engine start: 0.2 degC/s over the nominal level
    ends, stat = reference_paths(faulty, levels, tuned)[0]
    assert START_S <= ends[np.argmax(stat >= tuned.nominal_threshold)] < START_S + 120.0  # tested after the start


def test_too_few_flights_is_one_line() -> None:
    with pytest.raises(ParameterError, match="needs 3 nominal flights"):
        calibrate_reference([_flight("a", 0.0, 1), _flight("b", 0.0, 2)], DetectorSettings(), 1.0)


def test_reference_settings_are_checked() -> None:
    from ecu_monitor.errors import ConfigError

    with pytest.raises(ConfigError, match="nominal_mean, nominal_spread: expected 5 values"):
        DetectorSettings(nominal_threshold=3.0, nominal_mean=(0.0,), nominal_spread=(0.0,))
    with pytest.raises(ConfigError, match="nominal_threshold"):
        DetectorSettings(nominal_threshold=-1.0)
    off = DetectorSettings()
    assert not off.reference_on and off.nominal_settings().threshold == 1e300


def test_a_reference_learned_for_another_model_is_turned_off() -> None:
    import dataclasses

    from ecu_monitor.config import load_config
    from ecu_monitor.offline.calibration import without_foreign_reference
    from ecu_monitor.shipped import DEFAULT_CONFIG

    config = load_config(DEFAULT_CONFIG)  # the shipped reference: the virtual ECU's, for the shipped model
    params = config.load_params()
    assert config.detector.reference_on
    assert without_foreign_reference(config, (params,)) is None
    other = dataclasses.replace(params, cht_limit_c=params.cht_limit_c + 10.0)  # another engine's model
    stripped = without_foreign_reference(config, (other,))
    assert stripped is not None and not stripped.detector.reference_on
    assert stripped.detector.threshold == config.detector.threshold  # the in-flight test as it was
