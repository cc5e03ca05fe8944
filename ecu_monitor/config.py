"""The service configuration: YAML -> frozen, validated dataclasses (docs/service.md, shipped example.yaml).

Every problem raises :class:`~ecu_monitor.errors.ConfigError` whose one-line message names the file,
the key path and what was expected, e.g. ``x.yaml: inputs.rpm.unit: unknown unit 'rps' ...``
(the CLI prints it and exits 2). Paths in the file are relative to the file itself. The input DBC
files are loaded (:func:`ecu_monitor.bus.dbc.load_dbc`) while validating, so a ``Message.Signal``
that is not in them, or in a message that fails the DBC's strict checks, is caught here, not at the
first frame. An input's ``unit`` is a name of :data:`ecu_monitor.units.UNITS` or, for a unit it does
not know, ``{scale: S, offset: O}`` (canonical value = raw physical value * S + O).

``protocol: dronecan`` (default ``dbc``) reads DroneCAN messages instead (:mod:`ecu_monitor.bus.dronecan`,
the shipped dronecan.yaml): each input names ``field: data.type.Name.field.path`` instead of
``signal:``, checked against the DSDL definitions at load; ``dbc`` is not used; the ``dronecan:``
section gives the service's node id and the accepted senders (:class:`DroneCanSettings`).

``protocol: mavlink`` reads an autopilot's MAVLink telemetry (:mod:`ecu_monitor.bus.mavlink`, the shipped
mavlink.yaml): each input names ``field: MESSAGE.field`` (checked against pymavlink's dialect, its unit
against the message definition); no ``dbc`` and no ``bus``; the ``mavlink:`` section
(:class:`~ecu_monitor.bus.mavlink_settings.MavlinkSettings`) gives the link and the service's ids.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import yaml

from ecu_monitor.bus.codec import INPUT_NAMES, INPUT_QUANTITIES, SignalSpec
from ecu_monitor.bus.dbc import load_dbc, shipped_dbc
from ecu_monitor.bus.mavlink_settings import MavlinkSettings, parse_mavlink_settings
from ecu_monitor.errors import ConfigError
from ecu_monitor.estimation import ESTIMATORS, EstimatorSettings
from ecu_monitor.estimation.detection import DetectorSettings
from ecu_monitor.model import ThermalParams, load_model, paper_table_a1
from ecu_monitor.shipped import DEFAULT_CONFIG, resolve_file
from ecu_monitor.units import Unit, custom_unit

__all__ = [
    "CHT_INPUT",
    "CYLINDER_HEALTH_MESSAGES",
    "CYLINDER_INPUT",
    "DEFAULT_CONFIG",
    "DRONECAN_ALTITUDE_FIELD",
    "HEALTH_MESSAGES",
    "MAX_CYLINDERS",
    "MODEL_PRESETS",
    "PROTOCOLS",
    "REQUIRED_INPUTS",
    "SYMPTOMS",
    "Backoff",
    "DroneCanSettings",
    "HealthRate",
    "InputSpec",
    "SensorFaultSettings",
    "ServiceConfig",
    "load_config",
    "parse_config",
]

#: Bus protocols of the inputs: DBC-described frames, DroneCAN messages, or an autopilot's MAVLink telemetry.
PROTOCOLS: tuple[str, ...] = ("dbc", "dronecan", "mavlink")
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
SYMPTOMS: tuple[str, ...] = ("estimator", "isolation")
#: Built-in model presets accepted by ``model:`` instead of a file.
MODEL_PRESETS = MappingProxyType({"paper_table_a1": paper_table_a1})

_TOP_KEYS = (
    "protocol",
    "dronecan",
    "mavlink",
    "engine",
    "bus",
    "reopen_backoff_s",
    "dbc",
    "health_dbc",
    "inputs",
    "health",
    "model",
    "estimator",
    "detector",
    "cylinders",
    "stale_predict_limit_s",
    "no_frames_warning_s",
    "rehearse_lead_ms",
    "spin_ms",
    "state_dir",
    "sensor_fault",
)


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
class DroneCanSettings:
    """The service as a DroneCAN node (docs/service.md, "DroneCAN").

    node_id: the service's node id (1..127), the source of its NodeStatus, KeyValue and LogMessage.
    source_node_ids: accept inputs only from these nodes (empty: from any node). priority: the CAN
    priority of the service's transfers (0 highest .. 31 lowest). key_value_hz: rate of the health
    values as uavcan.protocol.debug.KeyValue (0: none). log_messages: state changes as
    uavcan.protocol.debug.LogMessage. dbc_health_frames: send the health.dbc frames too.
    """

    node_id: int = 100
    source_node_ids: tuple[int, ...] = ()
    priority: int = 24
    key_value_hz: float = 1.0
    log_messages: bool = True
    dbc_health_frames: bool = False


@dataclass(frozen=True)
class HealthRate:
    """A health message of health_dbc and its broadcast rate, Hz."""

    message: str
    rate_hz: float


@dataclass(frozen=True)
class Backoff:
    """Delays between attempts to reopen a failed bus: initial, doubling up to max, s."""

    initial: float = 0.5
    max: float = 10.0


@dataclass(frozen=True)
class SensorFaultSettings:
    """CHT sensor plausibility.

    min_c, max_c: readings outside are an open / shorted probe, degC. stuck_after_s: a reading that
    has not changed for this long while the model predicts a change of at least stuck_change_c
    (degC) is stuck. status_message/status_signal/open_values: optional ECU status signal whose
    value in open_values reports an open probe (engine.dbc: ECU_Slow.EcuStatus = 3 CHT_SENSOR_OPEN).
    """

    stuck_after_s: float = 120.0
    min_c: float = -40.0
    max_c: float = 350.0
    stuck_change_c: float = 5.0
    status_message: str | None = None
    status_signal: str | None = None
    open_values: tuple[int, ...] = ()


@dataclass(frozen=True)
class ServiceConfig:
    """The whole service configuration (see the shipped example.yaml for every key with its meaning)."""

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
    sensor_fault: SensorFaultSettings = field(default_factory=SensorFaultSettings)
    #: the daemon logs a warning when its bus has carried no engine frame for this long, s
    no_frames_warning_s: float = 10.0
    #: the daemon rehearses a Health_Status step this long before its frame is due, ms; 0: never
    #: (docs/service.md, "Rehearsal")
    rehearse_lead_ms: float = 0.6
    #: after a rehearsal the daemon polls the bus without sleeping until the frame comes, at most this long past
    #: the time it is expected, ms; 0: it sleeps in recv (docs/service.md, "Rehearsal")
    spin_ms: float = 0.5
    #: ``detector.calibrated_for``: fingerprint of the model the threshold was calibrated with (as
    #: ``ecu-monitor calibrate`` writes it, ecu_monitor.offline.calibration.model_fingerprint); None if not given.
    detector_calibrated_for: str | None = None
    #: ``dbc`` or ``dronecan`` (:data:`PROTOCOLS`): how the inputs are read from the bus
    protocol: str = "dbc"
    #: the service as a DroneCAN node (used when protocol is dronecan)
    dronecan: DroneCanSettings = field(default_factory=DroneCanSettings)
    #: the service on a MAVLink link (used when protocol is mavlink)
    mavlink: MavlinkSettings = field(default_factory=MavlinkSettings)
    #: ``cylinders.models``: one model (preset name or resolved file path) per cylinder, in cylinder
    #: order; empty: every cylinder runs on ``model``.
    cylinder_models: tuple[str, ...] = ()
    #: ``cylinders.spread_limit_c``: the CHT spread (hottest minus coldest estimate, degC) above which
    #: the service raises its spread alarm; None: no alarm.
    spread_limit_c: float | None = None
    #: ``cylinders.detectors``: one detector per cylinder, in cylinder order (each ``detector:`` with the
    #: entry's keys replaced, as ``ecu-monitor calibrate`` writes them); empty: every cylinder runs ``detector``.
    cylinder_detectors: tuple[DetectorSettings, ...] = ()
    #: each ``cylinders.detectors`` entry's ``calibrated_for`` (its model's fingerprint; None: not given)
    cylinder_calibrated_for: tuple[str | None, ...] = ()
    #: ``cylinders.cross_detector`` / ``cross_detectors``: one more detector per cylinder, on the
    #: cross-cylinder symptom (its symptom minus the median of the others', estimation/cross_cylinder.py);
    #: empty: off. Each cylinder's state is the more severe of its two detectors' verdicts.
    cross_detectors: tuple[DetectorSettings | None, ...] = ()
    #: each ``cylinders.cross_detectors`` entry's ``calibrated_for`` (None: not given)
    cross_calibrated_for: tuple[str | None, ...] = ()

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


class _Node:
    """A mapping in the YAML with its key path, for messages naming file + key."""

    def __init__(self, src: Path, path: str, data: Any, allowed: tuple[str, ...] | None = None) -> None:
        self.src = src
        self.path = path
        if not isinstance(data, dict):
            raise self.error(f"expected a mapping, got {_kind(data)}")
        self.data: dict[Any, Any] = data
        if allowed is not None:
            for key in data:
                if key not in allowed:
                    raise self.error(f"unknown key '{key}' (known: {', '.join(allowed)})", key)

    def key(self, name: str) -> str:
        return f"{self.path}.{name}" if self.path else name

    def error(self, message: str, name: str | None = None) -> ConfigError:
        where = self.key(name) if name is not None else (self.path or "top level")
        return ConfigError(f"{self.src}: {where}: {message}")

    def has(self, name: str) -> bool:
        return name in self.data

    def raw(self, name: str, default: Any = ...) -> Any:
        if name not in self.data:
            if default is ...:
                raise self.error("missing", name)
            return default
        return self.data[name]

    def child(self, name: str, allowed: tuple[str, ...] | None = None, default: Any = ...) -> _Node:
        return _Node(self.src, self.key(name), self.raw(name, default), allowed)

    def string(self, name: str, default: Any = ...) -> str:
        value = self.raw(name, default)
        if not isinstance(value, str) or not value.strip():
            raise self.error(f"expected a non-empty string, got {_kind(value)}", name)
        return value

    def number(
        self, name: str, default: Any = ..., *, low: float = -math.inf, high: float = math.inf, strict_low: bool = False
    ) -> float:
        value = self.raw(name, default)
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.error(f"expected a number, got {_kind(value)}", name)
        below = value <= low if strict_low else value < low
        if below or value > high:
            bound = f"> {low:g}" if strict_low else f">= {low:g}"
            rng = bound if high == math.inf else f"{bound} and <= {high:g}"
            raise self.error(f"expected a number {rng}, got {value!r}", name)
        return float(value)

    def path_value(self, name: str, default: Any = ...) -> Path:
        value = self.raw(name, default)
        if not isinstance(value, str | os.PathLike) or not str(value).strip():
            raise self.error(f"expected a file path, got {_kind(value)}", name)
        return _resolve(self.src, value)


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


def _resolve(src: Path, value: str | os.PathLike[str]) -> Path:
    path = Path(os.path.expanduser(str(value)))
    return path if path.is_absolute() else (src.parent / path)


def load_config(path: str | os.PathLike[str]) -> ServiceConfig:
    """Read and validate a service configuration YAML file: a path, or a shipped config's name
    (``example.yaml``; :func:`ecu_monitor.shipped.resolve_file`)."""
    src = resolve_file(path, "config")
    try:
        text = src.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else "not UTF-8 text"
        raise ConfigError(f"{src}: cannot read config file ({reason})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{src}: not valid YAML{where}: {problem}") from None
    return parse_config(data, src)


def parse_config(data: Any, src: str | os.PathLike[str]) -> ServiceConfig:
    """Validate already-parsed YAML ``data``; ``src`` names the file in messages and anchors relative paths."""
    source = Path(src)
    top = _Node(source, "", data, _TOP_KEYS)

    engine = top.child("engine", ("serial",))
    serial = engine.string("serial")

    protocol = top.raw("protocol", "dbc")
    if protocol == "mavlink":  # the link is mavlink.connection, not a CAN bus
        if top.has("bus"):
            raise top.error("does not apply to protocol mavlink (the link is mavlink.connection)", "bus")
        bus = _Node(source, "bus", {})
    else:
        bus = top.child("bus")
        bus.string("interface")
        if not bus.has("channel"):
            raise bus.error("missing", "channel")
    for key in bus.data:
        if not isinstance(key, str):
            raise bus.error(f"keys must be strings, got {key!r}")

    backoff_node = top.child("reopen_backoff_s", ("initial", "max"), {})
    initial = backoff_node.number("initial", 0.5, low=0.0, strict_low=True)
    backoff = Backoff(initial, backoff_node.number("max", 10.0, low=initial))

    if protocol not in PROTOCOLS:
        raise top.error(f"expected one of {', '.join(PROTOCOLS)}, got {_kind(protocol)}", "protocol")
    if protocol != "mavlink" and top.has("mavlink"):
        raise top.error("applies to protocol mavlink only (add protocol: mavlink)", "mavlink")
    mavlink = parse_mavlink_settings(top.raw("mavlink", None), str(source)) if protocol == "mavlink" else None
    if protocol in ("dronecan", "mavlink"):
        if top.has("dbc"):
            raise top.error(f"input DBC files do not apply to protocol {protocol} (inputs name its fields)", "dbc")
        dbc_paths: tuple[Path, ...] = ()
        databases: list[tuple[Path, Any]] = []
        dronecan = _dronecan(top) if protocol == "dronecan" else DroneCanSettings()
        health_dbc = _dbc_file(top, "health_dbc", top.raw("health_dbc", str(shipped_dbc("health.dbc"))))
    else:
        if top.has("dronecan"):
            raise top.error("applies to protocol dronecan only (add protocol: dronecan)", "dronecan")
        dbc_paths, databases = _dbc_list(top)
        dronecan = DroneCanSettings()
        health_dbc = _dbc_file(top, "health_dbc", top.raw("health_dbc"))
    health_db = _load(top, "health_dbc", health_dbc)
    find = {"dronecan": _find_field, "mavlink": _find_mavlink_field}.get(protocol, _find_signal)

    sensor_node = top.child(
        "sensor_fault", ("stuck_after_s", "min_c", "max_c", "stuck_change_c", "status_signal", "open_values"), {}
    )
    sensor = _sensor_fault(sensor_node, databases, find)

    inputs = _inputs(top, databases, protocol)
    if mavlink is not None:  # units against the MAVLink definitions; the service never echoes its inputs' EFI_STATUS
        from ecu_monitor.bus.mavlink import MavlinkDecoder

        try:
            MavlinkDecoder([spec.signal_spec() for spec in inputs])
        except ConfigError as exc:
            raise top.error(str(exc), "inputs") from None
        if mavlink.efi_status_out and any(spec.message == "EFI_STATUS" for spec in inputs):
            raise top.error(
                "efi_status_out: the inputs come from EFI_STATUS, which the service must not echo", "mavlink"
            )
    if sensor.status_message is not None and _cylinder_count(inputs) > 1:
        raise sensor_node.error(
            "an ECU status signal reports one probe: not with cht1_c .. chtN_c (each cylinder's probe is"
            " checked by range and the stuck test)",
            "status_signal",
        )
    estimator_name, estimator = _estimator(top)
    health = _health(top, health_db, estimator.dt_s)

    model = _model_name(top, "model", top.raw("model", "paper_table_a1"))

    detector, symptom, calibrated_for = _detector(top)
    cylinder_models, spread_limit, cylinder_detectors, cylinder_calibrated_for = _cylinders(top, inputs, detector)
    cross_detectors, cross_calibrated_for = _cross_detectors(top, inputs)

    return ServiceConfig(
        source=source,
        engine_serial=serial,
        bus=MappingProxyType(dict(bus.data)),
        reopen_backoff=backoff,
        dbc_paths=dbc_paths,
        health_dbc=health_dbc,
        inputs=inputs,
        health=health,
        model=model,
        estimator_name=estimator_name,
        estimator=estimator,
        detector=detector,
        detector_symptom=symptom,
        stale_predict_limit_s=top.number("stale_predict_limit_s", 30.0, low=0.0),
        state_dir=top.path_value("state_dir", "/var/lib/ecu-monitor"),
        sensor_fault=sensor,
        no_frames_warning_s=top.number("no_frames_warning_s", 10.0, low=0.0, strict_low=True),
        rehearse_lead_ms=top.number("rehearse_lead_ms", 0.6, low=0.0, high=10.0),
        spin_ms=top.number("spin_ms", 0.5, low=0.0, high=10.0),
        detector_calibrated_for=calibrated_for,
        protocol=protocol,
        dronecan=dronecan,
        mavlink=mavlink or MavlinkSettings(),
        cylinder_models=cylinder_models,
        spread_limit_c=spread_limit,
        cylinder_detectors=cylinder_detectors,
        cylinder_calibrated_for=cylinder_calibrated_for,
        cross_detectors=cross_detectors,
        cross_calibrated_for=cross_calibrated_for,
    )


def _model_name(node: _Node, key: str, value: Any) -> str:
    """A ``model:`` value: a preset's name, or a model file (resolved against the config file)."""
    if not isinstance(value, str) or not value.strip():
        presets = ", ".join(MODEL_PRESETS)
        raise node.error(f"expected a preset name ({presets}) or a file path, got {_kind(value)}", key)
    if value in MODEL_PRESETS:
        return value
    path = _resolve(node.src, value)
    if not path.is_file():
        raise node.error(f"no such model file {path} (or a preset: {', '.join(MODEL_PRESETS)})", key)
    return str(path)


