"""The service configuration: YAML -> frozen, validated structs (docs/service.md, shipped example.yaml).

The file's schema is :class:`ConfigFile` and its sections, msgspec structs (frozen, unknown keys
refused): every key's type, range, whether it is required, and its default are declared there, once,
and ``msgspec.convert`` checks the YAML-loaded mapping against them. Checks across keys that a type
cannot express are small explicit checks in the sections' ``__post_init__``. :func:`parse_config`
then resolves what the file names into a :class:`ServiceConfig`: paths are relative to the file
itself; the input DBC files are loaded (:func:`ecu_monitor.bus.dbc.load_dbc`), so a
``Message.Signal`` that is not in them, or in a message that fails the DBC's strict checks, is caught
here, not at the first frame. An input's ``unit`` is a name of :data:`ecu_monitor.units.UNITS` or,
for a unit it does not know, ``{scale: S, offset: O}`` (canonical value = raw physical value * S + O).

Every problem raises :class:`~ecu_monitor.errors.ConfigError` whose one-line message names the file,
the key path and what was expected, e.g. ``x.yaml: inputs.rpm.unit: unknown unit 'rps' ...``
(the CLI prints it and exits 2); msgspec's ValidationError (``... - at `$.inputs.rpm.unit```) is
put in that form in one place, :func:`validation_error`.

``protocol: dronecan`` (default ``dbc``) reads DroneCAN messages instead (:mod:`ecu_monitor.bus.dronecan`,
the shipped dronecan.yaml): each input names ``field: data.type.Name.field.path`` instead of
``signal:``, checked against the DSDL definitions at load; ``dbc`` is not used; the ``dronecan:``
section gives the service's node id and the accepted senders (:class:`DroneCanSettings`).
"""

from __future__ import annotations

import dataclasses
import os
import re
import sys
import typing
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Annotated, Any, Literal

import msgspec
import msgspec.inspect as schema
from msgspec import UNSET, Meta, UnsetType

from ecu_monitor.bus.codec import INPUT_NAMES, INPUT_QUANTITIES, SignalSpec
from ecu_monitor.bus.dbc import load_dbc, shipped_dbc
from ecu_monitor.bus.mavlink_settings import MavlinkSettings, parse_mavlink_settings
from ecu_monitor.errors import ConfigError
from ecu_monitor.estimation import ESTIMATORS, EstimatorSettings
from ecu_monitor.estimation.detection import DetectorSettings
from ecu_monitor.estimation.wear import WearReference, WearSettings
from ecu_monitor.model import ThermalParams, load_model, paper_table_a1
from ecu_monitor.model.params import MODEL_KIND
from ecu_monitor.shipped import DEFAULT_CONFIG, resolve_file
from ecu_monitor.units import Unit, custom_unit
from ecu_monitor.yamlfile import load_yaml_file

__all__ = [
    "CHT_INPUT",
    "CYLINDER_HEALTH_MESSAGES",
    "CYLINDER_INPUT",
    "DEFAULT_CONFIG",
    "DRONECAN_ALTITUDE_FIELD",
    "EVENT_INPUTS",
    "HEALTH_MESSAGES",
    "MAX_CYLINDERS",
    "MODEL_PRESETS",
    "PROTOCOLS",
    "REQUIRED_INPUTS",
    "SYMPTOMS",
    "Backoff",
    "ConfigFile",
    "DroneCanSettings",
    "EngineEvents",
    "HealthRate",
    "InputSpec",
    "SensorFaultSettings",
    "ServiceConfig",
    "config_default",
    "detector_section",
    "load_config",
    "parse_config",
    "validation_error",
]

#: Bus protocols of the inputs: DBC-described frames, DroneCAN messages, or an autopilot's MAVLink telemetry.
Protocol = Literal["dbc", "dronecan", "mavlink"]
PROTOCOLS: tuple[str, ...] = typing.get_args(Protocol)
#: Per-cylinder CHT inputs (``cht1_c`` .. ``cht16_c``, the flight-log column names). Two or more
#: mapped: every cylinder is monitored (one estimator each; docs/service.md, "Every cylinder"), and a
#: ``cht_c`` mapped beside them is held but not estimated; one alone is held beside ``cht_c``.
CYLINDER_INPUT = re.compile(r"^cht([1-9]|1[0-6])_c$")
#: DroneCAN: the field altitude_m is taken from when the config maps none (pressure altitude, Pa).
DRONECAN_ALTITUDE_FIELD = "uavcan.equipment.air_data.StaticPressure.static_pressure"

#: Inputs every configuration must map (the heat-map axes of the model come on top, checked by the pipeline).
REQUIRED_INPUTS: tuple[str, ...] = ("cht_c", "oat_c", "altitude_m", "airspeed_mps")
#: Health messages sent only when configured: the per-cylinder frames (health.dbc, docs/dbc.md).
CYLINDER_HEALTH_MESSAGES: tuple[str, ...] = ("Health_Spread", "Health_Cylinder")
#: The single-channel CHT input; an engine monitored per cylinder maps ``cht1_c .. chtN_c`` instead.
CHT_INPUT = "cht_c"
#: Most cylinders a configuration may monitor (the DroneCAN ICE status carries up to 16).
MAX_CYLINDERS = 16
#: Health messages the pipeline knows how to fill, with their default rates (Hz, health.dbc GenMsgCycleTime).
HEALTH_MESSAGES: Mapping[str, float] = MappingProxyType(
    {"Health_Status": 10.0, "Health_Isolation": 2.0, "Health_Diag": 1.0}
)
#: Model-deviation symptoms the detector may watch: the configured estimator's (the paper's Delta_k / dt)
#: or the isolation filter's f(T, gamma_Q, gamma_D) - f(T, 1, 1); both degC/s.
Symptom = Literal["estimator", "isolation"]
SYMPTOMS: tuple[str, ...] = typing.get_args(Symptom)
#: Built-in model presets accepted by ``model:`` instead of a file.
MODEL_PRESETS = MappingProxyType({"paper_table_a1": paper_table_a1})

# --- the file's schema ---------------------------------------------------------------------------------

_MAX = sys.float_info.max  # a float within +-_MAX is finite: the bounds make msgspec refuse inf and nan
_Number = Annotated[float, Meta(ge=-_MAX, le=_MAX)]
_Positive = Annotated[float, Meta(gt=0.0, le=_MAX)]
_NonNegative = Annotated[float, Meta(ge=0.0, le=_MAX)]
_Text = Annotated[str, Meta(pattern=r"\S", description="a non-empty string")]
_FilePath = Annotated[str, Meta(pattern=r"\S", description="a file path")]
_ModelRef = Annotated[
    str, Meta(pattern=r"\S", description=f"a preset name ({', '.join(MODEL_PRESETS)}) or a model file")
]
_Fingerprint = Annotated[str, Meta(pattern=r"^[0-9a-f]{16}$", description="16 hex digits (a model fingerprint)")]
_NodeId = Annotated[int, Meta(ge=1, le=127, description="a node id 1..127")]


