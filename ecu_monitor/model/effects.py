"""Unmodelled-effect extensions of the nominal CHT model (docs/model.md).

The paper's model has no airspeed, no density and no probe dynamics in its dissipation; real engines
do. Each effect here is a named, parameterised physical term. It can be switched on in the virtual
ECU's truth plant (to make a realistic sim-to-real gap) and, once the gap diagnosis finds it, in the
identified model. An effect that is ``None`` in :class:`Effects` is off and the model is the paper's.

- ``airspeed_cooling``: the convective conductance 1/R_Ce grows with the speed of the air over the
  fins. On the ground the propeller still blows air through the cowling, so the cooling flow never
  drops below the propeller wash: ``v_eff = max(v, prop_wash_mps)``, and
  ``G = (1/R_Ce) * max(floor, 1 + gain_per_mps * (v_eff - reference_mps))``. At the reference speed
  (cruise) the nominal R_Ce holds; ``floor`` only keeps G positive for a steep gain.
- ``density_cooling``: forced convection scales with air density,
  ``G *= (rho / reference_kg_m3) ** exponent`` with rho from ISA pressure and the measured OAT
  (h ~ (rho v)^0.8 for a turbulent flow over fins, so exponent ~0.5-0.8).
- ``mass_flow_cooling``: the cooling air removes heat by its mass flow, not its speed alone: the
  cooling air speed of ``airspeed_cooling`` is weighted by ``(rho / reference_kg_m3) ** exponent``
  (exponent 1: density x airspeed; a thinner air at the same indicated airspeed cools less), and
  needs ``airspeed_cooling`` on.
- ``engine_speed_cooling``: the propeller's slipstream and the engine's own air flow push cooling air
  through the cowling in proportion to engine speed, on the ground as in the air. Its conductance adds
  to the ram air's (the two air flows add, they do not multiply):
  ``G = (1/R_Ce) * max(0.05, airspeed factor + gain * (rpm / reference_rpm - 1))``, rpm read from the
  heat map's second axis (which must then be ``rpm``).
- ``sensor_lag``: the CHT probe (a thermocouple under the spark plug) lags the head with a first
  order time constant: ``dT_probe/dt = (T - T_probe) / time_constant_s``.
- ``mixture_cooling``: power enrichment at high load puts less heat into the head. With
  ``load`` the first heat-map axis normalised to 0..1 over its breakpoints,
  ``Q *= 1 - fraction * clip((load - onset) / (1 - onset), 0, 1)``.
- ``mixture_index``: the heat into the head follows the mixture, read from a logged lean/rich index
  (``source``: the exhaust gas temperature ``egt_c``, its rise over the intake air ``egt_rise`` =
  egt_c - oat_c, the fuel per revolution ``fuel_per_rev`` = fuel_flow_lph / rpm in mL/rev, or ``fuel_air``,
  the log of the fuel per unit of fresh air from the fuel flow, rpm, manifold pressure, OAT and altitude):
  ``Q *= exp(gain * (index - reference))``, smooth, positive, and ``1 + gain * (index - reference)``
  near the reference (on ``fuel_air`` a power of the fuel/air ratio: the heat per unit of fuel of a
  combustion that burns less of a richer mixture). Where the index is not logged (NaN) the factor is 1.

Each effect carries its own definition, as a progpy model carries its own (:class:`Effect`): its
parameters (:class:`EffectParameter`: the coefficient the equations read, its neutral value, its
physical range, the identification's search range, the virtual plant's draw), which of them
identification frees, how identification starts it from the flights (:meth:`Effect.start`), what the
gap diagnosis says it is and how it refits it (:class:`GapRefit`). Everything else (the coefficients,
the validation, the search space, the terms ``identify --effects`` knows, the gap library's candidates,
the virtual plant's draws) is made from these declarations.

Adding an effect: a frozen dataclass here (its fields with units, its :class:`Effect` declarations), an
entry in :data:`EFFECT_TYPES` and a field in :class:`Effects`; its coefficients (``Coefficients``) and
its term in :mod:`ecu_monitor.model.equations` (docs/model.md, "Adding an effect").
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any, ClassVar, Protocol

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import FlightLogError, ParameterError
from ecu_monitor.model.atmosphere import (
    KELVIN_OFFSET,
    SEA_LEVEL_DENSITY_KG_M3,
    SEA_LEVEL_PRESSURE_PA,
    air_density_kg_m3,
    isa_pressure_pa,
)
from ecu_monitor.model.equations import equation, exp, isa_log_pressure_ratio, log, maximum

__all__ = [
    "EFFECT_COEFFICIENTS",
    "EFFECT_NAMES",
    "EFFECT_TYPES",
    "MIXTURE_COLUMNS",
    "MIXTURE_SOURCES",
    "AirspeedCooling",
    "DensityCooling",
    "Effect",
    "EffectParameter",
    "Effects",
    "EngineSpeedCooling",
    "GapRefit",
    "MassFlowCooling",
    "MixtureCooling",
    "MixtureIndex",
    "SensorLag",
    "fuel_air_index",
    "median_density",
    "mixture_index",
    "running_rpm",
    "volumetric_efficiency",
]


class Columns(Protocol):
    """What a start rule reads from a flight: its named columns."""

    def has(self, name: str) -> bool: ...

    def __getitem__(self, name: str) -> Any: ...


@dataclass(frozen=True)
class EffectParameter:
    """One numeric parameter of an effect.

    coefficient: the :class:`~ecu_monitor.model.equations.Coefficients` field the equations read.
    neutral: that field's value while the effect is off (its factor is then exactly 1).
    valid: physical range, checked when the effect is made (None: the effect checks it itself).
    search: the identification's search range when the parameter is free.
    plant: range the virtual plant draws a random truth from (None: not drawn, the default holds).
    gap: how the gap diagnosis refits it (None: the gap does not free it).
    """

    coefficient: str
    neutral: float
    valid: tuple[float, float] | None
    search: tuple[float, float]
    plant: tuple[float, float] | None = None
    gap: GapRefit | None = None


@dataclass(frozen=True)
class GapRefit:
    """How the gap diagnosis refits a parameter from the nominal model: its start value (when the nominal
    model does not have the effect on), bounds, and further start values for a cost with local minima
    (checked inside the bounds by the gap library's ``FreeParameter``)."""

    start: float
    low: float
    high: float
    restarts: tuple[float, ...] = ()


class Effect:
    """The declarations every effect carries (class attributes) and its validation."""

    #: parameter name -> its declaration, in the dataclass's field order.
    PARAMETERS: ClassVar[dict[str, EffectParameter]]
    #: the parameters identification fits when it switches the effect on.
    FREE: ClassVar[tuple[str, ...]]
    #: what the gap diagnosis says the effect is (one line).
    GAP_TEXT: ClassVar[str]
    #: whether ``identify --effects auto`` tries it (False: used only when named).
    AUTO_SEARCH: ClassVar[bool] = True

    def __post_init__(self) -> None:
        name = _EFFECT_NAME_OF[type(self)]
        for parameter, spec in self.PARAMETERS.items():
            if spec.valid is not None:
                _check_range(name, parameter, getattr(self, parameter), *spec.valid)

    @classmethod
    def start(cls, flights: Sequence[Columns]) -> Effect:
        """The effect as identification switches it on for ``flights`` (its start values)."""
        return cls()


def _check_range(effect: str, name: str, value: float, low: float, high: float) -> None:
    if not isinstance(value, int | float) or not math.isfinite(value) or not low <= value <= high:
        raise ParameterError(f"effects.{effect}.{name}: expected a number in [{low}, {high}], got {value!r}")


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool):
        raise ParameterError(f"{where}: expected a number, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{where}: expected a number, got {value!r}") from None