def _cylinders(
    top: _Node, inputs: tuple[InputSpec, ...], detector: DetectorSettings
) -> tuple[tuple[str, ...], float | None, tuple[DetectorSettings, ...], tuple[str | None, ...]]:
    """``cylinders:``: one model per cylinder (optional), the CHT spread limit (optional) and one
    detector per cylinder (optional; each entry replaces keys of ``detector``)."""
    node = top.child("cylinders", ("models", "spread_limit_c", "detectors", "cross_detector", "cross_detectors"), {})
    count = _cylinder_count(inputs)
    models: tuple[str, ...] = ()
    if node.has("models"):
        items = node.raw("models")
        if not isinstance(items, list) or len(items) != count:
            raise node.error(f"expected a list of {count} models, one per cylinder, got {_kind(items)}", "models")
        models = tuple(_model_name(node, f"models[{i}]", item) for i, item in enumerate(items))
    limit = node.number("spread_limit_c", low=0.0, strict_low=True) if node.has("spread_limit_c") else None
    detectors: tuple[DetectorSettings, ...] = ()
    if node.has("detectors"):
        items = node.raw("detectors")
        if count < 2 or not isinstance(items, list) or len(items) != count:
            raise node.error(
                f"expected a list of {count} detectors, one per cylinder (cht1_c .. chtN_c), got {_kind(items)}",
                "detectors",
            )
        entries = [_Node(node.src, f"{node.key('detectors')}[{i}]", item) for i, item in enumerate(items)]
        detectors = tuple(_cylinder_detector(entry, detector) for entry in entries)
        calibrated_for = tuple(entry.data.get("calibrated_for") for entry in entries)
        return models, limit, detectors, calibrated_for
    return models, limit, detectors, ()