class _SectionError(ValueError):
    """A check across keys of a section failed: ``key`` (relative to the section) and what was expected.
    Raised in ``__post_init__``, where msgspec wraps it, with the section's path, in its ValidationError."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}")
        self.key = key
        self.message = message


class _Section(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A mapping of the config file: frozen, unknown keys refused (subclasses inherit both)."""


class _Engine(_Section, frozen=True):
    serial: _Text  # the engine's serial: persistence keeps its flights and trends under it
    #: its hours since overhaul as the logbook gives them (0 after an overhaul), h: the history counts on from
    #: its running hours when this value is first seen (None: not tracked)
    overhaul_hours: _NonNegative | None = None
    tbo_hours: _Positive | None = None  # its time between overhauls, h: ``history`` says when it is due


class Backoff(_Section, frozen=True):
    """``reopen_backoff_s``: delays between attempts to reopen a failed bus: initial, doubling up to max, s."""

    initial: _Positive = 0.5
    max: _Positive = 10.0

    def __post_init__(self) -> None:
        if self.max < self.initial:
            raise _SectionError("max", f"expected a number >= {self.initial:g}, got {self.max:g}")


class DroneCanSettings(_Section, frozen=True):
    """The service as a DroneCAN node (docs/service.md, "DroneCAN").

    node_id: the service's node id (1..127), the source of its NodeStatus, KeyValue and LogMessage.
    source_node_ids: accept inputs only from these nodes (empty: from any node). priority: the CAN
    priority of the service's transfers (0 highest .. 31 lowest). key_value_hz: rate of the health
    values as uavcan.protocol.debug.KeyValue (0: none). log_messages: state changes as
    uavcan.protocol.debug.LogMessage. dbc_health_frames: send the health.dbc frames too.
    """

    node_id: _NodeId = 100
    source_node_ids: tuple[_NodeId, ...] = ()
    priority: Annotated[int, Meta(ge=0, le=31, description="a CAN priority 0..31")] = 24
    key_value_hz: Annotated[float, Meta(ge=0.0, le=10.0)] = 1.0
    log_messages: bool = True
    dbc_health_frames: bool = False

    def __post_init__(self) -> None:
        if self.node_id in self.source_node_ids:
            raise _SectionError("source_node_ids", f"lists the service's own node id {self.node_id}")


class _DroneCanSection(DroneCanSettings, frozen=True):
    """``dronecan:`` as written: the node id is required, it must be unique on the bus (the default above
    is only that of a config with protocol dbc, where the service is no DroneCAN node)."""

    node_id: _NodeId


class _SensorFaultSection(_Section, frozen=True):
    """``sensor_fault:`` as written (:class:`SensorFaultSettings`; ``status_signal`` is ``Message.Signal``,
    a DroneCAN field path for protocol dronecan)."""

    stuck_after_s: _Positive = 120.0
    min_c: _Number = -40.0
    max_c: _Number = 350.0
    stuck_change_c: _Positive = 5.0
    status_signal: _Text | None = None
    open_values: Annotated[tuple[int, ...], Meta(min_length=1, description="a non-empty list of integers")] = ()

    def __post_init__(self) -> None:
        if self.max_c <= self.min_c:
            raise _SectionError("max_c", f"expected a number > {self.min_c:g}, got {self.max_c:g}")
        if self.status_signal is not None and not self.open_values:
            raise _SectionError("open_values", "missing")
        if self.open_values and self.status_signal is None:
            raise _SectionError("open_values", "given without status_signal")


class SensorFaultSettings(_SensorFaultSection, frozen=True):
    """CHT sensor plausibility.

    min_c, max_c: readings outside are an open / shorted probe, degC. stuck_after_s: a reading that
    has not changed for this long while the model predicts a change of at least stuck_change_c
    (degC) is stuck. status_message/status_signal/open_values: optional ECU status signal whose
    value in open_values reports an open probe (engine.dbc: ECU_Slow.EcuStatus = 3 CHT_SENSOR_OPEN);
    the file's ``status_signal: Message.Signal`` split in two (a DroneCAN data type and field path).
    """

    status_message: str | None = None


class EngineEvents(_Section, frozen=True):
    """``events:``: the engine events the step reports (docs/service.md, "Engine events"; each default's
    reason is there).

    enabled: report them at all. shock_cooling_c_per_min: a cylinder's CHT rate (the filter's, degC/min)
    falling faster than this is shock cooling, once it lasts shock_cooling_min_s (s).
    cht_divergence_c: a cylinder's estimated CHT further than this (degC) from the median of the other
    cylinders' diverges, once it lasts divergence_min_s (s); needs two or more CHT channels.
    cht_limit_c: an estimated CHT above this (degC) is an exceedance once it lasts exceedance_min_s (s);
    None: each cylinder's model's ``cht_limit_c`` (model.yaml). egt_divergence_c: a cylinder's EGT
    (``egtN_c`` mapped) whose offset from the median of the others' moves further than this (degC) from its
    normal offset diverges (divergence_min_s); the normal offset is the cylinder's own in each power band,
    learned at steady power (an average over egt_normal_s, s, counted once it has learned that long: every
    engine's EGTs spread by their own amount, another at another power), counted at steady power while the
    median of the EGTs is above egt_divergence_from_c (at power: at idle they scatter).
    egt_limit_c, oil_limit_c: an EGT, the oil temperature (``oil_temp_c``) above this (degC) is an
    exceedance (exceedance_min_s). valve_amplitude_c: the exhaust-valve advisory: one cylinder's EGT
    oscillating at 0.5-3 cycles/min with at least this peak-to-peak amplitude (degC) while every other
    cylinder's oscillates by less than half of it, for valve_min_s (s).
    """

    enabled: bool = True
    shock_cooling_c_per_min: _Positive = 33.0
    shock_cooling_min_s: _NonNegative = 5.0
    cht_divergence_c: _Positive = 40.0
    divergence_min_s: _NonNegative = 10.0
    cht_limit_c: _Number | None = None
    exceedance_min_s: _NonNegative = 2.0
    egt_divergence_c: _Positive = 60.0
    egt_divergence_from_c: _Number = 500.0
    egt_normal_s: _Positive = 120.0
    egt_limit_c: _Number = 900.0
    oil_limit_c: _Number = 118.0
    valve_amplitude_c: _Positive = 15.0
    valve_min_s: _Positive = 300.0


