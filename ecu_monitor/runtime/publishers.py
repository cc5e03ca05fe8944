"""Publishers: what the service sends back for each row of the pipeline's output table. Each publisher
takes the rows and gives the frames they make, in order; :func:`make_publishers` is the one table of them for a
config. :class:`LiveMonitor` is the pipeline with its publishers: frames in, health frames out (what the
daemon and the demo run).

* :class:`DbcHealthFrames`: the health.dbc messages (Health_Status, Health_Isolation, Health_Diag,
  Health_Spread, Health_Cylinder) at their configured rates, each signal from its row of the output table
  (pipeline/output_table.py; a nan sent as the row's idle value) or a service diagnostic; a Health_Event
  frame when an engine event starts.
* :class:`DroneCanPublisher`: the service as a DroneCAN node (runtime/dronecan_node.py).
* :class:`MavlinkHealth`: the service as a MAVLink component (runtime/mavlink_publisher.py).

Engine events (pipeline/events.py) are published when they start, each from its start record
(:meth:`Publisher.announce`): the Health_Event frame at once, a DroneCAN LogMessage and a MAVLink
STATUSTEXT (:meth:`~ecu_monitor.pipeline.events.Event.start_text`) with the next health-status period.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import can

from ecu_monitor.bus.codec import Encoder
from ecu_monitor.errors import ConfigError
from ecu_monitor.inputs import stale_bit
from ecu_monitor.model import ThermalParams
from ecu_monitor.pipeline.engine import Pipeline, StepRow
from ecu_monitor.pipeline.events import EVENT_KINDS, Event
from ecu_monitor.pipeline.output_table import HEALTH_VALUES, HealthValue, bus_number
from ecu_monitor.pipeline.outputs import HealthSnapshot
from ecu_monitor.runtime.dronecan_node import DroneCanNode

if TYPE_CHECKING:
    from can.typechecking import CanFilter

    from ecu_monitor.config import ServiceConfig

__all__ = [
    "EVENT_FRAME",
    "EVENT_SIGNALS",
    "DbcHealthFrames",
    "DroneCanPublisher",
    "LiveMonitor",
    "MavlinkHealth",
    "Publisher",
    "health_signal_sources",
    "make_publishers",
]

#: A health.dbc signal's value in one frame: f(snapshot, the frame's cylinder or None, the publisher).
_Source = Callable[[HealthSnapshot, Any, "DbcHealthFrames"], float]


def _margin(snap: HealthSnapshot, cyl: Any, frames: DbcHealthFrames) -> float:
    """CHT limit minus estimate, degC, the smallest over the cylinders (0 without an estimate)."""
    limits = frames.limits
    if snap.cylinders:
        margins = [limits[c.number - 1] - c.cht_est_c for c in snap.cylinders]
        margin = min((m for m in margins if math.isfinite(m)), default=math.nan)
    else:
        margin = limits[0] - snap.cht_est_c
    return margin if math.isfinite(margin) else 0.0


def _stale_bits(snap: HealthSnapshot) -> int:
    bits = 0
    for name in snap.stale_inputs:
        bits |= stale_bit(name)
    return bits


def _faulty(snap: HealthSnapshot) -> int:
    faulty = 0
    for cyl in snap.cylinders:
        if cyl.sensor_fault:
            faulty |= 1 << (cyl.number - 1)
    return faulty


#: The health.dbc signals that carry no row of the output table: the service's own diagnostics and what
#: frames a value (the cylinder a per-cylinder frame describes, how many there are).
_DIAGNOSTICS: dict[str, _Source] = {
    "Health_Isolation.ChtLimitMargin": _margin,
    "Health_Diag.StaleInputs": lambda snap, cyl, frames: _stale_bits(snap) & 0xFF,
    "Health_Diag.StaleInputsHigh": lambda snap, cyl, frames: _stale_bits(snap) >> 8,
    "Health_Diag.MalformedFrames": lambda snap, cyl, frames: min(frames.pipeline.counters["malformed"], 65535),
    "Health_Diag.BusErrors": lambda snap, cyl, frames: min(frames.pipeline.counters["bus_errors"], 255),
    "Health_Diag.MaintenanceAlert": lambda snap, cyl, frames: int(frames.maintenance_alert),
    "Health_Diag.HistoryDown": lambda snap, cyl, frames: frames.pipeline.counters.get("history_down", 0),
    "Health_Spread.CylinderCount": lambda snap, cyl, frames: len(snap.cylinders) or 1,
    "Health_Spread.FaultyCylinders": lambda snap, cyl, frames: _faulty(snap),
    "Health_Cylinder.CylinderNumber": lambda snap, cyl, frames: cyl.number,
}
#: The signals of the frames sent once per cylinder.
_PER_CYLINDER = {"Health_Cylinder.CylinderNumber", *(v.cylinder_dbc for v in HEALTH_VALUES if v.cylinder_dbc)}


def _engine_source(value: HealthValue) -> _Source:
    def source(snap: HealthSnapshot, cyl: Any, frames: DbcHealthFrames) -> float:
        return bus_number(value, getattr(snap, value.name), not math.isnan(snap.cht_est_c))

    return source


def _cylinder_source(value: HealthValue) -> _Source:
    def source(snap: HealthSnapshot, cyl: Any, frames: DbcHealthFrames) -> float:
        return bus_number(value, getattr(cyl, value.name), not math.isnan(cyl.cht_est_c))

    return source


def health_signal_sources() -> dict[str, _Source]:
    """``Message.Signal`` -> its value in a frame: the output table's ``dbc`` and ``cylinder_dbc`` rows (a nan
    sent as the row's idle value), then the service's diagnostics."""
    sources: dict[str, _Source] = {}
    for value in HEALTH_VALUES:
        if value.dbc:
            sources[value.dbc] = _engine_source(value)
        if value.cylinder_dbc:
            sources[value.cylinder_dbc] = _cylinder_source(value)
    return {**sources, **_DIAGNOSTICS}


class Publisher(Protocol):
    """One output of the service: the frames of the rows of the pipeline's output table."""

    def publish(self, rows: Sequence[StepRow]) -> Iterable[Any]:
        """The frames the rows make, oldest first (a generator may make each as it is asked for)."""
        ...

    def tell(self, text: str) -> None:
        """An open maintenance alert (its one-line text), told from the next row on (module docstring)."""
        ...

    def announce(self, event: Event) -> list[can.Message]:
        """An engine event that started (its start record): the frames it makes now (texts go out with the
        next health-status period)."""
        ...


