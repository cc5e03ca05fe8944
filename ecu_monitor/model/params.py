"""The thermal model's parameters: a frozen, validated object that round-trips through model.yaml.

Symbols follow the paper (Eq. 2, 10-12, 18; docs/model.md); units are in each field's comment.
``paper_table_a1()`` is the paper's identified values (Table A1) with the reference engine's heat
map: the default model everywhere. Note its radiative term uses degC inside T^4 (the only reading
under which 8.1e5 makes physical sense, docs/model.md); a model identified here states its own
convention in ``radiation_in_kelvin``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ecu_monitor.errors import ConfigError, ParameterError
from ecu_monitor.model.effects import Effects
from ecu_monitor.model.heatmap import HeatMap, reference_heat_map
from ecu_monitor.userfiles import write_output_bytes
from ecu_monitor.yamlfile import load_yaml_file

__all__ = [
    "MAX_STEADY_RISE_C",
    "MODEL_KIND",
    "MODEL_VERSION",
    "NOMINAL_TERMS",
    "SCALE_RANGE",
    "AirframeTerms",
    "ThermalParams",
    "airframe_warning",
    "load_model",
    "paper_table_a1",
    "save_model",
]

MODEL_KIND = "cht-0d-single-zone"
#: The model.yaml schema version this code reads and writes.
MODEL_VERSION = 1
#: Keys every model.yaml must give: a missing one is an error, never a silent default (the defaults
#: are the paper's engine, not the reader's). ``effects``, ``terms_off``, ``engine_type`` and ``airframes`` may be
#: left out (none).
REQUIRED_KEYS: tuple[str, ...] = (
    "model",
    "version",
    "c_w",
    "r_ce",
    "alpha_r_e",
    "radiation_in_kelvin",
    "tau_w",
    "a",
    "b",
    "cht_limit_c",
    "heat_map",
)
#: Terms of the paper's own model that a model may switch off (``ThermalParams.terms_off``):
#: "altitude_scaling" makes g(z) = 1 (a and b unused: a heat map driven by measured fuel flow already
#: carries altitude); "radiation" drops the T^4 term (alpha_r_e unused).
NOMINAL_TERMS: tuple[str, ...] = ("altitude_scaling", "radiation")
_SCALARS: dict[str, tuple[float, float]] = {
    # name: (lowest, highest) accepted
    "c_w": (1.0, 1e6),
    "r_ce": (1e-4, 100.0),
    "alpha_r_e": (1.0, math.inf),
    "tau_w": (0.05, 600.0),
    # g(z) = (p/p_SL)^a (T_SL/T_e)^b: an exponent below 0 would make thinner or warmer air put more
    # heat into the wall, which no aspirated engine does (the paper's a = 1.55, b = 2); 0 = no effect
    "a": (0.0, 10.0),
    "b": (0.0, 10.0),
    "cht_limit_c": (20.0, 500.0),
}
#: Highest steady CHT rise above the air a model may predict, degC: the heat map's largest value times
#: R_Ce (the wall's steady state without radiation). Aluminium melts at 660 degC; three times that still
#: leaves room for any identified engine while refusing a heat map in the wrong unit (1e9 W made every
#: filter step NaN).
MAX_STEADY_RISE_C = 2000.0
#: Accepted range of an airframe's heat and cooling scales (:class:`AirframeTerms`), dimensionless.
SCALE_RANGE: tuple[float, float] = (0.5, 2.0)

#: The fields of an airframe entry besides its id (:class:`AirframeTerms`: its own terms, then its head's
#: measured offset) and their accepted ranges.
_AIRFRAME_TERM_RANGES: dict[str, tuple[float, float]] = {
    "heat_scale": SCALE_RANGE,
    "cooling_scale": SCALE_RANGE,
    "probe_lag_s": (0.0, 300.0),
    "head_offset_c": (-200.0, 200.0),
}


@dataclass(frozen=True)
class AirframeTerms:
    """An airframe a model was made for (``airframes:`` in model.yaml) and its own terms.

    id: the airframe's name: a G1000 ``system_id``, a log's engine serial or a name the user gave.
    heat_scale: the airframe's heat into the head relative to the type's heat map (dimensionless),
        None when the airframe does not need its own.
    cooling_scale: the airframe's convective conductance 1/R_Ce relative to the type's (dimensionless),
        None when the airframe does not need its own.
    probe_lag_s: the airframe's CHT probe time constant (s), None when it does not need its own.
    head_offset_c: measured, not a term: its head's rise above the air against the type's other airframes' at
        the steady operating points they share (degC, ``ecu_monitor.identify.matched``), recorded by
        ``identify --type`` (None: not measured). No model applies it: it says how far apart the heads of
        the type's airframes run at the same inputs, so how far a new airframe's can be from the type's.

    In a type model (``engine_type`` set) the terms apply on top of the type's shared parameters
    (``ecu_monitor.identify.type_model.airframe_model``); in any other model they are a record of
    what is already in its parameters.
    """

    id: str
    heat_scale: float | None = None
    cooling_scale: float | None = None
    probe_lag_s: float | None = None
    head_offset_c: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.id, str) or not self.id.strip():
            raise ParameterError(f"airframes: id: expected a name, got {self.id!r}")
        for name, (low, high) in _AIRFRAME_TERM_RANGES.items():
            value = getattr(self, name)
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
                raise ParameterError(
                    f"airframes: {self.id}: {name}: expected a number in [{low:g}, {high:g}], got {value!r}"
                )
            object.__setattr__(self, name, float(value))

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for YAML: the id and the fields the airframe has."""
        terms = {name: getattr(self, name) for name in _AIRFRAME_TERM_RANGES if getattr(self, name) is not None}
        return {"id": self.id, **terms}

    @classmethod
    def from_dict(cls, data: Any) -> AirframeTerms:
        """Parse one entry of ``airframes:``; raises ParameterError naming the key."""
        if not isinstance(data, dict) or "id" not in data:
            raise ParameterError(f"airframes: expected entries {{id: NAME, heat_scale: S, ...}}, got {data!r}")
        for key in data:
            if key != "id" and key not in _AIRFRAME_TERM_RANGES:
                raise ParameterError(f"airframes: {key}: unknown key (known: id, {', '.join(_AIRFRAME_TERM_RANGES)})")
        values = {k: (_number(v, f"airframes.{k}") if k != "id" and v is not None else v) for k, v in data.items()}
        return cls(id=str(values.pop("id")), **values)