def _plain(value: Any) -> Any:
    return value if isinstance(value, str) else float(value)


@dataclass(frozen=True)
class AirspeedCooling(Effect):
    """Convective conductance grows linearly with the cooling air speed max(airspeed, prop wash).

    gain_per_mps: relative conductance change per m/s (1/(m/s)), typically 0.005-0.03.
    reference_mps: airspeed at which the nominal R_Ce holds (m/s), the cruise speed.
    floor: smallest conductance multiplier (a guard that keeps G positive), 0.05-1.
    prop_wash_mps: speed of the propeller wash through the cowling on the ground (m/s), 0-60; the
        cooling air never flows slower. 0 (the default) means airspeed alone.
    """

    gain_per_mps: float = 0.015
    reference_mps: float = 23.0
    floor: float = 0.4
    prop_wash_mps: float = 0.0

    PARAMETERS: ClassVar[dict[str, EffectParameter]] = {
        "gain_per_mps": EffectParameter(
            "airspeed_gain_per_mps", 0.0, (-0.2, 0.2), (-0.05, 0.1), (0.01, 0.03), GapRefit(0.0, -0.05, 0.1)
        ),
        "reference_mps": EffectParameter("airspeed_reference_mps", 23.0, (1.0, 200.0), (1.0, 200.0)),
        "floor": EffectParameter(
            "airspeed_floor", 1.0, (0.05, 1.0), (0.05, 1.0), (0.3, 0.6), GapRefit(0.95, 0.1, 1.0, (0.4,))
        ),
        "prop_wash_mps": EffectParameter("airspeed_prop_wash_mps", 0.0, (0.0, 60.0), (0.0, 60.0)),
    }
    FREE: ClassVar[tuple[str, ...]] = ("gain_per_mps", "prop_wash_mps")
    GAP_TEXT: ClassVar[str] = "convective conductance grows with airspeed (floor on the ground)"

    @classmethod
    def start(cls, flights: Sequence[Columns]) -> AirspeedCooling:
        """Nominal R_Ce at the flights' upper-quartile airspeed, the propeller wash half of it, a gain that
        halves the conductance at standstill."""
        airspeed = np.concatenate([np.asarray(log["airspeed_mps"], dtype=float) for log in flights])
        reference = max(1.0, float(np.quantile(airspeed, 0.75)))
        prop_wash = min(0.5 * reference, 60.0)
        return cls(gain_per_mps=0.5 / reference, reference_mps=reference, floor=0.05, prop_wash_mps=prop_wash)


