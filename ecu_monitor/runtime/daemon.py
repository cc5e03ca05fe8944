"""The live service: a receive thread feeding the pipeline, health frames back onto the bus.

Three threads share one :class:`~ecu_monitor.runtime.publishers.LiveMonitor` (the pipeline and its
publishers) under one lock:

* the receive thread: it calls the bus's ``recv`` itself (no python-can Notifier: its lock and listener
  dispatch cost time on every frame), each frame is stamped with
  the daemon's monotonic clock, fed to the pipeline, and ``advance_to(now)`` runs at once, so a health
  frame that falls due is sent within the handling of that frame, each frame as soon as it is made (the
  low-latency path: ``frames_until``);
* the tick thread: ``advance_to(now)`` at each instant a row of the pipeline's output table falls due
  (``tick_s``: ``ecu-monitor run`` gives the row period, the health frames' 100 ms with the shipped rates,
  20 ms on DroneCAN, whose node sends on every step; phased on the clock's start), so the 50 Hz steps and
  the health frames go on when the frames stop (that is how staleness gets reported). Steps between two
  rows output nothing: running them together at the next row gives the same rows, and an idle daemon
  wakes and crosses into the compiled step a fifth as often as with a 20 ms tick;
* the supervisor (the thread that calls :meth:`Daemon.run`): reopens a failed bus with backoff, feeds
  the health rows to the flight recorder (SQLite writes stay off the frame path), logs each change of the
  engine's state (``engine state DEGRADED (was SUSPECT) at t = ... s``, t on the daemon's monotonic
  clock), pings the systemd watchdog only while ``pipeline.steps_done`` grows, updates ``STATUS=`` and the log.

Bus failures never end the process: a receive error (python-can's ``CanError`` or ``OSError`` from
``recv``, or anything else ``recv`` raises, logged by :meth:`Daemon._guarded`), a failed open, and every
failed send count one bus error (shown in Health_Diag.BusErrors); a receive error, or
``SEND_FAILURES_TO_REOPEN`` sends failing in a row, closes the bus and reopens it after ``initial``,
``2*initial``, ... up to ``max`` seconds.

A bus that carries no engine frame for ``no_frames_warning_s`` gets one warning (:class:`SilenceWatch`),
and one more each time frames come back and stop again: a daemon and a sender that cannot reach each
other (python-can's ``virtual`` interface connects only the buses of one process) otherwise just show
UNAVAILABLE.

Garbage collection: after importing numba, cantools and numpy the process holds ~120,000 tracked
objects, and a full (generation 2) collection scanning them all stalled every thread for 50-350 ms
here, longer than a health period and long enough to overflow a socket's receive queue. The daemon
collects once before READY and moves the start-up heap into the permanent generation (``gc.freeze``),
and freezes again when the estimator has run its first steps (its compiled code is loaded then), so
the collector only ever scans what the service allocates while it runs (docs/service.md, "Daemon").
Then automatic collection is switched off and the supervisor collects every period instead (the young
generation every period, generation 1 every 10th, a full collection every 120th: every 0.5 s, 5 s and
minute with the default period): a collection is
work that can wait, so it never starts inside the callback of a frame on the bus thread.

GIL: a thread that wants the interpreter while another runs Python waits until that one blocks, or
for the switch interval (5 ms by default) and then asks it to let go; with several threads passing the
GIL between them, a waiting thread can wait several intervals. ``DaemonSettings.switch_interval_s``
(None: the interpreter's) sets the interval while :meth:`Daemon.run` runs and restores it after
(docs/performance.md, "Live path", measures both).

:meth:`Daemon._guarded` holds the codebase's only broad ``except Exception``: whatever a frame or a tick
raises is logged and counted (``daemon_errors``), and the daemon keeps running; the watchdog then
decides, from the pipeline's progress, whether the process is still useful.
"""

from __future__ import annotations

import gc
import logging
import math
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

