"""The pipeline: CAN frames in, health frames out, on a fixed 50 Hz step (live and replay, one object).

Data flow (docs/architecture.md)::

    feed(msg) -> Decoder (bus/codec.py: checks, DBC decode, unit conversion) -> held inputs
    advance_to(t) -> fixed steps t0 + k dt <= t -> supervise() -> estimator(s) -> detector
                  -> health rows (10 Hz) and health frames at their configured rates

Clock. The only clock is the one passed to :meth:`Pipeline.advance_to` (frame timestamps in replay,
a monotonic clock live), rounded to the microsecond (:func:`clock_tick`). A frame fed after
``advance_to(t)`` is stamped ``t`` and is seen by the steps after ``t`` (sample and hold). Steps fall
at ``t0 + k dt`` where ``t0`` is the first ``advance_to``. A jump of the clock by more than
:data:`MAX_CLOCK_GAP_S` restarts the schedule (counted).

Supervision, every step (:func:`supervise`, a pure function of floats so the replay's batch path
compiles the very same code with numba):

* UNAVAILABLE until every input the model needs is fresh and a plausible CHT reading is held; then
  the estimator starts from that reading;
* INPUT_STALE while any input has been silent longer than its ``stale_after_s``: the estimator keeps
  predicting on the model with the held inputs, no correction, so its variance grows; after
  ``stale_predict_limit_s`` it stops (UNAVAILABLE) and restarts once the inputs are back;
* SENSOR_FAULT while the CHT probe is reported open (ECU status), reads outside [min_c, max_c], or is
  stuck (no change for ``stuck_after_s`` while the open-loop model swings by ``stuck_change_c``): the
  filter runs open loop;
* otherwise the detector's verdict on the model-deviation symptom (NOMINAL / SUSPECT / DEGRADED).

The estimator is ``make_estimator(config.estimator_name)``; gamma_Q and gamma_D come from the
isolation filter run beside it; the detector (:class:`~ecu_monitor.estimation.detection.Detector`, a
CUSUM) watches the configured symptom from the first initialisation on, fed NaN (skipped) on steps
that are not NOMINAL-able, so its blocks stay on the clock; its DEGRADED verdict latches. The thermal
headroom (:func:`~ecu_monitor.estimation.headroom.thermal_headroom`, heat path taken in steady state
at the held inputs) is computed every Health_Isolation period and held in between.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Collection, Sequence
from typing import TYPE_CHECKING, NamedTuple

import can

if TYPE_CHECKING:
    from can.typechecking import CanFilter

    from ecu_monitor.bus.dronecan import DroneCanDecoder
from ecu_monitor.bus.codec import INPUT_NAMES, Decoder, Encoder, SignalSpec
from ecu_monitor.errors import ConfigError
from ecu_monitor.estimation import CHTEstimator, make_estimator
from ecu_monitor.estimation.cross_cylinder import cross_cylinder_step
from ecu_monitor.estimation.detection import STATES as VERDICTS
from ecu_monitor.estimation.detection import Detector
from ecu_monitor.estimation.ekf import ThermalEKF
from ecu_monitor.estimation.headroom import thermal_headroom, time_to_limit_s
from ecu_monitor.estimation.isolation import IsolationFilter, IsolationSettings
from ecu_monitor.model import InputSeries, ThermalParams, coefficients
from ecu_monitor.model.effects import MixtureIndex
from ecu_monitor.model.inputs import MIXTURE_COLUMNS, input_columns, series_of
from ecu_monitor.service.config import CHT_INPUT, ServiceConfig
from ecu_monitor.service.cylinders import engine_view
from ecu_monitor.service.dronecan_node import DroneCanNode
from ecu_monitor.service.health_rows import HEADROOM_NOT_LIMITED_S, CylinderSnapshot, HealthSnapshot
from ecu_monitor.service.live_call import LiveCall
from ecu_monitor.service.schedule import FILTER_PERIOD_S, MAX_CLOCK_GAP_S, MAX_CLOCK_S, clock_tick, filter_period_steps
from ecu_monitor.service.supervision import (
    ACTION_INITIALISE,
    ACTION_NONE,
    ACTION_PREDICT,
    ACTION_UPDATE,
    CODE_FAULT,
    CODE_NOMINAL,
    CODE_UNAVAILABLE,
    STATES,
    SupervisorState,
    initial_supervisor,
    supervise,
)

__all__ = [
    "ACTION_INITIALISE",
    "ACTION_NONE",
    "ACTION_PREDICT",
    "ACTION_UPDATE",
    "FILTER_PERIOD_S",
    "HEADROOM_NOT_LIMITED_S",
    "MAX_CLOCK_GAP_S",
    "MAX_CLOCK_S",
    "MODEL_INPUTS",
    "STATES",
    "STATUS_INPUT",
    "HealthSnapshot",
    "Pipeline",
    "SupervisorState",
    "clock_tick",
    "fed_mixture",
    "filter_period_steps",
    "initial_supervisor",
    "make_decoder",
    "model_input_names",
    "supervise",
]

_log = logging.getLogger(__name__)

#: Value name of the optional ECU status signal (sensor open) in the decoder.
STATUS_INPUT = "cht_sensor_status"
#: The model inputs besides the heat-map axes (InputSeries order after the axes).
MODEL_INPUTS: tuple[str, ...] = ("altitude_m", "airspeed_mps", "oat_c")


class _Held(NamedTuple):
    """Filter outputs held between filter calls (every FILTER_PERIOD_S)."""

    cht_est_c: float
    deviation: float
    gamma_q: float
    gamma_d: float
    iso_deviation: float
    model_c: float  # open-loop reference model, degC


_NO_ESTIMATE = _Held(math.nan, math.nan, math.nan, math.nan, math.nan, math.nan)


def make_decoder(config: ServiceConfig, specs: list[SignalSpec]) -> Decoder | DroneCanDecoder:
    """The decoder of the config's protocol: DBC frames (:class:`Decoder`) or DroneCAN messages
    (:class:`~ecu_monitor.bus.dronecan.DroneCanDecoder`, senders filtered by ``dronecan.source_node_ids``)."""
    if config.protocol == "dronecan":
        from ecu_monitor.bus.dronecan import DroneCanDecoder

        return DroneCanDecoder(specs, config.dronecan.source_node_ids)
    return Decoder(config.dbc_paths, specs)


class _Cylinder:
    """One cylinder's estimation: its CHT input, model, supervisor, filters, detector and held outputs."""

    __slots__ = (
        "coeffs", "cross_detector", "cross_settings", "detector", "detector_settings", "detector_started",
        "estimator", "headroom_s", "held", "isolation", "live", "name", "number", "params", "pending_reading",
        "readings", "readings_used", "reference", "slot", "sv",
    )  # fmt: skip

    def __init__(self, number: int, name: str, slot: int, params: ThermalParams, config: ServiceConfig) -> None:
        self.number = number  # 1-based
        self.name = name  # its CHT input (cht_c, or cht<number>_c)
        self.slot = slot  # its CHT value slot in the decoder
        self.params = params
        self.coeffs = coefficients(params)
        self.detector_settings = config.cylinder_detector(number)
        self.cross_settings = config.cross_detector(number)  # None: no cross-cylinder detector
        self.readings = 0  # valid CHT frames fed
        self.readings_used = 0
        self.stop()

    def stop(self) -> None:
        """Estimation and detection start afresh (at start and after a clock restart)."""
        self.held = _NO_ESTIMATE
        self.sv = initial_supervisor()
        self.estimator: CHTEstimator | None = None
        self.reference: CHTEstimator | None = None
        self.isolation: IsolationFilter | None = None
        self.live: LiveCall | None = None  # the three filters and the supervision as one compiled call
        self.detector = Detector(self.detector_settings)
        self.cross_detector = None if self.cross_settings is None else Detector(self.cross_settings)
        self.detector_started = False
        self.headroom_s = math.nan
        self.pending_reading = False