@dataclass(frozen=True)
class DensityCooling(Effect):
    """Convective conductance scales with air density: (rho/reference_kg_m3)^exponent.

    exponent: dimensionless, typically 0.5-0.8; reference_kg_m3: density of the nominal fit (kg/m^3).
    """

    exponent: float = 0.6
    reference_kg_m3: float = 1.225

    PARAMETERS: ClassVar[dict[str, EffectParameter]] = {
        "exponent": EffectParameter(
            "density_exponent", 0.0, (-3.0, 3.0), (0.0, 1.5), (0.4, 0.8), GapRefit(0.0, -1.5, 2.5)
        ),
        "reference_kg_m3": EffectParameter("density_reference_kg_m3", SEA_LEVEL_DENSITY_KG_M3, (0.3, 1.6), (0.3, 1.6)),
    }
    FREE: ClassVar[tuple[str, ...]] = ("exponent",)
    GAP_TEXT: ClassVar[str] = "convective conductance scales with air density"

    @classmethod
    def start(cls, flights: Sequence[Columns]) -> DensityCooling:
        """Exponent 0.5 about the flights' median air density."""
        return cls(exponent=0.5, reference_kg_m3=median_density(flights))


def median_density(flights: Sequence[Columns]) -> float:
    """Median air density of ``flights`` (kg/m^3, ISA pressure at the altitude and the measured OAT), kept
    within 0.3-1.6: the reference of density_cooling and mass_flow_cooling."""
    density = np.concatenate(
        [
            np.asarray(air_density_kg_m3(isa_pressure_pa(log["altitude_m"]), log["oat_c"]), dtype=float)
            for log in flights
        ]
    )
    return float(np.clip(np.median(density), 0.3, 1.6))