class _Input(_Section, frozen=True):
    """``inputs.<name>``: where the input is on the bus, its unit and when it goes stale, s."""

    unit: Annotated[str | dict[str, Any], Meta(description="a unit name or {scale: S, offset: O}")]
    stale_after_s: _Positive
    signal: _Text | UnsetType = UNSET  # protocol dbc: Message.Signal
    field: _Text | UnsetType = UNSET  # protocol dronecan: data.type.Name.field.path


class _Rate(_Section, frozen=True):
    rate_hz: _Positive


class _EstimatorName(_Section, frozen=True):
    name: _Text = "cbekf-au"

    def __post_init__(self) -> None:
        if self.name not in ESTIMATORS:
            raise _SectionError("name", f"unknown estimator {self.name!r} (known: {', '.join(sorted(ESTIMATORS))})")


class _DetectorMark(_Section, frozen=True):
    calibrated_for: _Fingerprint | None = None  # the model the threshold was calibrated for


class _DetectorHead(_DetectorMark, frozen=True):
    #: a detector file (relative to the config, or a shipped one's name): its ``detector:`` keys are this
    #: section's too (:func:`detector_section`)
    file: _FilePath | UnsetType = UNSET
    symptom: Symptom = "estimator"
    #: a detector not calibrated for the model: ``run`` refuses to start (exit 2), or (accept, a test bench)
    #: runs with a warning in every status line
    uncalibrated: Literal["refuse", "accept"] = "refuse"


class _WearReference(_Section, frozen=True):
    """``wear.reference``: the wear index over nominal flights (``ecu-monitor calibrate`` writes it)."""

    mean: float
    sd: Annotated[float, Meta(gt=0.0)]
    flights: Annotated[int, Meta(ge=2)]


class _WearHead(_Section, frozen=True):
    reference: _WearReference | None = None  # None: learned from the engine's own first flights


def _optional_keys(name: str, keys: Iterable[str], value: Any) -> Any:
    """A section with the optional keys ``keys``, each a ``value`` (UNSET: not given)."""
    return msgspec.defstruct(
        name, [(key, value | UnsetType, UNSET) for key in keys], bases=(_Section,), module=__name__
    )


def _settings_keys(name: str, settings: type, base: type) -> Any:
    """``base`` plus each field of the settings dataclass ``settings`` (which keeps their defaults and checks
    their values), optional."""
    hints = typing.get_type_hints(settings)
    keys = [(f.name, hints[f.name] | UnsetType, UNSET) for f in dataclasses.fields(settings)]
    return msgspec.defstruct(name, keys, bases=(base,), module=__name__)


def _given(section: msgspec.Struct, settings: type) -> dict[str, Any]:
    """The fields of the dataclass ``settings`` that ``section`` gives."""
    names = {f.name for f in dataclasses.fields(settings)}
    return {k: v for k, v in msgspec.structs.asdict(section).items() if k in names and v is not UNSET}


_CYLINDER_NAMES = tuple(f"cht{n}_c" for n in range(1, MAX_CYLINDERS + 1))
#: Inputs only the engine events read (docs/service.md, "Engine events"): held, never stale bits or model
#: inputs; each cylinder's EGT, the oil temperature.
EVENT_INPUTS: tuple[str, ...] = (*(f"egt{n}_c" for n in range(1, MAX_CYLINDERS + 1)), "oil_temp_c")
if TYPE_CHECKING:  # built below from names other modules declare; mypy sees their fixed part
    _Inputs = _Section
    _Health = _Section
    _EstimatorSection = _EstimatorName
    _DetectorSection = _DetectorHead
    _DetectorKeys = _DetectorMark
    _WearSection = _WearHead
else:
    _Inputs = _optional_keys("Inputs", (*INPUT_NAMES, *_CYLINDER_NAMES, *EVENT_INPUTS), _Input)
    _Health = _optional_keys("Health", (*HEALTH_MESSAGES, *CYLINDER_HEALTH_MESSAGES), _Rate)
    _EstimatorSection = _settings_keys("EstimatorSection", EstimatorSettings, _EstimatorName)
    _DetectorSection = _settings_keys("DetectorSection", DetectorSettings, _DetectorHead)
    _DetectorKeys = _settings_keys("DetectorKeys", DetectorSettings, _DetectorMark)
    _WearSection = _settings_keys("WearSection", WearSettings, _WearHead)


class _DetectorFile(_Section, frozen=True):
    """A detector file (``detector.file``): one ``detector:`` section, as ``ecu-monitor calibrate`` writes it."""

    detector: _DetectorSection


class _Cylinders(_Section, frozen=True):
    """``cylinders:``: one model per cylinder, the CHT spread limit, one detector per cylinder (each replacing
    keys of ``detector``), the cross-cylinder detector (replacing keys of DetectorSettings' defaults) and one
    per cylinder (replacing keys of ``cross_detector``; null: none on that cylinder); all optional."""

    models: list[_ModelRef] | UnsetType = UNSET
    spread_limit_c: _Positive | UnsetType = UNSET
    detectors: list[_DetectorKeys] | UnsetType = UNSET
    cross_detector: _DetectorKeys | UnsetType = UNSET
    cross_detectors: list[_DetectorKeys | None] | UnsetType = UNSET