#: A frame expected this long (s) before a Health_Status step's time may still be the one that runs it (its
#: arrival jitters around the step grid when the ECU's clock keeps phase with it): it is rehearsed for too.
REHEARSAL_EARLY_S = 0.001

#: DegradationState code of each state name.
_STATE_CODE = {name: code for code, name in enumerate(STATES)}
#: State codes 0 .. this are the detector's verdicts (NOMINAL, SUSPECT, DEGRADED): the supervisor said NOMINAL.
_LAST_VERDICT = _STATE_CODE["DEGRADED"]


#: State code of each detector verdict (by its index in detection.STATES: what Detector.step returns).
_VERDICT_CODE = tuple(_STATE_CODE[name] for name in VERDICTS)
#: The data signals of each health message (health.dbc), in the order Pipeline._health_values gives their values.
HEALTH_SIGNALS: dict[str, tuple[str, ...]] = {
    "Health_Status": ("ChtEstimate", "ModelDeviation", "DegradationState"),
    "Health_Isolation": ("GammaQEstimate", "GammaDEstimate", "ThermalHeadroom", "ChtLimitMargin"),
    "Health_Diag": ("StaleInputs", "MalformedFrames", "BusErrors"),
    "Health_Spread": ("ChtSpread", "HottestCylinder", "SpreadAlarm", "CylinderCount", "FaultyCylinders"),
    "Health_Cylinder": ("CylinderNumber", "CylChtEstimate", "CylState", "CylGammaQ", "CylGammaD"),
}
#: One cylinder's result of a step: (reading degC, estimate degC, deviation degC/s, state code, gamma_Q,
#: gamma_D, headroom s).
_Result = tuple[float, float, float, int, float, float, float]


def _cylinder_values(cyl: CylinderSnapshot) -> tuple[float, ...]:
    """Health_Cylinder's signals for one cylinder (HEALTH_SIGNALS order; nan sent as the signal's idle value)."""
    est = cyl.cht_est_c
    return (
        cyl.number,
        est if math.isfinite(est) else -40.0,
        _STATE_CODE[cyl.state],
        cyl.gamma_q if math.isfinite(cyl.gamma_q) else 1.0,
        cyl.gamma_d if math.isfinite(cyl.gamma_d) else 1.0,
    )