@dataclass(frozen=True)
class MassFlowCooling(Effect):
    """The cooling air's mass flow, not its speed alone, sets the ram air's conductance: the cooling air speed of
    ``airspeed_cooling`` (airspeed, or the propeller wash on the ground) is weighted by
    (rho / reference_kg_m3) ** exponent. At the same indicated airspeed a thinner air carries less mass through
    the fins; unlike ``density_cooling`` it leaves the conductance that does not come from the ram air (free
    convection, the slipstream of ``engine_speed_cooling``) as it is. Needs ``airspeed_cooling`` on.

    exponent: dimensionless, 1 for a mass flow of density x airspeed (0.5 if the flow through the baffles is
        driven by the dynamic pressure of an indicated airspeed); 0 leaves the airspeed as it is.
    reference_kg_m3: air density at which the airspeed is taken as it is (kg/m^3), the flights' median.
    """

    exponent: float = 1.0
    reference_kg_m3: float = 1.225

    PARAMETERS: ClassVar[dict[str, EffectParameter]] = {
        "exponent": EffectParameter(
            "mass_flow_exponent", 0.0, (-1.0, 3.0), (0.0, 1.5), gap=GapRefit(1.0, 0.0, 2.0, (0.5,))
        ),
        "reference_kg_m3": EffectParameter(
            "mass_flow_reference_kg_m3", SEA_LEVEL_DENSITY_KG_M3, (0.3, 1.6), (0.3, 1.6)
        ),
    }
    FREE: ClassVar[tuple[str, ...]] = ("exponent",)
    GAP_TEXT: ClassVar[str] = "the ram air cools by its mass flow (density x airspeed), not its speed alone"
    #: not searched: it only weights airspeed_cooling's term, and the term search's time and held-out figures
    #: on the real N550ND flights stand as measured without it (docs/results/jsbsim.md); named, it is fitted.
    AUTO_SEARCH: ClassVar[bool] = False

    @classmethod
    def start(cls, flights: Sequence[Columns]) -> MassFlowCooling:
        """A mass flow of density x airspeed (exponent 1) about the flights' median air density."""
        return cls(exponent=1.0, reference_kg_m3=median_density(flights))


@dataclass(frozen=True)
class EngineSpeedCooling(Effect):
    """Convective conductance grows with engine speed:
    G = (1/R_Ce) * max(0.05, airspeed factor + gain * (rpm / reference_rpm - 1)).

    The propeller's slipstream (and a fan or the engine's baffled flow) drives cooling air through the cowling
    in proportion to engine speed, whatever the airspeed: it is what cools a head on the ground, and in the
    air it adds to the ram air of ``airspeed_cooling`` (the airspeed factor, 1 without it): the two flows'
    conductances add. The engine speed is the heat map's second axis (the model's ``heat_axes`` end in
    ``rpm``, as both defaults do).

    gain: relative conductance change per unit of rpm / reference_rpm (dimensionless), typically 0.2-1;
        searched from 0 (a faster propeller does not cool less).
    reference_rpm: engine speed at which the nominal R_Ce holds (rev/min), the flights' median running speed.
    """

    gain: float = 0.4
    reference_rpm: float = 2400.0

    PARAMETERS: ClassVar[dict[str, EffectParameter]] = {
        "gain": EffectParameter("speed_gain", 0.0, (-1.0, 3.0), (0.0, 2.0), gap=GapRefit(0.0, 0.0, 2.0, (0.5,))),
        "reference_rpm": EffectParameter("speed_reference_rpm", 2400.0, (100.0, 30000.0), (100.0, 30000.0)),
    }
    FREE: ClassVar[tuple[str, ...]] = ("gain",)
    GAP_TEXT: ClassVar[str] = "convective conductance grows with engine speed (the propeller slipstream)"
    #: not searched: on JSBSim's engines it lowered the held-out error on one aircraft and raised it on the
    #: other, and the gap diagnosis did not confirm it (docs/results/jsbsim.md); named, it is fitted.
    AUTO_SEARCH: ClassVar[bool] = False

    @classmethod
    def start(cls, flights: Sequence[Columns]) -> EngineSpeedCooling:
        """Gain 0.4 about the flights' median running engine speed."""
        return cls(gain=0.4, reference_rpm=running_rpm(flights))