class ConfigFile(_Section, frozen=True, kw_only=True):
    """The config file as written (the shipped example.yaml gives every key with its meaning): each key's
    type, range and default, declared once (the daemon's settings read theirs here: :func:`config_default`)."""

    protocol: Protocol = "dbc"
    engine: _Engine
    bus: dict[str, Any] | UnsetType = UNSET  # keyword arguments of can.Bus; required but for protocol mavlink
    reopen_backoff_s: Backoff = Backoff()
    dronecan: _DroneCanSection | UnsetType = UNSET  # protocol dronecan only, and required there
    mavlink: dict[str, Any] | UnsetType | None = UNSET  # protocol mavlink only (bus/mavlink_settings.py checks it)
    dbc: Annotated[
        _FilePath | Annotated[list[_FilePath], Meta(min_length=1)] | UnsetType,
        Meta(description="a DBC file path or a non-empty list of them"),
    ] = UNSET  # protocol dbc only, and required there
    health_dbc: _FilePath | UnsetType = UNSET  # required for protocol dbc; dronecan: the shipped health.dbc
    inputs: _Inputs
    health: _Health = msgspec.convert({name: {"rate_hz": rate} for name, rate in HEALTH_MESSAGES.items()}, _Health)
    model: _ModelRef = "paper_table_a1"
    cylinders: _Cylinders = _Cylinders()
    estimator: _EstimatorSection = _EstimatorSection()
    detector: _DetectorSection = _DetectorSection()
    wear: _WearSection = _WearSection()  # across flights: the maintenance alert (estimation/wear.py)
    #: inputs stale: keep predicting on the model this long, s, then UNAVAILABLE
    stale_predict_limit_s: _NonNegative = 30.0
    #: the daemon logs a warning when its bus has carried no engine frame for this long, s
    no_frames_warning_s: _Positive = 10.0
    state_dir: _FilePath = "/var/lib/ecu-monitor"  # the SQLite database of flights and trends
    sensor_fault: _SensorFaultSection = _SensorFaultSection()
    events: EngineEvents = EngineEvents()

    def __post_init__(self) -> None:
        if self.protocol == "mavlink":  # the link is mavlink.connection, not a CAN bus
            if self.bus is not UNSET:
                raise _SectionError("bus", "does not apply to protocol mavlink (the link is mavlink.connection)")
        else:
            bus = {} if self.bus is UNSET else self.bus
            interface = bus.get("interface", UNSET)
            if self.bus is UNSET:
                raise _SectionError("bus", "missing")
            if interface is UNSET or "channel" not in bus:
                raise _SectionError("bus.interface" if interface is UNSET else "bus.channel", "missing")
            if not isinstance(interface, str) or not interface.strip():
                raise _SectionError("bus.interface", f"expected a non-empty string, got {_kind(interface)}")
        if self.protocol != "mavlink" and self.mavlink is not UNSET:
            raise _SectionError("mavlink", "applies to protocol mavlink only (add protocol: mavlink)")
        if self.protocol == "dronecan" and self.dronecan is UNSET:
            raise _SectionError("dronecan", "missing (protocol dronecan: the service's node id)")
        if self.protocol != "dronecan" and self.dronecan is not UNSET:
            raise _SectionError("dronecan", "applies to protocol dronecan only (add protocol: dronecan)")
        if self.protocol in ("dronecan", "mavlink"):
            if self.dbc is not UNSET:
                raise _SectionError(
                    "dbc", f"input DBC files do not apply to protocol {self.protocol} (inputs name its fields)"
                )
        else:
            for key in ("dbc", "health_dbc"):
                if getattr(self, key) is UNSET:
                    raise _SectionError(key, "missing")
        given = [name for name, spec in msgspec.structs.asdict(self.inputs).items() if spec is not UNSET]
        numbers = sorted(int(m.group(1)) for name in given if (m := CYLINDER_INPUT.match(name)))
        if numbers != list(range(1, len(numbers) + 1)):
            cylinders = ", ".join(f"cht{n}_c" for n in numbers)
            raise _SectionError(
                "inputs", f"cylinders must be numbered 1 .. N (N <= {MAX_CYLINDERS}) without gaps, got {cylinders}"
            )
        mapped = set(given)
        if self.protocol == "dronecan" and "airspeed_mps" in mapped:
            mapped.add("altitude_m")  # the pressure altitude of the air data's static pressure (_inputs)
        for name in REQUIRED_INPUTS:
            if name not in mapped and not (name == CHT_INPUT and len(numbers) > 1):
                every = ", ".join(REQUIRED_INPUTS)
                raise _SectionError(
                    f"inputs.{name}", f"missing (every configuration maps {every}; cht_c or cht1_c .. chtN_c)"
                )
        count = _cylinder_count(given)
        beyond = [name for name in given if name in EVENT_INPUTS[:MAX_CYLINDERS] and int(name[3:-2]) > count]
        if beyond:
            raise _SectionError(
                f"inputs.{beyond[0]}", f"an EGT of a cylinder the config does not monitor ({count} CHT channel(s))"
            )
        if self.sensor_fault.status_signal is not None and count > 1:
            raise _SectionError(
                "sensor_fault.status_signal",
                "an ECU status signal reports one probe: not with cht1_c .. chtN_c (each cylinder's probe is"
                " checked by range and the stuck test)",
            )
        _check_cylinders(self.cylinders, count)


def _check_cylinders(section: _Cylinders, count: int) -> None:
    """The ``cylinders:`` lists have one entry per cylinder; cross-cylinder detectors need two or more."""
    if section.models is not UNSET and len(section.models) != count:
        raise _SectionError(
            "cylinders.models",
            f"expected a list of {count} models, one per cylinder, got a list of {len(section.models)}",
        )
    each = "one per cylinder (cht1_c .. chtN_c), got a list of {}"
    if section.detectors is not UNSET and (count < 2 or len(section.detectors) != count):
        raise _SectionError(
            "cylinders.detectors", f"expected a list of {count} detectors, {each.format(len(section.detectors))}"
        )
    for key in ("cross_detector", "cross_detectors"):
        if getattr(section, key) is not UNSET and count < 2:
            raise _SectionError(
                f"cylinders.{key}", "compares cylinders: needs two or more CHT channels (cht1_c .. chtN_c)"
            )
    if section.cross_detectors is not UNSET and len(section.cross_detectors) != count:
        raise _SectionError(
            "cylinders.cross_detectors",
            f"expected a list of {count} detectors, {each.format(len(section.cross_detectors))}",
        )


def _cylinder_count(names: Iterable[str]) -> int:
    """Cylinders monitored: the numbered CHT inputs when two or more are mapped, else 1 (``cht_c``)."""
    count = sum(1 for name in names if CYLINDER_INPUT.match(name))
    return count if count > 1 else 1


def config_default(key: str) -> Any:
    """The default of the config file's top-level ``key`` (declared once, in :class:`ConfigFile`)."""
    for info in msgspec.structs.fields(ConfigFile):
        if info.encode_name == key:
            return info.default
    raise KeyError(key)


# --- the resolved configuration --------------------------------------------------------------------------


@dataclass(frozen=True)
class InputSpec:
    """One model input: ``name`` <- ``message.signal`` in ``unit`` (a name of the unit table, or a custom
    unit with its scale and offset), stale after ``stale_after_s`` s of silence."""

    name: str
    message: str
    signal: str
    unit: str | Unit
    stale_after_s: float

    def signal_spec(self) -> SignalSpec:
        """The decoder's view of this input."""
        return SignalSpec(self.name, self.message, self.signal, self.unit)


@dataclass(frozen=True)
class HealthRate:
    """A health message of health_dbc and its broadcast rate, Hz."""

    message: str
    rate_hz: float


