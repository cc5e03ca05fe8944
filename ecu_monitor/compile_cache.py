"""numba's on-disk cache in a user-writable directory, and the first run's one line that says it compiles.

Where: numba reads ``NUMBA_CACHE_DIR`` when it is imported. The ``ecu-monitor`` and ``virtual-ecu``
entry points call :func:`use_cache_dir` before anything imports numba: unless the user (or the systemd
unit, ``%C/ecu-monitor/numba``) set it, it becomes ``$XDG_CACHE_HOME/ecu-monitor/numba``
(``~/.cache/ecu-monitor/numba``). Without it numba writes ``__pycache__`` beside the sources when that
is writable and ``~/.cache/numba`` otherwise; with it the kernels of every install (editable, or
``pip install .`` into a read-only site-packages run by another user) are in one place a second
process reads. Only the command-line processes set it: importing the package as a library leaves the
host process's environment alone.

What the user sees: a fresh cache costs 15-25 s of compiling on the first ``replay`` on 2 cores
(docs/performance.md, "First run"). :func:`compile_notice` listens to numba's ``numba:compile``
events, which numba sends only when it compiles (a kernel loaded from the cache sends none), and once
the compiling of the command has lasted :data:`NOTICE_AFTER_S` it prints ``compiling (first run only)
...`` on stderr (the daemon: a log line); when the command is done, ``compiled in X s ...``. So it
says so exactly when the cache misses (a fresh install, an upgrade, a cleared cache, a command whose
kernels another command did not compile) and never on a run that only loads.

No numba at this module's top level: the command line's ``--help`` stays light
(tests/cli/test_cli_startup.py); numba is imported by :func:`compile_notice`, which only the commands that
compile call, when they run (demo, replay, simulate, identify, gap, calibrate, results, evaluate through
:func:`announce_compiles`; ``run`` around its warm-up, logging).
"""

from __future__ import annotations

import contextlib
import functools
import mmap
import os
import struct
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, MutableMapping
from pathlib import Path
from typing import Any, TypeVar

__all__ = [
    "CACHE_ENV",
    "COMPILING_LINE",
    "NOTICE_AFTER_S",
    "CompileClock",
    "announce_compiles",
    "compile_notice",
    "default_cache_dir",
    "use_cache_dir",
]

#: The environment variable numba reads for its cache directory.
CACHE_ENV = "NUMBA_CACHE_DIR"
#: The line the first run prints (stderr) or logs (daemon).
COMPILING_LINE = "compiling (first run only) ..."
#: Seconds of compiling before the line is shown: a command that compiles less says nothing.
NOTICE_AFTER_S = 1.0

F = TypeVar("F", bound=Callable[..., Any])


def default_cache_dir(environ: Mapping[str, str] | None = None) -> Path | None:
    """``$XDG_CACHE_HOME/ecu-monitor/numba``, or ``~/.cache/ecu-monitor/numba`` when XDG_CACHE_HOME is
    unset, empty or relative (the XDG base directory spec ignores a relative one); None without a home."""
    env = os.environ if environ is None else environ
    xdg = env.get("XDG_CACHE_HOME", "")
    if xdg and os.path.isabs(xdg):
        base = Path(xdg)
    else:
        try:
            base = Path.home() / ".cache"
        except (RuntimeError, KeyError):  # no HOME and no passwd entry
            return None
    return base / "ecu-monitor" / "numba"


def use_cache_dir(environ: MutableMapping[str, str] | None = None) -> str | None:
    """Set ``NUMBA_CACHE_DIR`` to :func:`default_cache_dir` unless it is set already (even to ""), and
    return the directory numba will use (None: numba's own default). Call before numba is imported."""
    env = os.environ if environ is None else environ
    if CACHE_ENV in env:
        return env[CACHE_ENV] or None
    directory = default_cache_dir(env)
    if directory is None:
        return None
    env[CACHE_ENV] = str(directory)
    return env[CACHE_ENV]


class _SharedFigures:
    """A few floats in anonymous shared memory (``mmap``: no file), seen by every process forked after it was
    made, and a lock they share: a POSIX semaphore, or a thread lock where the system has none (then two
    processes may each say the line)."""

    def __init__(self, count: int = 3) -> None:
        self._memory = mmap.mmap(-1, 8 * count)
        self.lock: Any
        try:
            import multiprocessing  # not at the top: the command line's start stays light

            self.lock = multiprocessing.get_context("fork").Lock()
        except (ImportError, OSError):  # no working sem_open (a container without /dev/shm)
            self.lock = threading.Lock()

    def get(self, index: int) -> float:
        return float(struct.unpack_from("d", self._memory, 8 * index)[0])

    def add(self, index: int, value: float) -> None:
        struct.pack_into("d", self._memory, 8 * index, self.get(index) + value)