import can
from can.interfaces.virtual import VirtualBus

from ecu_monitor.bus.kernel_filter import attach_kernel_filter
from ecu_monitor.config import config_default
from ecu_monitor.runtime.flight_recorder import FlightRecorder, HeldInputs, flight_samples
from ecu_monitor.runtime.notify import SystemdNotifier, WatchdogGate

__all__ = ["SEND_FAILURES_TO_REOPEN", "Daemon", "DaemonSettings", "PipelineLike", "SilenceWatch", "bad_datagram"]

_log = logging.getLogger(__name__)

#: Consecutive failed sends after which the bus is considered gone and reopened.
SEND_FAILURES_TO_REOPEN = 20
#: Send timeout, s: a full transmit queue must not stall the receive path.
_SEND_TIMEOUT_S = 0.01
#: The tick wakes this long after a row's instant, s (a wake-up a hair early would leave the row to the next tick).
_TICK_LAG_S = 0.001
#: Receive timeout, s: how soon the receive thread sees that it is asked to stop.
_RECEIVE_TIMEOUT_S = 0.2

_T = TypeVar("_T")


class PipelineLike(Protocol):
    """What the daemon uses of :class:`~ecu_monitor.runtime.publishers.LiveMonitor` (the service contract)."""

    counters: dict[str, int]

    def feed(self, msg: can.Message) -> None: ...

    def advance_to(self, t_s: float) -> list[can.Message]: ...

    def frames_until(self, t_s: float) -> Iterable[can.Message]: ...

    def snapshot(self) -> Any: ...

    def drain_rows(self) -> list[Any]: ...

    def drain_events(self) -> list[Any]: ...

    def warm_up(self) -> float: ...

    @property
    def steps_done(self) -> int: ...


@dataclass(frozen=True)
class DaemonSettings:
    """Timing of the daemon's threads, s, and the bus reopen backoff, s. What the service config sets
    (``ecu-monitor run`` passes it: commands/run.py, daemon_settings) defaults to the config's default,
    declared once in :class:`~ecu_monitor.config.ConfigFile`."""

    tick_s: float = 0.02  # the tick thread's period (module docstring); run: the pipeline's row period
    supervise_s: float = 0.5  # supervisor period: reopen, persistence, watchdog (each wake-up costs CPU)
    status_every_s: float = 10.0  # STATUS= and the INFO log line
    backoff_initial_s: float = config_default("reopen_backoff_s").initial
    backoff_max_s: float = config_default("reopen_backoff_s").max
    watchdog_period_s: float | None = None  # None: no watchdog (not under systemd's WatchdogSec)
    freeze_heap: bool = True  # gc.freeze() the start-up heap (module docstring, "Garbage collection")
    collect_in_supervisor: bool = True  # with freeze_heap: gc.disable(), the supervisor collects instead
    # warn once when the bus carries no engine frame this long
    no_frames_warning_s: float = config_default("no_frames_warning_s")
    switch_interval_s: float | None = None  # sys.setswitchinterval while running (module docstring, "GIL")
    uncalibrated_warning: str = ""  # a detector not calibrated for its model, accepted: said in every status line


class SilenceWatch:
    """When to warn that a bus is silent: once per silence of at least ``limit_s``, s.

    :meth:`frame` records the time of the latest frame; :meth:`check`, called periodically, returns
    ``"silent"`` the first time a silence reaches ``limit_s``, ``"resumed"`` the first time after that
    when a frame has come (which re-arms the warning for the next silence), and None otherwise.
    """

    def __init__(self, limit_s: float, start_s: float) -> None:
        self.limit_s = limit_s
        self.last_frame_s = start_s
        self._warned_for: float | None = None  # last_frame_s of the silence already warned about

    def frame(self, now_s: float) -> None:
        """A frame arrived at ``now_s``, s."""
        self.last_frame_s = now_s

    def check(self, now_s: float) -> str | None:
        """``"silent"``, ``"resumed"`` or None (see the class docstring)."""
        if self._warned_for is not None:
            if self.last_frame_s == self._warned_for:
                return None
            self._warned_for = None
            return "resumed"
        if now_s - self.last_frame_s >= self.limit_s:
            self._warned_for = self.last_frame_s
            return "silent"
        return None


