"""The one table of units: every unit a flight-log column or a CAN signal may be given in.

Each unit names its quantity and the affine map to that quantity's canonical unit,
``canonical = value * scale + offset``. The canonical units are those of the flight CSV: rpm, %,
degC, m, m/s, L/h, kPa, s. A unit this table does not know is given in a config or mapping as
``{scale: S, offset: O}`` (:func:`custom_unit`), the same affine map written out.

Spellings: several names of one unit are aliases of one entry (``lph`` = ``l_per_h``,
``gph`` = ``usgal_per_h``, ``mps`` = ``m/s``, ``kph`` = ``km/h``); docs and shipped files use the
first of each pair.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, NamedTuple

import numpy as np

__all__ = [
    "GASOLINE_DENSITY_KG_PER_L",
    "QUANTITY_OF_COLUMN",
    "UNITS",
    "Unit",
    "custom_unit",
    "pressure_altitude_m",
    "standard_pressure_kpa",
    "unit_conversion",
]


class Unit(NamedTuple):
    """A unit: its quantity and the affine map to the canonical unit, ``canonical = value * scale + offset``."""

    quantity: str
    scale: float
    offset: float

    def to_canonical(self, value: Any) -> Any:
        """``value * scale + offset`` (floats or numpy arrays)."""
        return value * self.scale + self.offset

    def from_canonical(self, value: Any) -> Any:
        """The inverse map: ``(value - offset) / scale``."""
        return (value - self.offset) / self.scale


#: Gasoline density used by the ``*_gasoline`` mass-flow units (kg/L, EN 228 summer grade at 15 degC: 0.72-0.775).
GASOLINE_DENSITY_KG_PER_L = 0.74

_RPM = Unit("engine_speed", 1.0, 0.0)
_PCT = Unit("fraction", 1.0, 0.0)
_MPS = Unit("speed", 1.0, 0.0)
_KPH = Unit("speed", 1.0 / 3.6, 0.0)
_LPH = Unit("fuel_flow", 1.0, 0.0)
_GPH = Unit("fuel_flow", 3.785411784, 0.0)

#: Every known unit name -> its conversion to the canonical unit of its quantity.
UNITS: Mapping[str, Unit] = MappingProxyType(
    {
        # engine speed, canonical rpm
        "rpm": _RPM,
        "rad_per_s": Unit("engine_speed", 60.0 / (2.0 * math.pi), 0.0),
        "hz": Unit("engine_speed", 60.0, 0.0),
        # throttle, canonical percent
        "pct": _PCT,
        "ratio": Unit("fraction", 100.0, 0.0),
        # temperature, canonical degC
        "degC": Unit("temperature", 1.0, 0.0),
        "K": Unit("temperature", 1.0, -273.15),
        "cdegC": Unit("temperature", 0.01, 0.0),  # centi-degrees Celsius (MAVLink SCALED_PRESSURE.temperature)
        "degF": Unit("temperature", 5.0 / 9.0, -32.0 * 5.0 / 9.0),
        "degR": Unit("temperature", 5.0 / 9.0, -273.15),  # Rankine (JSBSim's air temperature)
        # length (altitude), canonical m
        "m": Unit("length", 1.0, 0.0),
        "ft": Unit("length", 0.3048, 0.0),
        "cm": Unit("length", 0.01, 0.0),
        "mm": Unit("length", 0.001, 0.0),
        # speed (airspeed, vertical speed), canonical m/s
        "mps": _MPS,
        "m/s": _MPS,
        "kph": _KPH,
        "km/h": _KPH,
        "kt": Unit("speed", 1852.0 / 3600.0, 0.0),
        "fpm": Unit("speed", 0.3048 / 60.0, 0.0),
        "cm/s": Unit("speed", 0.01, 0.0),
        # fuel flow, canonical L/h
        "lph": _LPH,
        "l_per_h": _LPH,
        "gph": _GPH,
        "usgal_per_h": _GPH,
        "cc_per_min": Unit("fuel_flow", 0.06, 0.0),
        "g_per_s_gasoline": Unit("fuel_flow", 3.6 / GASOLINE_DENSITY_KG_PER_L, 0.0),
        "kg_per_h_gasoline": Unit("fuel_flow", 1.0 / GASOLINE_DENSITY_KG_PER_L, 0.0),
        # pressure (manifold pressure), canonical kPa
        "kPa": Unit("pressure", 1.0, 0.0),
        "Pa": Unit("pressure", 1e-3, 0.0),
        "hPa": Unit("pressure", 0.1, 0.0),
        "mbar": Unit("pressure", 0.1, 0.0),
        "inHg": Unit("pressure", 3.386389, 0.0),
        "psi": Unit("pressure", 6.894757293168, 0.0),
        # time, canonical s
        "s": Unit("time", 1.0, 0.0),
        "ms": Unit("time", 1e-3, 0.0),
        "min": Unit("time", 60.0, 0.0),
        # a value used as it is (an ECU status code)
        "raw": Unit("raw", 1.0, 0.0),
    }
)

#: Quantity each known flight-log column (and model input) must be given in.
QUANTITY_OF_COLUMN: Mapping[str, str] = MappingProxyType(
    {
        "time_s": "time",
        "rpm": "engine_speed",
        "throttle_pct": "fraction",
        "cht_c": "temperature",
        "cht_true_c": "temperature",
        "oat_c": "temperature",
        "altitude_m": "length",
        "airspeed_mps": "speed",
        "vspeed_mps": "speed",
        "fuel_flow_lph": "fuel_flow",
        "egt_c": "temperature",
        "egt_max_c": "temperature",
        "oil_temp_c": "temperature",
        "manifold_pressure_kpa": "pressure",
    }
)


#: Standard atmosphere (troposphere): pressure altitude h = (1 - (p / p0) ** _BARO_EXP) * _BARO_SCALE_M, p0 in kPa.
_P0_KPA = 101.325
_BARO_EXP = 0.190263
_BARO_SCALE_M = 44307.694


def pressure_altitude_m(pressure_kpa: Any) -> Any:
    """Pressure altitude (m, standard datum 101.325 kPa) of a static pressure (kPa); a float or a numpy
    array. A pressure of 0 or below, or NaN, gives NaN (no altitude), never an exception. A float is
    computed with Python's float power (C ``pow``, as numpy's for one value: the same result, much faster; the
    DroneCAN decoder calls it per StaticPressure message)."""
    if isinstance(pressure_kpa, float):
        if not pressure_kpa > 0.0:
            return math.nan
        return (1.0 - (pressure_kpa / _P0_KPA) ** _BARO_EXP) * _BARO_SCALE_M
    p = np.asarray(pressure_kpa, dtype=float)
    with np.errstate(invalid="ignore"):
        positive = p > 0.0
        h = np.where(positive, (1.0 - (np.where(positive, p, _P0_KPA) / _P0_KPA) ** _BARO_EXP) * _BARO_SCALE_M, np.nan)
    return float(h) if h.ndim == 0 else h


def standard_pressure_kpa(altitude_m: Any) -> Any:
    """The inverse of :func:`pressure_altitude_m`: static pressure (kPa) at a pressure altitude (m)."""
    h = np.asarray(altitude_m, dtype=float)
    p = _P0_KPA * np.maximum(1.0 - h / _BARO_SCALE_M, 0.0) ** (1.0 / _BARO_EXP)
    return float(p) if p.ndim == 0 else p


def unit_conversion(unit: str, quantity: str | None = None) -> Unit:
    """The conversion of unit ``unit``; ValueError (one line) if unknown or not of ``quantity``."""
    if unit not in UNITS:
        raise ValueError(f"unknown unit {unit!r} (known: {', '.join(UNITS)}; or give {{scale: S, offset: O}})")
    conv = UNITS[unit]
    if quantity is not None and conv.quantity != quantity:
        fitting = ", ".join(name for name, u in UNITS.items() if u.quantity == quantity)
        raise ValueError(f"unit {unit!r} is not a {quantity} unit (it is {conv.quantity}; expected one of: {fitting})")
    return conv


def custom_unit(value: Any, quantity: str | None = None) -> Unit:
    """A unit given as a known name or as ``{scale: S, offset: O}`` (offset optional, 0).

    ``quantity``: the quantity the unit is for (a custom unit takes it; a named unit must have it).
    ValueError (one line) if the value is neither, or the scale is zero or not finite.
    """
    if isinstance(value, str):
        return unit_conversion(value, quantity)
    if not isinstance(value, Mapping):
        raise ValueError(f"expected a unit name or {{scale: S, offset: O}}, got {value!r}")
    extra = set(value) - {"scale", "offset"}
    if extra or "scale" not in value:
        raise ValueError(f"a custom unit has keys scale and offset (got {', '.join(map(str, value)) or 'none'})")
    numbers = []
    for key in ("scale", "offset"):
        number = value.get(key, 0.0)
        if isinstance(number, bool) or not isinstance(number, int | float) or not math.isfinite(number):
            raise ValueError(f"custom unit {key}: expected a finite number, got {number!r}")
        numbers.append(float(number))
    if numbers[0] == 0.0:
        raise ValueError("custom unit scale: must not be 0")
    return Unit(quantity or "custom", numbers[0], numbers[1])