@dataclass(frozen=True)
class ThermalParams:
    """Parameters of the 0D single-zone CHT model.

    c_w: wall heat capacity C_w, J/degC.
    r_ce: convective resistance R_Ce, degC/W.
    alpha_r_e: radiative resistance alpha*R_e, degC^4/W (or K^4/W with radiation_in_kelvin);
        ``inf`` switches radiation off.
    radiation_in_kelvin: True to use Kelvin inside T^4 (physical); False for the paper's preset.
    tau_w: heat-path delay of the first-order Pade approximation, s.
    a, b: altitude-scaling exponents of g(z) = (p/p_SL)^a (T_SL/T_e)^b, dimensionless.
    heat_map: sea-level heat into the wall Q_SL0 on n x m breakpoints, W.
    effects: unmodelled-effect extensions switched on in this model (none in the paper's).
    cht_limit_c: CHT limit of the engine for headroom and the step-climb, degC.
    terms_off: terms of the paper's model switched off (names from :data:`NOMINAL_TERMS`), so that
        identification can test whether a term belongs on an engine; () is the paper's model.
    engine_type: the engine type of a type model (``identify --type``); "" for a model of one engine.
    airframes: the airframes the model was made for, with their own terms (:class:`AirframeTerms`);
        () when the flights named none.
    """

    c_w: float = 570.0
    r_ce: float = 0.15
    alpha_r_e: float = 8.1e5
    radiation_in_kelvin: bool = False
    tau_w: float = 6.0
    a: float = 1.55
    b: float = 2.0
    heat_map: HeatMap = field(default_factory=reference_heat_map)
    effects: Effects = field(default_factory=Effects)
    cht_limit_c: float = 150.0
    terms_off: tuple[str, ...] = ()
    engine_type: str = ""
    airframes: tuple[AirframeTerms, ...] = ()

    def __post_init__(self) -> None:
        for name, (low, high) in _SCALARS.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
                raise ParameterError(f"{name}: expected a number, got {value!r}")
            if not low <= value <= high:
                raise ParameterError(f"{name}: expected a value in [{low:g}, {high:g}], got {value!r}")
            object.__setattr__(self, name, float(value))
        if not isinstance(self.radiation_in_kelvin, bool):
            raise ParameterError("radiation_in_kelvin: expected true or false")
        if not isinstance(self.heat_map, HeatMap):
            raise ParameterError("heat_map: expected a HeatMap")
        peak_w = max(max(row) for row in self.heat_map.values_w)
        if peak_w * self.r_ce > MAX_STEADY_RISE_C:
            raise ParameterError(
                f"heat_map.values_w: {peak_w:g} W times r_ce {self.r_ce:g} degC/W is a steady CHT"
                f" {peak_w * self.r_ce:.3g} degC above the air, more than any engine ({MAX_STEADY_RISE_C:g});"
                " is the heat map in W?"
            )
        if not isinstance(self.effects, Effects):
            raise ParameterError("effects: expected an Effects")
        if self.effects.engine_speed_cooling is not None and self.heat_map.y_axis != "rpm":
            raise ParameterError(
                "effects.engine_speed_cooling: reads the engine speed from the heat map's second axis, which is"
                f" {self.heat_map.y_axis!r}, not rpm"
            )
        if isinstance(self.terms_off, str) or not isinstance(self.terms_off, tuple | list):
            raise ParameterError(f"terms_off: expected a list of term names, got {self.terms_off!r}")
        for term in self.terms_off:
            if term not in NOMINAL_TERMS:
                raise ParameterError(f"terms_off: unknown term {term!r} (known: {', '.join(NOMINAL_TERMS)})")
        object.__setattr__(self, "terms_off", tuple(t for t in NOMINAL_TERMS if t in self.terms_off))
        if not isinstance(self.engine_type, str):
            raise ParameterError(f"engine_type: expected a name, got {self.engine_type!r}")
        entries = self.airframes
        if not isinstance(entries, tuple | list) or not all(isinstance(a, AirframeTerms) for a in entries):
            raise ParameterError("airframes: expected a list of airframe entries")
        object.__setattr__(self, "airframes", tuple(self.airframes))
        ids = [a.id for a in self.airframes]
        if len(set(ids)) != len(ids):
            raise ParameterError(f"airframes: an airframe is listed twice ({', '.join(ids)})")

    def term_on(self, term: str) -> bool:
        """Whether a term of the paper's model (one of :data:`NOMINAL_TERMS`) is in this model."""
        if term not in NOMINAL_TERMS:
            raise ParameterError(f"terms_off: unknown term {term!r} (known: {', '.join(NOMINAL_TERMS)})")
        return term not in self.terms_off

    @property
    def heat_axes(self) -> tuple[str, str]:
        """The two flight columns that drive the heat map."""
        return self.heat_map.x_axis, self.heat_map.y_axis

    def replace(self, **changes: Any) -> ThermalParams:
        """A validated copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for YAML (the model.yaml schema)."""
        hm = self.heat_map
        return {
            "model": MODEL_KIND,
            "version": MODEL_VERSION,
            "c_w": self.c_w,
            "r_ce": self.r_ce,
            "alpha_r_e": self.alpha_r_e,
            "radiation_in_kelvin": self.radiation_in_kelvin,
            "tau_w": self.tau_w,
            "a": self.a,
            "b": self.b,
            "cht_limit_c": self.cht_limit_c,
            "heat_map": {
                "x_axis": hm.x_axis,
                "y_axis": hm.y_axis,
                "x_breakpoints": [float(v) for v in hm.x_breakpoints],
                "y_breakpoints": [float(v) for v in hm.y_breakpoints],
                "values_w": [[float(v) for v in row] for row in hm.values_w],
            },
            "effects": self.effects.to_dict(),
            **({"terms_off": list(self.terms_off)} if self.terms_off else {}),
            **({"engine_type": self.engine_type} if self.engine_type else {}),
            **({"airframes": [a.to_dict() for a in self.airframes]} if self.airframes else {}),
        }

    @classmethod
    def from_dict(cls, data: Any) -> ThermalParams:
        """Parse the model.yaml schema; raises ParameterError naming the key.

        Every key of :data:`REQUIRED_KEYS` must be given; unknown keys and another ``version`` than
        :data:`MODEL_VERSION` are refused. Values are checked before missing keys are reported, so a
        one-key file with a bad value names that value.
        """
        if not isinstance(data, dict):
            raise ParameterError("expected a mapping at the top level")
        known = {f.name for f in dataclasses.fields(cls)} | {"model", "version"}
        if "inputs" in data and "engine" in data:
            raise ParameterError("this is a service config, not a model file: give it as --config")
        for key in data:
            if key not in known:
                raise ParameterError(f"{key}: unknown key (known: {', '.join(sorted(known))})")
        if "model" in data and data["model"] != MODEL_KIND:
            raise ParameterError(f"model: expected {MODEL_KIND!r}, got {data['model']!r}")
        if "version" in data and (isinstance(data["version"], bool) or data["version"] != MODEL_VERSION):
            raise ParameterError(
                f"version: expected {MODEL_VERSION} (the schema this program reads), got {data['version']!r}"
            )
        kwargs: dict[str, Any] = {}
        for name, (low, high) in _SCALARS.items():
            if name in data:
                value = _number(data[name], name)
                if not low <= value <= high:
                    raise ParameterError(f"{name}: expected a value in [{low:g}, {high:g}], got {data[name]!r}")
                kwargs[name] = value
        if "radiation_in_kelvin" in data:
            kwargs["radiation_in_kelvin"] = data["radiation_in_kelvin"]
        if "heat_map" in data:
            kwargs["heat_map"] = _heat_map(data["heat_map"])
        kwargs["effects"] = Effects.from_dict(data.get("effects"))
        if "terms_off" in data:
            terms = data["terms_off"] or []
            if not isinstance(terms, list) or not all(isinstance(t, str) for t in terms):
                raise ParameterError(f"terms_off: expected a list of term names, got {data['terms_off']!r}")
            kwargs["terms_off"] = tuple(terms)
        if "engine_type" in data:
            kwargs["engine_type"] = "" if data["engine_type"] is None else str(data["engine_type"])
        if "airframes" in data:
            entries = data["airframes"] or []
            if not isinstance(entries, list):
                raise ParameterError(f"airframes: expected a list, got {data['airframes']!r}")
            kwargs["airframes"] = tuple(AirframeTerms.from_dict(entry) for entry in entries)
        params = cls(**kwargs)  # validates the values given
        for key in REQUIRED_KEYS:
            if key not in data:
                raise ParameterError(f"{key}: missing (a model file gives every one of {', '.join(REQUIRED_KEYS)})")
        return params


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool):
        raise ParameterError(f"{where}: expected a number, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{where}: expected a number, got {value!r}") from None