#: The health.dbc frame of an engine event that started, and its data signals (DBC order).
EVENT_FRAME = "Health_Event"
EVENT_SIGNALS = ("EventKind", "EventCylinder", "EventValue", "EventLimit")


def _finite_or_zero(value: float) -> float:
    return value if math.isfinite(value) else 0.0


class DbcHealthFrames:
    """The health.dbc frames of each row: every message whose period (steps) divides the row's step; a
    message with a per-cylinder signal (Health_Cylinder) once per cylinder. Each signal's value comes from
    :func:`health_signal_sources`; a health.dbc signal of a configured message that has none is a
    ConfigError."""

    def __init__(self, config: ServiceConfig, pipeline: Pipeline) -> None:
        self.pipeline: Pipeline = pipeline
        self.encoder = Encoder([config.health_dbc])
        self.periods = dict(pipeline.periods)
        self._ids = {
            name: (int(self.encoder.message(name).frame_id), bool(self.encoder.message(name).is_extended_frame))
            for name in self.periods
        }
        known = health_signal_sources()
        self._sources: dict[str, tuple[_Source, ...]] = {}
        self._per_cylinder: set[str] = set()
        for name in self.periods:
            signals = self.encoder.data_signals(name)
            missing = [s for s in signals if f"{name}.{s}" not in known]
            if missing:
                raise ConfigError(f"{config.health_dbc}: {name}.{missing[0]} is no health value the service makes "
                                  "(ecu_monitor/pipeline/output_table.py)")  # fmt: skip
            self._sources[name] = tuple(known[f"{name}.{s}"] for s in signals)
            if any(f"{name}.{s}" in _PER_CYLINDER for s in signals):
                self._per_cylinder.add(name)
        self._packers = {name: self.encoder.packer(name, self.encoder.data_signals(name)) for name in self.periods}
        self._counters = dict.fromkeys(self.periods, 0)
        #: each cylinder's CHT limit, degC
        self.limits = [m.cht_limit_c for m in pipeline.cylinder_params]
        self.maintenance_alert = False  # Health_Diag.MaintenanceAlert: an open alert told (set, never cleared)
        pipeline.counters.setdefault("health_frames", 0)
        try:
            event = self.encoder.message(EVENT_FRAME)
        except KeyError:  # a health.dbc of the user's without the event frame: events go out on no frame
            event = None
        self._events_framed = event is not None
        if event is not None:
            self._packers[EVENT_FRAME] = self.encoder.packer(EVENT_FRAME, EVENT_SIGNALS)
            self._ids[EVENT_FRAME] = (int(event.frame_id), bool(event.is_extended_frame))
            self._counters[EVENT_FRAME] = 0

    def tell(self, text: str) -> None:
        self.maintenance_alert = True

    def announce(self, event: Event) -> list[can.Message]:
        """The Health_Event frame of the event (none when the health.dbc has no such message)."""
        if not self._events_framed:
            return []
        values = (EVENT_KINDS.index(event.kind), event.cylinder, _finite_or_zero(event.value), event.limit)
        return [self._frame(EVENT_FRAME, self.pipeline.now_s, values)]

    def publish(self, rows: Sequence[StepRow]) -> Iterator[can.Message]:
        """The frames of the rows, each made as it is asked for (in the config's order: Health_Status first,
        so the daemon sends it before the rest are made)."""
        for row in rows:
            snap: HealthSnapshot | None = None
            for message, period in self.periods.items():
                if row.k % period:
                    continue
                if snap is None:
                    snap = self.pipeline.snapshot_of(row)
                if message in self._per_cylinder:
                    for cylinder in snap.cylinders:
                        yield self._frame(message, row.time_s, self.values(message, snap, cylinder))
                else:
                    yield self._frame(message, row.time_s, self.values(message, snap))

    def _frame(self, message: str, time_s: float, values: tuple[float, ...]) -> can.Message:
        counter = self._counters[message]
        self._counters[message] = (counter + 1) % 16
        frame_id, extended = self._ids[message]
        self.pipeline.counters["health_frames"] += 1
        data = self._packers[message](values, counter)
        return can.Message(timestamp=time_s, arbitration_id=frame_id, is_extended_id=extended, data=data)

    def values(self, message: str, snap: HealthSnapshot, cylinder: Any = None) -> tuple[float, ...]:
        """The values of ``message``'s data signals (DBC order) for ``snap`` (``cylinder``: the
        CylinderSnapshot a per-cylinder frame describes)."""
        return tuple(source(snap, cylinder, self) for source in self._sources[message])


