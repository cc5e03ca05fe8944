"""The output table: every health value the service produces, one row each (:data:`HEALTH_VALUES`).

Everything that carries a health value is made from this table: the step's output record
(``CYLINDER_OUTPUT`` in step.py: the ``cylinder`` rows), the snapshots (:class:`HealthSnapshot`,
:class:`CylinderSnapshot`: one attribute per row), health.csv's columns (pipeline/outputs.py), the
health.dbc signals (runtime/publishers.py), the DroneCAN KeyValues (runtime/dronecan_node.py), the
MAVLink NAMED_VALUE_FLOAT names (runtime/mavlink_publisher.py) and the flight history's trend columns
in SQLite (runtime/flight_recorder.py, runtime/persistence.py).

**Adding a health value** (a detector-armed flag, a not-isolable flag, a maintenance alert, an engine
event count, ...): append one :class:`HealthValue` row to :data:`HEALTH_VALUES`, add its signal to
``data/dbc/health.dbc`` (when it goes on the bus), and compute it: a ``cylinder`` row in the step
(``out["<name>"] = ...`` in ``step.cylinder_step``; the output record gains the field from the row); an
``engine`` or ``cylinders`` row in ``cylinders.engine_snapshot`` (live, and replays of several cylinders)
and, for an ``engine`` row, in the one-channel replay's columns (``offline/replay._columns``). health.csv
gains its column (after the others of its group), the snapshots its attribute, each publisher sends it
under the name its column gives (an empty name: not sent there), the flight history keeps its trend when
``history``. Then list it in docs/contracts.md and docs/dbc.md; a signal added to a message already sent
changes that message's bytes: rewrite the golden digests (tests/runtime/test_health_frames_golden.py).
Nothing else names the value.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any, ClassVar, Literal, NamedTuple

__all__ = [
    "HEADROOM_CAP_S",
    "HEALTH_VALUES",
    "STATES",
    "STATE_CONCERN",
    "CylinderSnapshot",
    "HealthSnapshot",
    "HealthValue",
    "as_number",
    "bus_number",
    "cylinder_snapshot",
    "cylinder_values",
    "engine_values",
    "output_fields",
]

#: DegradationState values of health.dbc, by code (the ``state`` rows' values; pipeline/supervision.py
#: decides them).
STATES: tuple[str, ...] = ("NOMINAL", "SUSPECT", "DEGRADED", "INPUT_STALE", "SENSOR_FAULT", "UNAVAILABLE")
#: The states ranked from best to worst by concern (a flight's worst state: the flight history, the fleet).
STATE_CONCERN = {"NOMINAL": 0, "INPUT_STALE": 1, "UNAVAILABLE": 2, "SENSOR_FAULT": 3, "SUSPECT": 4, "DEGRADED": 5}
#: Headroom reported when the limit is not reached within this time, s: the headroom's "not limited at
#: this power" (the step's march to the limit stops there).
HEADROOM_CAP_S = 6000.0

#: What a value is: a float (nan: not available), a state (one of STATES; its code on the bus and in the
#: step's record), a flag (0/1), a cylinder's number (1-based, 0: none), or a set of input names (the
#: stale inputs). A count or any other number is a float.
Kind = Literal["float", "state", "flag", "cylinder", "inputs"]
#: Whose value it is: ``cylinder`` each cylinder's (the engine's is its lead cylinder's); ``engine`` one
#: per row; ``cylinders`` one per row, only on an engine monitored per cylinder.
Scope = Literal["cylinder", "engine", "cylinders"]


class HealthValue(NamedTuple):
    """One health value: one row of the output table.

    name: the snapshot attribute and health.csv column (``cyl{n}_<name>`` per cylinder); unit; kind;
    scope (see :data:`Kind`, :data:`Scope`); csv: a column of health.csv; idle: what the bus carries
    instead of nan (its "no value"); idle_unestimated: the same while the CHT has no estimate (default
    ``idle``); dbc: ``Message.Signal`` of the engine's value in health.dbc; cylinder_dbc: its signal in
    the per-cylinder frame; dronecan: the KeyValue key of the engine's value; dronecan_cylinder: the key
    of cylinder n's (``{n}`` in it); mavlink: the NAMED_VALUE_FLOAT name (``{n}`` in it: one per
    cylinder, 1 for one CHT channel); history: the flight history (SQLite) keeps its trend per flight
    and per cylinder (start, end, mean, max, slope per hour; a ``cylinder`` row). An empty name: not
    published there. Publisher names are at most 10 characters (MAVLink's limit).
    """

    name: str
    unit: str
    kind: Kind = "float"
    scope: Scope = "cylinder"
    csv: bool = True
    idle: float = math.nan
    idle_unestimated: float | None = None
    dbc: str = ""
    cylinder_dbc: str = ""
    dronecan: str = ""
    dronecan_cylinder: str = ""
    mavlink: str = ""
    history: bool = False

    def default(self) -> Any:
        """The value before any step: nan, UNAVAILABLE, False, 0 or no inputs."""
        return {"float": math.nan, "state": STATES[-1], "flag": False, "cylinder": 0, "inputs": ()}[self.kind]


#: The output table, in health.csv's column order (engine columns, then each cylinder's ``cylinder``
#: rows, then the ``cylinders`` rows). New rows go at the end (module docstring).
HEALTH_VALUES: tuple[HealthValue, ...] = (
    HealthValue("time_s", "s", scope="engine"),
    HealthValue("cht_meas_c", "degC", dronecan="cht_meas"),
    HealthValue("cht_est_c", "degC", idle=-40.0, dbc="Health_Status.ChtEstimate",
                cylinder_dbc="Health_Cylinder.CylChtEstimate", dronecan="cht_est", dronecan_cylinder="cyl{n}_est",
                mavlink="CHT{n}_EST"),
    HealthValue("deviation", "degC/s", idle=0.0, dbc="Health_Status.ModelDeviation", dronecan="cht_dev",
                mavlink="ENG_DEV"),
    HealthValue("state", "", "state", dbc="Health_Status.DegradationState", cylinder_dbc="Health_Cylinder.CylState",
                dronecan="state", dronecan_cylinder="cyl{n}_st", mavlink="ENG_ST"),
    HealthValue("gamma_q", "", idle=1.0, dbc="Health_Isolation.GammaQEstimate",
                cylinder_dbc="Health_Cylinder.CylGammaQ", dronecan="gamma_q", dronecan_cylinder="cyl{n}_gq",
                mavlink="GAMMA_Q", history=True),
    HealthValue("gamma_d", "", idle=1.0, dbc="Health_Isolation.GammaDEstimate",
                cylinder_dbc="Health_Cylinder.CylGammaD", dronecan="gamma_d", mavlink="GAMMA_D", history=True),
    HealthValue("headroom_s", "s", idle=HEADROOM_CAP_S, idle_unestimated=0.0, dbc="Health_Isolation.ThermalHeadroom",
                dronecan="headroom", mavlink="HDRM{n}"),
    HealthValue("stale_inputs", "", "inputs", "engine"),
    HealthValue("sensor_fault", "", "flag", "engine"),
    HealthValue("cht_rate_c_per_min", "degC/min", idle=0.0, dbc="Health_Status.ChtRate"),
    HealthValue("cht_spread_c", "degC", scope="cylinders", idle=0.0, dbc="Health_Spread.ChtSpread",
                dronecan="spread", mavlink="CHT_SPRD"),
    HealthValue("hottest_cylinder", "", "cylinder", "cylinders", dbc="Health_Spread.HottestCylinder",
                dronecan="hottest", mavlink="CHT_HOT"),
    HealthValue("spread_alarm", "", "flag", "cylinders", dbc="Health_Spread.SpreadAlarm"),
    HealthValue("lead_cylinder", "", "cylinder", "cylinders", csv=False),
    HealthValue("gamma_q_sd", "", mavlink="GAMMA_Q_SD"),
    HealthValue("gamma_d_sd", "", mavlink="GAMMA_D_SD"),
    HealthValue("not_isolable", "", "flag", dbc="Health_Diag.NotIsolable",
                cylinder_dbc="Health_Cylinder.CylNotIsolable", dronecan="not_iso", mavlink="NOT_ISO"),
    HealthValue("detector_armed", "", idle=0.0, dbc="Health_Diag.DetectorArmed", dronecan="det_armed",
                mavlink="DET_ARMED"),
)  # fmt: skip


def cylinder_values() -> tuple[HealthValue, ...]:
    """The rows each cylinder has (``cylinder`` scope), in table order."""
    return _CYLINDER_VALUES


_CYLINDER_VALUES = tuple(v for v in HEALTH_VALUES if v.scope == "cylinder")


def engine_values(cylinders: int) -> Iterator[HealthValue]:
    """The rows of the engine's level for an engine with ``cylinders`` CHT channels, in table order."""
    return (v for v in HEALTH_VALUES if v.scope != "cylinders" or cylinders > 1)


#: The field type of each kind in the step's output record (a state: its code).
_RECORD_TYPES = {"float": "f8", "state": "i8", "flag": "?", "cylinder": "i8"}


def output_fields() -> list[tuple[str, str]]:
    """The fields of the step's output record (``CYLINDER_OUTPUT``) its ``cylinder`` rows make."""
    return [(v.name, _RECORD_TYPES[v.kind]) for v in cylinder_values()]


def cylinder_snapshot(number: int, record: Any) -> CylinderSnapshot:
    """Cylinder ``number``'s snapshot from its step output record (a ``CYLINDER_OUTPUT`` record, whose first
    fields are the ``cylinder`` rows: :func:`output_fields`)."""
    values = dict(zip(_CYLINDER_NAMES, record.item(), strict=False))
    for name in _CYLINDER_STATES:
        values[name] = STATES[values[name]]
    values["number"] = number
    return CylinderSnapshot._of(values)


_CYLINDER_NAMES = tuple(v.name for v in _CYLINDER_VALUES)
_CYLINDER_STATES = tuple(v.name for v in _CYLINDER_VALUES if v.kind == "state")


def as_number(value: HealthValue, x: Any) -> float:
    """``x`` (a snapshot's value of ``value``) as a float: a state's code, a flag's 0/1 (nan stays nan)."""
    return float(_STATE_CODE[x]) if value.kind == "state" else float(x)


def bus_number(value: HealthValue, x: Any, estimated: bool = True) -> float:
    """``x`` (a snapshot's value of ``value``) as a number on the bus: :func:`as_number`, a non-finite value
    as the row's idle value (``idle_unestimated`` when the CHT has no estimate)."""
    number = as_number(value, x)
    if math.isfinite(number):
        return number
    if not estimated and value.idle_unestimated is not None:
        return value.idle_unestimated
    return value.idle


_STATE_CODE = {name: code for code, name in enumerate(STATES)}


class _Values:
    """A frozen record whose attributes are the rows of the output table (and a few fixed ones): one
    read-only property per field, made by ``__init_subclass__`` from ``_fields`` (name -> default)."""

    __slots__ = ("_v",)
    _fields: ClassVar[dict[str, Any]] = {}

    def __init_subclass__(cls) -> None:
        for name in cls._fields:
            setattr(cls, name, _field(name))

    def __init__(self, **values: Any) -> None:
        if not values.keys() <= self._fields.keys():
            unknown = sorted(values.keys() - self._fields.keys())
            raise TypeError(f"{type(self).__name__}: no field {', '.join(unknown)}")
        object.__setattr__(self, "_v", {**self._fields, **values})

    @classmethod
    def _of(cls, values: dict[str, Any]) -> Any:
        """A record of ``values`` (known field names only; the others take their defaults), not copied."""
        record = object.__new__(cls)
        object.__setattr__(record, "_v", values if len(values) == len(cls._fields) else {**cls._fields, **values})
        return record

    def __getattr__(self, name: str) -> Any:
        raise AttributeError(f"{type(self).__name__} has no field {name!r}")

    def values(self) -> dict[str, Any]:
        """The fields by name (a copy)."""
        return dict(self._v)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{type(self).__name__} is frozen")

    def __getstate__(self) -> dict[str, Any]:
        return self._v

    def __setstate__(self, state: dict[str, Any]) -> None:
        object.__setattr__(self, "_v", state)

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and self._v == other._v

    def __hash__(self) -> int:
        return hash(tuple(self._v.items()))

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(f'{k}={v!r}' for k, v in self._v.items())})"

    def replace(self, **changes: Any) -> Any:
        """A copy with ``changes``."""
        return type(self)(**{**self._v, **changes})


