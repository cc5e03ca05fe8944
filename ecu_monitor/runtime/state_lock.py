"""One service per state directory: ``ecu-monitor run`` holds an exclusive ``flock`` on
``<state_dir>/ecu-monitor.lock`` while it runs.

A second service on the same state_dir would run its start-up recovery on the first one's open flight
and write the same flight numbers; it is refused in one line naming the holder's process id. The kernel
drops the lock when its holder dies (even by SIGKILL), so a crash never leaves a stale lock behind.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from pathlib import Path

from ecu_monitor.errors import ConfigError

__all__ = ["LOCK_NAME", "StateDirLock"]

#: The lock file in the state directory (it holds the holder's process id, for the message).
LOCK_NAME = "ecu-monitor.lock"


class StateDirLock:
    """The exclusive lock of ``state_dir`` (created if missing); ConfigError if another process holds it.
    Context manager; ``close()`` (idempotent) releases it."""

    def __init__(self, state_dir: str | os.PathLike[str]) -> None:
        self.state_dir = Path(state_dir)
        self.path = self.state_dir / LOCK_NAME
        try:
            self.state_dir.mkdir(parents=True, exist_ok=True)
            self._fd: int | None = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o644)
        except OSError as exc:
            raise ConfigError(f"{self.state_dir}: state_dir: cannot use it ({exc.strerror or exc})") from None
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(self._fd, 32, 0).decode("ascii", errors="replace").strip() or "?"
            self.close()
            raise ConfigError(
                f"{self.state_dir}: state_dir: another ecu-monitor run (pid {holder}) is using it; one service"
                " per state_dir (stop it, or give this one another state_dir)"
            ) from None
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, f"{os.getpid()}\n".encode("ascii"), 0)

    def close(self) -> None:
        """Release the lock (idempotent); the lock file stays (removing it could race a new holder)."""
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = None

    def __enter__(self) -> StateDirLock:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