def running_rpm(flights: Sequence[Columns]) -> float:
    """Median engine speed of ``flights`` while the engine runs (rpm above :data:`_MIN_RPM`), rev/min;
    the reference of ``engine_speed_cooling``."""
    rpm = np.concatenate([np.asarray(log["rpm"], dtype=float) for log in flights])
    running = rpm[rpm > _MIN_RPM]
    return float(np.clip(np.median(running), 100.0, 30000.0)) if running.size else 2400.0


@dataclass(frozen=True)
class SensorLag(Effect):
    """First-order lag of the CHT probe. time_constant_s: probe time constant (s), 0-300."""

    time_constant_s: float = 8.0

    PARAMETERS: ClassVar[dict[str, EffectParameter]] = {
        "time_constant_s": EffectParameter(
            "sensor_lag_s", 0.0, (0.0, 300.0), (0.0, 60.0), (4.0, 20.0), GapRefit(1.0, 0.0, 120.0, (15.0,))
        ),
    }
    FREE: ClassVar[tuple[str, ...]] = ("time_constant_s",)
    GAP_TEXT: ClassVar[str] = "first-order lag of the CHT probe"

    @classmethod
    def start(cls, flights: Sequence[Columns]) -> SensorLag:
        """A 10 s probe."""
        return cls(time_constant_s=10.0)


@dataclass(frozen=True)
class MixtureCooling(Effect):
    """Less heat into the head at high load from power enrichment.

    fraction: heat reduction at full load (0-0.6); onset: normalised load where it starts (0-0.95).
    """

    fraction: float = 0.12
    onset: float = 0.7

    PARAMETERS: ClassVar[dict[str, EffectParameter]] = {
        "fraction": EffectParameter(
            "mixture_fraction", 0.0, (0.0, 0.6), (0.0, 0.6), (0.06, 0.2), GapRefit(0.02, 0.0, 0.6)
        ),
        "onset": EffectParameter(
            "mixture_onset", 0.7, (0.0, 0.95), (0.0, 0.95), (0.6, 0.8), GapRefit(0.6, 0.0, 0.95, (0.3, 0.85))
        ),
    }
    FREE: ClassVar[tuple[str, ...]] = ("fraction", "onset")
    GAP_TEXT: ClassVar[str] = "less heat into the head at high load (power enrichment)"


#: Lean/rich indices the mixture_index effect can read -> (unit, accepted range of the reference, the
#: index's typical swing over a flight; |gain| x swing <= 3 keeps the factor within e^-3..e^3).
MIXTURE_SOURCES: dict[str, tuple[str, float, float, float]] = {
    "egt_c": ("degC", 0.0, 1200.0, 300.0),  # exhaust gas temperature
    "fuel_per_rev": ("mL/rev", 0.0, 5.0, 0.3),  # fuel_flow_lph / rpm, in mL per revolution
    "egt_rise": ("degC", 0.0, 1200.0, 300.0),  # exhaust gas temperature over the intake air (OAT)
    "fuel_air": ("ln(mL m^3/(rev kg))", -20.0, 20.0, 0.5),  # log of a fuel/air ratio (fuel per unit of fresh air)
}
#: Columns each mixture-index source is computed from.
MIXTURE_COLUMNS: dict[str, tuple[str, ...]] = {
    "egt_c": ("egt_c",),
    "fuel_per_rev": ("fuel_flow_lph", "rpm"),
    "egt_rise": ("egt_c", "oat_c"),
    "fuel_air": ("fuel_flow_lph", "rpm", "manifold_pressure_kpa", "oat_c", "altitude_m"),
}
#: Below this engine speed (rpm) the fuel per revolution is taken at this speed (engine stopped).
_MIN_RPM = 100.0