def _field(name: str) -> property:
    """The read-only attribute of field ``name``."""

    def get(self: _Values) -> Any:
        return self._v[name]

    return property(get, doc=f"the {name} value")


class CylinderSnapshot(_Values):
    """One cylinder at one instant (engines monitored per cylinder, ``cht1_c .. chtN_c``): ``number``
    (1-based) and each ``cylinder`` row of :data:`HEALTH_VALUES` (units there)."""

    __slots__ = ()
    _fields: ClassVar[dict[str, Any]] = {"number": 0, **{v.name: v.default() for v in cylinder_values()}}

    @property
    def sensor_fault(self) -> bool:
        """The cylinder's CHT probe is faulty."""
        return bool(self._v["state"] == "SENSOR_FAULT")


class HealthSnapshot(_Values):
    """The service's view of the engine at one instant (one health-status period): each row of
    :data:`HEALTH_VALUES` (units there; ``cylinder`` rows are the lead cylinder's on an engine monitored
    per cylinder, :mod:`ecu_monitor.pipeline.cylinders`), and ``cylinders``: one
    :class:`CylinderSnapshot` each (empty for a single CHT channel)."""

    __slots__ = ()
    _fields: ClassVar[dict[str, Any]] = {**{v.name: v.default() for v in HEALTH_VALUES}, "cylinders": ()}
