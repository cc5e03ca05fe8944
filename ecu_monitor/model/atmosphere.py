"""International Standard Atmosphere (troposphere) and air density.

Pressure comes from the ISA at the pressure altitude; temperature is the measured outside air
temperature (OAT), never the ISA one (docs/model.md).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "ISA_PRESSURE_EXPONENT",
    "KELVIN_OFFSET",
    "LAPSE_RATE_K_PER_M",
    "SEA_LEVEL_DENSITY_KG_M3",
    "SEA_LEVEL_PRESSURE_PA",
    "SEA_LEVEL_TEMPERATURE_K",
    "air_density_kg_m3",
    "isa_pressure_pa",
]

KELVIN_OFFSET = 273.15
SEA_LEVEL_PRESSURE_PA = 101_325.0
SEA_LEVEL_TEMPERATURE_K = 288.15
SEA_LEVEL_DENSITY_KG_M3 = 1.225
LAPSE_RATE_K_PER_M = 0.0065
_GAS_CONSTANT_AIR = 287.053  # J/(kg K)
_GRAVITY = 9.80665
ISA_PRESSURE_EXPONENT = _GRAVITY / (_GAS_CONSTANT_AIR * LAPSE_RATE_K_PER_M)  # ~5.2559


def isa_pressure_pa(altitude_m: ArrayLike) -> np.ndarray | float:
    """ISA static pressure (Pa) at a pressure altitude (m), troposphere (valid up to 11 km)."""
    ratio = 1.0 - LAPSE_RATE_K_PER_M * np.asarray(altitude_m, dtype=float) / SEA_LEVEL_TEMPERATURE_K
    result = SEA_LEVEL_PRESSURE_PA * np.maximum(ratio, 1e-6) ** ISA_PRESSURE_EXPONENT
    return float(result) if np.ndim(result) == 0 else result


def air_density_kg_m3(pressure_pa: ArrayLike, temperature_c: ArrayLike) -> np.ndarray | float:
    """Ideal-gas air density (kg/m^3) from static pressure (Pa) and air temperature (degC)."""
    result = np.asarray(pressure_pa, dtype=float) / (
        _GAS_CONSTANT_AIR * (np.asarray(temperature_c, dtype=float) + KELVIN_OFFSET)
    )
    return float(result) if np.ndim(result) == 0 else result