class Daemon:
    """The bus loop around one pipeline (see the module docstring).

    ``open_bus`` opens (and reopens) the bus: the bus is passed in, the daemon never builds one from a
    config itself. ``recorder`` (optional) receives one :class:`FlightSample` per health row;
    ``held_inputs()`` (called under the pipeline lock; :func:`~ecu_monitor.runtime.flight_recorder.held_inputs`)
    gives the engine speed held by the pipeline (the recorder finds flights from it), the reference model's
    CHT, OAT and throttle (the flight's wear index and time at high power). ``receive_ids`` (the
    decoder's frame ids) become the bus's receive filter, so other traffic (kernel-filtered on
    socketcan, and on udp_multicast by a socket filter: :mod:`ecu_monitor.bus.kernel_filter`) and our own
    health frames never reach the pipeline lock; ``receive_filters`` (python-can
    filters, the decoder's ``can_filters()``: DroneCAN matches a data type id under a mask) replace them.
    ``stop()`` is safe from a signal handler; :meth:`run` returns once everything is flushed.
    """

    def __init__(
        self,
        pipeline: PipelineLike,
        open_bus: Callable[[], can.BusABC],
        *,
        settings: DaemonSettings | None = None,
        notifier: SystemdNotifier | None = None,
        recorder: FlightRecorder | None = None,
        held_inputs: Callable[[], HeldInputs] | None = None,
        receive_ids: Sequence[int] = (),
        receive_filters: Sequence[can.typechecking.CanFilter] | None = None,
        clock: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        self.pipeline = pipeline
        self.settings = settings or DaemonSettings()
        self._open_bus = open_bus
        self._notifier = notifier or SystemdNotifier(address="")
        self._recorder = recorder
        self._held_inputs = held_inputs
        self._filters: list[can.typechecking.CanFilter] = (
            list(receive_filters)
            if receive_filters is not None
            else [{"can_id": i, "can_mask": 0x1FFFFFFF} for i in receive_ids]
        )
        self._clock = clock
        self._wall_clock = wall_clock
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._bus_failed = threading.Event()
        self._bus: can.BusABC | None = None
        self._receiver: threading.Thread | None = None  # the receive thread of the open bus
        self._receiver_stop = threading.Event()
        self._tick_thread: threading.Thread | None = None
        self._send_failures_in_row = 0
        self._heap_frozen_running = False
        self._collections = 0  # supervisor periods since the start (the collections it ran)
        self._manual_gc = False  # automatic collection switched off by run()
        self._switch_interval_before: float | None = None  # the interpreter's, while run() has its own
        self._state: str | None = None  # the engine's state in the last health row logged (_log_states)
        self._silence = SilenceWatch(self.settings.no_frames_warning_s, clock())
        self._errors_by_path: dict[str, int] = {}
        self._watchdog = WatchdogGate(self.settings.watchdog_period_s)
        self.counters: dict[str, int] = {
            "frames_in": 0,
            "health_sent": 0,
            "health_dropped": 0,
            "send_errors": 0,
            "receive_errors": 0,
            "bad_datagrams": 0,
            "open_errors": 0,
            "bus_errors": 0,
            "bus_opens": 0,
            "daemon_errors": 0,
            "watchdog_pings": 0,
            "rows_recorded": 0,
            "silence_warnings": 0,
        }

    # --- the one keep-alive handler ---------------------------------------------------------------

    def _guarded(self, where: str, func: Callable[..., _T], *args: Any) -> _T | None:
        """Run ``func``; anything it raises is counted and logged with its traceback, never propagated.

        This is the only broad ``except Exception`` of ecu_monitor: the daemon must outlive any bug in a
        frame's path or a tick. The watchdog still stops being fed if the pipeline stops progressing.
        A fault that repeats (a full disk under the database, a frame that always trips a bug) is logged
        on its 1st, 10th, 100th, ... occurrence per path, so it cannot flood the journal.
        """
        try:
            return func(*args)
        except Exception:  # noqa: BLE001 - the daemon's one keep-alive handler (module docstring)
            with self._lock:
                self.counters["daemon_errors"] += 1
                seen = self._errors_by_path[where] = self._errors_by_path.get(where, 0) + 1
            if seen == 10 ** (len(str(seen)) - 1):
                _log.exception("unexpected error in the %s path, occurrence %d (kept running)", where, seen)
            return None

    # --- frame path and tick ------------------------------------------------------------------------

    def _receive_loop(self, bus: can.BusABC, stop: threading.Event) -> None:
        """The receive thread of one open bus, until ``stop``: each frame to :meth:`_on_frame` (whatever that
        raises is counted under "frame" and the next frame taken); a receive error to :meth:`_on_receive_error`,
        and so is anything else ``recv`` raises (after :meth:`_guarded` has logged it), as python-can's
        Notifier would hand it to ``on_error``."""
        while not stop.is_set():
            if self._guarded("receive", self._receive_frames, bus, stop) is None:
                self._on_receive_error(can.CanOperationError("the bus's recv raised (logged above)"))

    def _receive_frames(self, bus: can.BusABC, stop: threading.Event) -> bool:
        """Receive and handle frames until ``stop`` (returns True); a python-can or OS error of ``recv`` goes to
        :meth:`_on_receive_error` and the loop goes on (the supervisor reopens the bus and stops this thread)."""
        recv, guarded, on_frame, stopped = bus.recv, self._guarded, self._on_frame, stop.is_set
        while not stopped():
            try:
                msg = recv(_RECEIVE_TIMEOUT_S)
            except (can.CanError, OSError) as exc:
                if bad_datagram(exc):
                    self._on_bad_datagram(exc)
                else:
                    self._on_receive_error(exc)
                continue
            if msg is not None:
                guarded("frame", on_frame, msg)
        return True

    def _on_frame(self, msg: can.Message) -> None:
        now = self._clock()
        msg.timestamp = now  # one clock for frames and steps: the daemon's monotonic time of reception
        with self._lock:
            self.counters["frames_in"] += 1
            self._silence.frame(now)
            self.pipeline.feed(msg)
            self._send_locked(self.pipeline.frames_until(now))

    def _tick(self) -> None:
        with self._lock:
            self._send_locked(self.pipeline.frames_until(self._clock()))

    def _tick_loop(self, start_s: float) -> None:
        """Tick at ``start_s`` (the pipeline clock's start) + whole periods, ``_TICK_LAG_S`` after each."""
        period = self.settings.tick_s
        next_s = start_s + period
        while not self._stop.wait(max(0.0, next_s + _TICK_LAG_S - self._clock())):
            self._guarded("tick", self._tick)
            next_s += period
            now = self._clock()
            if next_s < now - period:  # fell behind (machine suspended, CPU starved): skip, in phase, no burst
                next_s += period * math.floor((now - next_s) / period)

    def _send_locked(self, frames: Iterable[can.Message]) -> None:
        """Send health frames in order, each as it is made (the caller holds the lock, which keeps counters
        in sequence)."""
        bus = self._bus
        for frame in frames:
            if bus is None or self._bus_failed.is_set():
                self.counters["health_dropped"] += 1  # bus down: the failure was counted once already
                continue
            try:
                bus.send(frame, timeout=_SEND_TIMEOUT_S)
            except (can.CanError, OSError) as exc:
                self._count_bus_error("send_errors")
                self._send_failures_in_row += 1
                if self._send_failures_in_row == 1 or self._send_failures_in_row % 100 == 0:
                    _log.warning("health frame 0x%X not sent: %s", frame.arbitration_id, exc)
                if self._send_failures_in_row >= SEND_FAILURES_TO_REOPEN:
                    _log.error("%d sends failed in a row: reopening the bus", self._send_failures_in_row)
                    self._bus_failed.set()
            else:
                self._send_failures_in_row = 0
                self.counters["health_sent"] += 1

    def _count_bus_error(self, counter: str) -> None:
        """Count a failed bus operation (caller holds the lock); Health_Diag.BusErrors reports the total."""
        self.counters[counter] += 1
        self.counters["bus_errors"] += 1
        pipeline_counters = self.pipeline.counters
        pipeline_counters["bus_errors"] = pipeline_counters.get("bus_errors", 0) + 1
        if counter == "send_errors":
            pipeline_counters["send_errors"] = pipeline_counters.get("send_errors", 0) + 1

    def _on_bad_datagram(self, exc: Exception) -> None:
        """A datagram that is no CAN frame reached the bus (anyone on the multicast group can send one):
        counted as a bus error and dropped; the bus is kept (reopening it would lose the frames behind)."""
        with self._lock:
            self._count_bus_error("bad_datagrams")
            seen = self.counters["bad_datagrams"]
        if seen == 10 ** (len(str(seen)) - 1):  # 1, 10, 100, ...: a flood does not flood the journal
            _log.warning("%d datagram(s) on the bus were no CAN frame (%s): dropped, the bus kept", seen, exc)

    def _on_receive_error(self, exc: Exception) -> None:
        """The receive thread hit an error: count it once, ask the supervisor to reopen."""
        if self._bus_failed.is_set():
            self._stop.wait(0.05)  # the receive loop retries at once: do not spin while the supervisor reopens
            return
        with self._lock:
            self._count_bus_error("receive_errors")
        _log.error("bus receive failed: %s; reopening", exc)
        self._bus_failed.set()

    # --- bus lifecycle --------------------------------------------------------------------------------

    def _attach(self) -> bool:
        """Open the bus and start its receive thread; False (counted) when the bus cannot be opened."""
        try:
            bus = self._open_bus()
        except (can.CanError, OSError, ValueError) as exc:
            with self._lock:
                self._count_bus_error("open_errors")
            _log.error("cannot open the bus: %s", exc)
            return False
        if self._filters:
            try:
                bus.set_filters(self._filters)
            except (can.CanError, OSError, ValueError, NotImplementedError) as exc:
                _log.warning("bus filters not set (%s): every frame goes through the pipeline's id check", exc)
            if attach_kernel_filter(bus, self._filters):  # udp_multicast: other ids dropped by the kernel too
                _log.info("udp_multicast: receive filter attached in the kernel (%d ids)", len(self._filters))
        with self._lock:
            self._bus = bus
            self._send_failures_in_row = 0
            self.counters["bus_opens"] += 1
        self._bus_failed.clear()
        self._receiver_stop = threading.Event()
        self._receiver = threading.Thread(
            target=self._receive_loop, args=(bus, self._receiver_stop), name="ecu-monitor receive", daemon=True
        )
        self._receiver.start()
        _log.info("bus open: %s", bus.channel_info)
        return True

    def _detach(self) -> None:
        """Stop the receive thread and shut the bus down (idempotent)."""
        if self._receiver is not None:
            self._receiver_stop.set()
            self._receiver.join(timeout=2.0)
            self._receiver = None
        with self._lock:
            bus, self._bus = self._bus, None
        if bus is not None:
            try:
                bus.shutdown()
            except (can.CanError, OSError) as exc:
                _log.warning("bus shutdown failed: %s", exc)

    def _reopen_with_backoff(self, delay_s: float) -> float:
        """Close the failed bus, wait ``delay_s`` and try once; returns the next delay."""
        self._detach()
        if self._stop.wait(delay_s):
            return delay_s
        if self._attach():
            return self.settings.backoff_initial_s
        return min(delay_s * 2.0, self.settings.backoff_max_s)

    # --- supervisor -------------------------------------------------------------------------------

    def _record(self) -> None:
        if self._recorder is None:
            with self._lock:
                rows = self.pipeline.drain_rows()
                events = self.pipeline.drain_events()
            self._log_states(rows)
            _log_events(events)
            return
        with self._lock:
            rows = self.pipeline.drain_rows()
            events = self.pipeline.drain_events()
            held = self._held_inputs() if self._held_inputs is not None else HeldInputs(None)
            offset = self._wall_clock() - self._clock()
        self._log_states(rows)
        _log_events(events)
        for sample in flight_samples(rows, held, offset):  # the inputs held at the end of this supervisor period
            self._recorder.add(sample)
        self._recorder.add_events(events)
        self.counters["rows_recorded"] += len(rows)
        down = int(self._recorder.history_fault is not None)
        if self.pipeline.counters.get("history_down") != down:
            with self._lock:
                self.pipeline.counters["history_down"] = down  # Health_Diag.HistoryDown

    def _log_states(self, rows: Sequence[Any]) -> None:
        """One INFO line per change of the engine's state among the health rows, with the row's time on the
        daemon's clock (monotonic, s): the instant the publishers were given the new state."""
        for row in rows:
            if row.state != self._state:
                _log.info("engine state %s (was %s) at t = %.3f s", row.state, self._state or "none", row.time_s)
                self._state = row.state

    def _status_line(self) -> str:
        with self._lock:
            snap = self.pipeline.snapshot()
            counters = dict(self.pipeline.counters)
            mine = dict(self.counters)
        stale = ",".join(snap.stale_inputs) if snap.stale_inputs else "none"
        warning = self.settings.uncalibrated_warning
        isolation = f"gamma_Q {snap.gamma_q:.3f}" if not snap.not_isolable else "gamma_Q not isolable"
        return (
            f"state {snap.state}, CHT est {snap.cht_est_c:.1f} degC, {isolation}, "
            f"stale {stale}, frames {mine['frames_in']}, malformed {counters.get('malformed', 0)}, "
            f"bus errors {mine['bus_errors']}, health sent {mine['health_sent']}"
            + (f"; WARNING {warning}" if warning else "")
            + self._history_note()
        )

    def _history_note(self) -> str:
        """``, NO HISTORY: <why>`` while the flight history cannot be written, else nothing."""
        fault = self._recorder.history_fault if self._recorder is not None else None
        return f", NO HISTORY: {fault}" if fault else ""

    def _supervise_once(self, now: float) -> None:
        with self._lock:
            steps = self.pipeline.steps_done
            estimating = _finite(self.pipeline.snapshot().cht_est_c)
        if self._watchdog.due(now, steps) and self._notifier.watchdog():
            self.counters["watchdog_pings"] += 1
        if estimating and self.settings.freeze_heap and not self._heap_frozen_running:
            gc.freeze()  # the estimator's first steps loaded its compiled code: keep it out of collections too
            self._heap_frozen_running = True
        self._record()
        self._check_silence(now)
        if self._manual_gc:
            self._collect()

    def _collect(self) -> None:
        """The cyclic collector's work of one supervisor period (module docstring, "Garbage collection")."""
        self._collections += 1
        every = self._collections
        gc.collect(2 if every % 120 == 0 else 1 if every % 10 == 0 else 0)

    def _check_silence(self, now: float) -> None:
        with self._lock:
            event = self._silence.check(now)
            bus = self._bus
        if event == "silent":
            self.counters["silence_warnings"] += 1
            hint = ""
            if isinstance(bus, VirtualBus):
                hint = (
                    " (python-can's virtual interface connects only the buses of one process: across processes "
                    "use udp_multicast, e.g. the shipped multicast.yaml)"
                )
            where = bus.channel_info if bus is not None else "the bus (not open)"
            _log.warning("no frames on %s for %.0f s: is the sender on this bus?%s", where, self._silence.limit_s, hint)
        elif event == "resumed":
            _log.info("frames again on the bus after a silence")

    def run(self) -> int:
        """Run until :meth:`stop`; returns 0 after a clean stop (flight closed, bus shut down)."""
        settings = self.settings
        # compiled code loaded before the bus opens: the first frames must not wait for numba
        _log.info("estimators warmed up in %.2f s", self.pipeline.warm_up())
        self._attach()
        with self._lock:
            self._silence.frame(self._clock())  # the silence counts from the first open, not from the warm-up
        start_s = self._clock()
        with self._lock:
            self.pipeline.advance_to(start_s)  # the pipeline's clock starts: the tick's phase
        if settings.switch_interval_s is not None:
            self._switch_interval_before = sys.getswitchinterval()
            sys.setswitchinterval(settings.switch_interval_s)
        if settings.freeze_heap:
            gc.collect()  # once, before READY: then the start-up heap leaves the collector's sight
            gc.freeze()
            if settings.collect_in_supervisor and gc.isenabled():
                gc.disable()  # the supervisor collects (_collect), never the bus thread
                self._manual_gc = True
        self._tick_thread = threading.Thread(
            target=self._tick_loop, args=(start_s,), name="ecu-monitor tick", daemon=True
        )
        self._tick_thread.start()
        self._notifier.ready(status="running: " + self._status_line())
        _log.info("running; watchdog period %s s", settings.watchdog_period_s)
        delay_s = settings.backoff_initial_s
        next_status_s = self._clock() + settings.status_every_s
        while not self._stop.wait(settings.supervise_s):
            if self._bus_failed.is_set() or self._bus is None:
                delay_s = self._reopen_with_backoff(delay_s)
            now = self._clock()
            self._guarded("supervisor", self._supervise_once, now)
            if now >= next_status_s:
                next_status_s = now + settings.status_every_s
                line = self._guarded("status", self._status_line)
                if line:
                    self._notifier.status(line)
                    _log.info("%s", line)
        return self._shutdown()

    def _shutdown(self) -> int:
        self._notifier.stopping(status="stopping: flushing state")
        _log.info("stopping")
        if self._tick_thread is not None:
            self._tick_thread.join(timeout=2.0)
        self._detach()
        self._guarded("flush", self._record)
        if self._recorder is not None:
            self._guarded("flush", self._recorder.close)
        if self._manual_gc:
            gc.enable()
            self._manual_gc = False
        if self.settings.freeze_heap:
            gc.unfreeze()  # back to normal collection for whoever runs on in this process (tests, benchmarks)
        if self._switch_interval_before is not None:
            sys.setswitchinterval(self._switch_interval_before)
            self._switch_interval_before = None
        _log.info("stopped: %s", ", ".join(f"{k} {v}" for k, v in self.counters.items()))
        return 0

    def stop(self) -> None:
        """Ask :meth:`run` to return (safe from a signal handler and from any thread)."""
        self._stop.set()


def _log_events(events: Sequence[Any]) -> None:
    """One log line per engine event: WARNING when it starts, INFO when it ends (pipeline/events.py)."""
    for event in events:
        if event.ongoing:
            _log.warning("engine event: %s", event.start_text())
        else:
            _log.info("engine event ended: %s", event.text())


def bad_datagram(exc: BaseException) -> bool:
    """True when a receive error is one bad datagram rather than a failed bus: python-can's
    CanOperationError raised from a decoding error of the payload (udp_multicast's "could not unpack
    received message"), not from the operating system."""
    cause = exc.__cause__
    return (
        isinstance(exc, can.CanOperationError) and cause is not None and not isinstance(cause, OSError | can.CanError)
    )


def _finite(value: Any) -> bool:
    return isinstance(value, int | float) and math.isfinite(value)