@dataclass(frozen=True)
class ServiceConfig:
    """The whole service configuration, resolved (:class:`ConfigFile` has every key with its default)."""

    source: Path
    engine_serial: str
    bus: Mapping[str, Any]
    reopen_backoff: Backoff
    dbc_paths: tuple[Path, ...]
    health_dbc: Path
    inputs: tuple[InputSpec, ...]
    health: tuple[HealthRate, ...]
    model: str
    estimator_name: str
    estimator: EstimatorSettings
    detector: DetectorSettings
    detector_symptom: str
    stale_predict_limit_s: float
    state_dir: Path
    sensor_fault: SensorFaultSettings
    no_frames_warning_s: float
    #: ``detector.calibrated_for``: fingerprint of the model the threshold was calibrated with (as
    #: ``ecu-monitor calibrate`` writes it, ecu_monitor.offline.calibration.model_fingerprint); None if not given.
    detector_calibrated_for: str | None
    #: ``detector.uncalibrated``: "refuse" (run exits 2 when the detector was not calibrated for the model) or
    #: "accept" (a test bench: run anyway, warning in every status line)
    detector_uncalibrated: str
    #: ``dbc``, ``dronecan`` or ``mavlink`` (:data:`PROTOCOLS`): how the inputs are read
    protocol: str
    #: the service as a DroneCAN node (used when protocol is dronecan)
    dronecan: DroneCanSettings
    #: the service on a MAVLink link (used when protocol is mavlink)
    mavlink: MavlinkSettings
    #: ``cylinders.models``: one model (preset name or resolved file path) per cylinder, in cylinder
    #: order; empty: every cylinder runs on ``model``.
    cylinder_models: tuple[str, ...]
    #: ``cylinders.spread_limit_c``: the CHT spread (hottest minus coldest estimate, degC) above which
    #: the service raises its spread alarm; None: no alarm.
    spread_limit_c: float | None
    #: ``cylinders.detectors``: one detector per cylinder, in cylinder order (each ``detector:`` with the
    #: entry's keys replaced, as ``ecu-monitor calibrate`` writes them); empty: every cylinder runs ``detector``.
    cylinder_detectors: tuple[DetectorSettings, ...]
    #: each ``cylinders.detectors`` entry's ``calibrated_for`` (its model's fingerprint; None: not given)
    cylinder_calibrated_for: tuple[str | None, ...]
    #: ``cylinders.cross_detector`` / ``cross_detectors``: one more detector per cylinder, on the
    #: cross-cylinder symptom (its symptom minus the median of the others', pipeline/step.py cross_step);
    #: empty: off. Each cylinder's state is the more severe of its two detectors' verdicts.
    cross_detectors: tuple[DetectorSettings | None, ...]
    #: each ``cylinders.cross_detectors`` entry's ``calibrated_for`` (None: not given)
    cross_calibrated_for: tuple[str | None, ...]
    #: ``events:``: the engine events' limits
    events: EngineEvents
    #: ``engine.overhaul_hours``, ``engine.tbo_hours``: the engine's hours since overhaul as last given (the
    #: history counts on from there) and its time between overhauls, h (None: not given)
    overhaul_hours: float | None
    tbo_hours: float | None
    #: ``wear:``: the across-flight detector's settings and the engine's nominal wear reference (None: learned
    #: from its own first flights)
    wear: WearSettings = dataclasses.field(default_factory=WearSettings)
    wear_reference: WearReference | None = None

    def cylinder_detector(self, number: int) -> DetectorSettings:
        """The detector settings of cylinder ``number`` (1-based): its ``cylinders.detectors`` entry, else
        ``detector``."""
        return self.cylinder_detectors[number - 1] if self.cylinder_detectors else self.detector

    def cross_detector(self, number: int) -> DetectorSettings | None:
        """The cross-cylinder detector of cylinder ``number`` (1-based), None when off (on that cylinder)."""
        return self.cross_detectors[number - 1] if self.cross_detectors else None

    @property
    def input_names(self) -> tuple[str, ...]:
        """Names of the mapped inputs, in config order."""
        return tuple(spec.name for spec in self.inputs)

    @property
    def cylinder_inputs(self) -> tuple[str, ...]:
        """The CHT input of each monitored cylinder, in cylinder order: ``("cht1_c", ..., "chtN_c")`` when
        two or more are mapped, else ``("cht_c",)``."""
        numbered = sorted(
            (int(match.group(1)), spec.name) for spec in self.inputs if (match := CYLINDER_INPUT.match(spec.name))
        )
        return tuple(name for _, name in numbered) if len(numbered) > 1 else (CHT_INPUT,)

    def load_cylinder_params(self) -> tuple[ThermalParams, ...]:
        """The model of each cylinder (``cylinders.models``, else ``model`` for all), in cylinder order."""
        if not self.cylinder_models:
            return (self.load_params(),) * len(self.cylinder_inputs)
        return tuple(self.replace(model=model, cylinder_models=()).load_params() for model in self.cylinder_models)

    def input(self, name: str) -> InputSpec:
        """The mapping of input ``name`` (KeyError if not mapped)."""
        for spec in self.inputs:
            if spec.name == name:
                return spec
        raise KeyError(name)

    def load_params(self) -> ThermalParams:
        """The thermal model named by ``model:`` (preset or file); ConfigError naming this file otherwise."""
        preset = MODEL_PRESETS.get(self.model)
        if preset is not None:
            return preset()
        try:
            return load_model(self.model)
        except ConfigError as exc:
            raise ConfigError(f"{self.source}: model: {exc}") from None

    def replace(self, **changes: Any) -> ServiceConfig:
        """A copy with some fields changed (e.g. another estimator for replay)."""
        return dataclasses.replace(self, **changes)


def load_config(path: str | os.PathLike[str]) -> ServiceConfig:
    """Read and validate a service configuration YAML file: a path, or a shipped config's name
    (``example.yaml``; :func:`ecu_monitor.shipped.resolve_file`)."""
    src = resolve_file(path, "config")
    return parse_config(load_yaml_file(src, "config file", ConfigError), src)


def parse_config(data: Any, src: str | os.PathLike[str]) -> ServiceConfig:
    """Validate already-parsed YAML ``data``; ``src`` names the file in messages and anchors relative paths."""
    source = Path(src)
    if isinstance(data, dict) and data.get("model") == MODEL_KIND and "heat_map" in data:
        raise ConfigError(f"{source}: this is a model file (model.yaml), not a service config: give it as --model")
    try:
        file = msgspec.convert(data, ConfigFile)
        if file.detector.file is not UNSET:
            data = {**data, "detector": detector_section(data, source)}
            file = msgspec.convert(data, ConfigFile)
    except msgspec.ValidationError as exc:
        raise validation_error(source, exc, data) from None
    return _Resolver(source).config(file, order=list(data["inputs"]))  # the inputs in the file's order


