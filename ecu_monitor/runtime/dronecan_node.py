"""The service as a DroneCAN node (protocol: dronecan; docs/service.md, "DroneCAN"): what it publishes.

The pipeline calls :meth:`DroneCanNode.frames` once per health-status period (the 10 Hz health rows)
with that period's snapshot, and :meth:`DroneCanNode.step_frames` on each of its other steps; they return
the frames of the transfers due (built by :class:`ecu_monitor.bus.dronecan.DroneCanEncoder`, source node
``dronecan.node_id``, priority ``dronecan.priority``):

* ``uavcan.protocol.NodeStatus`` every second, and at once when the health or the mode changes.
  ``health`` follows the engine (:func:`node_health`): OK while NOMINAL; WARNING while SUSPECT,
  INPUT_STALE or UNAVAILABLE (the monitor cannot vouch for the engine); ERROR while DEGRADED or
  SENSOR_FAULT; CRITICAL whenever the CHT (the estimate, else the reading) is at or above the model's
  CHT limit. ``mode`` is INITIALIZATION until the estimator has run once, OPERATIONAL after.
  ``uptime_sec``: whole seconds since the node's first step. ``vendor_specific_status_code``: the
  state's code (Health_Status.DegradationState: 0 NOMINAL .. 5 UNAVAILABLE) in bits 0-3 and the
  stale inputs (Health_Diag.StaleInputs bits) from bit 4.
* ``uavcan.protocol.debug.KeyValue`` at ``dronecan.key_value_hz``: one transfer per key of
  :data:`KEY_VALUES` (the output table's ``dronecan`` names, pipeline/output_table.py; keys of at most
  10 characters, so MAVLink's NAMED_VALUE_FLOAT can relay them);
  NaN when the value is unknown (no estimate yet). The set is the snapshot of the health-status period
  in which it fell due, sent over the steps that follow until the next one is due, a few keys a step
  (:meth:`DroneCanNode.step_frames`; one a step for one channel at 1 Hz), never in a health-status step:
  a burst of KeyValue frames would hold the bus thread behind the step's health frames (two frames per
  key, 14 or more a set). An engine monitored per cylinder adds
  ``spread`` (degC), ``hottest`` (its number) and, per cylinder n, ``cyl<n>_est`` (degC),
  ``cyl<n>_st`` (its state's code) and ``cyl<n>_gq`` (gamma_Q): the ``dronecan_cylinder`` names.
* ``uavcan.protocol.debug.LogMessage`` when the state changes (and once at start), source
  ``ecu-monitor``, level INFO for NOMINAL, WARNING for SUSPECT, INPUT_STALE and UNAVAILABLE, ERROR for
  DEGRADED and SENSOR_FAULT; at most one a second: a change within a second of the last message is
  told when the second is up, if the state still differs from the one last told. Per cylinder, the
  state is the engine's (its lead cylinder's) and the text names that cylinder. An open maintenance alert
  of the across-flight detector (:meth:`DroneCanNode.tell`, at each start of the daemon) is one more
  LogMessage, level WARNING, its text cut to 90 characters; so is each engine event that starts
  (runtime/publishers.py), level INFO for an advisory. One such text a health-status period, in order.

It answers ``uavcan.protocol.GetNodeInfo`` requests addressed to it (:meth:`DroneCanNode.take_request`,
called by the pipeline for every frame it is fed): the response, sent with the frames of the next step
(within 20 ms; a requester waits up to a second), carries the NodeStatus as it would be sent now, the
software version (ecu_monitor's major and minor), no hardware version and the name :data:`NODE_NAME`.
The node answers no other service.
"""

from __future__ import annotations

import math

import can
from can.typechecking import CanFilter

from ecu_monitor import __version__
from ecu_monitor.bus.codec import INPUT_NAMES
from ecu_monitor.bus.dronecan import DroneCanEncoder
from ecu_monitor.config import DroneCanSettings
from ecu_monitor.pipeline.output_table import HEALTH_VALUES, STATES, as_number, cylinder_values, engine_values
from ecu_monitor.pipeline.outputs import HealthSnapshot