def _cross_detectors(
    top: _Node, inputs: tuple[InputSpec, ...]
) -> tuple[tuple[DetectorSettings | None, ...], tuple[str | None, ...]]:
    """``cylinders.cross_detector`` (the cross-cylinder detector of every cylinder: DetectorSettings'
    defaults with the keys given replaced) and ``cylinders.cross_detectors`` (one per cylinder, each
    replacing keys of ``cross_detector``, or null: none on that cylinder, as ``ecu-monitor calibrate``
    writes them); either turns it on."""
    node = top.child("cylinders", None, {})
    if not (node.has("cross_detector") or node.has("cross_detectors")):
        return (), ()
    count = _cylinder_count(inputs)
    if count < 2:
        key = "cross_detector" if node.has("cross_detector") else "cross_detectors"
        raise node.error("compares cylinders: needs two or more CHT channels (cht1_c .. chtN_c)", key)
    base = DetectorSettings()
    if node.has("cross_detector"):
        base = _cylinder_detector(node.child("cross_detector"), base)
    if not node.has("cross_detectors"):
        return (base,) * count, (None,) * count
    items = node.raw("cross_detectors")
    if not isinstance(items, list) or len(items) != count:
        raise node.error(
            f"expected a list of {count} detectors, one per cylinder (cht1_c .. chtN_c), got {_kind(items)}",
            "cross_detectors",
        )
    detectors: list[DetectorSettings | None] = []
    calibrated_for: list[str | None] = []
    for i, item in enumerate(items):  # null: no cross-cylinder detector on this cylinder
        entry = None if item is None else _Node(node.src, f"{node.key('cross_detectors')}[{i}]", item)
        detectors.append(None if entry is None else _cylinder_detector(entry, base))
        calibrated_for.append(None if entry is None else entry.data.get("calibrated_for"))
    return tuple(detectors), tuple(calibrated_for)