def detector_section(data: dict[str, Any], src: Path) -> Any:
    """The ``detector`` section of the config ``data`` (read from ``src``) with the keys of its ``detector.file``
    in place of that key: a detector file (relative to the config, else a shipped one: ``ecu-monitor files``)
    holding one ``detector:`` section, as calibrate writes it, so that configs of one engine share one reference.
    A key given in both places is an error (one place for each)."""
    section = data.get("detector")
    if not isinstance(section, dict) or "file" not in section:
        return section
    try:
        path = resolve_file(section["file"], "detector", base=src.parent)
    except ConfigError as exc:
        raise ConfigError(f"{src}: detector.file: {exc}") from None
    loaded = load_yaml_file(path, "detector file", ConfigError)
    try:
        msgspec.convert(loaded, _DetectorFile)
    except msgspec.ValidationError as exc:
        raise validation_error(path, exc, loaded, _DetectorFile) from None
    keys = loaded["detector"]
    if "file" in keys:
        raise ConfigError(f"{path}: detector.file: a detector file names no other")
    both = sorted(set(keys) & set(section))
    if both:
        raise ConfigError(f"{src}: detector.{both[0]}: given here and in the detector file {path}; give it once")
    return {**keys, **{key: value for key, value in section.items() if key != "file"}}


# --- from the file to the configuration: what a schema cannot check -------------------------------------