__all__ = ["HEALTH_CODES", "KEY_VALUES", "LOG_LEVELS", "NODE_NAME", "DroneCanNode", "key_values", "node_health"]

#: NodeStatus.health values (DSDL constants of uavcan.protocol.NodeStatus)
HEALTH_CODES = {"OK": 0, "WARNING": 1, "ERROR": 2, "CRITICAL": 3}
_MODE_OPERATIONAL, _MODE_INITIALIZATION = 0, 1
#: state -> NodeStatus health (without the CHT limit, which makes any state CRITICAL)
_STATE_HEALTH = {
    "NOMINAL": "OK",
    "SUSPECT": "WARNING",
    "INPUT_STALE": "WARNING",
    "UNAVAILABLE": "WARNING",
    "DEGRADED": "ERROR",
    "SENSOR_FAULT": "ERROR",
}
#: state -> LogMessage level (uavcan.protocol.debug.LogLevel: 0 DEBUG, 1 INFO, 2 WARNING, 3 ERROR)
LOG_LEVELS = {"NOMINAL": 1, "SUSPECT": 2, "INPUT_STALE": 2, "UNAVAILABLE": 2, "DEGRADED": 3, "SENSOR_FAULT": 3}
#: KeyValue key -> HealthSnapshot field: the output table's ``dronecan`` names (the engine's values, or with
#: one CHT channel its own); per cylinder n its ``dronecan_cylinder`` names (``{n}`` in them)
KEY_VALUES: dict[str, str] = {v.dronecan: v.name for v in HEALTH_VALUES if v.dronecan and v.scope != "cylinders"}
_NODE_STATUS = "uavcan.protocol.NodeStatus"
_GET_NODE_INFO = "uavcan.protocol.GetNodeInfo"
_GET_NODE_INFO_ID = 1  # its service type id (uavcan.protocol.GetNodeInfo's DSDL)
#: GetNodeInfo's node name (DroneCAN: a reverse internet domain name, lower case)
NODE_NAME = "org.ecu-monitor.cht"
_KEY_VALUE = "uavcan.protocol.debug.KeyValue"
_LOG_MESSAGE = "uavcan.protocol.debug.LogMessage"
_LOG_SOURCE = "ecu-monitor"
#: LogMessage level of a maintenance alert or an engine event (WARNING), of an advisory (INFO), and the longest
#: text a LogMessage carries (uint8[<=90])
_WARNING = 2
_INFO = 1
_MAX_LOG_TEXT = 90
_VERSION = tuple(int(part) for part in __version__.split(".")[:2])
_LOG_EVERY_S = 1.0
_SLACK_S = 1e-3  # periods are counted on the health-status instants, rounded to the microsecond


def node_health(state: str, cht_c: float, cht_limit_c: float) -> int:
    """NodeStatus.health of an engine in ``state`` whose CHT is ``cht_c`` (degC; NaN: unknown)."""
    if math.isfinite(cht_c) and cht_c >= cht_limit_c:
        return HEALTH_CODES["CRITICAL"]
    return HEALTH_CODES[_STATE_HEALTH[state]]