def _print_stderr(line: str) -> None:
    sys.stderr.write(line + "\n")  # one write: the lines of two processes never mix on one line
    sys.stderr.flush()


class CompileClock:
    """Seconds numba spends compiling, and the one line said once they pass ``after_s``.

    ``start``/``end``: numba's ``numba:compile`` events (nested ones, a kernel compiling its callees,
    count once). The line comes from a timer thread while a compile runs (one that ends first cancels
    it), so the line means "compiling now, for a second already". Processes forked from this one (the
    parallel fits of identify and gap) hear their own compiles with a copy of the clock: the line is said
    once across them all (a flag in shared memory), and :attr:`shared_total_s` adds up every process's
    compiling."""

    def __init__(self, say: Callable[[str], None], after_s: float = NOTICE_AFTER_S) -> None:
        self.say = say
        self.after_s = after_s
        self.total_s = 0.0  # finished compiles, this process
        self.announced = False
        self._depth = 0
        self._since = 0.0
        self._timer: threading.Timer | None = None
        self._lock = threading.Lock()
        # [line said by any process, seconds compiled by every process, processes that compiled]: anonymous
        # shared memory (no file: a full disk cannot stop a command here), which forked processes share
        self._shared = _SharedFigures()
        self._counted_pid = 0  # the process last counted among those that compiled (a fork copies the clock)

    @property
    def shared_total_s(self) -> float:
        """Seconds compiled by this process and every process forked from it so far."""
        return self._shared.get(1)

    @property
    def said(self) -> bool:
        """Whether this process or one forked from it has said the line."""
        return bool(self._shared.get(0))

    @property
    def processes(self) -> int:
        """How many processes (this one and those forked from it) have compiled."""
        return int(self._shared.get(2))

    def start(self) -> None:
        with self._lock:
            self._depth += 1
            if self._depth > 1:
                return
            self._since = time.perf_counter()
            if self.announced:
                return
            wait_s = self.after_s - self.total_s
            if wait_s <= 0.0:
                self._announce()
                return
            self._timer = threading.Timer(wait_s, self._fire)
            self._timer.daemon = True
            self._timer.start()

    def end(self) -> None:
        with self._lock:
            if self._depth == 0:  # its start came before the listener
                return
            self._depth -= 1
            if self._depth > 0:
                return
            elapsed = time.perf_counter() - self._since
            self.total_s += elapsed
            self._cancel()
            with self._shared.lock:
                self._shared.add(1, elapsed)
                if self._counted_pid != os.getpid():
                    self._counted_pid = os.getpid()
                    self._shared.add(2, 1.0)

    def close(self) -> None:
        """Stop the timer (the command is over)."""
        with self._lock:
            self._cancel()

    def _cancel(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _fire(self) -> None:
        with self._lock:
            if self._depth > 0 and not self.announced:
                self._announce()

    def _announce(self) -> None:
        self.announced = True
        with self._shared.lock:
            if self._shared.get(0):  # another process said it
                return
            self._shared.add(0, 1.0)
        self.say(COMPILING_LINE)


@contextlib.contextmanager
def compile_notice(say: Callable[[str], None] | None = None, after_s: float = NOTICE_AFTER_S) -> Iterator[CompileClock]:
    """Within the block, numba's compiles are timed; once they pass ``after_s`` seconds ``say`` (default:
    print on stderr) gets :data:`COMPILING_LINE`, and after a block that ends normally, the seconds
    compiled. Imports numba. Nothing is said when numba compiles nothing (every kernel from the cache)."""
    from numba.core import config, event  # the commands that compile import numba anyway

    tell = say or _print_stderr
    clock = CompileClock(tell, after_s)

    class _Forward(event.Listener):
        def on_start(self, _event: Any) -> None:
            clock.start()

        def on_end(self, _event: Any) -> None:
            clock.end()

    listener = _Forward()
    event.register("numba:compile", listener)
    try:
        yield clock
    finally:
        event.unregister("numba:compile", listener)
        clock.close()
    if clock.said:
        where = getattr(config, "CACHE_DIR", "") or "numba's default cache (__pycache__ or ~/.cache/numba)"
        spent = f"{clock.shared_total_s:.1f} s" + (f" in {clock.processes} processes" if clock.processes > 1 else "")
        tell(f"compiled in {spent}, cached in {where}: later runs load it")


def announce_compiles(command: F) -> F:
    """``command`` (a subcommand's run function) inside :func:`compile_notice` printing on stderr."""

    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with compile_notice():
            return command(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