def _heat_map(data: Any) -> HeatMap:
    if not isinstance(data, dict):
        raise ParameterError("heat_map: expected a mapping")
    required = ("x_axis", "y_axis", "x_breakpoints", "y_breakpoints", "values_w")
    for key in data:
        if key not in required:
            raise ParameterError(f"heat_map.{key}: unknown key")
    for key in required:
        if key not in data:
            raise ParameterError(f"heat_map.{key}: missing")
    for key in ("x_breakpoints", "y_breakpoints", "values_w"):
        if not isinstance(data[key], list):
            raise ParameterError(f"heat_map.{key}: expected a list, got {data[key]!r}")
    xb = tuple(_number(v, "heat_map.x_breakpoints") for v in data["x_breakpoints"])
    yb = tuple(_number(v, "heat_map.y_breakpoints") for v in data["y_breakpoints"])
    rows = data["values_w"]
    if len(rows) != len(xb):
        raise ParameterError(f"heat_map.values_w: expected {len(xb)} rows (one per x breakpoint), got {len(rows)}")
    for i, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != len(yb):
            got = f"{len(row)} values" if isinstance(row, list) else repr(row)
            raise ParameterError(
                f"heat_map.values_w: row {i + 1}: expected {len(yb)} values (one per y breakpoint), got {got}"
            )
    values = tuple(tuple(_number(v, "heat_map.values_w") for v in row) for row in rows)
    return HeatMap(str(data["x_axis"]), str(data["y_axis"]), xb, yb, values)


