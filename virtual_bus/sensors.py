"""Sensor model of the virtual ECU: what the ECU and the air-data computer measure of the truth.

* CHT: the probe temperature (the head temperature itself, or its first-order lag when the plant's
  ``sensor_lag`` effect is on) plus Gaussian noise, then quantised to ``cht_resolution_c`` with a
  round function (the paper's 1 degC sensor): ``cht = resolution * round((probe + n) / resolution)``,
  ``n ~ N(0, cht_sigma_c^2)``. The noise before the quantiser dithers the level changes.
* rpm, throttle, altitude, airspeed, OAT, vertical speed, fuel flow: truth plus white Gaussian noise
  of a small standard deviation each, clipped to the physical range (no negative airspeed).

Every draw comes from the ``numpy.random.Generator`` passed in, so a seed fixes the measurements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np

from ecu_monitor.errors import ParameterError

__all__ = ["Measurements", "SensorModel"]


class Measurements(NamedTuple):
    """Measured values at each step (arrays of equal length)."""

    cht_c: np.ndarray
    throttle_pct: np.ndarray
    rpm: np.ndarray
    altitude_m: np.ndarray
    airspeed_mps: np.ndarray
    oat_c: np.ndarray
    vspeed_mps: np.ndarray
    fuel_flow_lph: np.ndarray
    #: per-cylinder CHT (cylinders, steps) of an engine flown with cylinders (then cht_c is their mean)
    cht_cylinders_c: np.ndarray | None = None


@dataclass(frozen=True)
class SensorModel:
    """Noise standard deviations (units in the names) and the CHT quantisation step.

    Defaults: CHT 0.3 degC before a 1 degC round quantiser; rpm 10 rpm; throttle 0.2 %; pressure
    altitude 1.0 m; airspeed 0.2 m/s; OAT 0.1 degC; vertical speed 0.05 m/s; fuel flow 0.005 L/h.
    A resolution of 0 switches the quantiser off.
    """

    cht_sigma_c: float = 0.3
    cht_resolution_c: float = 1.0
    rpm_sigma: float = 10.0
    throttle_sigma_pct: float = 0.2
    altitude_sigma_m: float = 1.0
    airspeed_sigma_mps: float = 0.2
    oat_sigma_c: float = 0.1
    vspeed_sigma_mps: float = 0.05
    fuel_flow_sigma_lph: float = 0.005

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
                raise ParameterError(f"sensors.{f.name}: expected a number >= 0, got {value!r}")

    def quantise_cht(self, probe_c: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Measured CHT (degC): noise then round to the resolution."""
        noisy = probe_c + self.cht_sigma_c * rng.standard_normal(np.shape(probe_c))
        if self.cht_resolution_c == 0.0:
            return noisy
        return self.cht_resolution_c * np.round(noisy / self.cht_resolution_c)

    def measure(
        self,
        rng: np.random.Generator,
        *,
        probe_c: np.ndarray,
        throttle_pct: np.ndarray,
        rpm: np.ndarray,
        altitude_m: np.ndarray,
        airspeed_mps: np.ndarray,
        oat_c: np.ndarray,
        vspeed_mps: np.ndarray,
        fuel_flow_lph: np.ndarray,
    ) -> Measurements:
        """Every measurement of one block of steps; draws in a fixed order (reproducible)."""
        n = np.shape(probe_c)

        def noisy(values: np.ndarray, sigma: float) -> np.ndarray:
            return values + sigma * rng.standard_normal(n)

        cht = self.quantise_cht(probe_c, rng)
        return Measurements(
            cht_c=cht,
            throttle_pct=np.clip(noisy(throttle_pct, self.throttle_sigma_pct), 0.0, 100.0),
            rpm=np.maximum(noisy(rpm, self.rpm_sigma), 0.0),
            altitude_m=noisy(altitude_m, self.altitude_sigma_m),
            airspeed_mps=np.maximum(noisy(airspeed_mps, self.airspeed_sigma_mps), 0.0),
            oat_c=noisy(oat_c, self.oat_sigma_c),
            vspeed_mps=noisy(vspeed_mps, self.vspeed_sigma_mps),
            fuel_flow_lph=np.maximum(noisy(fuel_flow_lph, self.fuel_flow_sigma_lph), 0.0),
        )
