"""``ecu-monitor run --config FILE``: the daemon (systemd Type=notify with watchdog, docs/service.md).

Loads the config (any error: one line, exit 2), opens the flight database in ``state_dir``, opens the
bus once to check the interface (an unknown interface, a missing driver or an interface this host cannot
have, such as socketcan on a kernel without CAN, is a config error, exit 2; a device that is not up yet
is retried with backoff by the daemon), then runs until SIGTERM or SIGINT and exits 0 once the flight in
progress is written.
"""

from __future__ import annotations

import argparse
import errno
import functools
import gc
import logging
import os
import signal
import socket
import sys
from collections.abc import Callable
from types import FrameType
from typing import TYPE_CHECKING, Any

from ecu_monitor.compile_cache import compile_notice
from ecu_monitor.errors import ConfigError
from ecu_monitor.runtime.persistence import FlightRules

if TYPE_CHECKING:  # the run imports these (python-can, numba kernels): --help stays light
    import can

    from ecu_monitor.config import ServiceConfig
    from ecu_monitor.runtime.daemon import DaemonSettings

__all__ = ["add_subparser", "bus_opener", "daemon_settings", "uncalibrated_warning", "unsupported_on_host"]

_log = logging.getLogger("ecu_monitor.run")

#: errno values of a first open that say the interface cannot exist on this host (the kernel lacks the
#: protocol or address family, e.g. AF_CAN on a kernel without CAN): no retry can succeed.
_UNSUPPORTED_ON_HOST = frozenset({errno.EAFNOSUPPORT, errno.EPFNOSUPPORT, errno.EPROTONOSUPPORT, errno.ESOCKTNOSUPPORT})

#: syslog priorities journald reads from a ``<N>`` line prefix (sd-daemon(3)).
_JOURNAL_PRIORITY = {"DEBUG": 7, "INFO": 6, "WARNING": 4, "ERROR": 3, "CRITICAL": 2}


def add_subparser(subparsers: Any) -> None:
    """Register ``run``."""
    parser = subparsers.add_parser(
        "run",
        help="run the monitoring daemon on the configured CAN bus",
        description="Run the daemon: decode the engine frames, run the estimator, broadcast health frames, "
        "record flights in state_dir. systemd Type=notify (READY, STATUS, WATCHDOG) when NOTIFY_SOCKET is set.",
    )
    parser.add_argument("--config", required=True, metavar="FILE", help="service configuration YAML")
    parser.add_argument(
        "--min-flight-s",
        type=float,
        default=FlightRules.min_flight_s,
        metavar="SECONDS",
        help=f"shortest engine run recorded as a flight (default {FlightRules.min_flight_s:g})",
    )
    parser.set_defaults(func=_run)


class _JournalFormatter(logging.Formatter):
    """Prefix each line with its syslog priority so journald keeps the level (stderr under systemd)."""

    def format(self, record: logging.LogRecord) -> str:
        return f"<{_JOURNAL_PRIORITY.get(record.levelname, 6)}>{super().format(record)}"


def _log_to_journal() -> None:
    if not os.environ.get("JOURNAL_STREAM"):
        return
    for handler in logging.getLogger().handlers:
        handler.setFormatter(_JournalFormatter("%(name)s: %(message)s"))