#: Below this manifold pressure (kPa) the intake charge's density is taken at this pressure.
_MIN_MANIFOLD_KPA = 1.0
#: A spark-ignition engine's ratio of specific heats and compression ratio in :func:`volumetric_efficiency`
#: (typical of air-cooled aircraft engines, 7-10: from 7 to 10 the efficiency moves 3 % at half throttle).
_CHARGE_GAMMA = 1.3
_COMPRESSION_RATIO = 8.5
_AIR_GAS_CONSTANT = 287.053  # J/(kg K), as atmosphere.air_density_kg_m3


@equation
def volumetric_efficiency(exhaust_over_intake: Any) -> Any:
    """The ideal cycle's volumetric efficiency at an exhaust over intake pressure ratio (dimensionless): 1 with
    the throttle open at the ambient pressure, lower at part throttle, where the burnt gas left in the cylinder
    at the exhaust's pressure expands into the intake stroke and takes the place of fresh air:
    (gamma - 1)/gamma + (r - p_e/p_i) / (gamma (r - 1))."""
    return (_CHARGE_GAMMA - 1.0) / _CHARGE_GAMMA + (_COMPRESSION_RATIO - exhaust_over_intake) / (
        _CHARGE_GAMMA * (_COMPRESSION_RATIO - 1.0)
    )


@equation
def fuel_air_index(fuel_flow_lph: Any, rpm: Any, manifold_pressure_kpa: Any, oat_c: Any, altitude_m: Any) -> Any:
    """ln of the fuel per revolution (mL/rev) over the fresh air a revolution draws in per unit of swept volume
    (kg/m^3): the intake charge's density (manifold pressure at the OAT) times :func:`volumetric_efficiency` with
    the exhaust at the ambient pressure (ISA at the pressure altitude). The log of the fuel/air ratio up to a
    constant of the engine (half its swept volume). No fuel (the engine stopped): -inf, not finite."""
    per_rev = fuel_flow_lph * (1000.0 / 60.0) / maximum(rpm, _MIN_RPM)
    manifold_pa = 1000.0 * maximum(manifold_pressure_kpa, _MIN_MANIFOLD_KPA)
    charge = manifold_pa / (_AIR_GAS_CONSTANT * (oat_c + KELVIN_OFFSET))
    ambient_pa = SEA_LEVEL_PRESSURE_PA * exp(isa_log_pressure_ratio(altitude_m))
    fresh = maximum(volumetric_efficiency(ambient_pa / manifold_pa), 0.05)
    return log(maximum(per_rev, 0.0) / (charge * fresh))


def mixture_index(source: str, columns: Mapping[str, Any]) -> NDArray[np.float64]:
    """The lean/rich index of ``source`` from its columns: EGT (degC) as logged, its rise over the intake air
    egt_c - oat_c (degC), the fuel per revolution fuel_flow_lph / rpm in mL/rev (1000 mL/L / 60 min/h), or
    :func:`fuel_air_index`, the log of a fuel/air ratio (a power of the ratio in the effect's exp; NaN where no
    fuel flows, so that the effect's factor is 1 with the engine stopped)."""
    if source == "egt_c":
        return np.asarray(columns["egt_c"], dtype=float)
    if source == "egt_rise":
        return np.asarray(columns["egt_c"], dtype=float) - np.asarray(columns["oat_c"], dtype=float)
    if source == "fuel_per_rev":
        rpm = np.maximum(np.asarray(columns["rpm"], dtype=float), _MIN_RPM)
        return np.asarray(columns["fuel_flow_lph"], dtype=float) * (1000.0 / 60.0) / rpm
    if source == "fuel_air":
        with np.errstate(divide="ignore", invalid="ignore"):
            index = fuel_air_index(*(np.asarray(columns[name], dtype=float) for name in MIXTURE_COLUMNS[source]))
        return np.where(np.isfinite(index), index, np.nan)
    raise FlightLogError(f"mixture_index: unknown source {source!r}")