def model_input_names(params: ThermalParams, mapped: Collection[str] = ()) -> tuple[str, ...]:
    """Inputs the service feeds the model: the two heat-map axes, altitude, airspeed, OAT, then the
    columns of its mixture index (egt_c, or fuel_flow_lph and rpm) when the model has the mixture_index
    effect and ``mapped`` (the config's input names) holds them all; otherwise the index is not fed and
    the effect's factor is 1."""
    names = (*params.heat_axes, *MODEL_INPUTS)
    mixture = fed_mixture(params, mapped)
    if mixture is None:
        return names
    return tuple(dict.fromkeys((*names, *MIXTURE_COLUMNS[mixture.source])))


def fed_mixture(params: ThermalParams, mapped: Collection[str]) -> MixtureIndex | None:
    """The model's mixture_index effect if the service feeds its index (see :func:`model_input_names`)."""
    mixture = params.effects.mixture_index
    if mixture is None or not all(name in mapped for name in MIXTURE_COLUMNS[mixture.source]):
        return None
    return mixture


class Pipeline:
    """Frames -> fixed-step estimation -> health frames (the contract in docs/service.md).

    Not thread-safe: the daemon guards it with a lock. ``counters`` (frames, ok, unknown_id,
    malformed and its reasons, ignored, bus_errors, steps, health_frames, send_errors, clock_restarts)
    may be incremented by the owner for events it sees (send_errors, bus_errors).
    """

    def __init__(self, config: ServiceConfig, params: ThermalParams | Sequence[ThermalParams]) -> None:
        """``params``: the model of every cylinder, or one per cylinder (``config.load_cylinder_params()``)."""
        self.config = config
        cylinder_inputs = config.cylinder_inputs
        models = (params,) * len(cylinder_inputs) if isinstance(params, ThermalParams) else tuple(params)
        if len(models) != len(cylinder_inputs):
            raise ConfigError(
                f"{config.source}: {len(models)} models for {len(cylinder_inputs)} cylinders"
                f" ({', '.join(cylinder_inputs)})"
            )
        self.params = models[0]
        self.cylinder_params = models
        mapped = set(config.input_names)
        self.model_inputs = model_input_names(self.params, mapped)
        for number, model in enumerate(models[1:], start=2):
            if input_columns(model) != input_columns(self.params):
                raise ConfigError(
                    f"{config.source}: cylinders.models: cylinder {number}'s model reads"
                    f" {', '.join(input_columns(model))}, cylinder 1's {', '.join(input_columns(self.params))} (the"
                    " inputs are shared: every cylinder's model must read the same)"
                )
        self._mixture = fed_mixture(self.params, mapped)
        unfed = [name for name in input_columns(self.params) if name not in self.model_inputs]
        if unfed:  # the model's own list (model/inputs.py) names more than the config maps
            _log.warning(
                "%s: the model's mixture_index effect reads %s, which the config's inputs do not map: the effect"
                " is off here (factor 1, the model's rule for an index not logged)",
                config.source,
                ", ".join(unfed),
            )
        missing = [name for name in (*self.model_inputs, *cylinder_inputs) if name not in mapped]
        unreadable = [name for name in missing if name not in INPUT_NAMES and name not in cylinder_inputs]
        if unreadable:  # e.g. a heat map identified on manifold pressure: no config can map it
            raise ConfigError(
                f"{config.source}: the model reads {', '.join(unreadable)}, which is not an input the service can"
                f" read (inputs: {', '.join(INPUT_NAMES)}): identify the model with --heat-axes among them"
            )
        if missing:
            raise ConfigError(
                f"{config.source}: inputs: missing {', '.join(missing)} (the model reads "
                f"{', '.join(self.model_inputs)} and the CHT)"
            )
        specs = [spec.signal_spec() for spec in config.inputs]
        sf = config.sensor_fault
        if sf.status_message is not None and sf.status_signal is not None:
            specs.append(SignalSpec(STATUS_INPUT, sf.status_message, sf.status_signal, "raw"))
        self.decoder = make_decoder(config, specs)
        self.encoder = Encoder([config.health_dbc])
        self.counters: dict[str, int] = self.decoder.counters
        for key in ("bus_errors", "steps", "health_frames", "send_errors", "clock_restarts"):
            self.counters[key] = 0
        names = self.decoder.names
        self._slot = {name: i for i, name in enumerate(names)}
        self._stale_after = [config.input(n).stale_after_s if n in mapped else math.inf for n in names]
        self._values = [math.nan] * len(names)
        self._stamps = [math.nan] * len(names)
        self._model_slots = [self._slot[n] for n in self.model_inputs]
        self._status_slot = self._slot.get(STATUS_INPUT, -1)
        self._plausible = (sf.min_c, sf.max_c, sf.open_values)  # a CHT reading's range, the ECU's "open" codes
        # stale inputs in Health_Diag.StaleInputs order; a cylinder's CHT is reported as cht_c
        self._input_slots: list[tuple[str, int]] = []
        for n in INPUT_NAMES:
            if n == CHT_INPUT:
                self._input_slots += [(c, self._slot[c]) for c in cylinder_inputs]
            elif n in mapped:
                self._input_slots.append((n, self._slot[n]))
        self._stale_checks = tuple((name, slot, self._stale_after[slot]) for name, slot in self._input_slots)
        self._model_input_set = frozenset(self.model_inputs)
        self._cylinders = [
            _Cylinder(number, name, self._slot[name], model, config)
            for number, (name, model) in enumerate(zip(cylinder_inputs, models, strict=True), start=1)
        ]
        self._per_cylinder = len(cylinder_inputs) > 1
        self._cross = bool(config.cross_detectors)
        self._single = self._cylinders[0]
        self._cht_names = frozenset(cylinder_inputs)
        self._cht_slots = {cyl.slot: cyl for cyl in self._cylinders}
        self._early: set[int] = set()  # slots fed before the first advance_to
        self._last_frame: can.Message | None = None  # the latest frame that decoded (rehearse() decodes it again)
        self._dt = config.estimator.dt_s
        self._origin: float | None = None
        self._now = -math.inf
        self._k = 0
        self._periods = {h.message: round(1.0 / (h.rate_hz * self._dt)) for h in config.health}
        self._frame_counters = dict.fromkeys(self._periods, 0)
        self._frame_ids = {  # (frame id, extended) of each health message, read once from cantools
            name: (int(self.encoder.message(name).frame_id), bool(self.encoder.message(name).is_extended_frame))
            for name in self._periods
        }
        # each health message packed from its values in HEALTH_SIGNALS order (its prepared layout, bus/codec.py)
        self._packers = {name: self.encoder.packer(name, HEALTH_SIGNALS[name]) for name in self._periods}
        self._stale_bit = {name: 1 << bit for bit, name in enumerate(INPUT_NAMES)}  # Health_Diag.StaleInputs
        self._estimator_symptom = config.detector_symptom == "estimator"
        self._status_period = self._periods["Health_Status"]
        # the steps of the health-status periods since drain_rows(): made into snapshots there, off the frame path
        self._rows: list[tuple[float, list[_Result], list[str]]] = []
        self._headroom_period = self._periods.get("Health_Isolation", self._status_period)
        self._filter_period = filter_period_steps(self._dt)
        # protocol dronecan: the service is a DroneCAN node (service/dronecan_node.py, called each step: the
        # health-status periods' snapshots, and the steps between); its health.dbc frames go out only if asked
        # for (dronecan.dbc_health_frames)
        self._node: DroneCanNode | None = None
        self._dbc_health = config.protocol == "dbc" or config.dronecan.dbc_health_frames
        if config.protocol == "dronecan":
            self._node = DroneCanNode(
                config.dronecan,
                min(m.cht_limit_c for m in self.cylinder_params),
                self._status_period * self._dt,
                self._status_period,
            )
            self.counters["dronecan_frames"] = 0
            self.counters["dronecan_requests"] = 0
        self._snapshot: HealthSnapshot | None = self._empty_snapshot(math.nan)
        self._last_step: tuple[float, list[_Result], list[str]] = (math.nan, [], [])

    # ------------------------------------------------------------------ public API

    @property
    def steps_done(self) -> int:
        """Fixed steps run since start (grows while the pipeline makes progress)."""
        return self.counters["steps"]

    def snapshot(self) -> HealthSnapshot:
        """The latest health snapshot (updated every step)."""
        snap = self._snapshot
        if snap is None:
            snap = self._snapshot = self._build_snapshot(*self._last_step)
        return snap

    def held_input(self, name: str) -> float | None:
        """The held (sample-and-hold) value of a mapped input, or None if never seen, stale or unmapped."""
        slot = self._slot.get(name)
        if slot is None or name in self.snapshot().stale_inputs:
            return None
        value = float(self._values[slot])
        return value if math.isfinite(value) else None

    def warm_up(self) -> float:
        """Load (or, on a fresh install, compile: ~3 s) the estimators' numba code; returns the seconds taken.

        Runs the filters, the detector and the headroom on a throwaway mid-map operating point; the
        pipeline's own state is untouched. The daemon calls it before it opens the bus: otherwise the
        first CHT frame would hold the frame path for the whole load.
        """
        started = time.perf_counter()
        heat_map = self.params.heat_map
        u = InputSeries(
            heat_map.x_breakpoints[len(heat_map.x_breakpoints) // 2],
            heat_map.y_breakpoints[len(heat_map.y_breakpoints) // 2],
            1000.0,
            20.0,
            15.0,
        )
        filters: list[CHTEstimator | IsolationFilter] = [
            make_estimator(self.config.estimator_name, self.params, self.config.estimator),
            make_estimator("ekf", self.params, self.config.estimator),
            IsolationFilter(self.params, IsolationSettings(dt_s=self._dt)),
        ]
        detector = Detector(self.config.detector)
        step_s = self._dt * self._filter_period
        for filt in filters:
            filt.initialise(0.0, u, 100.0)
            for k, reading_c in enumerate((100.0, None, 101.0), start=1):
                detector.update(k * step_s, filt.estimate(k * step_s, u, reading_c).deviation)
        thermal_headroom(100.0, None, u, self.params, coeffs=self._cylinders[0].coeffs)
        sf = self.config.sensor_fault
        live = LiveCall.of(filters[1], filters[0], filters[2], self._cylinders[0].coeffs, 3 * step_s,
                           self.config.stale_predict_limit_s, sf.stuck_after_s, sf.stuck_change_c)  # fmt: skip
        if live is not None:
            sv = SupervisorState(True, math.nan, 0.0, 100.0, 100.0, 100.0)
            live.call(4 * step_s, u, False, True, 101.0, False, True, sv)
        return time.perf_counter() - started

    def rehearse(self) -> None:
        """The work of the next step that sends Health_Status, on copies and with no effect on the pipeline:
        the decode of the latest input frame, the staleness and inputs, each cylinder's compiled call
        (:meth:`LiveCall.rehearse`), the detector's state, the headroom when that step computes it, the
        snapshot and the Health_Status frame. Run shortly before that step's frame is due, it brings the step's
        code and data into the caches (docs/performance.md, "Rehearsal")."""
        msg = self._last_frame
        if msg is not None:
            self.decoder.rehearse(msg.arbitration_id, msg.is_extended_id, msg.data)
        time_s, results, stale = self._last_step
        if not results:
            return
        self._stale(time_s)
        u = self._inputs()
        headroom_next = (self._k // self._status_period + 1) * self._status_period % self._headroom_period == 0
        for cyl in self._cylinders:
            if cyl.live is not None:
                cyl.live.rehearse(u)
            cyl.detector.output()
            est_c, _, gamma_q, gamma_d, _, _ = cyl.held
            if headroom_next and math.isfinite(est_c) and math.isfinite(gamma_q) and math.isfinite(gamma_d):
                time_to_limit_s(est_c, u, cyl.params, gamma_q=gamma_q, gamma_d=gamma_d, coeffs=cyl.coeffs)
        if self._dbc_health:
            snap = self._build_snapshot(time_s, results, stale) if self._per_cylinder else None
            lead, names, snap = self._frame_view(results, stale, snap)
            data = self._packers["Health_Status"](self._health_values("Health_Status", lead, names, snap), 0)
            frame_id, extended = self._frame_ids["Health_Status"]
            can.Message(timestamp=time_s, arbitration_id=frame_id, is_extended_id=extended, data=data)

    def receive_filters(self) -> list[CanFilter]:
        """python-can receive filters of the frames the pipeline reads: the decoder's, and on DroneCAN the
        service requests to the node."""
        filters = list(self.decoder.can_filters())
        if self._node is not None:
            filters.append(self._node.request_filter())
        return filters

    def drain_rows(self) -> list[HealthSnapshot]:
        """Snapshots of the health-status periods since the last call (oldest first)."""
        rows, self._rows = self._rows, []
        last = self._last_step
        return [self.snapshot() if step is last else self._build_snapshot(*step) for step in rows]

    def feed(self, msg: can.Message) -> None:
        """Take one received frame (never raises for any frame content)."""
        if msg.is_error_frame:
            self.counters["frames"] += 1
            self.counters["bus_errors"] += 1
            self.counters["ignored"] += 1
            return
        if msg.is_remote_frame:
            self.counters["frames"] += 1
            self.counters["ignored"] += 1
            return
        stamp = self._now if self._origin is not None else math.nan
        if self._node is not None and msg.arbitration_id & 0x80 and self._node.take_request(msg, self._now):
            self.counters["dronecan_requests"] += 1  # a service request to the node (GetNodeInfo), not an input
            return
        data = msg.data if msg.data is not None else b""
        decoded = self.decoder.decode(int(msg.arbitration_id), bool(msg.is_extended_id), data, stamp)
        if decoded is None:
            return
        self._last_frame = msg  # for rehearse()
        values, stamps, cht_slots = self._values, self._stamps, self._cht_slots
        for slot, value in decoded:
            values[slot] = value
            stamps[slot] = stamp
            if slot in cht_slots:
                cht_slots[slot].readings += 1
        if self._origin is None:
            self._early.update(slot for slot, _ in decoded)

    def advance_to(self, t_s: float) -> list[can.Message]:
        """Run every fixed step at or before ``t_s`` (s); returns the health frames that fell due."""
        if not (math.isfinite(t_s) and abs(t_s) < MAX_CLOCK_S):
            return []
        t_s = clock_tick(t_s)
        if self._origin is None or t_s - self._now > MAX_CLOCK_GAP_S:
            if self._origin is not None:
                self.counters["clock_restarts"] += 1
                self._stop_estimation()
            self._origin = float(t_s)
            self._now = float(t_s)
            self._k = 0
            for slot in self._early:  # frames fed before the clock started count as fed at its start
                self._stamps[slot] = float(t_s)
            self._early.clear()
            return []
        if t_s <= self._now:
            return []
        frames: list[can.Message] = []
        while True:
            step_time = clock_tick(self._origin + (self._k + 1) * self._dt)
            if step_time > t_s:
                break
            self._k += 1
            self._step(step_time, frames)
        self._now = float(t_s)
        return frames

    def rehearsal_frame_s(self, frame_s: float) -> float:
        """After a frame received at ``frame_s`` (s, the clock of ``advance_to``): when the next is expected
        (one step later: the ECU sends once per step) if that one may make the next Health_Status step fall
        due (it comes after that step's time, or at most ``REHEARSAL_EARLY_S`` before it); nan if it will not,
        or before the clock starts. The daemon rehearses (:meth:`rehearse`) shortly before that time."""
        if self._origin is None:
            return math.nan
        expected = frame_s + self._dt
        k = (self._k // self._status_period + 1) * self._status_period
        return expected if expected >= self._origin + k * self._dt - REHEARSAL_EARLY_S else math.nan

    # ------------------------------------------------------------------ one step

    def _stale(self, time_s: float) -> list[str]:
        """The inputs stale at ``time_s``: never seen (nan stamp: the test is False) or silent too long."""
        stamps = self._stamps
        return [name for name, slot, limit in self._stale_checks if not time_s - stamps[slot] <= limit]

    def _inputs(self) -> InputSeries:
        v = self._values
        s = self._model_slots
        if self._mixture is None:
            return InputSeries(v[s[0]], v[s[1]], v[s[2]], v[s[3]], v[s[4]])
        columns = {name: v[slot] for name, slot in zip(self.model_inputs, s, strict=True)}
        return series_of(columns, self.params.heat_axes, self._mixture)

    def _reading_bad(self, reading: float) -> bool:
        low, high, open_values = self._plausible
        if not low <= reading <= high:
            return True
        if self._status_slot >= 0:
            status = self._values[self._status_slot]
            return not math.isnan(status) and int(status) in open_values
        return False

    def _stop_estimation(self) -> None:
        """After a clock restart: estimation and detection start afresh."""
        for cyl in self._cylinders:
            cyl.stop()

    def _step(self, time_s: float, frames: list[can.Message]) -> None:
        self.counters["steps"] += 1
        stale = self._stale(time_s)
        model_stale = bool(stale) and not self._model_input_set.isdisjoint(stale)
        u = self._inputs()
        call = self._k % self._filter_period == 0
        isolation_due = self._k % self._headroom_period == 0
        if self._per_cylinder:
            results = [
                self._step_cylinder(cyl, time_s, u, model_stale or cyl.name in stale, call, isolation_due)
                for cyl in self._cylinders
            ]
            if self._cross:
                self._cross_step(time_s, results)
        else:
            cyl = self._single
            results = [self._step_cylinder(cyl, time_s, u, model_stale or cyl.name in stale, call, isolation_due)]
        # the snapshot is built when asked for (snapshot(), drain_rows() on the daemon's supervisor thread),
        # or for the frames of an engine monitored per cylinder: not on every step
        step = self._last_step = (time_s, results, stale)
        self._snapshot = None
        k = self._k
        status_due = k % self._status_period == 0
        if status_due:
            self._rows.append(step)
        if self._dbc_health:
            view = None
            for message, period in self._periods.items():
                if k % period == 0:
                    if view is None:
                        view = self._frame_view(results, stale, self.snapshot() if self._per_cylinder else None)
                    self._health_frames(frames, message, time_s, *view)
        if self._node is not None:  # after the health.dbc frames; a KeyValue set goes out over the other steps
            published = self._node.frames(time_s, self.snapshot()) if status_due else self._node.step_frames(time_s)
            if published:
                self.counters["dronecan_frames"] += len(published)
                frames.extend(published)

    def _build_snapshot(self, time_s: float, results: list[_Result], stale: list[str]) -> HealthSnapshot:
        """The snapshot of one step from its cylinders' results (one cylinder: its own values)."""
        if self._per_cylinder:
            names = tuple(dict.fromkeys(CHT_INPUT if name in self._cht_names else name for name in stale))
            return self._engine_snapshot(time_s, results, names)
        reading, est_c, deviation, state, gamma_q, gamma_d, headroom = results[0]
        return HealthSnapshot(
            time_s=time_s,
            cht_meas_c=reading,
            cht_est_c=est_c,
            deviation=deviation,
            state=STATES[state],
            gamma_q=gamma_q,
            gamma_d=gamma_d,
            headroom_s=headroom,
            stale_inputs=tuple(stale),
            sensor_fault=state == CODE_FAULT,
        )

    def _step_cylinder(
        self, cyl: _Cylinder, time_s: float, u: InputSeries, any_stale: bool, call: bool, isolation_due: bool
    ) -> _Result:
        """One step of one cylinder: (reading, estimate, deviation, state code, gamma_Q, gamma_D, headroom)."""
        reading = self._values[cyl.slot]
        new_reading = cyl.readings > cyl.readings_used
        cyl.readings_used = cyl.readings
        reading_bad = not math.isnan(reading) and self._reading_bad(reading)
        call = call and cyl.sv.running
        cfg = self.config
        live = cyl.live if call else None
        drive = None  # the model's drive at u if the estimator has just computed it (for the headroom)
        if live is not None:  # reference, supervision, estimator and isolation filter in one compiled call
            cyl.pending_reading = cyl.pending_reading or new_reading
            cyl.sv, code, action, model_c, est_c, deviation, gamma_q, gamma_d, iso_deviation = live.call(
                time_s, u, any_stale, new_reading, reading, reading_bad, cyl.pending_reading, cyl.sv
            )
        else:  # separate calls: an estimator the one call does not run (one added by register_estimator)
            if call and cyl.reference is not None:
                cyl.held = cyl.held._replace(model_c=cyl.reference.estimate(time_s, u, None).cht_c)
            model_c = cyl.held.model_c if cyl.sv.running else reading
            sf = cfg.sensor_fault
            cyl.sv, code, action = supervise(
                cyl.sv,
                time_s,
                any_stale,
                new_reading,
                reading,
                reading_bad,
                model_c,
                cfg.stale_predict_limit_s,
                sf.stuck_after_s,
                sf.stuck_change_c,
            )
            cyl.pending_reading = cyl.pending_reading or new_reading
        if action == ACTION_NONE:
            cyl.estimator = cyl.reference = cyl.isolation = cyl.live = None
            cyl.held = _NO_ESTIMATE
        elif action == ACTION_INITIALISE:
            cyl.estimator = make_estimator(cfg.estimator_name, cyl.params, cfg.estimator)
            cyl.reference = make_estimator("ekf", cyl.params, cfg.estimator)
            cyl.isolation = IsolationFilter(cyl.params, IsolationSettings(dt_s=self._dt))
            for filt in (cyl.estimator, cyl.reference, cyl.isolation):
                filt.initialise(time_s, u, reading)
            cyl.held = _Held(reading, 0.0, cyl.isolation.gamma_q, cyl.isolation.gamma_d, 0.0, reading)
            cyl.pending_reading = False
            cyl.headroom_s = math.nan
            cyl.detector_started = True
            if isolation_due and isinstance(cyl.estimator, ThermalEKF):
                drive = cyl.estimator.held_drive
            sf = cfg.sensor_fault
            cyl.live = LiveCall.of(cyl.reference, cyl.estimator, cyl.isolation, cyl.coeffs, time_s,
                                   cfg.stale_predict_limit_s, sf.stuck_after_s, sf.stuck_change_c)  # fmt: skip
            if cyl.live is not None:  # the call holds the filters' state from now on
                cyl.estimator = cyl.reference = cyl.isolation = None
        elif live is not None:
            cyl.pending_reading = False
            cyl.held = _Held(est_c, deviation, gamma_q, gamma_d, iso_deviation, model_c)
            drive = live.estimator_drive() if isolation_due else None
        elif call and cyl.estimator is not None and cyl.isolation is not None:
            z = reading if cyl.pending_reading and code == CODE_NOMINAL else None
            cyl.pending_reading = False
            estimate = cyl.estimator.estimate(time_s, u, z)
            iso_deviation = cyl.isolation.estimate(time_s, u, z).deviation
            iso = cyl.isolation
            cyl.held = _Held(estimate.cht_c, estimate.deviation, iso.gamma_q, iso.gamma_d, iso_deviation,
                             cyl.held.model_c)  # fmt: skip
            if isolation_due and isinstance(cyl.estimator, ThermalEKF):
                drive = cyl.estimator.held_drive
        est_c, deviation, gamma_q, gamma_d, iso_deviation, _ = cyl.held
        state = code
        if cyl.detector_started:
            symptom = deviation if self._estimator_symptom else iso_deviation
            verdict = cyl.detector.step(time_s, symptom if code == CODE_NOMINAL else math.nan)
            if code == CODE_NOMINAL:
                state = _VERDICT_CODE[verdict]
        if action == ACTION_NONE or not (math.isfinite(est_c) and math.isfinite(gamma_q) and math.isfinite(gamma_d)):
            cyl.headroom_s = math.nan
        elif isolation_due:  # the drive the estimator's compiled call has just computed at u, not again
            cyl.headroom_s = time_to_limit_s(
                est_c, u, cyl.params, gamma_q=gamma_q, gamma_d=gamma_d, coeffs=cyl.coeffs, drive=drive
            )
        return reading, est_c, deviation, state, gamma_q, gamma_d, cyl.headroom_s

    def _cross_step(self, time_s: float, results: list[_Result]) -> None:
        """The cross-cylinder detectors (estimation/cross_cylinder.py) on this step's symptoms: each
        cylinder's state (in ``results``, in place) becomes the more severe of its two detectors' verdicts."""
        estimator_symptom = self._estimator_symptom
        symptoms = [
            (cyl.held.deviation if estimator_symptom else cyl.held.iso_deviation)
            if cyl.detector_started and result[3] <= _LAST_VERDICT
            else math.nan
            for cyl, result in zip(self._cylinders, results, strict=True)
        ]
        for i, (cyl, cross) in enumerate(zip(self._cylinders, cross_cylinder_step(symptoms), strict=True)):
            if not cyl.detector_started or cyl.cross_detector is None:
                continue
            verdict = _VERDICT_CODE[cyl.cross_detector.step(time_s, cross)]
            if results[i][3] < verdict <= _LAST_VERDICT:
                results[i] = (*results[i][:3], verdict, *results[i][4:])

    def _engine_snapshot(
        self,
        time_s: float,
        results: list[_Result],
        stale: tuple[str, ...],
    ) -> HealthSnapshot:
        """The engine's snapshot from its cylinders' (service/cylinders.py: lead cylinder, spread, hottest)."""
        cylinders = tuple(
            CylinderSnapshot(number, reading, est_c, deviation, STATES[state], gamma_q, gamma_d, headroom)
            for number, (reading, est_c, deviation, state, gamma_q, gamma_d, headroom) in enumerate(results, start=1)
        )
        view = engine_view(cylinders, self.config.spread_limit_c)
        lead = cylinders[view.lead]
        return HealthSnapshot(
            time_s=time_s,
            cht_meas_c=lead.cht_meas_c,
            cht_est_c=lead.cht_est_c,
            deviation=lead.deviation,
            state=lead.state,
            gamma_q=lead.gamma_q,
            gamma_d=lead.gamma_d,
            headroom_s=lead.headroom_s,
            stale_inputs=stale,
            sensor_fault=any(c.sensor_fault for c in cylinders),
            cylinders=cylinders,
            cht_spread_c=view.spread_c,
            hottest_cylinder=view.hottest,
            spread_alarm=view.alarm,
        )

    # ------------------------------------------------------------------ health frames

    def _frame_view(
        self, results: list[_Result], stale: list[str], snap: HealthSnapshot | None
    ) -> tuple[_Result, Sequence[str], HealthSnapshot | None]:
        """What the engine's health frames say: (the lead's result, the stale input names, the snapshot). One
        cylinder: its own result and this step's stale names, no snapshot needed; per cylinder (``snap``: this
        step's snapshot): the lead cylinder's values and the snapshot's names (service/cylinders.py)."""
        if snap is None:
            return results[0], stale, None
        lead = (snap.cht_meas_c, snap.cht_est_c, snap.deviation, _STATE_CODE[snap.state], snap.gamma_q, snap.gamma_d,
                snap.headroom_s)  # fmt: skip
        return lead, snap.stale_inputs, snap

    def _health_frames(
        self,
        frames: list[can.Message],
        message: str,
        time_s: float,
        lead: _Result,
        stale: Sequence[str],
        snap: HealthSnapshot | None,
    ) -> None:
        """Append the frames of ``message`` due now: one, or one per cylinder for Health_Cylinder."""
        if message == "Health_Cylinder":
            snap = self.snapshot() if snap is None else snap
            frames.extend(self._frame(message, time_s, _cylinder_values(c)) for c in snap.cylinders)
        else:
            frames.append(self._frame(message, time_s, self._health_values(message, lead, stale, snap)))

    def _frame(self, message: str, time_s: float, values: tuple[float, ...]) -> can.Message:
        counter = self._frame_counters[message]
        self._frame_counters[message] = (counter + 1) % 16
        data = self._packers[message](values, counter)
        frame_id, extended = self._frame_ids[message]
        self.counters["health_frames"] += 1
        return can.Message(timestamp=time_s, arbitration_id=frame_id, is_extended_id=extended, data=data)

    def _health_values(
        self, message: str, lead: _Result, stale: Sequence[str], snap: HealthSnapshot | None
    ) -> tuple[float, ...]:
        """The values of ``message``'s signals in HEALTH_SIGNALS order (nan sent as each signal's idle value),
        from :meth:`_frame_view`'s (lead, stale, snap)."""
        _, est, deviation, code, gamma_q, gamma_d, headroom = lead
        finite = math.isfinite
        if message == "Health_Status":
            return (est if finite(est) else -40.0, deviation if finite(deviation) else 0.0, code)
        if message == "Health_Isolation":
            margin = self.params.cht_limit_c - est
            if snap is not None and snap.cylinders:  # the smallest margin of any cylinder (each to its own limit)
                margins = [self.cylinder_params[c.number - 1].cht_limit_c - c.cht_est_c for c in snap.cylinders]
                margin = min((m for m in margins if finite(m)), default=math.nan)
            return (
                gamma_q if finite(gamma_q) else 1.0,
                gamma_d if finite(gamma_d) else 1.0,
                headroom if finite(headroom) else 0.0 if math.isnan(est) else 6000.0,
                margin if finite(margin) else 0.0,
            )
        if message == "Health_Spread":
            snap = self.snapshot() if snap is None else snap
            faulty = 0
            for cyl in snap.cylinders:
                if cyl.sensor_fault:
                    faulty |= 1 << (cyl.number - 1)
            spread = snap.cht_spread_c
            return (spread if finite(spread) else 0.0, snap.hottest_cylinder, int(snap.spread_alarm),
                    len(snap.cylinders) or 1, faulty)  # fmt: skip
        bits = 0
        stale_bit = self._stale_bit
        for name in stale:
            bits |= stale_bit.get(name, 0)
        return (bits, min(self.counters["malformed"], 65535), min(self.counters["bus_errors"], 255))

    def _empty_snapshot(self, time_s: float) -> HealthSnapshot:
        stale = tuple(dict.fromkeys(CHT_INPUT if n in self._cht_names else n for n, _ in self._input_slots))
        if not self._per_cylinder:
            return HealthSnapshot(time_s, math.nan, math.nan, math.nan, STATES[CODE_UNAVAILABLE], math.nan, math.nan,
                                  math.nan, stale, False)  # fmt: skip
        nothing = (math.nan, math.nan, math.nan, CODE_UNAVAILABLE, math.nan, math.nan, math.nan)
        return self._engine_snapshot(time_s, [nothing] * len(self._cylinders), stale)