class _Resolver:
    """Resolves a checked :class:`ConfigFile` from ``src``: its files, signals, units and settings."""

    def __init__(self, src: Path) -> None:
        self.src = src
        self.databases: list[tuple[Path, Any]] = []

    def error(self, key: str, message: str) -> ConfigError:
        return ConfigError(f"{self.src}: {key}: {message}")

    def config(self, file: ConfigFile, order: list[str]) -> ServiceConfig:
        """The configuration; ``order``: the input names in the order of the file."""
        dronecan = DroneCanSettings()
        mavlink = MavlinkSettings()
        if file.protocol == "mavlink":
            mavlink = parse_mavlink_settings(None if file.mavlink is UNSET else file.mavlink, str(self.src))
        if file.protocol in ("dronecan", "mavlink"):
            if file.dronecan is not UNSET:
                dronecan = DroneCanSettings(**msgspec.structs.asdict(file.dronecan))
            health_name = str(shipped_dbc("health.dbc")) if file.health_dbc is UNSET else file.health_dbc
        else:
            names = [file.dbc] if isinstance(file.dbc, str) else list(file.dbc or ())
            for index, name in enumerate(names):
                path = self.dbc_file(f"dbc[{index}]", name)
                self.databases.append((path, self.load(f"dbc[{index}]", path)))
            health_name = str(file.health_dbc)
        health_dbc = self.dbc_file("health_dbc", health_name)
        health_db = self.load("health_dbc", health_dbc)

        inputs = self.inputs(file, order)
        if file.protocol == "mavlink":  # units against the MAVLink definitions; never echo the inputs' EFI_STATUS
            from ecu_monitor.bus.mavlink import MavlinkDecoder

            try:
                MavlinkDecoder([spec.signal_spec() for spec in inputs])
            except ConfigError as exc:
                raise self.error("inputs", str(exc)) from None
            if mavlink.efi_status_out and any(spec.message == "EFI_STATUS" for spec in inputs):
                raise self.error(
                    "mavlink.efi_status_out", "the inputs come from EFI_STATUS, which the service must not echo"
                )
        estimator = self.settings("", EstimatorSettings(), _given(file.estimator, EstimatorSettings))
        detector = self.settings("", DetectorSettings(), _given(file.detector, DetectorSettings))
        cylinders = file.cylinders
        count = _cylinder_count(order)
        return ServiceConfig(
            source=self.src,
            engine_serial=file.engine.serial,
            bus=MappingProxyType({} if file.bus is UNSET else dict(file.bus)),
            reopen_backoff=file.reopen_backoff_s,
            dbc_paths=tuple(path for path, _ in self.databases),
            health_dbc=health_dbc,
            inputs=inputs,
            health=self.health(file, health_db, estimator.dt_s),
            model=self.model_name("model", file.model),
            estimator_name=file.estimator.name,
            estimator=estimator,
            detector=detector,
            detector_symptom=file.detector.symptom,
            stale_predict_limit_s=file.stale_predict_limit_s,
            state_dir=_resolve(self.src, file.state_dir),
            sensor_fault=self.sensor_fault(file),
            no_frames_warning_s=file.no_frames_warning_s,
            detector_calibrated_for=file.detector.calibrated_for,
            detector_uncalibrated=file.detector.uncalibrated,
            protocol=file.protocol,
            dronecan=dronecan,
            mavlink=mavlink,
            cylinder_models=tuple(
                self.model_name(f"cylinders.models[{i}]", model) for i, model in enumerate(cylinders.models or ())
            ),
            spread_limit_c=None if cylinders.spread_limit_c is UNSET else cylinders.spread_limit_c,
            cylinder_detectors=tuple(
                self.settings(f"cylinders.detectors[{i}]", detector, _given(entry, DetectorSettings))
                for i, entry in enumerate(cylinders.detectors or ())
            ),
            cylinder_calibrated_for=tuple(entry.calibrated_for for entry in cylinders.detectors or ()),
            **self.cross_detectors(cylinders, count),
            events=file.events,
            overhaul_hours=file.engine.overhaul_hours,
            tbo_hours=file.engine.tbo_hours,
            wear=self.settings("", WearSettings(), _given(file.wear, WearSettings)),
            wear_reference=None
            if file.wear.reference is None
            else WearReference(file.wear.reference.mean, file.wear.reference.sd, file.wear.reference.flights),
        )

    def load(self, key: str, path: Path) -> Any:
        try:
            return load_dbc(path)
        except ConfigError as exc:
            raise self.error(key, str(exc)) from None

    def dbc_file(self, key: str, name: str) -> Path:
        """A DBC named in the config: a path relative to the config file, else a shipped DBC's name."""
        try:
            return resolve_file(name, "dbc", base=self.src.parent)
        except ConfigError as exc:
            raise self.error(key, str(exc)) from None

    def find(self, protocol: str, key: str, ref: str) -> tuple[str, str]:
        """``ref`` split into message and signal (protocol dbc: ``Message.Signal``, checked against the DBCs)
        or DroneCAN data type and field path (checked against the DSDL definitions)."""
        if protocol == "mavlink":
            from ecu_monitor.bus.mavlink import parse_field as parse_mavlink_field

            try:
                ref_path = parse_mavlink_field(ref)
            except ConfigError as exc:
                raise self.error(key, str(exc)) from None
            return ref_path.message, ref_path.text[len(ref_path.message) + 1 :]
        if protocol == "dronecan":
            from ecu_monitor.bus.dronecan import parse_field

            try:
                path = parse_field(ref)
            except ConfigError as exc:
                raise self.error(key, str(exc)) from None
            return path.type_name, path.text[len(path.type_name) + 1 :]
        if ref.count(".") != 1 or "" in ref.split("."):
            raise self.error(key, f"expected 'Message.Signal', got {_kind(ref)}")
        msg_name, sig_name = ref.split(".")
        for _, db in self.databases:
            message = db.find(msg_name)
            if message is not None:
                if sig_name not in {s.name for s in message.signals}:
                    known = ", ".join(s.name for s in message.signals)
                    raise self.error(key, f"message '{msg_name}' has no signal '{sig_name}' (signals: {known})")
                if msg_name in db.broken:
                    raise self.error(key, f"message '{msg_name}' cannot be used: {db.broken[msg_name]}")
                return msg_name, sig_name
        raise self.error(key, f"no message '{msg_name}' in {', '.join(str(p) for p, _ in self.databases)}")

    def inputs(self, file: ConfigFile, order: list[str]) -> tuple[InputSpec, ...]:
        dronecan = file.protocol == "dronecan"
        fields = file.protocol in ("dronecan", "mavlink")  # inputs name message fields, not DBC signals
        ref_key, other = ("field", "signal") if fields else ("signal", "field")
        specs: list[InputSpec] = []
        for name in order:
            entry: _Input = getattr(file.inputs, name)
            key = f"inputs.{name}"
            if getattr(entry, other) is not UNSET:
                raise self.error(f"{key}.{other}", f"unknown key '{other}' (known: {ref_key}, unit, stale_after_s)")
            ref = getattr(entry, ref_key)
            if ref is UNSET:
                raise self.error(f"{key}.{ref_key}", "missing")
            message, signal = self.find(file.protocol, f"{key}.{ref_key}", ref)
            quantity = INPUT_QUANTITIES.get(name, "temperature")
            if fields and name == "altitude_m" and _is_pressure(entry.unit):
                quantity = "pressure"  # a static pressure: its pressure altitude
            try:
                unit = _unit(entry.unit, quantity)
            except ValueError as exc:
                hint = (
                    " (or, for protocol dronecan or mavlink, a pressure unit: the pressure altitude)"
                    if name == "altitude_m"
                    else ""
                )
                raise self.error(f"{key}.unit", f"{exc}{hint}") from None
            specs.append(InputSpec(name, message, signal, unit, entry.stale_after_s))
        if dronecan and "altitude_m" not in order and "airspeed_mps" in order:
            # no altitude sent: the pressure altitude of the air-data computer's static pressure, as fresh as its
            # airspeed
            air = next(spec for spec in specs if spec.name == "airspeed_mps")
            message, signal = self.find(file.protocol, "inputs.altitude_m", DRONECAN_ALTITUDE_FIELD)
            specs.append(InputSpec("altitude_m", message, signal, "Pa", air.stale_after_s))
        return tuple(specs)

    def sensor_fault(self, file: ConfigFile) -> SensorFaultSettings:
        section = file.sensor_fault
        message = signal = None
        if section.status_signal is not None:
            message, signal = self.find(file.protocol, "sensor_fault.status_signal", section.status_signal)
        fields = msgspec.structs.asdict(section)
        return SensorFaultSettings(**{**fields, "status_signal": signal, "status_message": message})

    def health(self, file: ConfigFile, health_db: Any, dt_s: float) -> tuple[HealthRate, ...]:
        names = {m.name for m in health_db.messages}
        rates: list[HealthRate] = []
        for name, entry in msgspec.structs.asdict(file.health).items():
            if entry is UNSET:
                continue
            key = f"health.{name}"
            if name not in names:
                raise self.error(key, f"message not in health_dbc (it has: {', '.join(sorted(names))})")
            if entry.rate_hz > 1.0 / dt_s:
                raise self.error(
                    f"{key}.rate_hz", f"expected a number > 0 and <= {1.0 / dt_s:g}, got {entry.rate_hz!r}"
                )
            steps = 1.0 / (entry.rate_hz * dt_s)
            if abs(steps - round(steps)) > 1e-6:
                raise self.error(
                    f"{key}.rate_hz",
                    f"period 1/{entry.rate_hz:g} s is not a whole number of estimator steps of {dt_s:g} s",
                )
            rates.append(HealthRate(name, entry.rate_hz))
        if not any(r.message == "Health_Status" for r in rates):
            raise self.error("health.Health_Status", "missing (Health_Status is the frame the autopilot watches)")
        return tuple(rates)

    def model_name(self, key: str, value: str) -> str:
        """A ``model:`` value: a preset's name, or a model file (resolved against the config file)."""
        if value in MODEL_PRESETS:
            return value
        path = _resolve(self.src, value)
        if not path.is_file():
            raise self.error(key, f"no such model file {path} (or a preset: {', '.join(MODEL_PRESETS)})")
        return str(path)

    def settings(self, key: str, base: _Settings, changes: dict[str, Any]) -> _Settings:
        """``base`` with ``changes``: checked by the settings' own class (its message names the section's key;
        ``key``, the entry of a list, goes before it)."""
        try:
            return dataclasses.replace(base, **changes)
        except ConfigError as exc:
            raise ConfigError(f"{self.src}: {key + ': ' if key else ''}{exc}") from None

    def cross_detectors(self, section: _Cylinders, count: int) -> dict[str, Any]:
        """``cross_detectors`` and ``cross_calibrated_for`` of the ServiceConfig: either key turns them on."""
        if section.cross_detector is UNSET and section.cross_detectors is UNSET:
            return {"cross_detectors": (), "cross_calibrated_for": ()}
        base = DetectorSettings()
        if section.cross_detector is not UNSET:
            base = self.settings("cylinders.cross_detector", base, _given(section.cross_detector, DetectorSettings))
        if section.cross_detectors is UNSET:
            return {"cross_detectors": (base,) * count, "cross_calibrated_for": (None,) * count}
        detectors = tuple(
            None
            if entry is None
            else self.settings(f"cylinders.cross_detectors[{i}]", base, _given(entry, DetectorSettings))
            for i, entry in enumerate(section.cross_detectors)
        )
        marks = tuple(None if entry is None else entry.calibrated_for for entry in section.cross_detectors)
        return {"cross_detectors": detectors, "cross_calibrated_for": marks}


