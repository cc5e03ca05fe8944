"""The service as a MAVLink component (protocol: mavlink; docs/service.md, "MAVLink"): what it publishes.

The daemon calls :meth:`MavlinkPublisher.messages` once per health-status period (the 10 Hz health
rows) with that period's :class:`~ecu_monitor.pipeline.outputs.HealthSnapshot` (and, for
EFI_STATUS out, the held input values), and sends :meth:`MavlinkPublisher.encode` of what it returns
on ``mavlink.output`` (or back over ``mavlink.connection``). Every message is a pymavlink message
object packed by one ``mavutil.mavlink.MAVLink`` instance with the service's ``system_id`` /
``component_id`` (its sequence numbers run across everything sent), MAVLink 2 unless
``mavlink.mavlink1``:

* ``HEARTBEAT`` every second, and at once when ``system_status`` changes: type
  MAV_TYPE_ONBOARD_CONTROLLER, autopilot MAV_AUTOPILOT_INVALID (a component that is no autopilot),
  base_mode 0; ``system_status`` (:func:`system_status`) MAV_STATE_STANDBY while UNAVAILABLE, ACTIVE
  while NOMINAL, SUSPECT or INPUT_STALE, CRITICAL while DEGRADED or SENSOR_FAULT, EMERGENCY whenever a
  CHT (the estimate, else the reading) is at or above its limit; ``custom_mode`` the state's code
  (Health_Status.DegradationState: 0 NOMINAL .. 5 UNAVAILABLE) in bits 0-3 and the stale inputs
  (Health_Diag.StaleInputs bits) from bit 4, as the DroneCAN node's vendor status code.
* ``STATUSTEXT`` for the pilot (:func:`state_text`, docs/contracts.md): on every state change (and once
  at start), while INPUT_STALE when more inputs are lost than the last text named (again, with all of
  them: a dropped link loses the inputs of its slower messages first), when a CHT reaches its limit and
  when it is back below, when the CHT spread alarm rises, and once for an open maintenance alert of the
  across-flight detector (:meth:`MavlinkPublisher.tell`, at each start of the daemon), severity WARNING,
  and once when an engine event starts (:meth:`MavlinkPublisher.announce`, its
  :meth:`~ecu_monitor.pipeline.events.Event.start_text`), severity WARNING, NOTICE for an advisory.
  Severity (:data:`SEVERITY`): NOMINAL INFO, UNAVAILABLE NOTICE, SUSPECT and INPUT_STALE WARNING,
  DEGRADED and SENSOR_FAULT CRITICAL, a CHT at its limit ALERT. A text longer than 50 characters is
  sent in chunks of 50 (MAVLink 2 ``id`` and ``chunk_seq``, as the message definition says a long
  text is reassembled; ``id`` 0 for a text of one chunk; a text of a whole number of chunks ends with an
  empty one, since receivers take a chunk shorter than 50 as the last); on MAVLink 1 it is cut to 50. At most
  ``mavlink.statustext_per_s`` texts a second (a token bucket; a text's chunks count once): a text that
  would pass the rate waits. Nothing is dropped: a new text of the same kind (state, limit, spread)
  that comes while one is waiting is merged with it, with the more severe severity of the two: a state
  text names the states passed through, ``ENGINE: normal, NOMINAL (via SUSPECT)``; an alert keeps the
  first and the last said, ``...; then ENGINE: CHT back below limit``.
* ``NAMED_VALUE_FLOAT`` at ``mavlink.named_value_hz``: the set of :func:`named_values` (names of at
  most 10 characters, docs/contracts.md), NaN where unknown, ``time_boot_ms`` the time since the
  publisher's first call.
* ``EFI_STATUS`` at ``mavlink.efi_status_hz`` when ``mavlink.efi_status_out`` (an engine only the
  service reads, for ArduPilot's EFI_TYPE 9): rpm, throttle, fuel flow (cm^3/min), CHT (the reading,
  degC), EGT, manifold pressure from the held inputs, the standard pressure at the pressure altitude
  as barometric pressure, ``health`` 1 while no input is stale (NaN where the service holds no value;
  the fields it never knows 0, as ArduPilot's own backends leave them). Refused (ConfigError) when an input
  comes from EFI_STATUS: the autopilot's own engine status is never echoed back to it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ecu_monitor.bus.codec import INPUT_NAMES
from ecu_monitor.bus.mavlink import mavlink_module
from ecu_monitor.bus.mavlink_settings import MavlinkSettings
from ecu_monitor.errors import ConfigError
from ecu_monitor.pipeline.events import Event
from ecu_monitor.pipeline.output_table import STATES, as_number, engine_values
from ecu_monitor.pipeline.outputs import HealthSnapshot
from ecu_monitor.units import UNITS, standard_pressure_kpa

__all__ = [
    "MAX_NAME",
    "MAX_TEXT",
    "SEVERITY",
    "MavlinkPublisher",
    "named_values",
    "state_text",
    "system_status",
    "text_chunks",
]

#: Characters of a STATUSTEXT chunk and of a NAMED_VALUE_FLOAT name (the message definitions' char arrays).
MAX_TEXT = 50
MAX_NAME = 10
#: MAV_SEVERITY of each state's STATUSTEXT (common.xml: 0 EMERGENCY .. 7 DEBUG).
SEVERITY: Mapping[str, int] = {
    "NOMINAL": 6,  # INFO
    "UNAVAILABLE": 5,  # NOTICE
    "SUSPECT": 4,  # WARNING
    "INPUT_STALE": 4,  # WARNING
    "DEGRADED": 2,  # CRITICAL
    "SENSOR_FAULT": 2,  # CRITICAL
}
_SEVERITY_ALERT, _SEVERITY_WARNING, _SEVERITY_NOTICE, _SEVERITY_INFO = 1, 4, 5, 6
#: MAV_STATE values (common.xml)
_STANDBY, _ACTIVE, _CRITICAL, _EMERGENCY = 3, 4, 5, 6
_STATE_STATUS = {
    "NOMINAL": _ACTIVE,
    "SUSPECT": _ACTIVE,
    "INPUT_STALE": _ACTIVE,
    "UNAVAILABLE": _STANDBY,
    "DEGRADED": _CRITICAL,
    "SENSOR_FAULT": _CRITICAL,
}
_MAV_TYPE_ONBOARD_CONTROLLER, _MAV_AUTOPILOT_INVALID = 18, 8
#: how an input is named to a pilot (INPUT_STALE texts)
_INPUT_WORDS = {
    "rpm": "rpm",
    "throttle_pct": "throttle",
    "cht_c": "CHT",
    "oat_c": "OAT",
    "altitude_m": "altitude",
    "airspeed_mps": "airspeed",
    "fuel_flow_lph": "fuel flow",
    "egt_c": "EGT",
}
_NOTABLE_PCT = 5  # a gamma is named in a text when it departs from 1 by this many percent or more
_HEARTBEAT_S = 1.0
_SLACK_S = 1e-3
_CC_PER_MIN = UNITS["cc_per_min"].scale  # L/h per cm^3/min


def system_status(snap: HealthSnapshot, cht_limits: Sequence[float]) -> int:
    """HEARTBEAT.system_status (MAV_STATE) for a snapshot (module docstring)."""
    if _over_limit(snap, cht_limits):
        return _EMERGENCY
    return _STATE_STATUS[snap.state]


def _over_limit(snap: HealthSnapshot, cht_limits: Sequence[float]) -> int:
    """The number of a cylinder whose CHT (estimate, else reading) is at or above its limit (1 for one
    channel), the hottest relative to its limit; 0 when none is."""
    if snap.cylinders:
        values = [(c.number, c.cht_est_c if math.isfinite(c.cht_est_c) else c.cht_meas_c) for c in snap.cylinders]
    else:
        values = [(1, snap.cht_est_c if math.isfinite(snap.cht_est_c) else snap.cht_meas_c)]
    worst, margin = 0, -math.inf
    for number, cht in values:
        limit = cht_limits[min(number, len(cht_limits)) - 1]
        if math.isfinite(cht) and cht >= limit and cht - limit > margin:
            worst, margin = number, cht - limit
    return worst


def _deviation_words(snap: HealthSnapshot) -> str:
    """gamma_Q 1.18 -> 'heat-in +18 %', gamma_D 0.85 -> 'cooling -15 %' (the larger first; those under
    5 % left out); without either, the model-deviation symptom."""
    parts = []
    for value, word in ((snap.gamma_q, "heat-in"), (snap.gamma_d, "cooling")):
        if math.isfinite(value):
            pct = round((value - 1.0) * 100.0)
            if abs(pct) >= _NOTABLE_PCT:
                parts.append((abs(pct), f"{word} {pct:+d} %"))
    if parts:
        return ", ".join(text for _, text in sorted(parts, reverse=True))
    cause = "" if not snap.not_isolable or math.isfinite(snap.gamma_q) else ", cause not isolable"
    if math.isfinite(snap.deviation):
        return f"CHT {snap.deviation:+.2f} C/s off model{cause}"
    return f"CHT off model{cause}"


def state_text(snap: HealthSnapshot, first: bool = False) -> str:
    """The pilot's text of a snapshot's state (docs/contracts.md, "STATUSTEXT"), e.g.
    ``ENGINE cyl 3: heat-in +18 %, DEGRADED``; ``first``: the first text since start."""
    lead = snap.lead_cylinder
    who = f"ENGINE cyl {lead}" if lead else "ENGINE"
    state = snap.state
    if state in ("SUSPECT", "DEGRADED"):
        return f"{who}: {_deviation_words(snap)}, {state}"
    if state == "SENSOR_FAULT":
        return f"{who}: CHT probe fault, {state}"
    if state == "INPUT_STALE":
        lost = "+".join(_INPUT_WORDS.get(name, name) for name in snap.stale_inputs) or "inputs"
        return f"ENGINE monitor: {lost} lost, {state}"
    if state == "UNAVAILABLE":
        return f"ENGINE monitor: {'started' if first else 'estimate stopped'}, {state}"
    cht = f", CHT {snap.cht_est_c:.0f} C" if math.isfinite(snap.cht_est_c) else ""
    return f"{who}: {'monitoring' if first else 'normal'}, {state}{cht}"


def text_chunks(text: str, mavlink1: bool = False) -> list[str]:
    """``text`` in STATUSTEXT chunks of at most :data:`MAX_TEXT` characters (ASCII; MAVLink 1: one,
    cut with '...'). A receiver knows the last chunk of a text by its being shorter than MAX_TEXT (MAVProxy
    waits for one): a text of a whole number of chunks ends with an empty chunk."""
    text = text.encode("ascii", "replace").decode("ascii")
    if len(text) <= MAX_TEXT:
        return [text]
    if mavlink1:
        return [text[: MAX_TEXT - 3] + "..."]
    chunks = [text[i : i + MAX_TEXT] for i in range(0, len(text), MAX_TEXT)]
    return [*chunks, ""] if len(chunks[-1]) == MAX_TEXT else chunks


def named_values(snap: HealthSnapshot) -> list[tuple[str, float]]:
    """The NAMED_VALUE_FLOAT set of a snapshot (docs/contracts.md): the output table's ``mavlink`` names; a
    name with ``{n}`` per cylinder n (1 for one channel: the snapshot's own value), in table order (``CHTn_EST``
    degC, ``HDRMn`` s); then the engine's (its lead cylinder's) in table order (``ENG_DEV`` degC/s, ``ENG_ST``
    the state's code, ``GAMMA_Q``, ``GAMMA_D``; with several cylinders ``CHT_SPRD`` degC, ``CHT_HOT`` the
    hottest's number, 0: none). NaN where unknown."""
    rows = [v for v in engine_values(len(snap.cylinders)) if v.mavlink]
    per = [v for v in rows if "{n}" in v.mavlink]
    out = []
    for number, cyl in ((c.number, c) for c in snap.cylinders) if snap.cylinders else ((1, snap),):
        out += [(v.mavlink.format(n=number), as_number(v, getattr(cyl, v.name))) for v in per]
    out += [(v.mavlink, as_number(v, getattr(snap, v.name))) for v in rows if "{n}" not in v.mavlink]
    return out


@dataclass
class _Text:
    """A STATUSTEXT waiting for the rate limit: its kind, severity, text, the states it went through."""

    kind: str
    severity: int
    text: str
    via: tuple[str, ...] = ()
    state: str = ""

    def full_text(self) -> str:
        return f"{self.text} (via {', '.join(self.via)})" if self.via else self.text


class _Sink:
    """The file pymavlink's MAVLink instance writes packed frames to."""

    def __init__(self) -> None:
        self.data = bytearray()

    def write(self, buf: bytes) -> None:
        self.data += buf


class MavlinkPublisher:
    """The publications of the service as a MAVLink component (module docstring), one health-status period at a time.

    ``cht_limits``: the CHT limit (degC) of each cylinder, in cylinder order (one value: every cylinder's).
    ``input_messages``: the MAVLink messages the inputs come from (EFI_STATUS among them refuses
    ``efi_status_out``).
    """

    def __init__(
        self, settings: MavlinkSettings, cht_limits: float | Sequence[float], input_messages: Iterable[str] = ()
    ) -> None:
        self.settings = settings
        limits = (float(cht_limits),) if isinstance(cht_limits, int | float) else tuple(float(v) for v in cht_limits)
        if not limits:
            raise ConfigError("MavlinkPublisher: no CHT limit given")
        self.cht_limits = limits
        if settings.efi_status_out and "EFI_STATUS" in set(input_messages):
            raise ConfigError(
                "mavlink.efi_status_out: the inputs come from EFI_STATUS, which the service must not echo"
            )
        self._ml = mavlink_module()
        self._sink = _Sink()
        self.mav = self._ml.MAVLink(self._sink, srcSystem=settings.system_id, srcComponent=settings.component_id)
        self._first_s: float | None = None
        self._heartbeat_s = -math.inf
        self._status: tuple[int, int] | None = None
        self._named_every_s = 1.0 / settings.named_value_hz if settings.named_value_hz > 0.0 else math.inf
        self._named_s = -math.inf
        self._efi_every_s = 1.0 / settings.efi_status_hz if settings.efi_status_hz > 0.0 else math.inf
        self._efi_s = -math.inf
        self._state: str | None = None  # the state of the last snapshot
        self._stale_told: frozenset[str] = frozenset()  # the stale inputs the last INPUT_STALE text named
        self._over = 0  # the cylinder at its CHT limit in the last snapshot (0: none)
        self._spread = False
        self._pending: dict[str, _Text] = {}  # kind -> the text waiting for the rate limit
        rate = settings.statustext_per_s
        self._burst = max(1.0, rate)
        self._tokens = self._burst
        self._tokens_s: float | None = None
        self._text_id = 0
        #: texts sent so far (full text, severity), for the daemon's log and the tests
        self.sent_texts: list[tuple[str, int]] = []

    def messages(self, time_s: float, snap: HealthSnapshot, inputs: Mapping[str, float] | None = None) -> list[Any]:
        """The pymavlink messages due at ``time_s`` (s, the pipeline's clock) for that health-status period's
        snapshot; ``inputs``: the held input values by name (EFI_STATUS out only)."""
        if self._first_s is None:
            self._first_s = time_s
        out: list[Any] = []
        over = _over_limit(snap, self.cht_limits)
        status = (_EMERGENCY if over else _STATE_STATUS[snap.state], self._custom_mode(snap))
        if _due(time_s, self._heartbeat_s, _HEARTBEAT_S) or self._status is None or status[0] != self._status[0]:
            out.append(self._heartbeat(status))
            self._status, self._heartbeat_s = status, time_s
        self._events(snap, over)
        out += self._texts(time_s)
        if _due(time_s, self._named_s, self._named_every_s):
            self._named_s = time_s
            boot_ms = self._boot_ms(time_s)
            out += [
                self._ml.MAVLink_named_value_float_message(boot_ms, name.encode("ascii"), value)
                for name, value in named_values(snap)
            ]
        if self.settings.efi_status_out and inputs is not None and _due(time_s, self._efi_s, self._efi_every_s):
            self._efi_s = time_s
            out.append(self._efi_status(snap, inputs))
        return out

    def encode(self, msgs: Iterable[Any]) -> bytes:
        """The bytes of ``msgs`` packed in order with the service's ids and running sequence number."""
        self._sink.data.clear()
        for msg in msgs:
            self.mav.send(msg, force_mavlink1=self.settings.mavlink1)
        data = bytes(self._sink.data)
        self._sink.data.clear()
        return data

    # --- STATUSTEXT -------------------------------------------------------------------------------

    def tell(self, text: str) -> None:
        """A maintenance alert's text: one STATUSTEXT, severity WARNING, as the rate allows."""
        self._queue(_Text("maintenance", _SEVERITY_WARNING, text))

    def announce(self, event: Event) -> None:
        """An engine event that started: one STATUSTEXT of its start record, as the rate allows (a text of the
        same kind and cylinder still waiting is merged with it)."""
        severity = _SEVERITY_NOTICE if event.advisory else _SEVERITY_WARNING
        self._queue(_Text(f"event {event.kind} {event.cylinder}", severity, event.start_text()))

    def _events(self, snap: HealthSnapshot, over: int) -> None:
        """Queue the texts of what changed since the last snapshot."""
        if snap.state != self._state:
            first = self._state is None
            self._queue(_Text("state", SEVERITY[snap.state], state_text(snap, first), state=snap.state))
            self._state = snap.state
            self._stale_told = frozenset(snap.stale_inputs)
        elif snap.state == "INPUT_STALE" and not self._stale_told.issuperset(snap.stale_inputs):
            self._more_lost(snap)
        if over != self._over:
            if over:
                cyl = next((c for c in snap.cylinders if c.number == over), None)
                cht = snap.cht_est_c if cyl is None else cyl.cht_est_c
                cht = cht if math.isfinite(cht) else (snap.cht_meas_c if cyl is None else cyl.cht_meas_c)
                limit = self.cht_limits[min(over, len(self.cht_limits)) - 1]
                who = f"ENGINE cyl {over}" if snap.cylinders else "ENGINE"
                self._queue(_Text("limit", _SEVERITY_ALERT, f"{who}: CHT {cht:.0f} C at limit {limit:.0f} C"))
            else:
                self._queue(_Text("limit", _SEVERITY_INFO, "ENGINE: CHT back below limit"))
            self._over = over
        if snap.spread_alarm and not self._spread:
            hottest = f", cyl {snap.hottest_cylinder} hottest" if snap.hottest_cylinder else ""
            self._queue(_Text("spread", _SEVERITY_WARNING, f"ENGINE: CHT spread {snap.cht_spread_c:.0f} C{hottest}"))
        self._spread = snap.spread_alarm

    def _more_lost(self, snap: HealthSnapshot) -> None:
        """While INPUT_STALE, inputs lost since the text that named the lost ones: told again with the whole set
        (a link that drops loses the inputs of its slower messages first: the first text names only those). A
        text of the state still waiting for the rate takes the whole set instead."""
        text = _Text("state", SEVERITY["INPUT_STALE"], state_text(snap), state="INPUT_STALE")
        waiting = self._pending.get("state")
        if waiting is not None and waiting.state == "INPUT_STALE":
            waiting.text = text.text
        else:
            self._queue(text)
        self._stale_told = frozenset(snap.stale_inputs)

    def _queue(self, text: _Text) -> None:
        """Queue a text; one of the same kind still waiting is merged into it (module docstring)."""
        waiting = self._pending.pop(text.kind, None)
        if waiting is not None:
            text.severity = min(text.severity, waiting.severity)
            if text.state:  # a state change: the states passed through, named
                text.via = (*waiting.via, waiting.state)
            else:  # an alert and its end (or the reverse): the first and the last said
                text.text = f"{waiting.text.split('; then ')[0]}; then {text.text}"
        self._pending[text.kind] = text

    def _texts(self, time_s: float) -> list[Any]:
        """The STATUSTEXT messages the rate allows now, oldest text first."""
        if self._tokens_s is not None:
            self._tokens = min(
                self._burst, self._tokens + max(0.0, time_s - self._tokens_s) * self.settings.statustext_per_s
            )
        self._tokens_s = time_s
        out: list[Any] = []
        while self._pending and self._tokens >= 1.0 - 1e-9:
            kind = next(iter(self._pending))
            text = self._pending.pop(kind)
            self._tokens -= 1.0
            out += self._statustext(text)
        return out

    def _statustext(self, text: _Text) -> list[Any]:
        full = text.full_text()
        chunks = text_chunks(full, self.settings.mavlink1)
        self.sent_texts.append((full, text.severity))
        text_id = 0
        if len(chunks) > 1:
            self._text_id = self._text_id % 0xFFFF + 1
            text_id = self._text_id
        return [
            self._ml.MAVLink_statustext_message(text.severity, chunk.encode("ascii"), text_id, seq)
            for seq, chunk in enumerate(chunks)
        ]

    # --- HEARTBEAT, EFI_STATUS ----------------------------------------------------------------------

    @staticmethod
    def _custom_mode(snap: HealthSnapshot) -> int:
        stale = sum(1 << bit for bit, name in enumerate(INPUT_NAMES) if name in snap.stale_inputs)
        return STATES.index(snap.state) | stale << 4

    def _heartbeat(self, status: tuple[int, int]) -> Any:
        return self._ml.MAVLink_heartbeat_message(
            _MAV_TYPE_ONBOARD_CONTROLLER, _MAV_AUTOPILOT_INVALID, 0, status[1], status[0], 3
        )

    def _efi_status(self, snap: HealthSnapshot, inputs: Mapping[str, float]) -> Any:
        def value(name: str) -> float:
            got = inputs.get(name, math.nan)
            return float(got) if got is not None else math.nan

        altitude = value("altitude_m")
        baro = float(standard_pressure_kpa(altitude)) if math.isfinite(altitude) else math.nan
        # what the service holds: its value, NaN when not held; what it never knows: 0, as ArduPilot's own EFI
        # backends leave a field their ECU does not report
        return self._ml.MAVLink_efi_status_message(
            0 if snap.stale_inputs else 1,  # health
            0,  # ecu_index
            value("rpm"),
            0.0,  # fuel_consumed
            value("fuel_flow_lph") / _CC_PER_MIN,
            0.0,  # engine_load
            value("throttle_pct"),
            0.0,  # spark_dwell_time
            baro,
            value("manifold_pressure_kpa"),
            0.0,  # intake_manifold_temperature
            snap.cht_meas_c,
            0.0,  # ignition_timing
            0.0,  # injection_time
            value("egt_c"),
            0.0,  # throttle_out
            0.0,  # pt_compensation
            0.0,  # ignition_voltage: unknown
            0.0,  # fuel_pressure: unknown
        )

    def _boot_ms(self, time_s: float) -> int:
        return int(max(0.0, time_s - (self._first_s or time_s)) * 1000.0) & 0xFFFFFFFF


def _due(time_s: float, last_s: float, every_s: float) -> bool:
    """A message sent every ``every_s`` (inf: never) is due at ``time_s``, last sent at ``last_s``."""
    return math.isfinite(every_s) and time_s - last_s >= every_s - _SLACK_S