def _cylinder_detector(node: _Node, detector: DetectorSettings) -> DetectorSettings:
    """One ``cylinders.detectors`` entry: ``detector`` with the entry's keys replaced (``calibrated_for``,
    the fingerprint of the cylinder's model, is checked and kept only as a record)."""
    known = {f.name for f in dataclasses.fields(DetectorSettings)}
    kwargs = {}
    for key, value in node.data.items():
        if key == "calibrated_for":
            if not (isinstance(value, str) and re.fullmatch(r"[0-9a-f]{16}", value)):
                raise node.error(f"expected 16 hex digits (a model fingerprint), got {_kind(value)}", key)
            continue
        if key not in known:
            raise node.error(f"unknown key '{key}' (known: calibrated_for, {', '.join(sorted(known))})", key)
        kwargs[key] = value
    try:
        return dataclasses.replace(detector, **kwargs)
    except ConfigError as exc:
        raise node.error(str(exc)) from None


def _load(node: _Node, key: str, path: Path) -> Any:
    try:
        return load_dbc(path)
    except ConfigError as exc:
        raise node.error(str(exc), key) from None


def _dbc_file(top: _Node, key: str, value: Any) -> Path:
    """A DBC named in the config: a path relative to the config file, else a shipped DBC's name."""
    if not isinstance(value, str | os.PathLike) or not str(value).strip():
        raise top.error(f"expected a file path, got {_kind(value)}", key)
    try:
        return resolve_file(value, "dbc", base=top.src.parent)
    except ConfigError as exc:
        raise top.error(str(exc), key) from None