class DroneCanPublisher:
    """The service as a DroneCAN node: NodeStatus, KeyValue and LogMessage from the health-status rows, the
    rest of a KeyValue set and service replies on the rows between (runtime/dronecan_node.py)."""

    def __init__(self, config: ServiceConfig, pipeline: Pipeline) -> None:
        self.pipeline = pipeline
        status = pipeline.status_period
        self.node = DroneCanNode(
            config.dronecan, min(m.cht_limit_c for m in pipeline.cylinder_params), status * pipeline.dt_s, status
        )
        pipeline.counters["dronecan_frames"] = 0
        pipeline.counters["dronecan_requests"] = 0

    def publish(self, rows: Sequence[StepRow]) -> list[can.Message]:
        out: list[can.Message] = []
        status = self.pipeline.status_period
        for row in rows:
            if row.k % status == 0:
                out += self.node.frames(row.time_s, self.pipeline.snapshot_of(row))
            else:
                out += self.node.step_frames(row.time_s)
        self.pipeline.counters["dronecan_frames"] += len(out)
        return out

    def tell(self, text: str) -> None:
        self.node.tell(text)

    def announce(self, event: Event) -> list[can.Message]:
        self.node.tell(event.start_text(), advisory=event.advisory)
        return []

    def take_request(self, msg: can.Message, time_s: float) -> bool:
        """A service request to the node (GetNodeInfo), taken here: not an input."""
        taken = bool(msg.arbitration_id & 0x80) and self.node.take_request(msg, time_s)
        if taken:
            self.pipeline.counters["dronecan_requests"] += 1
        return taken


class MavlinkHealth:
    """The service as a MAVLink component (runtime/mavlink_publisher.py): HEARTBEAT, STATUSTEXT on each state
    change, NAMED_VALUE_FLOAT, optionally EFI_STATUS, from the health-status rows; pymavlink messages, which
    the link (runtime/mavlink_link.py) packs with the service's ids."""

    def __init__(self, config: ServiceConfig, pipeline: Pipeline) -> None:
        from ecu_monitor.runtime.mavlink_publisher import MavlinkPublisher

        self.pipeline = pipeline
        self.publisher = MavlinkPublisher(
            config.mavlink, [m.cht_limit_c for m in pipeline.cylinder_params], {s.message for s in config.inputs}
        )
        pipeline.counters["mavlink_messages"] = 0

    def tell(self, text: str) -> None:
        self.publisher.tell(text)

    def announce(self, event: Event) -> list[Any]:
        self.publisher.announce(event)
        return []

    def publish(self, rows: Sequence[StepRow]) -> list[Any]:
        out: list[Any] = []
        status = self.pipeline.status_period
        for row in rows:
            if row.k % status:
                continue
            inputs = {
                name: value for name in self.pipeline.names if (value := self.pipeline.held_input(name)) is not None
            }
            out += self.publisher.messages(row.time_s, self.pipeline.snapshot_of(row), inputs)
        self.pipeline.counters["mavlink_messages"] += len(out)
        return out


