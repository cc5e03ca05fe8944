"""The pipeline of one engine: decoded inputs held, the one compiled step (step.py) on the fixed-step
schedule, and the output table. Live and replay are the same object and the same compiled functions;
only where frames and time come from differs (:meth:`Pipeline.feed` + :meth:`Pipeline.advance_to` frame
by frame, or :meth:`Pipeline.run_frames` over a whole log's arrays).

Clock. The only clock is the one passed to :meth:`Pipeline.advance_to` (frame timestamps in replay, a
monotonic clock live), rounded to the microsecond. A frame fed after ``advance_to(t)`` is stamped ``t``
and is seen by the steps after ``t`` (sample and hold). Steps fall at ``t0 + k dt`` where ``t0`` is the
first ``advance_to``; a jump of the clock by more than ``MAX_CLOCK_GAP_S`` restarts the schedule.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import msgspec
import numba
import numpy as np
from numpy.typing import NDArray

from ecu_monitor.bus.codec import INPUT_NAMES, Decoder, SignalSpec
from ecu_monitor.errors import ConfigError
from ecu_monitor.estimation.ekf import _RESET_CODES, ThermalEKF
from ecu_monitor.estimation.isolation import IsolationFilter, IsolationSettings, model_vector
from ecu_monitor.estimation.registry import ESTIMATORS, make_estimator
from ecu_monitor.model import ThermalParams, coefficients, pack_coefficients
from ecu_monitor.model.effects import MixtureIndex
from ecu_monitor.model.inputs import MIXTURE_COLUMNS, input_columns
from ecu_monitor.pipeline.events import EVENT_KINDS, Event
from ecu_monitor.pipeline.output_table import cylinder_snapshot, output_fields
from ecu_monitor.pipeline.outputs import HealthSnapshot
from ecu_monitor.pipeline.schedule import filter_period_steps
from ecu_monitor.pipeline.step import (
    CLOCK,
    CYLINDER_OUTPUT,
    CYLINDER_SETTINGS,
    CYLINDER_STATE,
    EVENT,
    Engine,
    Rows,
    Traces,
    compiled,
)
from ecu_monitor.pipeline.supervision import CODE_UNAVAILABLE

if TYPE_CHECKING:
    from can.typechecking import CanFilter

    from ecu_monitor.bus.dronecan import DroneCanDecoder
    from ecu_monitor.bus.mavlink import MavlinkDecoder
    from ecu_monitor.config import ServiceConfig
    from ecu_monitor.estimation.detection import DetectorSettings

__all__ = [
    "MIXTURE_CODES",
    "MODEL_INPUTS",
    "STATUS_INPUT",
    "Pipeline",
    "StepRow",
    "fed_mixture",
    "make_decoder",
    "model_input_names",
]

_log = logging.getLogger(__name__)

#: Value name of the optional ECU status signal (sensor open) in the decoder.
STATUS_INPUT = "cht_sensor_status"
#: The model inputs besides the heat-map axes (InputSeries order after the axes).
MODEL_INPUTS: tuple[str, ...] = ("altitude_m", "airspeed_mps", "oat_c")
#: The CHT input of a single-channel engine (a cylinder's is reported under this name when stale).
CHT_INPUT = "cht_c"
#: Rows the live pipeline's output table holds between two drains.
_LIVE_ROWS = 8192
#: The integer type of the decoded values' slots (an index into :attr:`Pipeline.names`) the compiled loop
#: reads, live and in replay alike (one type: the loop is compiled once).
SLOT_DTYPE = np.int16
#: Events the step's buffer holds between two :meth:`Pipeline.take_events` (more are counted, dropped).
_EVENT_CAPACITY = 4096


@dataclass(frozen=True)
class StepRow:
    """One row of the output table: step ``k`` at ``time_s`` (s), the stale inputs, each cylinder's result
    (a CYLINDER_OUTPUT record each, in ``cylinders``)."""

    k: int
    time_s: float
    stale: tuple[str, ...]
    stale_bits: int  # Health_Diag.StaleInputs: bit i = INPUT_NAMES[i]
    cylinders: Any  # CYLINDER_OUTPUT[cylinders]


def make_decoder(config: ServiceConfig, specs: list[SignalSpec]) -> Decoder | DroneCanDecoder | MavlinkDecoder:
    """The decoder of the config's protocol: DBC frames (:class:`Decoder`), DroneCAN messages
    (:class:`~ecu_monitor.bus.dronecan.DroneCanDecoder`, senders filtered by ``dronecan.source_node_ids``)
    or MAVLink messages (:class:`~ecu_monitor.bus.mavlink.MavlinkDecoder`, senders filtered by
    ``mavlink.source_system`` / ``source_component``, the service's own messages ignored)."""
    if config.protocol == "mavlink":
        from ecu_monitor.bus.mavlink import MavlinkDecoder

        m = config.mavlink
        return MavlinkDecoder(specs, m.source_system, m.source_component, own=(m.system_id, m.component_id))
    if config.protocol == "dronecan":
        from ecu_monitor.bus.dronecan import DroneCanDecoder

        return DroneCanDecoder(specs, config.dronecan.source_node_ids)
    return Decoder(config.dbc_paths, specs)


#: The step's code of each mixture-index source (pipeline/step.py, engine_step: how it computes the index).
MIXTURE_CODES: dict[str, int] = {"egt_c": 1, "fuel_per_rev": 2, "egt_rise": 3, "fuel_air": 4}


def model_input_names(params: ThermalParams, mapped: Collection[str] = ()) -> tuple[str, ...]:
    """Inputs the service feeds the model: the two heat-map axes, altitude, airspeed, OAT, then the
    columns of its mixture index (model/effects.py MIXTURE_COLUMNS) when the model has the mixture_index
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


def _detector_record(record: Any, settings: DetectorSettings | None) -> None:
    if settings is None:
        record["on"] = False
        record["threshold"] = 1.0
        record["block_s"] = 1.0
        record["suspect_fraction"] = 0.5
        return
    record["on"] = True
    for name in ("threshold", "reference", "warmup_s", "suspect_fraction", "block_s", "baseline_s", "scale_s",
                 "scale_floor"):  # fmt: skip
        record[name] = getattr(settings, name)
    record["delay_blocks"] = settings.delay_blocks
    record["freeze"] = settings.baseline_freeze


class Pipeline:
    """Frames -> held inputs -> the one step on the fixed-step schedule -> the output table
    (docs/architecture.md). Not thread-safe: the daemon guards it with a lock. ``counters`` (frames, ok,
    unknown_id, malformed and its reasons, ignored, bus_errors, steps, clock_restarts) may be incremented
    by the owner for events it sees."""

    def __init__(
        self, config: ServiceConfig, params: ThermalParams | Sequence[ThermalParams], *, rows: str = "health"
    ) -> None:
        """``params``: the model of every cylinder, or one per cylinder (``config.load_cylinder_params()``).
        ``rows``: when the output table has a row: ``"health"`` every step a health message falls due,
        ``"status"`` every health-status period (replay's health.csv), ``"step"`` every step."""
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
        estimator = make_estimator(config.estimator_name, self.params, config.estimator)  # unknown: ConfigError
        if not isinstance(estimator, ThermalEKF | IsolationFilter):  # a registered estimator the step cannot run
            raise ConfigError(
                f"{config.source}: estimator: {config.estimator_name!r} is not one the service's step runs (an"
                f" EKF-family filter or the isolation filter; known: {', '.join(sorted(ESTIMATORS))})"
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
            hint = (
                "; the shipped manifold.yaml maps manifold_pressure_kpa" if "manifold_pressure_kpa" in missing else ""
            )
            raise ConfigError(
                f"{config.source}: inputs: missing {', '.join(missing)} (the model reads "
                f"{', '.join(self.model_inputs)} and the CHT){hint}"
            )
        specs = [spec.signal_spec() for spec in config.inputs]
        sf = config.sensor_fault
        if sf.status_message is not None and sf.status_signal is not None:
            specs.append(SignalSpec(STATUS_INPUT, sf.status_message, sf.status_signal, "raw"))
        self.decoder: Any = make_decoder(config, specs)  # the protocol's: CAN frames or MAVLink messages
        self.counters: dict[str, int] = self.decoder.counters
        for key in ("bus_errors", "steps", "clock_restarts", "events_dropped"):
            self.counters[key] = 0
        self.names = self.decoder.names
        self._slot = {name: i for i, name in enumerate(self.names)}
        dt = config.estimator.dt_s
        self.dt_s = dt
        self.periods = {h.message: round(1.0 / (h.rate_hz * dt)) for h in config.health}
        self.status_period = self.periods["Health_Status"]
        row_period = {"status": self.status_period, "health": math.gcd(*self.periods.values()), "step": 1}[rows]
        self._cht_names = frozenset(cylinder_inputs)
        # the stale checks, in Health_Diag.StaleInputs order; a cylinder's CHT is reported as cht_c
        checks: list[tuple[str, int]] = []
        for n in INPUT_NAMES:
            if n == CHT_INPUT:
                checks += [(c, self._slot[c]) for c in cylinder_inputs]
            elif n in mapped:
                checks.append((n, self._slot[n]))
        self._check_names = tuple(CHT_INPUT if n in self._cht_names else n for n, _ in checks)
        self._check_bits = tuple(1 << INPUT_NAMES.index(n) for n in self._check_names)
        self._engine = self._build_engine(config, models, checks, dt, row_period)
        self._row_period = row_period
        self._rows = _rows(_LIVE_ROWS, len(models))
        self._no_traces = _traces(0, len(models))
        self._functions: Any = None
        self._live_entry: Callable[..., int] | None = None
        self._pending: list[StepRow] = []  # the health-status rows since drain_rows()
        self._latest: StepRow | None = None
        self._snapshot: HealthSnapshot | None = None
        # values decoded since the last compiled call (feed_values), held by the next advance_to
        self._slots_buffer = np.zeros(64, dtype=SLOT_DTYPE)
        self._values_buffer = np.zeros(64)
        self._fed = 0
        self._frame_times = np.zeros(2)  # advance_to's two frames: the fed values, then the clock reading
        self._frame_bounds = np.zeros(3, dtype=np.int64)
        clock = self._engine.clock
        self._clock_now, self._clock_started = clock["now_s"], clock["started"]
        self._clock_steps, self._clock_restarts = clock["steps"], clock["restarts"]

    # ------------------------------------------------------------------ building the records

    def _build_engine(
        self, config: ServiceConfig, models: tuple[ThermalParams, ...], checks: list[tuple[str, int]], dt: float,
        row_period: int,
    ) -> Engine:  # fmt: skip
        count = len(models)
        slots = len(self.names)
        clock = np.zeros(1, dtype=CLOCK)
        c = clock[0]
        c["origin_s"] = c["now_s"] = math.nan
        c["dt_s"] = dt
        c["filter_period"] = filter_period_steps(dt)
        c["headroom_period"] = self.periods.get("Health_Isolation", self.status_period)
        c["row_period"] = row_period
        c["status_slot"] = self._slot.get(STATUS_INPUT, -1)
        sf = config.sensor_fault
        c["min_c"], c["max_c"] = sf.min_c, sf.max_c
        c["cross"] = bool(config.cross_detectors)
        mixture_slots = np.zeros(max(len(names) for names in MIXTURE_COLUMNS.values()), dtype=np.int64)
        if self._mixture is not None:
            columns = MIXTURE_COLUMNS[self._mixture.source]
            c["mixture"] = MIXTURE_CODES[self._mixture.source]
            mixture_slots[: len(columns)] = [self._slot[n] for n in columns]
        model_slots = np.array([self._slot[n] for n in (*self.params.heat_axes, *MODEL_INPUTS)], dtype=np.int64)
        packed = [pack_coefficients(coefficients(m)) for m in models]
        n_s = packed[0].scalars.size
        n_x = max(p.heat_values_w.shape[0] for p in packed)
        n_y = max(p.heat_values_w.shape[1] for p in packed)
        scalars = np.zeros((count, n_s))
        heat = np.zeros((count, n_x, n_y))
        xb = np.zeros((count, n_x))
        yb = np.zeros((count, n_y))
        settings = np.zeros(count, dtype=CYLINDER_SETTINGS)
        iso_settings = IsolationSettings(dt_s=dt)
        iso_model = np.zeros((count, 4))
        iso_config = np.zeros((count, 7))
        est = config.estimator
        capacity = 1
        for i, (model, p) in enumerate(zip(models, packed, strict=True)):
            number = i + 1
            mx, my = p.heat_values_w.shape
            scalars[i] = p.scalars
            heat[i, :mx, :my] = p.heat_values_w
            xb[i, :mx] = p.x_breakpoints
            yb[i, :my] = p.y_breakpoints
            iso_model[i] = model_vector(coefficients(model))
            iso_config[i] = iso_settings.vector()
            s = settings[i]
            name = config.cylinder_inputs[i]
            s["cht_slot"] = self._slot[name]
            s["cht_check"] = next(j for j, (n, _) in enumerate(checks) if n == name)
            for field in ("dt_s", "process_var", "measurement_var", "sigmoid_a", "sigmoid_b", "quantum_c",
                          "deviation_time_s", "initial_var"):  # fmt: skip
                s[field] = getattr(est, field)
            # what the registry's estimator of that name is (estimation/registry.py: the one table of them)
            estimator = make_estimator(config.estimator_name, model, est)
            s["iso_estimator"] = isinstance(estimator, IsolationFilter)
            if isinstance(estimator, ThermalEKF):
                s["use_deviation"] = estimator.use_deviation
                s["reset_code"] = _RESET_CODES[estimator.reset_mode]
            s["iso_initial_cht_var"] = iso_settings.initial_cht_var
            s["iso_initial_gamma_var"] = iso_settings.initial_gamma_var
            s["stale_limit_s"] = config.stale_predict_limit_s
            s["stuck_after_s"] = sf.stuck_after_s
            s["stuck_change_c"] = sf.stuck_change_c
            s["cht_limit_c"] = model.cht_limit_c
            s["estimator_symptom"] = config.detector_symptom == "estimator"
            s["n_x"], s["n_y"] = mx, my
            own = config.cylinder_detector(number)
            cross = config.cross_detector(number)
            _detector_record(s["detector"], own)
            _detector_record(s["cross"], cross)
            e = s["events"]  # the config's events: limits under the same names, the inputs' slots
            for field, value in msgspec.structs.asdict(config.events).items():
                e[field] = model.cht_limit_c if field == "cht_limit_c" and value is None else value
            e["egt_slot"], e["egt_stale_s"] = self._event_input(config, f"egt{number}_c")
            e["oil_slot"], e["oil_stale_s"] = self._event_input(config, "oil_temp_c")
            _detector_record(s["nominal"], own.nominal_settings() if own.reference_on else None)
            s["nominal_level"][:] = own.nominal_levels() if own.reference_on else np.nan
            s["start_fit_mean"][:] = own.start_fit_mean or np.nan
            s["start_fit_spread"][:] = own.start_fit_spread or np.nan
            for d in (own, cross):
                if d is not None:
                    capacity = max(capacity, d.delay_blocks + 1)
        state = np.zeros(count, dtype=CYLINDER_STATE)  # made ready by the first advance_to (the clock's start)
        state["egt_fast"] = math.nan  # the EGT band-pass starts at the first fresh EGT
        state["egt_offset"] = math.nan  # the EGT's normal offsets, learned from the first EGT at steady power
        state["power_held"] = math.nan
        engine = Engine(
            clock=clock,
            values=np.full(slots, math.nan),
            stamps=np.full(slots, math.nan),
            early=np.zeros(slots, dtype=np.bool_),
            check_slot=np.array([slot for _, slot in checks], dtype=np.int64),
            check_limit_s=np.array(
                [config.input(n).stale_after_s if n in config.input_names else math.inf for n, _ in checks]
            ),
            check_model=np.array([n in self.model_inputs for n, _ in checks], dtype=np.bool_),
            model_slots=model_slots,
            mixture_slots=mixture_slots,
            open_values=np.array([float(v) for v in sf.open_values], dtype=np.float64),
            settings=settings,
            state=state,
            rings=np.zeros((count, 3, capacity)),  # the detector's, the cross-cylinder's, the reference test's
            coeff_scalars=scalars,
            heat_values=heat,
            x_breakpoints=xb,
            y_breakpoints=yb,
            iso_model=iso_model,
            iso_config=iso_config,
            output=np.zeros(count, dtype=CYLINDER_OUTPUT),
            scratch=np.zeros(24),
            symptoms=np.zeros((2, count)),
            events=np.zeros(_EVENT_CAPACITY, dtype=EVENT),
            event_count=np.zeros(2, dtype=np.int64),
        )
        return engine

    def _event_input(self, config: ServiceConfig, name: str) -> tuple[int, float]:
        """An input only the engine events read: its slot and stale time (s), or (-1, 0) when not mapped."""
        if name not in self._slot:
            return -1, 0.0
        return self._slot[name], config.input(name).stale_after_s

    def _compiled(self) -> Any:
        if self._functions is None:
            self._functions = compiled()
        return self._functions

    # ------------------------------------------------------------------ live

    @property
    def row_period_s(self) -> float:
        """How often the output table gets a row, s (its rows fall at the clock's start + whole periods)."""
        return self._row_period * self.dt_s

    @property
    def steps_done(self) -> int:
        """Fixed steps run since start (grows while the pipeline makes progress)."""
        return int(self._clock_steps[0])

    @property
    def now_s(self) -> float:
        """The clock's time, s (nan before it starts)."""
        return float(self._clock_now[0])

    @property
    def cylinder_count(self) -> int:
        """CHT channels (1: a single channel)."""
        return len(self.cylinder_params)

    def feed(self, msg: Any) -> None:
        """Take one received frame, a ``can.Message`` (a pymavlink message with ``protocol: mavlink``); never
        raises for any content."""
        if self.config.protocol == "mavlink":
            decoded = self.decoder.decode(msg)
            if decoded:
                self.feed_values(decoded)
            return
        if msg.is_error_frame:
            self.counters["frames"] += 1
            self.counters["bus_errors"] += 1
            self.counters["ignored"] += 1
            return
        if msg.is_remote_frame:
            self.counters["frames"] += 1
            self.counters["ignored"] += 1
            return
        stamp = float(self._clock_now[0]) if self._clock_started[0] else math.nan
        data = msg.data if msg.data is not None else b""
        decoded = self.decoder.decode(int(msg.arbitration_id), bool(msg.is_extended_id), data, stamp)
        if decoded:
            self.feed_values(decoded)

    def feed_values(self, decoded: Sequence[tuple[int, float]]) -> None:
        """Hold decoded values, (slot of :attr:`names`, value in its canonical unit), as of the clock's time
        (they reach the step's records with the next :meth:`advance_to`, before it moves the clock: one
        compiled call a frame)."""
        n = self._fed + len(decoded)
        if n > self._slots_buffer.size:
            self._slots_buffer = np.resize(self._slots_buffer, 2 * n)
            self._values_buffer = np.resize(self._values_buffer, 2 * n)
        j = self._fed
        for slot, value in decoded:
            self._slots_buffer[j] = slot
            self._values_buffer[j] = value
            j += 1
        self._fed = n

    def advance_to(self, t_s: float) -> list[StepRow]:
        """Hold the values fed since the last call (as of the clock's time then), then run every fixed step at
        or before ``t_s`` (s); returns the rows of the output table they wrote. One call of the compiled loop
        over two frames: the fed values at the clock's time (which runs no step), then ``t_s``."""
        times, bounds = self._frame_times, self._frame_bounds
        times[0] = self._clock_now[0] if self._clock_started[0] else math.nan  # nan: holds, starts nothing
        times[1] = t_s
        bounds[1] = bounds[2] = self._fed
        out: list[StepRow] = []
        start = 0
        while start < 2:  # the rows filled up: drain them and go on from the frame reached
            args = (self._engine, self._rows, self._no_traces, times, bounds, self._slots_buffer, self._values_buffer)
            if self._live_entry is None:
                self._live_entry = self._entry_for(*args, start)
            start = self._live_entry(*args, start)
            out += self._take_rows()
        self._fed = 0
        self._sync_counters()
        return out

    def _entry_for(self, *args: Any) -> Callable[..., int]:
        """``replay_loop``'s compiled entry point for these arguments' numba types, found once: a call through
        the dispatcher checks the types of every array of the records first, which costs several times
        the call itself (the live path calls it once a frame with arguments of the same types for the
        pipeline's life: the arrays are only ever replaced by arrays of the same dtype and layout)."""
        dispatcher = self._compiled().replay_loop
        if numba.config.DISABLE_JIT:  # NUMBA_DISABLE_JIT=1: the plain Python function, nothing to resolve
            return dispatcher  # type: ignore[no-any-return]
        # compile(): the entry point of the overload for these types (loaded or compiled if it is not there yet)
        return dispatcher.compile(tuple(dispatcher.typeof_pyval(arg) for arg in args))  # type: ignore[no-any-return]

    def _sync_counters(self) -> None:
        self.counters["steps"] = int(self._clock_steps[0])
        self.counters["clock_restarts"] = int(self._clock_restarts[0])
        self.counters["events_dropped"] = int(self._engine.event_count[1])

    def take_events(self) -> list[Event]:
        """The engine events the step wrote since the last call (oldest first; pipeline/events.py)."""
        count = self._engine.event_count
        n = int(count[0])
        if n == 0:
            return []
        records = self._engine.events[:n].tolist()
        count[0] = 0
        return [Event(t, EVENT_KINDS[kind], cylinder, value, limit, duration, ongoing)
                for t, kind, cylinder, value, limit, duration, ongoing in records]  # fmt: skip

    def close_events(self) -> list[Event]:
        """End every event condition still holding (the log ended) and take the events
        (:meth:`take_events`)."""
        self._compiled().close_events(self._engine)
        return self.take_events()

    def _take_rows(self) -> list[StepRow]:
        rows = self._rows
        count = int(rows.count[0])
        if count == 0:
            return []
        ks, times, masks = rows.k[:count].tolist(), rows.time_s[:count].tolist(), rows.stale[:count].tolist()
        out = [self._step_row(ks[r], times[r], masks[r], rows.cylinders[r].copy()) for r in range(count)]
        rows.count[0] = 0
        status = self.status_period
        for row in out:
            if row.k % status == 0:
                self._pending.append(row)
        self._latest = out[-1]
        self._snapshot = None
        return out

    def _step_row(self, k: int, time_s: float, mask: int, cylinders: Any) -> StepRow:
        names, bits = self._stale_of(mask)
        return StepRow(k, time_s, names, bits, cylinders)

    def _stale_of(self, mask: int) -> tuple[tuple[str, ...], int]:
        """A row's stale mask (bit j: stale check j) as the stale inputs' names and their
        Health_Diag.StaleInputs bits (bit i = INPUT_NAMES[i])."""
        names: list[str] = []
        bits = 0
        for j, name in enumerate(self._check_names):
            if mask >> j & 1:
                bits |= self._check_bits[j]
                if name not in names:
                    names.append(name)
        return tuple(names), bits

    def stale_bits(self, mask: NDArray[np.int64]) -> NDArray[np.int64]:
        """The output table's stale masks (bit j: stale check j) as Health_Diag.StaleInputs bits (bit i =
        INPUT_NAMES[i])."""
        if mask.size == 0:
            return np.zeros(0, dtype=np.int64)
        starts = np.flatnonzero(np.diff(mask, prepend=mask[0] - 1))  # runs of one mask: they change seldom
        masks = mask[starts].tolist()
        bits = {m: self._stale_of(m)[1] for m in set(masks)}
        return np.repeat(np.array([bits[m] for m in masks], dtype=np.int64), np.diff(starts, append=mask.size))

    def snapshot(self) -> HealthSnapshot:
        """The latest health snapshot (updated every row of the output table)."""
        if self._snapshot is None:
            row = self._latest
            self._snapshot = self._empty_snapshot() if row is None else self.snapshot_of(row)
        return self._snapshot

    def drain_rows(self) -> list[HealthSnapshot]:
        """Snapshots of the health-status periods since the last call (oldest first)."""
        rows, self._pending = self._pending, []
        return [self.snapshot() if row is self._latest else self.snapshot_of(row) for row in rows]

    def snapshot_of(self, row: StepRow) -> HealthSnapshot:
        """The snapshot of one row (one cylinder: its own values; several: the engine's view of them)."""
        from ecu_monitor.pipeline.cylinders import engine_snapshot

        cylinders = [cylinder_snapshot(n, r) for n, r in enumerate(row.cylinders, start=1)]
        return engine_snapshot(row.time_s, row.stale, cylinders, self.config.spread_limit_c)

    def _empty_snapshot(self) -> HealthSnapshot:
        nothing = np.zeros(len(self.cylinder_params), dtype=CYLINDER_OUTPUT)
        for name, _ in output_fields():
            nothing[name] = math.nan if nothing[name].dtype.kind == "f" else 0
        nothing["state"] = CODE_UNAVAILABLE
        nothing["region"] = -1
        stale = tuple(dict.fromkeys(self._check_names))
        return self.snapshot_of(StepRow(0, math.nan, stale, 0, nothing))

    def held_input(self, name: str) -> float | None:
        """The held (sample-and-hold) value of a mapped input, or None if never seen, stale or unmapped."""
        slot = self._slot.get(name)
        if self._fed:
            self.advance_to(math.nan)  # hold what was fed (a clock reading of nan moves nothing)
        if slot is None or name in self.snapshot().stale_inputs:
            return None
        value = float(self._engine.values[slot])
        return value if math.isfinite(value) else None

    def reference_model_c(self) -> float:
        """The open-loop reference model's CHT held now for the engine-level (lead) cylinder, degC: the nominal
        model run from the first reading (nan while the estimator is not running)."""
        lead = self.snapshot().lead_cylinder
        return float(self._engine.state[max(lead - 1, 0)]["model_c"])

    def receive_filters(self) -> list[CanFilter]:
        """python-can receive filters of the frames the pipeline reads (none on a MAVLink link)."""
        if self.config.protocol == "mavlink":
            return []
        return list(self.decoder.can_filters())

    def warm_up(self) -> float:
        """Load (or, on a fresh install, compile) the step's numba code by running it on a throwaway copy of
        this pipeline; returns the seconds taken. The daemon calls it before it opens the bus: otherwise the
        first frame would wait for the load. This pipeline's own state is untouched."""
        started = time.perf_counter()
        probe = Pipeline(self.config, self.cylinder_params)
        probe.feed_values([(slot, 100.0) for slot in range(len(probe.names))])
        for t_s in (0.0, 1.0):
            probe.advance_to(t_s)
        return time.perf_counter() - started

    @property
    def engine(self) -> Engine:
        """The step's records (settings, state, held inputs), for inspection."""
        return self._engine

    # ------------------------------------------------------------------ replay

    def run_frames(
        self, frame_time_s: NDArray[np.float64], first_value: NDArray[np.int64], slots: NDArray[np.int16],
        values: NDArray[np.float64], on_rows: Callable[[Rows, int], None], *, traces: bool = False,
    ) -> Traces:  # fmt: skip
        """The live loop over a whole log in compiled calls: for each frame, advance the clock to its time
        (``frame_time_s``, s) and feed its decoded values (``slots[first_value[f]:first_value[f + 1]]``).
        ``on_rows(rows, n)``: called with each block of up to :data:`ROW_BLOCK` rows of the output table (the
        first ``n`` of ``rows``, every ``row_period`` steps) as the loop writes them; the next block is written
        over it (the callback copies what it keeps). The loop releases the GIL, so a thread the callback feeds
        (the health.csv writer) runs beside it. Returns, with ``traces``, every step's results."""
        n_frames = frame_time_s.size
        span = 0.0
        finite = frame_time_s[np.isfinite(frame_time_s)]
        if finite.size:
            span = float(np.max(finite) - np.min(finite))
        steps = int(span / self.dt_s) + 16
        count = len(self.cylinder_params)
        rows = _rows(ROW_BLOCK, count)
        kept = _traces(steps + 16 if traces else 0, count)
        loop = self._compiled().replay_loop_released
        start = 0
        while start < n_frames:
            start = int(loop(self._engine, rows, kept, frame_time_s, first_value, slots, values, start))
            if rows.count[0]:
                on_rows(rows, int(rows.count[0]))
            rows.count[0] = 0
        self._sync_counters()
        return kept


#: Rows of the output table handed to ``run_frames``' ``on_rows`` at a time.
ROW_BLOCK = 32768


def _rows(capacity: int, cylinders: int) -> Rows:
    return Rows(
        count=np.zeros(1, dtype=np.int64),
        k=np.zeros(capacity, dtype=np.int64),
        time_s=np.zeros(capacity),
        stale=np.zeros(capacity, dtype=np.int64),
        cylinders=np.zeros((capacity, cylinders), dtype=CYLINDER_OUTPUT),
    )


def _traces(capacity: int, cylinders: int) -> Traces:
    return Traces(
        count=np.zeros(1, dtype=np.int64),
        time_s=np.zeros(capacity),
        restart=np.zeros(capacity, dtype=np.int64),
        model_c=np.zeros((capacity, cylinders)),
        oat_c=np.zeros(capacity),
        detector_on=np.zeros((capacity, cylinders), dtype=np.bool_),
        cylinders=np.zeros((capacity, cylinders), dtype=CYLINDER_OUTPUT),
    )