def _dbc_list(top: _Node) -> tuple[tuple[Path, ...], list[tuple[Path, Any]]]:
    value = top.raw("dbc")
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list) or not items:
        raise top.error(f"expected a DBC file path or a non-empty list of them, got {_kind(value)}", "dbc")
    paths: list[Path] = []
    databases: list[tuple[Path, Any]] = []
    for index, item in enumerate(items):
        path = _dbc_file(top, f"dbc[{index}]", item)
        databases.append((path, _load(top, f"dbc[{index}]", path)))
        paths.append(path)
    return tuple(paths), databases


def _find_signal(node: _Node, key: str, ref: Any, databases: list[tuple[Path, Any]]) -> tuple[str, str]:
    """Split and check ``Message.Signal`` against the DBCs."""
    if not isinstance(ref, str) or ref.count(".") != 1 or "" in ref.split("."):
        raise node.error(f"expected 'Message.Signal', got {_kind(ref)}", key)
    msg_name, sig_name = ref.split(".")
    files = ", ".join(str(p) for p, _ in databases)
    for _, db in databases:
        message = db.find(msg_name)
        if message is not None:
            if sig_name not in {s.name for s in message.signals}:
                known = ", ".join(s.name for s in message.signals)
                raise node.error(f"message '{msg_name}' has no signal '{sig_name}' (signals: {known})", key)
            if msg_name in db.broken:
                raise node.error(f"message '{msg_name}' cannot be used: {db.broken[msg_name]}", key)
            return msg_name, sig_name
    raise node.error(f"no message '{msg_name}' in {files}", key)