@dataclass(frozen=True)
class MixtureIndex(Effect):
    """Heat into the head follows a logged lean/rich index: Q *= exp(gain * (index - reference)).

    source: the index, one of :data:`MIXTURE_SOURCES`: "egt_c" (degC), "egt_rise" (EGT over the OAT, degC),
        "fuel_per_rev" (mL/rev) or "fuel_air" (the log of a fuel/air ratio, :func:`fuel_air_index`). The rise is
        what the combustion sets (the exhaust starts from the intake air's temperature): on the rich side of peak
        EGT, where engines are run, a lower rise is a richer mixture that burns less of its fuel and puts less
        heat per unit of fuel into the head; near peak EGT the rise barely moves while the burnt share of the fuel
        still does. The fuel/air ratio reads the mixture itself: on the rich side the heat per unit of fuel
        falls as a power of it (the gain, about -1 where the air, not the fuel, sets how much burns).
    gain: relative change of the heat per unit of the index (1/degC, rev/mL, or the power of the fuel/air
        ratio); a richer mixture (lower EGT, more fuel per revolution or per unit of air) cools the head.
    reference: index value at which the nominal heat map holds (degC, mL/rev or the log of the ratio).
    """

    source: str = "egt_c"
    gain: float = 0.001
    reference: float = 650.0

    # gain and reference: their ranges depend on the source (checked below; the search's gain range too)
    PARAMETERS: ClassVar[dict[str, EffectParameter]] = {
        "gain": EffectParameter("mixture_gain", 0.0, None, (-0.01, 0.01), gap=GapRefit(0.0, -0.01, 0.01)),
        "reference": EffectParameter("mixture_reference", 0.0, None, (0.0, 1200.0)),
    }
    FREE: ClassVar[tuple[str, ...]] = ("gain",)
    GAP_TEXT: ClassVar[str] = "heat into the head follows the mixture (a logged fuel/air ratio or EGT)"

    @staticmethod
    def gain_reach(source: str) -> float:
        """The largest |gain| on an index of ``source``: 3 over its typical swing over a flight (the factor stays
        within e^-3..e^3); the range identification searches and the gap refits (its declared +-0.01 is the
        EGT's)."""
        return 3.0 / MIXTURE_SOURCES[source][3]

    @staticmethod
    def source_for(flights: Sequence[Columns]) -> str:
        """The index the flights give, the first whose columns every flight logs: the fuel/air ratio (with the
        manifold pressure), the EGT's rise over the OAT, else the fuel per revolution."""
        for source in ("fuel_air", "egt_rise"):
            if all(log.has(name) for log in flights for name in MIXTURE_COLUMNS[source]):
                return source
        return "fuel_per_rev"

    @classmethod
    def start(cls, flights: Sequence[Columns]) -> MixtureIndex:
        """No gain, about the flights' median index of :meth:`source_for`."""
        source = cls.source_for(flights)
        index = np.concatenate(
            [mixture_index(source, {name: log[name] for name in MIXTURE_COLUMNS[source]}) for log in flights]
        )
        return cls(source=source, gain=0.0, reference=float(np.nanmedian(index)))

    def __post_init__(self) -> None:
        if self.source not in MIXTURE_SOURCES:
            raise ParameterError(
                f"effects.mixture_index.source: expected one of {', '.join(MIXTURE_SOURCES)}, got {self.source!r}"
            )
        unit, low, high, _swing = MIXTURE_SOURCES[self.source]
        reach = self.gain_reach(self.source)
        _check_range("mixture_index", "gain", self.gain, -reach, reach)
        _check_range("mixture_index", f"reference ({unit})", self.reference, low, high)


