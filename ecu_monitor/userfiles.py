"""The one place that opens the files a user hands us and writes the files we make for them.

Reading (:func:`open_input`, :func:`read_input_bytes`, :func:`read_input_text`): regular files only - a
FIFO would block for ever, ``/dev/zero`` never ends, a directory is not a file - each refused in one line
before a byte is read, and a size limit per kind of file (a YAML config or a DBC is kilobytes; a flight
log is not limited by size, only by being a regular file).

Writing (:func:`atomic_output`): a unique temporary file created with ``O_EXCL`` in the output's folder
(never a fixed ``OUT.tmp`` a planted link could redirect), written, ``fsync``-ed and renamed over the
output. The rename replaces the output's directory entry, so an output that is a symbolic link is
replaced by the file, never written through to the link's target. On any failure (a full disk, an
error, Ctrl-C) the temporary file is removed and the old output, if any, is left as it was. An output
that is one of the command's inputs is refused before any work.

Checking before the work (:func:`check_output_file`, :func:`prepare_output_dir`): every command that
writes checks its outputs before it reads a flight or fits a model, so a mistyped path costs a second,
not a finished run: a file output that names a directory, sits in a folder that does not exist or
cannot be written; a directory output that is a file or cannot be created or written.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, BinaryIO

from ecu_monitor.errors import UserInputError

__all__ = [
    "MAX_TEXT_BYTES",
    "atomic_output",
    "check_input",
    "check_output_file",
    "check_output_not_input",
    "open_input",
    "prepare_output_dir",
    "read_input_bytes",
    "read_input_text",
    "save_figure",
    "write_output_bytes",
]

#: Largest YAML config, model, mapping, mission or DBC file read (bytes): hundreds of times the largest
#: real one, small enough that reading it cannot exhaust the memory of the smallest target computer.
MAX_TEXT_BYTES = 16 * 1024 * 1024

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def open_input(
    path: str | os.PathLike[str], what: str, error: type[UserInputError] = UserInputError, limit: int | None = None
) -> BinaryIO:
    """``path`` opened for binary reading if it is a regular file of at most ``limit`` bytes; else
    ``error`` in one line naming the file and what it is (``what``: the file asked for, e.g. "DBC file").

    Opened without blocking, so a FIFO is refused instead of waiting for a writer.
    """
    src = os.fspath(path)
    try:
        fd = os.open(src, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise error(f"{src}: no such {what}") from None
    except OSError as exc:
        raise error(f"{src}: cannot read {what} ({exc.strerror or exc})") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            kind = _kind(info.st_mode)
            raise error(f"{src}: {kind}: give a {what}")
        if limit is not None and info.st_size > limit:
            raise error(f"{src}: {info.st_size} bytes, more than any {what} (at most {limit // 1048576} MiB)")
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def check_input(
    path: str | os.PathLike[str], what: str, error: type[UserInputError] = UserInputError, limit: int | None = None
) -> None:
    """:func:`open_input`'s checks without keeping the file open: for readers that open it themselves."""
    open_input(path, what, error, limit).close()


def read_input_bytes(
    path: str | os.PathLike[str],
    what: str,
    error: type[UserInputError] = UserInputError,
    limit: int | None = MAX_TEXT_BYTES,
) -> bytes:
    """The bytes of regular file ``path`` (:func:`open_input`); at most ``limit`` bytes, even if it grows."""
    with open_input(path, what, error, limit) as handle:
        try:
            data = handle.read() if limit is None else handle.read(limit + 1)
        except OSError as exc:
            raise error(f"{os.fspath(path)}: cannot read {what} ({exc.strerror or exc})") from None
    if limit is not None and len(data) > limit:
        raise error(f"{os.fspath(path)}: more than any {what} (at most {limit // 1048576} MiB)")
    return data


def read_input_text(
    path: str | os.PathLike[str],
    what: str,
    error: type[UserInputError] = UserInputError,
    limit: int | None = MAX_TEXT_BYTES,
) -> str:
    """The UTF-8 text of regular file ``path`` (a byte-order mark skipped); ``error`` if it is not text."""
    data = read_input_bytes(path, what, error, limit)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise error(f"{os.fspath(path)}: not a {what} (not UTF-8 text: byte {exc.start})") from None


def check_output_not_input(
    out: str | os.PathLike[str],
    inputs: Iterable[str | os.PathLike[str] | None],
    error: type[UserInputError] = UserInputError,
) -> None:
    """``error`` if output ``out`` is the same file as one of ``inputs`` (writing it would destroy the input)."""
    for given in inputs:
        if given is None:
            continue
        try:
            same = os.path.samefile(out, given)
        except OSError:  # either does not exist (yet): not the same file
            continue
        if same:
            raise error(f"{os.fspath(out)}: is the input {os.fspath(given)}: give another output file")