def make_publishers(config: ServiceConfig, pipeline: Pipeline) -> list[Publisher]:
    """The publishers of a config, the one table of them, in the order their frames go out: the health.dbc
    frames (protocol dbc, or dronecan with ``dronecan.dbc_health_frames``), the DroneCAN node (protocol
    dronecan), the MAVLink component (protocol mavlink)."""
    publishers: list[Publisher] = []
    if config.protocol == "dbc" or (config.protocol == "dronecan" and config.dronecan.dbc_health_frames):
        publishers.append(DbcHealthFrames(config, pipeline))
    if config.protocol == "dronecan":
        publishers.append(DroneCanPublisher(config, pipeline))
    if config.protocol == "mavlink":
        publishers.append(MavlinkHealth(config, pipeline))
    return publishers


#: Event records LiveMonitor keeps for :meth:`LiveMonitor.drain_events` (older ones dropped).
_KEPT_EVENTS = 1000


class LiveMonitor:
    """The pipeline and its publishers: :meth:`feed` a received frame, :meth:`advance_to` the clock and get
    the frames to send (what the daemon's receive and tick threads call)."""

    def __init__(self, config: ServiceConfig, params: ThermalParams | Sequence[ThermalParams]) -> None:
        self.config = config
        # the DroneCAN node spreads its KeyValue sets over every step
        self.pipeline = Pipeline(config, params, rows="step" if config.protocol == "dronecan" else "health")
        self.publishers = make_publishers(config, self.pipeline)
        self.counters = self.pipeline.counters
        self.counters.setdefault("health_frames", 0)
        self.counters.setdefault("send_errors", 0)
        self.counters.setdefault("history_down", 0)  # 1 while the flight history cannot be written (the daemon)
        self._node = next((p for p in self.publishers if isinstance(p, DroneCanPublisher)), None)
        self._events: list[Event] = []  # event records not yet drained (drain_events)

    @property
    def params(self) -> ThermalParams:
        return self.pipeline.params

    @property
    def cylinder_params(self) -> tuple[ThermalParams, ...]:
        return self.pipeline.cylinder_params

    @property
    def steps_done(self) -> int:
        return self.pipeline.steps_done

    @property
    def row_period_s(self) -> float:
        return self.pipeline.row_period_s

    @property
    def decoder(self) -> Any:
        return self.pipeline.decoder

    @property
    def model_inputs(self) -> tuple[str, ...]:
        return self.pipeline.model_inputs

    def feed(self, msg: can.Message) -> None:
        """Take one received frame (never raises for any frame content)."""
        if self._node is not None and self._node.take_request(msg, self.pipeline.now_s):
            return
        self.pipeline.feed(msg)

    def advance_to(self, t_s: float) -> list[can.Message]:
        """Run the steps up to ``t_s`` (s); the frames to send (:meth:`frames_until`, all made)."""
        return list(self.frames_until(t_s))

    def frames_until(self, t_s: float) -> Iterator[can.Message]:
        """A generator: on the first frame asked for, run the steps up to ``t_s`` (s); then the frames the
        publishers make of their rows, then of the engine events that started (:meth:`Publisher.announce`),
        each made as it is asked for (the daemon sends each before the next is made). Nothing runs until it
        is iterated, and it must be iterated to the end: the publishers' state moves as the frames are made."""
        for row in self.pipeline.advance_to(t_s):
            for publisher in self.publishers:
                yield from publisher.publish((row,))
        events = self.pipeline.take_events()
        if events:
            for event in events:
                if event.ongoing:
                    for publisher in self.publishers:
                        yield from publisher.announce(event)
            self._events += events
            del self._events[:-_KEPT_EVENTS]

    def drain_events(self) -> list[Event]:
        """The event records (starts and ends, pipeline/events.py) since the last call (the flight recorder's;
        the last _KEPT_EVENTS when nobody drains them)."""
        out, self._events = self._events, []
        return out

    def snapshot(self) -> HealthSnapshot:
        return self.pipeline.snapshot()

    def drain_rows(self) -> list[HealthSnapshot]:
        return self.pipeline.drain_rows()

    def held_input(self, name: str) -> float | None:
        return self.pipeline.held_input(name)

    def tell(self, text: str) -> None:
        """Tell an open maintenance alert on every output (each publisher's :meth:`Publisher.tell`)."""
        for publisher in self.publishers:
            publisher.tell(text)

    def reference_model_c(self) -> float:
        return self.pipeline.reference_model_c()

    def warm_up(self) -> float:
        return self.pipeline.warm_up()

    def receive_filters(self) -> list[CanFilter]:
        """python-can receive filters of the frames the service reads: the inputs', and the node's requests."""
        filters = self.pipeline.receive_filters()
        if self._node is not None:
            filters.append(self._node.node.request_filter())
        return filters
