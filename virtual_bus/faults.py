"""What the virtual ECU's truth plant is given besides the mission: degradation schedules (gamma_Q, gamma_D),
unmodelled effects switched on in the truth, and truth-only forms the model library does not contain.

Degradation syntax (:meth:`Degradation.parse`, the CLI's ``--degrade``)::

    gamma_q=1.2@1800            step of gamma_Q to 1.2 at t = 1800 s (every cylinder)
    gamma_d=1.1@600:ramp=300    gamma_D ramps linearly from its level at 600 s to 1.1 at 900 s
    gamma_q=1.2@1800:cylinder=3 gamma_Q of cylinder 3 alone (an engine flown with cylinders)

Effect syntax (:func:`parse_effect`, the CLI's ``--effect``): ``NAME`` (default sizes) or
``NAME:key=value,key=value``, e.g. ``sensor_lag:time_constant_s=12``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ecu_monitor.errors import ConfigError, ParameterError
from ecu_monitor.model import EFFECT_NAMES, EFFECT_TYPES, Effects

__all__ = [
    "DEGRADATION_FACTORS",
    "TRUTH_FORM_KINDS",
    "Degradation",
    "TruthForm",
    "gamma_schedule",
    "parse_effect",
    "parse_effects",
    "random_effects",
    "random_truth_form",
]

DEGRADATION_FACTORS: tuple[str, ...] = ("gamma_q", "gamma_d")
_DEGRADE_RE = re.compile(
    r"^\s*(?P<factor>gamma_[qQdD])\s*=\s*(?P<value>[^@\s]+)\s*@\s*(?P<start>[^:\s]+)"
    r"(?:\s*:\s*ramp\s*=\s*(?P<ramp>[^:\s]+))?(?:\s*:\s*cylinder\s*=\s*(?P<cylinder>\S+))?\s*$"
)


@dataclass(frozen=True)
class Degradation:
    """One degradation event: ``factor`` (gamma_q or gamma_d) goes to ``value`` from ``start_s``,
    as a step (ramp_s = 0) or a linear ramp over ``ramp_s`` seconds, in every cylinder (``cylinder``
    None) or in one (1-based)."""

    factor: str
    value: float
    start_s: float
    ramp_s: float = 0.0
    cylinder: int | None = None

    def __post_init__(self) -> None:
        if self.factor not in DEGRADATION_FACTORS:
            raise ParameterError(f"degradation factor: expected gamma_q or gamma_d, got {self.factor!r}")
        checks = (
            ("value", self.value, 0.2, 5.0),
            ("start_s", self.start_s, 0.0, 1e7),
            ("ramp_s", self.ramp_s, 0.0, 1e7),
        )
        for name, value, low, high in checks:
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ParameterError(f"degradation {name}: expected a number, got {value!r}")
            if not low <= value <= high:
                raise ParameterError(f"degradation {name}: expected a number in [{low:g}, {high:g}], got {value!r}")
        if self.cylinder is not None and (type(self.cylinder) is not int or not 1 <= self.cylinder <= 16):
            raise ParameterError(f"degradation cylinder: expected a cylinder number 1 .. 16, got {self.cylinder!r}")

    def applies_to(self, cylinder: int) -> bool:
        """Whether this event degrades cylinder ``cylinder`` (1-based)."""
        return self.cylinder is None or self.cylinder == cylinder

    @classmethod
    def parse(cls, text: str) -> Degradation:
        """Parse ``gamma_q=1.2@1800``, ``gamma_d=1.1@600:ramp=300`` or, in one cylinder,
        ``gamma_q=1.2@1800:cylinder=3``; ConfigError on bad syntax."""
        match = _DEGRADE_RE.match(text)
        if match is None:
            raise ConfigError(f"--degrade {text!r}: expected gamma_q|gamma_d=VALUE@START_S[:ramp=SECONDS][:cylinder=N]")
        try:
            value = float(match["value"])
            start = float(match["start"])
            ramp = float(match["ramp"]) if match["ramp"] is not None else 0.0
        except ValueError:
            raise ConfigError(f"--degrade {text!r}: VALUE, START_S and ramp must be numbers") from None
        cylinder = match["cylinder"]
        if cylinder is not None and not cylinder.isdigit():
            raise ConfigError(f"--degrade {text!r}: cylinder must be a cylinder number (1, 2, ...), got {cylinder!r}")
        try:
            return cls(match["factor"].lower(), value, start, ramp, None if cylinder is None else int(cylinder))
        except ParameterError as exc:
            raise ConfigError(f"--degrade {text!r}: {exc}") from None

    def __str__(self) -> str:
        ramp = f":ramp={self.ramp_s:g}" if self.ramp_s > 0 else ""
        cylinder = f":cylinder={self.cylinder}" if self.cylinder is not None else ""
        return f"{self.factor}={self.value:g}@{self.start_s:g}{ramp}{cylinder}"


def gamma_schedule(events: Sequence[Degradation], factor: str, time_s: Any) -> np.ndarray:
    """Value of ``factor`` (1 before any event) at the times ``time_s`` (array or float)."""
    t = np.asarray(time_s, dtype=float)
    mine = sorted((e for e in events if e.factor == factor), key=lambda e: e.start_s)
    level = np.ones_like(t)
    for i, event in enumerate(mine):
        before = float(gamma_schedule(mine[:i], factor, event.start_s)) if i else 1.0
        if event.ramp_s > 0.0:
            fraction = np.clip((t - event.start_s) / event.ramp_s, 0.0, 1.0)
        else:
            fraction = (t >= event.start_s).astype(float)
        level = np.where(t >= event.start_s, before + (event.value - before) * fraction, level)
    return level


def parse_effect(text: str) -> tuple[str, dict[str, float]]:
    """Parse ``NAME`` or ``NAME:key=value,key=value`` into (name, params); ParameterError if bad."""
    name, _, rest = text.strip().partition(":")
    if name not in EFFECT_NAMES:
        raise ParameterError(f"--effect {text!r}: unknown effect {name!r} (known: {', '.join(EFFECT_NAMES)})")
    params: dict[str, float] = {}
    for item in filter(None, (p.strip() for p in rest.split(","))):
        key, eq, value = item.partition("=")
        if not eq:
            raise ParameterError(f"--effect {text!r}: expected key=value, got {item!r}")
        try:
            params[key.strip()] = float(value)
        except ValueError:
            raise ParameterError(f"--effect {text!r}: {key.strip()} must be a number, got {value!r}") from None
    return name, params


def parse_effects(specs: Iterable[str], base: Effects | None = None) -> Effects:
    """Effects from CLI specs (see :func:`parse_effect`) on top of ``base``; ParameterError if bad."""
    merged: dict[str, Any] = (base or Effects()).to_dict()
    for spec in specs:
        name, params = parse_effect(spec)
        merged[name] = params
    try:
        return Effects.from_dict(merged, where="--effect")
    except TypeError as exc:  # a dataclass rejecting a keyword never reaches here: from_dict checks keys
        raise ParameterError(f"--effect: {exc}") from None


#: The effects the virtual plant draws: those that declare a draw range for a parameter (mixture_index
#: needs a logged EGT or fuel flow the plant does not model).
PLANT_EFFECTS: tuple[str, ...] = tuple(
    name for name, kind in EFFECT_TYPES.items() if any(spec.plant for spec in kind.PARAMETERS.values())
)


def random_effects(seed: int, names: Sequence[str] = PLANT_EFFECTS) -> Effects:
    """The named effects with sizes drawn uniformly from the ranges each effect declares for the plant
    (``EffectParameter.plant``; the other parameters keep their defaults), deterministic for ``seed``."""
    rng = np.random.default_rng(seed)
    chosen: dict[str, Any] = {}
    for name in names:
        if name not in PLANT_EFFECTS:
            raise ParameterError(f"random_effects: cannot draw effect {name!r} (drawn: {', '.join(PLANT_EFFECTS)})")
        kind = EFFECT_TYPES[name]
        chosen[name] = kind(
            **{p: float(rng.uniform(*spec.plant)) for p, spec in kind.PARAMETERS.items() if spec.plant is not None}
        )
    return Effects(**chosen)


#: Kinds of :class:`TruthForm`, with their parameters (name, low, high of the random draw).
TRUTH_FORM_KINDS: dict[str, tuple[tuple[str, float, float], ...]] = {
    "airspeed_power": (("exponent", 0.5, 0.9), ("slipstream_mps", 12.0, 20.0), ("reference_mps", 23.0, 23.0)),
    "mixture_sigmoid": (("fraction", 0.08, 0.2), ("centre", 0.55, 0.75), ("width", 0.04, 0.1)),
    "cooling_drift": (("size", 0.08, 0.2), ("time_constant_s", 900.0, 2400.0)),
    "oil_coupling": (("coupling", 0.15, 0.35), ("time_constant_s", 600.0, 1500.0)),
}


@dataclass(frozen=True)
class TruthForm:
    """A truth term the model library does not contain exactly (blind cases of the gap diagnosis).

    With ``v`` the airspeed (m/s), ``load`` = throttle/100, ``t`` the time since engine start (s):

    - ``airspeed_power``: conductance x (max(v, slipstream_mps) / reference_mps)^exponent (a power law
      with a slipstream floor, on the whole dissipation; the library's law is linear, on convection);
    - ``mixture_sigmoid``: heat in x (1 - fraction / (1 + exp(-(load - centre) / width))) (a smooth
      enrichment; the library's is a clipped ramp);
    - ``cooling_drift``: conductance / (1 + size (1 - exp(-t / time_constant_s))) (a cooling loss that
      grows with run time on every flight);
    - ``oil_coupling``: an oil state ``T_oil' = (T - T_oil) / time_constant_s`` from the starting head
      temperature; conductance x (1 - coupling (T_oil - T_oil(0)) / 100 degC) (hot oil takes less heat
      from the head: a second, slow time constant).
    """

    kind: str
    params: tuple[tuple[str, float], ...]

    def __post_init__(self) -> None:
        spec = TRUTH_FORM_KINDS.get(self.kind)
        if spec is None:
            raise ParameterError(f"truth form {self.kind!r}: unknown (known: {', '.join(TRUTH_FORM_KINDS)})")
        given = dict(self.params)
        if set(given) != {name for name, _, _ in spec}:
            raise ParameterError(f"truth form {self.kind}: expected parameters {[n for n, _, _ in spec]}")
        for name, value in given.items():
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0.0):
                raise ParameterError(f"truth form {self.kind}.{name}: expected a positive number, got {value!r}")

    def value(self, name: str) -> float:
        """One parameter."""
        return float(dict(self.params)[name])

    def factors(self, time_s: np.ndarray, airspeed_mps: np.ndarray, throttle_pct: np.ndarray) -> tuple[Any, Any]:
        """Stateless factors (gamma_Q, gamma_D) of this form at each step (1.0 where it has none)."""
        if self.kind == "airspeed_power":
            v = np.maximum(airspeed_mps, self.value("slipstream_mps"))
            return 1.0, (v / self.value("reference_mps")) ** -self.value("exponent")
        if self.kind == "mixture_sigmoid":
            load = np.asarray(throttle_pct, dtype=float) / 100.0
            z = (load - self.value("centre")) / self.value("width")
            return 1.0 - self.value("fraction") / (1.0 + np.exp(-z)), 1.0
        if self.kind == "cooling_drift":
            return 1.0, 1.0 + self.value("size") * (1.0 - np.exp(-np.asarray(time_s) / self.value("time_constant_s")))
        return 1.0, 1.0  # oil_coupling: stateful, in the step loop


def random_truth_form(seed: int, kind: str) -> TruthForm:
    """A truth form of ``kind`` with parameters drawn uniformly from :data:`TRUTH_FORM_KINDS`."""
    spec = TRUTH_FORM_KINDS.get(kind)
    if spec is None:
        raise ParameterError(f"truth form {kind!r}: unknown (known: {', '.join(TRUTH_FORM_KINDS)})")
    rng = np.random.default_rng(seed)
    return TruthForm(kind, tuple((name, float(rng.uniform(low, high))) for name, low, high in spec))