def paper_table_a1() -> ThermalParams:
    """The paper's Table A1 (C_w 570, R_Ce 0.15, alpha*R_e 8.1e5 with degC in T^4, tau_w 6, a 1.55,
    b 2) with the reference engine's documented heat map."""
    return ThermalParams()


def load_model(path: str | Path) -> ThermalParams:
    """Read model.yaml; any problem raises ConfigError naming the file and the key."""
    path = Path(path)
    data = load_yaml_file(path, "model file", ConfigError)
    try:
        return ThermalParams.from_dict(data)
    except ParameterError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def save_model(params: ThermalParams, path: str | Path, comment: str | None = None) -> None:
    """Write model.yaml (loads back to an equal ThermalParams)."""
    header = "".join(f"# {line}\n" for line in (comment or "").splitlines())
    text = header + yaml.safe_dump(params.to_dict(), sort_keys=False)
    write_output_bytes(path, text.encode("utf-8"), ConfigError)


def airframe_warning(params: ThermalParams, airframe: str | None, model_name: str, log_name: str) -> str | None:
    """One line when a model made for other airframes (``params.airframes``) is used on a log or an engine of
    another (``airframe``: its G1000 system_id or engine serial); None when either is unknown or they agree.
    For a type model it says how far apart its airframes' heads ran at the same inputs (where recorded:
    :attr:`AirframeTerms.head_offset_c`) and how the new airframe's own terms are set."""
    made_for = [a.id for a in params.airframes]
    if not airframe or not made_for or airframe in made_for:
        return None
    if not params.engine_type:
        return (
            f"{log_name}: airframe {airframe}, but {model_name} is a model made for {', '.join(made_for)}:"
            " expect a larger error (identify --base TYPE.yaml adapts a type model to an airframe)"
        )
    offsets = [a.head_offset_c for a in params.airframes if a.head_offset_c is not None]
    apart = (
        f"; at the same inputs its airframes' heads ran {min(offsets):+.1f} to {max(offsets):+.1f} degC from the"
        " others', and a new airframe's can be as far from the model"
        if offsets
        else ""
    )
    return (
        f"{log_name}: airframe {airframe}, but {model_name} is the {params.engine_type} type model made for"
        f" {', '.join(made_for)}{apart}: the first 20 minutes of one of its flights set its own terms"
        " (identify --base TYPE.yaml FLIGHT --first-minutes 20 --out AIRFRAME.yaml)"
    )