class DroneCanNode:
    """The publications of the service's DroneCAN node (module docstring), one health-status period at a time."""

    def __init__(
        self, settings: DroneCanSettings, cht_limit_c: float, status_every_s: float, steps_per_status: int
    ) -> None:
        """``status_every_s``: the health-status period (s), made of ``steps_per_status`` pipeline steps."""
        self.settings = settings
        self.cht_limit_c = cht_limit_c
        self.encoder = DroneCanEncoder(settings.node_id)
        rate = settings.key_value_hz
        self._key_value_every_s = 1.0 / rate if rate > 0.0 else math.inf
        # the steps between two KeyValue sets that carry no health-status period: a set is spread over them
        periods = math.ceil(self._key_value_every_s / status_every_s - _SLACK_S) if rate > 0.0 else 1
        self._spread_steps = max(1, periods) * (steps_per_status - 1)
        self._pending: list[tuple[str, float]] = []  # the KeyValue pairs of the current set not yet sent, last first
        self._per_step = 1
        self._replies: list[can.Message] = []  # service responses, sent with the next step's frames
        # a GetNodeInfo request to this node: its CAN id under the mask (any priority and requester)
        self._request_id = _GET_NODE_INFO_ID << 16 | 1 << 15 | settings.node_id << 8 | 0x80
        self._status_values: dict[str, int] = {"mode": _MODE_INITIALIZATION}  # the NodeStatus fields last published
        self._first_s: float | None = None
        self._status: tuple[int, int] | None = None  # (health, mode) last published
        self._status_s = -math.inf
        self._key_value_s = -math.inf
        self._estimated = False
        self._told: str | None = None  # the state the last LogMessage told
        self._told_s = -math.inf
        self._notices: list[tuple[str, int]] = []  # texts to tell (LogMessage) and their levels, oldest first

    def tell(self, text: str, advisory: bool = False) -> None:
        """A maintenance alert's or an engine event's text, sent as a LogMessage (WARNING; INFO for an
        ``advisory``) with the next health-status period."""
        self._notices.append((text, _INFO if advisory else _WARNING))

    def frames(self, time_s: float, snap: HealthSnapshot) -> list[can.Message]:
        """The frames due at ``time_s`` (s) for that health-status period's snapshot."""
        if self._first_s is None:
            self._first_s = time_s
        out: list[can.Message] = []
        cht = snap.cht_est_c if math.isfinite(snap.cht_est_c) else snap.cht_meas_c
        if snap.cylinders:
            finite = [c.cht_est_c for c in snap.cylinders if math.isfinite(c.cht_est_c)]
            cht = max(finite) if finite else cht
        self._estimated = self._estimated or math.isfinite(snap.cht_est_c)
        status = (
            node_health(snap.state, cht, self.cht_limit_c),
            _MODE_OPERATIONAL if self._estimated else _MODE_INITIALIZATION,
        )
        if self._replies:
            out += self._take_replies()
        if _due(time_s, self._status_s, 1.0) or status != self._status:
            out += self._node_status(time_s, snap, status)
        if _due(time_s, self._key_value_s, self._key_value_every_s):
            self._key_value_s = time_s
            out += self._key_values(time_s, len(self._pending))  # what is left of the last set (never, as spread)
            self._pending = key_values(snap)[::-1]
            if self._spread_steps < 1:  # a health-status period every step: nothing to spread over
                out += self._key_values(time_s, len(self._pending))
            self._per_step = math.ceil(len(self._pending) / self._spread_steps) if self._spread_steps else 0
        if self.settings.log_messages and snap.state != self._told and time_s - self._told_s >= _LOG_EVERY_S - _SLACK_S:
            out += self._log_message(time_s, snap)
        if self._notices:
            (text, level), self._notices = self._notices[0], self._notices[1:]  # one a period: many frames each
            values = {"level": {"value": level}, "source": _LOG_SOURCE, "text": text[:_MAX_LOG_TEXT]}
            out += self.encoder.frames(_LOG_MESSAGE, values, time_s, self.settings.priority)
        return out

    def step_frames(self, time_s: float) -> list[can.Message]:
        """The frames due at a step (``time_s``, s) that is not a health-status period's: service responses
        and the next keys of the current KeyValue set."""
        out = self._take_replies() if self._replies else []
        return out + self._key_values(time_s, self._per_step) if self._pending else out

    def take_request(self, msg: can.Message, time_s: float) -> bool:
        """True when ``msg`` (received at ``time_s``, s) is a GetNodeInfo request to this node (from any node, at
        any priority), taken here: the decoder never sees it. It is answered with the next step's frames when
        it is one frame holding the tail byte alone (the request has no fields: a single-frame transfer);
        any other frame is not taken (a request of another service goes on to the decoder: a foreign id)."""
        can_id = msg.arbitration_id
        if not (msg.is_extended_id and can_id & 0x00FFFF80 == self._request_id and can_id & 0x7F):
            return False
        data = msg.data
        if data is not None and len(data) == 1 and data[0] & 0xC0 == 0xC0:  # one frame: start and end
            values = {
                "status": {**self._status_values, "uptime_sec": self._uptime(time_s)},
                "software_version": {"major": _VERSION[0], "minor": _VERSION[1]},
                "name": NODE_NAME,
            }
            self._replies += self.encoder.response_frames(_GET_NODE_INFO, values, time_s, can_id, data[0] & 0x1F)
        return True

    def request_filter(self) -> CanFilter:
        """The python-can receive filter of the service requests to this node."""
        return {"can_id": self._request_id, "can_mask": 0x00FFFF80, "extended": True}

    def _take_replies(self) -> list[can.Message]:
        out, self._replies = self._replies, []
        return out

    def _uptime(self, time_s: float) -> int:
        return max(0, math.floor(time_s - (self._first_s if self._first_s is not None else time_s) + _SLACK_S))

    def _key_values(self, time_s: float, count: int) -> list[can.Message]:
        """The frames of the next ``count`` pending KeyValue pairs."""
        out: list[can.Message] = []
        pending, priority = self._pending, self.settings.priority
        for _ in range(min(count, len(pending))):
            key, value = pending.pop()
            out += self.encoder.frames(_KEY_VALUE, {"key": key, "value": value}, time_s, priority)
        return out

    def _node_status(self, time_s: float, snap: HealthSnapshot, status: tuple[int, int]) -> list[can.Message]:
        self._status, self._status_s = status, time_s
        stale = sum(1 << bit for bit, name in enumerate(INPUT_NAMES) if name in snap.stale_inputs)
        values = {
            "uptime_sec": math.floor(time_s - (self._first_s or time_s) + _SLACK_S),
            "health": status[0],
            "mode": status[1],
            "sub_mode": 0,
            "vendor_specific_status_code": STATES.index(snap.state) | stale << 4,
        }
        self._status_values = values
        return self.encoder.frames(_NODE_STATUS, values, time_s, self.settings.priority)

    def _log_message(self, time_s: float, snap: HealthSnapshot) -> list[can.Message]:
        was = f" (was {self._told})" if self._told is not None else ""
        text = f"CHT {snap.state}{was}"
        lead = snap.lead_cylinder
        if lead:
            text += f" cyl {lead}"
        if math.isfinite(snap.cht_est_c):
            isolation = f"gamma_Q {snap.gamma_q:.2f}" if not snap.not_isolable else "cause not isolable"
            text += f": est {snap.cht_est_c:.1f} C, {isolation}"
        self._told, self._told_s = snap.state, time_s
        values = {"level": {"value": LOG_LEVELS[snap.state]}, "source": _LOG_SOURCE, "text": text}
        return self.encoder.frames(_LOG_MESSAGE, values, time_s, self.settings.priority)


def key_values(snap: HealthSnapshot) -> list[tuple[str, float]]:
    """The KeyValue pairs of one snapshot (module docstring): the engine's, then per cylinder; a state as its
    code, NaN where unknown."""
    rows = list(engine_values(len(snap.cylinders)))
    out = [(v.dronecan, as_number(v, getattr(snap, v.name))) for v in rows if v.dronecan]
    for cyl in snap.cylinders:
        out += [(v.dronecan_cylinder.format(n=cyl.number), as_number(v, getattr(cyl, v.name)))
                for v in cylinder_values() if v.dronecan_cylinder]  # fmt: skip
    return out


def _due(time_s: float, last_s: float, every_s: float) -> bool:
    return time_s - last_s >= every_s - _SLACK_S