#: Effect name -> its parameter class (the one list of effects).
EFFECT_TYPES: dict[str, type[Effect]] = {
    "airspeed_cooling": AirspeedCooling,
    "density_cooling": DensityCooling,
    "mass_flow_cooling": MassFlowCooling,
    "engine_speed_cooling": EngineSpeedCooling,
    "sensor_lag": SensorLag,
    "mixture_cooling": MixtureCooling,
    "mixture_index": MixtureIndex,
}
EFFECT_NAMES: tuple[str, ...] = tuple(EFFECT_TYPES)
_EFFECT_NAME_OF: dict[type, str] = {kind: name for name, kind in EFFECT_TYPES.items()}
#: "effect.parameter" -> (its Coefficients field, the neutral value while the effect is off: a factor of
#: exactly 1). :func:`ecu_monitor.model.coefficients` fills the effects' fields from this table.
EFFECT_COEFFICIENTS: dict[str, tuple[str, float]] = {
    f"{name}.{parameter}": (spec.coefficient, spec.neutral)
    for name, kind in EFFECT_TYPES.items()
    for parameter, spec in kind.PARAMETERS.items()
}


@dataclass(frozen=True)
class Effects:
    """Which unmodelled effects are on (None = off) and their parameters."""

    airspeed_cooling: AirspeedCooling | None = None
    density_cooling: DensityCooling | None = None
    mass_flow_cooling: MassFlowCooling | None = None
    engine_speed_cooling: EngineSpeedCooling | None = None
    sensor_lag: SensorLag | None = None
    mixture_cooling: MixtureCooling | None = None
    mixture_index: MixtureIndex | None = None

    def __post_init__(self) -> None:
        for name, kind in EFFECT_TYPES.items():
            value = getattr(self, name)
            if value is not None and not isinstance(value, kind):
                raise ParameterError(f"effects.{name}: expected {kind.__name__} or None")
        if self.mass_flow_cooling is not None and self.airspeed_cooling is None:
            raise ParameterError(
                "effects.mass_flow_cooling: weights the cooling air speed of airspeed_cooling, which is off"
                " (switch airspeed_cooling on)"
            )

    @property
    def active(self) -> tuple[str, ...]:
        """Names of the effects that are on."""
        return tuple(name for name in EFFECT_NAMES if getattr(self, name) is not None)

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Plain dict of the active effects (for YAML): numbers as floats, choices as strings."""
        out: dict[str, dict[str, Any]] = {}
        for name in self.active:
            value = getattr(self, name)
            out[name] = {f.name: _plain(getattr(value, f.name)) for f in fields(value)}
        return out

    @classmethod
    def from_dict(cls, data: Any, where: str = "effects") -> Effects:
        """Parse ``{name: {param: value}}``; unknown names or keys raise ParameterError."""
        if data is None:
            return cls()
        if not isinstance(data, dict):
            raise ParameterError(f"{where}: expected a mapping of effect name -> parameters")
        kwargs: dict[str, Any] = {}
        for name, params in data.items():
            kind = EFFECT_TYPES.get(name)
            if kind is None:
                raise ParameterError(f"{where}.{name}: unknown effect (known: {', '.join(EFFECT_NAMES)})")
            params = params or {}
            if not isinstance(params, dict):
                raise ParameterError(f"{where}.{name}: expected a mapping of parameters")
            known = {f.name for f in fields(kind)}
            for key in params:
                if key not in known:
                    raise ParameterError(f"{where}.{name}.{key}: unknown parameter (known: {sorted(known)})")
            choices = {f.name for f in fields(kind) if f.type in ("str", str)}
            values: dict[str, Any] = {}
            for key, value in params.items():
                if key in choices:
                    if not isinstance(value, str):
                        raise ParameterError(f"{where}.{name}.{key}: expected a name, got {value!r}")
                    values[key] = value
                else:
                    values[key] = _number(value, f"{where}.{name}.{key}")
            kwargs[name] = kind(**values)
        return cls(**kwargs)

    def replace(self, name: str, value: Any) -> Effects:
        """A copy with one effect switched on (an effect object) or off (None)."""
        if name not in EFFECT_TYPES:
            raise ParameterError(f"effects.{name}: unknown effect")
        current = {n: getattr(self, n) for n in EFFECT_NAMES}
        current[name] = value
        return Effects(**current)