def _find_field(node: _Node, key: str, ref: Any, databases: list[tuple[Path, Any]]) -> tuple[str, str]:
    """Split and check ``data.type.Name.field.path`` against the DroneCAN DSDL definitions."""
    from ecu_monitor.bus.dronecan import parse_field

    try:
        path = parse_field(ref)
    except ConfigError as exc:
        raise node.error(str(exc), key) from None
    return path.type_name, path.text[len(path.type_name) + 1 :]


def _find_mavlink_field(node: _Node, key: str, ref: Any, databases: list[tuple[Path, Any]]) -> tuple[str, str]:
    """Split and check ``MESSAGE.field`` against pymavlink's MAVLink dialect."""
    from ecu_monitor.bus.mavlink import parse_field as parse_mavlink_field

    try:
        path = parse_mavlink_field(ref)
    except ConfigError as exc:
        raise node.error(str(exc), key) from None
    return path.message, path.text[len(path.message) + 1 :]


def _dronecan(top: _Node) -> DroneCanSettings:
    keys = ("node_id", "source_node_ids", "priority", "key_value_hz", "log_messages", "dbc_health_frames")
    node = top.child("dronecan", keys)
    node_id = node.raw("node_id")
    if type(node_id) is not int or not 1 <= node_id <= 127:
        raise node.error(f"expected a node id 1..127, got {_kind(node_id)}", "node_id")
    sources = node.raw("source_node_ids", [])
    if not isinstance(sources, list) or not all(type(n) is int and 1 <= n <= 127 for n in sources):
        raise node.error(f"expected a list of node ids 1..127, got {_kind(sources)}", "source_node_ids")
    if node_id in sources:
        raise node.error(f"lists the service's own node id {node_id}", "source_node_ids")
    priority = node.raw("priority", 24)
    if type(priority) is not int or not 0 <= priority <= 31:
        raise node.error(f"expected a CAN priority 0..31, got {_kind(priority)}", "priority")
    flags = {}
    for key, default in (("log_messages", True), ("dbc_health_frames", False)):
        value = node.raw(key, default)
        if not isinstance(value, bool):
            raise node.error(f"expected true or false, got {_kind(value)}", key)
        flags[key] = value
    return DroneCanSettings(
        node_id=node_id,
        source_node_ids=tuple(sources),
        priority=priority,
        key_value_hz=node.number("key_value_hz", 1.0, low=0.0, high=10.0),
        **flags,
    )


