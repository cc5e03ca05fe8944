"""Publishers: what the service sends back for each row of the pipeline's output table. Each publisher
takes the rows and returns the frames they make; :func:`make_publishers` is the one table of them for a
config. :class:`LiveMonitor` is the pipeline with its publishers: frames in, health frames out (what the
daemon and the demo run).

* :class:`DbcHealthFrames`: the health.dbc messages (Health_Status, Health_Isolation, Health_Diag,
  Health_Spread, Health_Cylinder) at their configured rates; a nan value is sent as the signal's idle value.
* :class:`DroneCanPublisher`: the service as a DroneCAN node (runtime/dronecan_node.py).
* :class:`MavlinkHealth`: the service as a MAVLink component (runtime/mavlink_publisher.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol

import can

from ecu_monitor.bus.codec import Encoder
from ecu_monitor.inputs import stale_bit
from ecu_monitor.model import ThermalParams
from ecu_monitor.pipeline.engine import Pipeline, StepRow
from ecu_monitor.pipeline.outputs import HealthSnapshot
from ecu_monitor.pipeline.supervision import STATES
from ecu_monitor.runtime.dronecan_node import DroneCanNode

if TYPE_CHECKING:
    from can.typechecking import CanFilter

    from ecu_monitor.config import ServiceConfig

__all__ = [
    "HEALTH_SIGNALS",
    "DbcHealthFrames",
    "DroneCanPublisher",
    "LiveMonitor",
    "MavlinkHealth",
    "Publisher",
    "make_publishers",
]

#: The data signals of each health message (health.dbc), in the order :meth:`DbcHealthFrames.values` gives them.
HEALTH_SIGNALS: dict[str, tuple[str, ...]] = {
    "Health_Status": ("ChtEstimate", "ModelDeviation", "DegradationState", "ChtRate"),
    "Health_Isolation": ("GammaQEstimate", "GammaDEstimate", "ThermalHeadroom", "ChtLimitMargin"),
    "Health_Diag": ("StaleInputs", "MalformedFrames", "BusErrors", "StaleInputsHigh", "MaintenanceAlert"),
    "Health_Spread": ("ChtSpread", "HottestCylinder", "SpreadAlarm", "CylinderCount", "FaultyCylinders"),
    "Health_Cylinder": ("CylinderNumber", "CylChtEstimate", "CylState", "CylGammaQ", "CylGammaD"),
}
#: Idle values sent for a nan (no estimate): the CHT estimate's floor, no deviation, gammas at 1, the
#: headroom's "not limited" with an estimate and 0 without one, no margin, no spread.
_IDLE_CHT_C = -40.0
_NOT_LIMITED_S = 6000.0
_STATE_CODE = {name: code for code, name in enumerate(STATES)}


class Publisher(Protocol):
    """One output of the service: the frames of the rows of the pipeline's output table."""

    def publish(self, rows: Sequence[StepRow]) -> list[can.Message]:
        """The frames the rows make, oldest first."""
        ...

    def tell(self, text: str) -> None:
        """An open maintenance alert (its one-line text), told from the next row on (module docstring)."""
        ...