_Settings = typing.TypeVar("_Settings", EstimatorSettings, DetectorSettings)


def _unit(value: Any, quantity: str) -> str | Unit:
    """A unit name of the unit table, or a custom ``{scale: S, offset: O}`` unit (ValueError if neither)."""
    conversion = custom_unit(value, quantity)
    return value if isinstance(value, str) else conversion


def _is_pressure(value: Any) -> bool:
    """True for a unit of the unit table that measures a pressure."""
    try:
        return isinstance(value, str) and custom_unit(value).quantity == "pressure"
    except ValueError:
        return False


def _resolve(src: Path, value: str | os.PathLike[str]) -> Path:
    path = Path(os.path.expanduser(str(value)))
    return path if path.is_absolute() else (src.parent / path)


def _kind(value: Any) -> str:
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    if value is None:
        return "nothing"
    text = repr(value)
    if len(text) > 60:  # a CSV given as a config is one long YAML string: keep the message one short line
        text = f"{text[:50]}... ({len(text)} characters)"
    return f"{type(value).__name__} {text}"


# --- msgspec's ValidationError as our one line -----------------------------------------------------------

_AT = re.compile(r" - at `(?:key` in `)?(\$[^`]*)`$")
_STEP = re.compile(r"\.([^.\[]+)|\[(\d+|\.\.\.)\]")


def validation_error(src: Path, exc: msgspec.ValidationError, data: Any, root: type = ConfigFile) -> ConfigError:
    """msgspec's ``Expected `float`, got `str` - at `$.detector.threshold``` as
    ``<src>: detector.threshold: expected a number, got str 'abc'``: the key path, what the schema expects
    there (its description, else its type and range) and what the file has. ``root``: the file's schema
    (a service config's, or another YAML file's such as a fleet file)."""
    text = str(exc)
    at = _AT.search(text)
    path: list[str | int] = []
    for name, index in _STEP.findall(at.group(1)[1:] if at else ""):
        path.append(name or (int(index) if index.isdigit() else index))
    problem = text[: at.start()] if at else text
    cause = exc.__cause__
    if isinstance(cause, _SectionError):  # a section's __post_init__
        return ConfigError(f"{src}: {_where([*path, cause.key])}: {cause.message}")
    if isinstance(cause, ValueError | TypeError):
        return ConfigError(f"{src}: {_where(path)}: {cause}")
    if at is not None and "`key` in" in at.group(0):
        return ConfigError(f"{src}: {_where(path)}: keys must be strings")
    if match := re.fullmatch(r"Object missing required field `(.*)`", problem):
        return ConfigError(f"{src}: {_where([*path, match.group(1)])}: missing")
    if match := re.fullmatch(r"Object contains unknown field `(.*)`", problem):
        key = match.group(1)
        known = _known(_type_at(path, root))
        return ConfigError(f"{src}: {_where([*path, key])}: unknown key '{key}' (known: {known})")
    expected = _expected(_type_at(path, root)) or problem[:1].lower() + problem[1:]
    return ConfigError(f"{src}: {_where(path)}: expected {expected}, got {_kind(_value_at(data, path))}")


def _where(path: Iterable[str | int]) -> str:
    """``cylinders.detectors[1].threshold``, or ``top level``."""
    text = "".join(f"[{step}]" if isinstance(step, int) else f".{step}" for step in path if step != "")
    return text.lstrip(".") or "top level"


def _value_at(data: Any, path: list[str | int]) -> Any:
    for step in path:
        data = data[step]
    return data


def _options(kind: schema.Type | None) -> list[schema.Type]:
    """The types ``kind`` may be (unions and Annotated metadata opened, null left out)."""
    if isinstance(kind, schema.Metadata):
        return _options(kind.type)
    if isinstance(kind, schema.UnionType):
        return [option for member in kind.types for option in _options(member)]
    return [] if kind is None or isinstance(kind, schema.NoneType) else [kind]


def _type_at(path: list[str | int], root: type = ConfigFile) -> schema.Type | None:
    """The type of schema ``root`` at ``path`` in the file (None where it has none)."""
    kind: schema.Type | None = schema.type_info(root)
    for step in path:
        options = _options(kind)
        kind = None
        for option in options:
            if isinstance(step, str) and isinstance(option, schema.StructType):
                kind = next((f.type for f in option.fields if f.encode_name == step), None)
            elif isinstance(step, int) and isinstance(option, schema.ListType | schema.VarTupleType):
                kind = option.item_type
            if kind is not None:
                break
    return kind


def _known(kind: schema.Type | None) -> str:
    """The keys of the section of type ``kind`` (the cylinder inputs as one range)."""
    names = [f.encode_name for option in _options(kind) if isinstance(option, schema.StructType) for f in option.fields]
    egt = EVENT_INPUTS[:MAX_CYLINDERS]
    shown = [name for name in names if not CYLINDER_INPUT.match(name) and name not in egt]
    if len(shown) < len(names):
        shown.append(f"{_CYLINDER_NAMES[0]} .. {_CYLINDER_NAMES[-1]}")
        shown.append(f"{egt[0]} .. {egt[-1]}")
    return ", ".join(shown)


def _expected(kind: schema.Type | None) -> str:
    """What the schema expects of a value of type ``kind``, in words ("" if it cannot say)."""
    if isinstance(kind, schema.Metadata):
        return str((kind.extra_json_schema or {}).get("description") or _expected(kind.type))
    if isinstance(kind, schema.UnionType):
        members = (member for member in kind.types if not isinstance(member, schema.NoneType))
        return " or ".join(filter(None, map(_expected, members)))
    if isinstance(kind, schema.FloatType | schema.IntType):
        low = f"> {kind.gt:g}" if kind.gt is not None else f">= {kind.ge:g}" if kind.ge not in (None, -_MAX) else ""
        high = f"<= {kind.le:g}" if kind.le not in (None, _MAX) else ""
        bounds = " and ".join(filter(None, (low, high)))
        noun = "a number" if isinstance(kind, schema.FloatType) else "an integer"
        return f"{noun} {bounds}" if bounds else noun
    if isinstance(kind, schema.LiteralType):
        return f"one of {', '.join(map(str, kind.values))}"
    if isinstance(kind, schema.BoolType):
        return "true or false"
    if isinstance(kind, schema.StrType):
        return "a string"
    if isinstance(kind, schema.ListType | schema.VarTupleType):
        return "a list"
    return "a mapping" if isinstance(kind, schema.StructType | schema.DictType) else ""