def _unit(value: Any, quantity: str) -> str | Unit:
    """A unit name of the unit table, or a custom ``{scale: S, offset: O}`` unit (ValueError if neither)."""
    conversion = custom_unit(value, quantity)
    return value if isinstance(value, str) else conversion


def _inputs(top: _Node, databases: list[tuple[Path, Any]], protocol: str = "dbc") -> tuple[InputSpec, ...]:
    node = top.child("inputs")
    dronecan = protocol == "dronecan"
    ref_key = "field" if protocol in ("dronecan", "mavlink") else "signal"
    specs: list[InputSpec] = []
    for name in node.data:
        if name not in INPUT_NAMES and not (isinstance(name, str) and CYLINDER_INPUT.match(name)):
            raise node.error(f"unknown key '{name}' (known: {', '.join(INPUT_NAMES)}, cht1_c .. cht16_c)", name)
        item = node.child(name, (ref_key, "unit", "stale_after_s"))
        find = {"dronecan": _find_field, "mavlink": _find_mavlink_field}.get(protocol, _find_signal)
        message, signal = find(item, ref_key, item.raw(ref_key), databases)
        quantity = INPUT_QUANTITIES.get(name, "temperature")
        try:
            if ref_key == "field" and name == "altitude_m" and _is_pressure(item.raw("unit")):
                unit = _unit(item.raw("unit"), "pressure")  # a static pressure: its pressure altitude
            else:
                unit = _unit(item.raw("unit"), quantity)
        except ValueError as exc:
            hint = (
                " (or, for protocol dronecan or mavlink, a pressure unit: the pressure altitude)"
                if name == "altitude_m"
                else ""
            )
            raise item.error(f"{exc}{hint}", "unit") from None
        stale = item.number("stale_after_s", low=0.0, strict_low=True)
        specs.append(InputSpec(name, message, signal, unit, stale))
    if dronecan and "altitude_m" not in node.data and "airspeed_mps" in node.data:
        # no altitude sent: the pressure altitude of the air-data computer's static pressure, as fresh as its airspeed
        air = next(spec for spec in specs if spec.name == "airspeed_mps")
        message, signal = _find_field(node, "altitude_m", DRONECAN_ALTITUDE_FIELD, databases)
        specs.append(InputSpec("altitude_m", message, signal, "Pa", air.stale_after_s))
    matches = [CYLINDER_INPUT.match(name) for name in node.data if isinstance(name, str)]
    numbers = sorted(int(m.group(1)) for m in matches if m is not None)
    if numbers and numbers != list(range(1, len(numbers) + 1)):
        raise node.error(
            f"cylinders must be numbered 1 .. N (N <= {MAX_CYLINDERS}) without gaps, got"
            f" {', '.join(f'cht{n}_c' for n in numbers)}"
        )
    mapped = {spec.name for spec in specs}
    for name in REQUIRED_INPUTS:
        if name not in mapped and not (name == CHT_INPUT and len(numbers) > 1):
            raise node.error(
                f"missing (every configuration maps {', '.join(REQUIRED_INPUTS)}; cht_c or cht1_c .. chtN_c)", name
            )
    return tuple(specs)


def _cylinder_count(inputs: tuple[InputSpec, ...]) -> int:
    """Cylinders monitored: the numbered CHT inputs when two or more are mapped, else 1 (``cht_c``)."""
    count = sum(1 for spec in inputs if CYLINDER_INPUT.match(spec.name))
    return count if count > 1 else 1


def _is_pressure(value: Any) -> bool:
    """True for a unit of the unit table that measures a pressure."""
    try:
        return isinstance(value, str) and custom_unit(value).quantity == "pressure"
    except ValueError:
        return False