class DbcHealthFrames:
    """The health.dbc frames of each row: every message whose period (steps) divides the row's step."""

    def __init__(self, config: ServiceConfig, pipeline: Pipeline) -> None:
        self.pipeline = pipeline
        self.encoder = Encoder([config.health_dbc])
        self.periods = dict(pipeline.periods)
        self._ids = {
            name: (int(self.encoder.message(name).frame_id), bool(self.encoder.message(name).is_extended_frame))
            for name in self.periods
        }
        self._packers = {name: self.encoder.packer(name, HEALTH_SIGNALS[name]) for name in self.periods}
        self._counters = dict.fromkeys(self.periods, 0)
        self._limits = [m.cht_limit_c for m in pipeline.cylinder_params]
        self.maintenance_alert = False  # Health_Diag.MaintenanceAlert: an open alert told (set, never cleared)
        pipeline.counters.setdefault("health_frames", 0)

    def tell(self, text: str) -> None:
        self.maintenance_alert = True

    def publish(self, rows: Sequence[StepRow]) -> list[can.Message]:
        out: list[can.Message] = []
        per_cylinder = self.pipeline.cylinder_count > 1
        for row in rows:
            snap: HealthSnapshot | None = None
            for message, period in self.periods.items():
                if row.k % period:
                    continue
                if per_cylinder and snap is None:
                    snap = self.pipeline.snapshot_of(row)
                if message == "Health_Cylinder" and snap is not None:
                    out += [self._frame(message, row.time_s, _cylinder_values(c)) for c in snap.cylinders]
                else:
                    out.append(self._frame(message, row.time_s, self.values(message, row, snap)))
        return out

    def _frame(self, message: str, time_s: float, values: tuple[float, ...]) -> can.Message:
        counter = self._counters[message]
        self._counters[message] = (counter + 1) % 16
        frame_id, extended = self._ids[message]
        self.pipeline.counters["health_frames"] += 1
        data = self._packers[message](values, counter)
        return can.Message(timestamp=time_s, arbitration_id=frame_id, is_extended_id=extended, data=data)

    def values(self, message: str, row: StepRow, snap: HealthSnapshot | None) -> tuple[float, ...]:
        """The values of ``message``'s signals in HEALTH_SIGNALS order; ``snap``: the row's snapshot on an
        engine monitored per cylinder (its lead cylinder's values), None for one cylinder (its own)."""
        finite = math.isfinite
        if snap is None:
            r = row.cylinders[0]
            est, deviation, code = float(r["cht_est_c"]), float(r["deviation"]), int(r["state"])
            gamma_q, gamma_d, headroom = float(r["gamma_q"]), float(r["gamma_d"]), float(r["headroom_s"])
            margin = self._limits[0] - est
            stale = row.stale
            rate = float(r["cht_rate_c_per_min"])
        else:
            est, deviation, code = snap.cht_est_c, snap.deviation, _STATE_CODE[snap.state]
            gamma_q, gamma_d, headroom = snap.gamma_q, snap.gamma_d, snap.headroom_s
            margins = [self._limits[c.number - 1] - c.cht_est_c for c in snap.cylinders]
            margin = min((m for m in margins if finite(m)), default=math.nan)
            stale = snap.stale_inputs
            rate = snap.cht_rate_c_per_min
        if message == "Health_Status":
            rate = min(max(rate, -128.0), 127.0) if finite(rate) else 0.0  # the signal's range, degC/min
            return (est if finite(est) else _IDLE_CHT_C, deviation if finite(deviation) else 0.0, code, rate)
        if message == "Health_Isolation":
            return (
                gamma_q if finite(gamma_q) else 1.0,
                gamma_d if finite(gamma_d) else 1.0,
                headroom if finite(headroom) else 0.0 if math.isnan(est) else _NOT_LIMITED_S,
                margin if finite(margin) else 0.0,
            )
        if message == "Health_Spread":
            snap = self.pipeline.snapshot_of(row) if snap is None else snap
            faulty = 0
            for cyl in snap.cylinders:
                if cyl.sensor_fault:
                    faulty |= 1 << (cyl.number - 1)
            spread = snap.cht_spread_c
            return (spread if finite(spread) else 0.0, snap.hottest_cylinder, int(snap.spread_alarm),
                    len(snap.cylinders) or 1, faulty)  # fmt: skip
        bits = 0
        for name in stale:
            bits |= stale_bit(name)
        counters = self.pipeline.counters
        return (bits & 0xFF, min(counters["malformed"], 65535), min(counters["bus_errors"], 255), bits >> 8,
                int(self.maintenance_alert))  # fmt: skip


def _cylinder_values(cyl: Any) -> tuple[float, ...]:
    """Health_Cylinder's signals for one cylinder (nan sent as the signal's idle value)."""
    est = cyl.cht_est_c
    return (
        cyl.number,
        est if math.isfinite(est) else _IDLE_CHT_C,
        _STATE_CODE[cyl.state],
        cyl.gamma_q if math.isfinite(cyl.gamma_q) else 1.0,
        cyl.gamma_d if math.isfinite(cyl.gamma_d) else 1.0,
    )


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
        self._node = next((p for p in self.publishers if isinstance(p, DroneCanPublisher)), None)

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
        """Run the steps up to ``t_s`` (s); the frames the publishers make of their rows."""
        frames: list[can.Message] = []
        for row in self.pipeline.advance_to(t_s):
            for publisher in self.publishers:
                frames += publisher.publish((row,))
        return frames

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