class _HalfOpenBusFilter(logging.Filter):
    """Drops python-can's "was not properly shut down" warning for a bus whose constructor failed."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "not properly shut down" not in record.getMessage()


def mavlink_opener(config: ServiceConfig) -> Callable[[], Any]:
    """A function that opens the config's MAVLink link (runtime/mavlink_link.py); the first open happens here,
    so that a connection string that cannot be opened is one line and exit 2."""
    from ecu_monitor.runtime.mavlink_link import MavlinkLink

    first: list[MavlinkLink] = [MavlinkLink(config.mavlink)]

    def open_link() -> MavlinkLink:
        return first.pop() if first else MavlinkLink(config.mavlink)

    return open_link


def bus_opener(config: ServiceConfig) -> Callable[[], can.BusABC]:
    """A function that opens the configured bus (``can.Bus(**config.bus)``); checks the interface first.

    The first open happens here: an unknown interface, a missing driver, bad options, an address that
    does not resolve or an interface the host cannot have (:func:`unsupported_on_host`) raise
    ConfigError; a device that is not there yet (any other OSError or CanInitializationError) is left to
    the daemon's backoff.
    """
    import can

    options = dict(config.bus)
    interface = options.get("interface")
    if interface not in can.interfaces.VALID_INTERFACES:
        known = ", ".join(sorted(can.interfaces.VALID_INTERFACES))
        raise ConfigError(f"{config.source}: bus.interface: unknown interface {interface!r} (known: {known})")

    def open_bus() -> can.BusABC:
        bus = can.Bus(**options)
        if bus.channel_info == can.BusABC.channel_info:  # "unknown" (udp_multicast): the daemon's log names it
            bus.channel_info = f"{interface} {options.get('channel')}"
        return bus

    first: can.BusABC | None = None
    error: str | None = None
    half_open = _HalfOpenBusFilter()
    logging.getLogger("can.bus").addFilter(half_open)
    try:
        first = open_bus()
    except (can.CanInterfaceNotImplementedError, ImportError, TypeError, ValueError, socket.gaierror) as exc:
        error = f"{config.source}: bus: cannot use {interface}:{options.get('channel')}: {exc}"
    except (can.CanError, OSError) as exc:
        if unsupported_on_host(exc):
            error = f"{config.source}: bus: this host cannot have a {interface} bus ({exc}); no retry can help"
        else:
            _log.warning("bus %s:%s not available yet (%s); will retry", interface, options.get("channel"), exc)
    finally:
        gc.collect()  # a bus whose constructor failed is collected here, its "not shut down" warning dropped
        logging.getLogger("can.bus").removeFilter(half_open)
    if error is not None:
        raise ConfigError(error)

    def reopen() -> can.BusABC:
        nonlocal first
        if first is not None:
            bus, first = first, None
            return bus
        return open_bus()

    return reopen


def unsupported_on_host(exc: BaseException) -> bool:
    """True when ``exc`` (or an error it was raised from) says the kernel lacks the bus's protocol family.

    EAFNOSUPPORT and its kin (``_UNSUPPORTED_ON_HOST``): socketcan on a kernel without AF_CAN. A device
    that is missing or down (ENODEV, ENETDOWN, ...) is not one of them: it may appear later.
    """
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, OSError) and current.errno in _UNSUPPORTED_ON_HOST:
            return True
        current = current.__cause__ or current.__context__
    return False


def _run(args: argparse.Namespace) -> int:
    from ecu_monitor.config import load_config
    from ecu_monitor.model import airframe_warning
    from ecu_monitor.runtime.daemon import Daemon
    from ecu_monitor.runtime.flight_recorder import FlightRecorder, held_inputs
    from ecu_monitor.runtime.notify import SystemdNotifier, watchdog_period_s
    from ecu_monitor.runtime.persistence import DATABASE_NAME, StateStore
    from ecu_monitor.runtime.publishers import LiveMonitor  # the estimator stack: imported only when running
    from ecu_monitor.runtime.state_lock import StateDirLock

    config = load_config(args.config)
    models = config.load_cylinder_params()  # one per cylinder (one for a single CHT channel)
    params = models[0]
    if not args.min_flight_s >= 0.0:
        raise ConfigError(f"--min-flight-s: expected a number >= 0, got {args.min_flight_s!r}")
    uncalibrated = uncalibrated_warning(config, models)
    _log_to_journal()
    lock = StateDirLock(config.state_dir)  # before the store's start-up recovery; held until the process ends
    pipeline = LiveMonitor(config, models)
    # a history that cannot be opened (read-only, disk full) is retried while the service monitors on
    recorder = FlightRecorder(
        lambda: StateStore(config.state_dir),
        config.engine_serial,
        params.cht_limit_c,
        FlightRules(min_flight_s=args.min_flight_s),
        wear=config.wear,
        reference=config.wear_reference,
        hours=(config.overhaul_hours, config.tbo_hours),
    )
    # kept across restarts: told at each start (not while the history cannot be opened)
    for alert in recorder.store.alerts(config.engine_serial, open_only=True) if recorder.store else ():
        _log.warning("ALERT %s", alert.text)
        pipeline.tell(alert.text)
    hours = recorder.store.engine_hours(config.engine_serial) if recorder.store else None
    if hours is not None and hours.due:
        _log.warning("ALERT engine %s: %s", config.engine_serial, hours.text())
        pipeline.tell(f"MAINTENANCE {config.engine_serial}: overhaul due ({hours.since_overhaul_h:.0f} h)")
    open_bus = mavlink_opener(config) if config.protocol == "mavlink" else bus_opener(config)
    # The estimators' kernels compiled (first run, an empty numba cache: 8 s on 2 cores, logged) or loaded, once
    # the config and the bus are known good; the daemon's own warm-up before it opens the bus then only
    # finds them loaded.
    with compile_notice(say=_log.info):
        pipeline.warm_up()
    settings = daemon_settings(config, watchdog_period_s(), pipeline.row_period_s, uncalibrated)
    if uncalibrated:
        _log.warning("%s", uncalibrated)
    mismatch = airframe_warning(params, config.engine_serial, "its model", str(config.source))
    if mismatch:  # a model made for another airframe (the config's engine serial is not among its airframes)
        _log.warning("%s", mismatch)
    with SystemdNotifier() as notifier:
        daemon = Daemon(
            pipeline,
            open_bus,
            settings=settings,
            notifier=notifier,
            recorder=recorder,
            held_inputs=functools.partial(held_inputs, pipeline),
            receive_filters=pipeline.receive_filters(),
        )

        def on_signal(signum: int, _frame: FrameType | None) -> None:
            _log.info("signal %s: stopping", signal.Signals(signum).name)
            daemon.stop()

        signal.signal(signal.SIGTERM, on_signal)
        signal.signal(signal.SIGINT, on_signal)
        if config.protocol == "mavlink":
            output = config.mavlink.output
            link = f"MAVLink {config.mavlink.connection}" + (f" -> {output}" if output else "")
        else:
            link = f"bus {config.bus.get('interface')}:{config.bus.get('channel')}"
        _log.info("engine %s, %s, state %s", config.engine_serial, link, config.state_dir / DATABASE_NAME)
        try:
            code = daemon.run()
        finally:
            if recorder.store is not None:
                recorder.store.close()
            lock.close()
    sys.stdout.flush()
    return code


def uncalibrated_warning(config: ServiceConfig, models: Any) -> str:
    """The warning a test bench runs with when a detector was not calibrated for its model (the config says
    ``detector: {uncalibrated: accept}``), else empty; ConfigError (one line, exit 2) when the config does not
    accept it: a threshold calibrated for another model false-alarms (or misses) on this one."""
    from ecu_monitor.offline.calibration import uncalibrated_detectors

    lines = uncalibrated_detectors(config, models)
    if not lines:
        return ""
    if config.detector_uncalibrated != "accept":
        raise ConfigError(
            f"{config.source}: detector: {lines[0]}; a test bench may run anyway with"
            " detector: {uncalibrated: accept}"
        )
    return f"UNCALIBRATED detector (detector.uncalibrated: accept): {lines[0]}"


def daemon_settings(
    config: ServiceConfig, watchdog_s: float | None, tick_s: float | None = None, uncalibrated: str = ""
) -> DaemonSettings:
    """The daemon's settings from the config: bus reopen backoff, s; silence warning, s; systemd's watchdog
    period, s (None: no watchdog); the tick, s (the pipeline's row period; None: the default);
    ``uncalibrated``: the warning every status line carries (empty: none)."""
    from ecu_monitor.runtime.daemon import DaemonSettings

    tick = {} if tick_s is None else {"tick_s": tick_s}
    return DaemonSettings(
        **tick,
        backoff_initial_s=config.reopen_backoff.initial,
        backoff_max_s=config.reopen_backoff.max,
        watchdog_period_s=watchdog_s,
        no_frames_warning_s=config.no_frames_warning_s,
        uncalibrated_warning=uncalibrated,
    )