def _prove_writable(folder: Path) -> str | None:
    """None if a file can be created in ``folder`` (made and removed at once), else the reason."""
    try:
        with tempfile.TemporaryFile(dir=folder):
            return None
    except OSError as exc:
        return exc.strerror or str(exc)


def check_output_file(path: str | os.PathLike[str], option: str, error: type[UserInputError] = UserInputError) -> Path:
    """``path`` as a Path if a file can be written there; else ``error`` in one line naming ``option`` and
    the path: a name ending in a separator or naming a directory, an existing non-regular file, a folder
    that does not exist or cannot be written."""
    text = os.fspath(path)
    out = Path(text)
    if text.endswith(("/", os.sep)) or out.is_dir():
        raise error(f"{option} {text}: a directory; give a file name")
    if out.exists() and not out.is_file():
        raise error(f"{option} {text}: {_kind(out.stat().st_mode)}; give a file name")
    folder = out.parent
    if not folder.is_dir():
        raise error(f"{option} {text}: no such folder {folder}")
    reason = _prove_writable(folder)
    if reason is not None:
        raise error(f"{option} {text}: cannot write in {folder} ({reason})")
    return out


def prepare_output_dir(path: str | os.PathLike[str], option: str, error: type[UserInputError] = UserInputError) -> Path:
    """The directory ``path`` created (with its parents) and proved writable; else ``error`` in one line
    naming ``option`` and the path."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        what = "a file" if out.is_file() else _kind(out.stat().st_mode)
        raise error(f"{option} {out}: {what}, not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise error(f"{option} {out}: cannot create the directory ({exc.strerror or exc})") from None
    reason = _prove_writable(out)
    if reason is not None:
        raise error(f"{option} {out}: cannot write in the directory ({reason})")
    return out


def _umask() -> int:
    """The process's umask, read without changing it (Linux); 0o022 where it cannot be read."""
    with contextlib.suppress(OSError, ValueError), open("/proc/self/status", encoding="ascii") as status:
        for line in status:
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    return 0o022


@contextlib.contextmanager
def atomic_output(
    path: str | os.PathLike[str],
    error: type[UserInputError] = UserInputError,
    inputs: Iterable[str | os.PathLike[str] | None] = (),
    text: bool = False,
) -> Iterator[Any]:
    """A binary handle (with ``text``: UTF-8 text, newlines as written) whose bytes become ``path`` only
    when the ``with`` block ends without an error.

    The handle is a unique temporary file in ``path``'s folder (``O_EXCL``, so no planted file or link
    is followed); on success it is flushed, ``fsync``-ed and renamed over ``path`` (a link at ``path`` is
    replaced, its target untouched). On any failure the temporary file is removed; an ``OSError``
    becomes ``error`` in one line. ``inputs``: the command's input files, which ``path`` must not be.
    """
    out = Path(path)
    check_output_not_input(out, inputs, error)
    folder = out.parent
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".part", dir=folder)
    except OSError as exc:
        raise error(f"{out}: cannot write ({exc.strerror or exc})") from None
    try:
        handle = os.fdopen(fd, "w", encoding="utf-8", newline="") if text else os.fdopen(fd, "wb")
        with handle:
            os.fchmod(fd, 0o666 & ~_umask())  # as open() would have made it (mkstemp makes 0600)
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, out)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise error(f"{out}: cannot write ({exc.strerror or exc})") from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    with contextlib.suppress(OSError):  # the rename itself durable (best effort: some filesystems refuse)
        dir_fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)


def write_output_bytes(
    path: str | os.PathLike[str],
    data: bytes,
    error: type[UserInputError] = UserInputError,
    inputs: Iterable[str | os.PathLike[str] | None] = (),
) -> None:
    """Write ``data`` to ``path`` through :func:`atomic_output`."""
    with atomic_output(path, error, inputs) as handle:
        handle.write(data)


def save_figure(
    figure: Any, path: str | os.PathLike[str], dpi: float, error: type[UserInputError] = UserInputError
) -> None:
    """Save a matplotlib ``figure`` to ``path`` (format by suffix, PNG without one) through :func:`atomic_output`."""
    out = Path(path)
    with atomic_output(out, error) as handle:
        figure.savefig(handle, format=out.suffix.lstrip(".").lower() or "png", dpi=dpi)