def _health(top: _Node, health_db: Any, dt_s: float) -> tuple[HealthRate, ...]:
    defaults = {name: {"rate_hz": rate} for name, rate in HEALTH_MESSAGES.items()}
    node = top.child("health", (*HEALTH_MESSAGES, *CYLINDER_HEALTH_MESSAGES), defaults)
    names = {m.name for m in health_db.messages}
    rates: list[HealthRate] = []
    for name in node.data:
        if name not in names:
            raise node.error(f"message not in health_dbc (it has: {', '.join(sorted(names))})", name)
        item = node.child(name, ("rate_hz",))
        rate = item.number("rate_hz", low=0.0, strict_low=True, high=1.0 / dt_s)
        steps = 1.0 / (rate * dt_s)
        if abs(steps - round(steps)) > 1e-6:
            raise item.error(f"period 1/{rate:g} s is not a whole number of estimator steps of {dt_s:g} s", "rate_hz")
        rates.append(HealthRate(name, rate))
    if not any(r.message == "Health_Status" for r in rates):
        raise node.error("missing (Health_Status is the frame the autopilot watches)", "Health_Status")
    return tuple(rates)


def _estimator(top: _Node) -> tuple[str, EstimatorSettings]:
    node = top.child("estimator", None, {"name": "cbekf-au"})
    name = node.string("name", "cbekf-au")
    if name not in ESTIMATORS:
        raise node.error(f"unknown estimator {name!r} (known: {', '.join(sorted(ESTIMATORS))})", "name")
    known = {f.name for f in dataclasses.fields(EstimatorSettings)}
    kwargs = {}
    for key, value in node.data.items():
        if key == "name":
            continue
        if key not in known:
            raise node.error(f"unknown key '{key}' (known: name, {', '.join(sorted(known))})", key)
        kwargs[key] = value
    try:
        settings = EstimatorSettings(**kwargs)
    except ConfigError as exc:
        raise ConfigError(f"{top.src}: {exc}") from None
    return name, settings


def _detector(top: _Node) -> tuple[DetectorSettings, str, str | None]:
    node = top.child("detector", None, {})
    symptom = node.raw("symptom", "estimator")
    if symptom not in SYMPTOMS:
        raise node.error(f"expected one of {', '.join(SYMPTOMS)}, got {_kind(symptom)}", "symptom")
    calibrated_for = node.raw("calibrated_for", None)
    if calibrated_for is not None and not (
        isinstance(calibrated_for, str) and re.fullmatch(r"[0-9a-f]{16}", calibrated_for)
    ):
        raise node.error(f"expected 16 hex digits (a model fingerprint), got {_kind(calibrated_for)}", "calibrated_for")
    known = {f.name for f in dataclasses.fields(DetectorSettings)}
    kwargs = {}
    for key, value in node.data.items():
        if key in ("symptom", "calibrated_for"):
            continue
        if key not in known:
            raise node.error(f"unknown key '{key}' (known: symptom, calibrated_for, {', '.join(sorted(known))})", key)
        kwargs[key] = value
    try:
        return DetectorSettings(**kwargs), symptom, calibrated_for
    except ConfigError as exc:
        raise ConfigError(f"{top.src}: {exc}") from None


def _sensor_fault(node: _Node, databases: list[tuple[Path, Any]], find: Any = None) -> SensorFaultSettings:
    min_c = node.number("min_c", -40.0)
    max_c = node.number("max_c", 350.0, low=min_c, strict_low=True)
    status_message = status_signal = None
    open_values: tuple[int, ...] = ()
    if node.has("status_signal"):
        status_message, status_signal = (find or _find_signal)(
            node, "status_signal", node.raw("status_signal"), databases
        )
        values = node.raw("open_values")
        if not isinstance(values, list) or not values or not all(type(v) is int for v in values):
            raise node.error(f"expected a non-empty list of integers, got {_kind(values)}", "open_values")
        open_values = tuple(values)
    elif node.has("open_values"):
        raise node.error("given without status_signal", "open_values")
    return SensorFaultSettings(
        stuck_after_s=node.number("stuck_after_s", 120.0, low=0.0, strict_low=True),
        min_c=min_c,
        max_c=max_c,
        stuck_change_c=node.number("stuck_change_c", 5.0, low=0.0, strict_low=True),
        status_message=status_message,
        status_signal=status_signal,
        open_values=open_values,
    )
