"""The one reader of CAN logs: any python-can log (.asc, .blf, .log, .trc, ...) to arrays, and the
import of such a log into a :class:`~ecu_monitor.flightlog.FlightLog`.

:func:`read_frames` gives :class:`FrameArrays` (what replay, calibrate and import read). What it does
with a damaged or unusual log (each repair is logged with ``logging.warning``):

* an empty file, a file python-can cannot parse, a log without frames: FlightLogError, one line;
* a log cut in the middle (a .blf whose last object or container is incomplete, a text log whose
  last line is cut): the frames read are kept, with a warning naming the time reached;
* a frame whose stamp no clock could give (not finite, negative, or alone more than :data:`RESTART_S`
  ahead of both its neighbours: a logger's glitch): dropped, with a warning counting them;
* time going back by more than :data:`RESTART_S` (two logs back to back, the second starting its
  clock again): FlightLogError naming the frame, since one log has one clock (split the file and
  give each part on its own);
* stamps as the logger wrote them (seconds since 1970 for most loggers, since the start of the
  measurement for others) become time since the log's first frame, as a flight's ``time_s`` is;
* a hole in time (no frame for more than :data:`GAP_S`): kept; :func:`time_gaps` lists the holes,
  replay reports them and runs no step across one longer than the pipeline's clock-restart limit,
  import writes no row inside one.

A .blf holding only classic CAN frames (the usual case, and every log the virtual ECU writes) is read
straight into arrays (no Message objects: several times faster than python-can's reader); anything else
goes through python-can's ``LogReader``.

:func:`import_can_log` decodes the frames with the one decoder (:class:`~ecu_monitor.bus.codec.Decoder`,
batch path) and samples and holds every mapped signal onto a uniform grid. :func:`load_flight` loads
any supported flight log by suffix (CSV through :mod:`ecu_monitor.flightlog`, CAN logs here).
"""

from __future__ import annotations

import logging
import math
import os
import re
import struct
import zlib
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from types import MappingProxyType
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.bus.codec import MALFORMED_REASONS, Decoder, SignalSpec
from ecu_monitor.bus.dbc import load_dbc, shipped_dbc
from ecu_monitor.errors import ConfigError, FlightLogError
from ecu_monitor.flightlog import GAP_WARN_S, FlightLog, choose_cht, load_csv
from ecu_monitor.userfiles import check_input

__all__ = [
    "CAN_LOG_SUFFIXES",
    "DEFAULT_SIGNAL_MAP",
    "GAP_S",
    "RESTART_S",
    "FrameArrays",
    "import_can_log",
    "load_flight",
    "read_blf_arrays",
    "read_frames",
    "time_gaps",
]

_log = logging.getLogger(__name__)

#: Suffixes read as CAN logs (python-can's readers).
CAN_LOG_SUFFIXES: tuple[str, ...] = (".asc", ".blf", ".log", ".trc")
#: A silence of every frame longer than this (s) is a hole in the log (reported; import writes no row in
#: it); the same limit as a time gap in a flight CSV.
GAP_S = GAP_WARN_S
#: Time going back by more than this (s) is a second log after the first: refused.
RESTART_S = 1.0
#: Canonical column -> "Message.Signal" in the shipped engine.dbc (its units are the canonical ones).
DEFAULT_SIGNAL_MAP: Mapping[str, str] = MappingProxyType(
    {
        "throttle_pct": "ECU_Fast.ThrottlePos",
        "rpm": "ECU_Fast.EngineSpeed",
        "altitude_m": "AirData.PressureAltitude",
        "airspeed_mps": "AirData.CalibratedAirspeed",
        "oat_c": "ECU_Slow.OAT",
        "cht_c": "ECU_Slow.CHT",
        "fuel_flow_lph": "ECU_Fast.FuelFlow",
    }
)
#: Timestamp tolerance of the sample-and-hold grid (log formats store us or 10 us resolution).
_TIE_S = 1e-6
_IDENTIFIER = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class FrameArrays(NamedTuple):
    """Frames of a log as arrays (log order): time_s, id, extended, dlc, data (N, 8) uint8, ignored
    (error and remote frames)."""

    time_s: NDArray[np.float64]
    arbitration_id: NDArray[np.int64]
    is_extended: NDArray[np.bool_]
    dlc: NDArray[np.int64]
    data: NDArray[np.uint8]
    ignored: NDArray[np.bool_]

    def __len__(self) -> int:
        return int(self.time_s.size)

    def take(self, index: Any) -> FrameArrays:
        """The frames at ``index`` (a slice, a boolean mask or indices)."""
        return FrameArrays(
            self.time_s[index],
            self.arbitration_id[index],
            self.is_extended[index],
            self.dlc[index],
            self.data[index],
            self.ignored[index],
        )

    def messages(self) -> Iterable[Any]:
        """The frames as can.Message objects (for the live path)."""
        import can

        for i in range(len(self)):
            n = int(self.dlc[i])
            yield can.Message(
                timestamp=float(self.time_s[i]),
                arbitration_id=int(self.arbitration_id[i]),
                is_extended_id=bool(self.is_extended[i]),
                is_error_frame=bool(self.ignored[i]),
                dlc=n,
                data=self.data[i, : min(n, 8)].tobytes(),
                check=False,
            )


def time_gaps(time_s: NDArray[np.float64], longer_than_s: float = GAP_S) -> list[tuple[float, float]]:
    """(last stamp before, first stamp after) of every silence longer than ``longer_than_s`` (s)."""
    t = np.asarray(time_s, dtype=np.float64)
    if t.size < 2:
        return []
    clock = np.maximum.accumulate(t)
    at = np.flatnonzero(np.diff(clock) > longer_than_s)
    return [(float(clock[i]), float(clock[i + 1])) for i in at.tolist()]


def read_frames(path: str | os.PathLike[str]) -> FrameArrays:
    """Read a python-can log into arrays (rules in the module docstring); FlightLogError if unusable."""
    src = str(path)
    check_input(src, "CAN log", FlightLogError)
    if os.path.getsize(src) == 0:
        raise FlightLogError(f"{src}: empty file (0 bytes), not a CAN log")
    truncated = False
    frames: FrameArrays | None = None
    if src.lower().endswith(".blf"):
        frames, truncated = _read_blf(src)
    if frames is None:
        whole_lines = _whole_lines_of_cut_text_log(src)
        truncated = truncated or whole_lines is not None
        frames = _read_with_python_can(src, whole_lines)
    if len(frames) == 0:
        raise FlightLogError(f"{src}: no frames")
    frames = _drop_stray_stamps(src, frames)
    since_start = frames.time_s - np.min(frames.time_s)
    frames = FrameArrays(since_start, *(frames[i] for i in range(1, len(FrameArrays._fields))))
    if truncated:
        reached = float(np.max(frames.time_s))
        _log.warning(
            "%s: the log is cut in the middle (incomplete last record): %d frames kept, up to t=%.3f s",
            src,
            len(frames),
            reached,
        )
    _check_one_clock(src, frames.time_s)
    return frames


def _drop_stray_stamps(src: str, frames: FrameArrays) -> FrameArrays:
    """The frames without those whose stamp no clock could give: not finite, negative, or one frame
    more than RESTART_S ahead of both its neighbours (a logger's glitch, not a second log); warns with
    the count. FlightLogError if no frame is left."""
    t = frames.time_s
    with np.errstate(invalid="ignore"):
        stray = ~np.isfinite(t) | (t < 0.0)
        if t.size >= 3:
            stray[1:-1] |= (t[1:-1] - t[:-2] > RESTART_S) & (t[1:-1] - t[2:] > RESTART_S)
        if t.size >= 2:
            stray[0] |= bool(t[0] - t[1] > RESTART_S)
    if not np.any(stray):
        return frames
    first = int(np.argmax(stray))
    _log.warning(
        "%s: %d frame(s) with a stamp out of line with their neighbours dropped (first: frame %d, t=%r s)",
        src,
        int(np.count_nonzero(stray)),
        first + 1,
        float(t[first]),
    )
    if np.all(stray):
        raise FlightLogError(f"{src}: no frame has a usable time stamp")
    return frames.take(~stray)


def _check_one_clock(src: str, time_s: NDArray[np.float64]) -> None:
    """FlightLogError if time goes back by more than RESTART_S (a second log appended to the first)."""
    if time_s.size < 2:
        return
    previous = np.maximum.accumulate(time_s)[:-1]
    back = previous - time_s[1:] > RESTART_S
    if np.any(back):
        k = int(np.argmax(back)) + 1
        raise FlightLogError(
            f"{src}: frame {k + 1}: time goes back from {previous[k - 1]:.3f} s to {time_s[k]:.3f} s (two logs back"
            " to back?): give each log on its own"
        )


#: Text log formats whose last line may be cut mid-write.
_TEXT_LOGS: tuple[str, ...] = (".asc", ".log", ".trc")


def _whole_lines_of_cut_text_log(src: str) -> str | None:
    """For a text log whose last line is cut (no final line break): the text up to its last whole
    line; None for any other file."""
    if Path(src).suffix.lower() not in _TEXT_LOGS:
        return None
    try:
        with open(src, "rb") as handle:
            handle.seek(-1, os.SEEK_END)
            if handle.read(1) in (b"\n", b"\r"):
                return None
            handle.seek(0)
            raw = handle.read()
    except OSError:
        return None
    return raw[: raw.rfind(b"\n") + 1].decode("utf-8", errors="replace")


def _escaped(text: str) -> str:
    """``text`` with each character that is not printable (a line break, NUL, ...) written as its escape: a
    skipped line quoted in a one-line error stays one line."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


class _SkippedLines(logging.Filter):
    """While entered, counts and silences what python-can's log readers say about lines they skip (a
    .trc whose body is another version than its header logs one line per frame: tens of thousands)."""

    def __init__(self) -> None:
        super().__init__()
        self.count = 0
        self.first = ""
        self._loggers: list[logging.Logger] = []

    def filter(self, record: logging.LogRecord) -> bool:
        self.count += 1
        self.first = self.first or _escaped(record.getMessage()[:120])
        return False

    def __enter__(self) -> _SkippedLines:
        names = [name for name in logging.root.manager.loggerDict if name.startswith("can.io")]
        self._loggers = [logging.getLogger(name) for name in names]
        for logger in self._loggers:
            logger.addFilter(self)
        return self

    def __exit__(self, *exc_info: object) -> None:
        for logger in self._loggers:
            logger.removeFilter(self)


def _read_with_python_can(src: str, text: str | None = None) -> FrameArrays:
    """Frames through python-can's reader of the file's suffix; ``text``: the log's text to read instead
    of the file (a cut text log without its last line)."""
    import io

    import can

    times: list[float] = []
    ids: list[int] = []
    ext: list[bool] = []
    dlcs: list[int] = []
    ignored: list[bool] = []
    payload = bytearray()
    skipped = _SkippedLines()
    try:
        reader_class = can.io.player.MESSAGE_READERS.get(Path(src).suffix.lower())
        opened = can.LogReader(src) if text is None or reader_class is None else reader_class(io.StringIO(text))  # type: ignore[arg-type]  # the text readers take a file object too
        with opened as reader, skipped:
            for msg in reader:
                times.append(msg.timestamp)
                ids.append(msg.arbitration_id)
                ext.append(msg.is_extended_id)
                data = bytes(msg.data[:8])
                dlcs.append(len(msg.data))
                ignored.append(msg.is_error_frame or msg.is_remote_frame)
                payload += data.ljust(8, b"\0")
    except FileNotFoundError:
        raise FlightLogError(f"{src}: no such file") from None
    except OSError as exc:
        raise FlightLogError(f"{src}: cannot read: {exc.strerror or exc}") from None
    except KeyError as exc:  # a text log whose header does not name a column its reader needs
        raise FlightLogError(f"{src}: unreadable CAN log: its header names no column {exc.args[0]!r}") from None
    except (
        ValueError,
        IndexError,
        OverflowError,
        struct.error,
        zlib.error,
        UnicodeDecodeError,
        can.io.blf.BLFParseError,
    ) as exc:
        detail = str(exc).strip().splitlines()[0][:120] if str(exc).strip() else type(exc).__name__
        if isinstance(exc, OverflowError):
            detail = f"a time stamp beyond any calendar (its start time or a frame's time: {detail})"
        raise FlightLogError(f"{src}: unreadable CAN log after {len(times)} frames: {detail}") from None
    if skipped.count and not times:
        raise FlightLogError(f"{src}: no frames: python-can skipped {skipped.count} line(s), first: {skipped.first}")
    if skipped.count:
        _log.warning("%s: python-can skipped %d line(s), first: %s", src, skipped.count, skipped.first)
    return FrameArrays(
        np.asarray(times, dtype=np.float64),
        np.asarray(ids, dtype=np.int64),
        np.asarray(ext, dtype=bool),
        np.asarray(dlcs, dtype=np.int64),
        np.frombuffer(bytes(payload), dtype=np.uint8).reshape(-1, 8).copy(),
        np.asarray(ignored, dtype=bool),
    )


_BLF_RECORD = np.dtype(
    [
        ("signature", "S4"),
        ("header_size", "<u2"),
        ("header_version", "<u2"),
        ("object_size", "<u4"),
        ("object_type", "<u4"),
        ("flags", "<u4"),
        ("client", "<u2"),
        ("object_version", "<u2"),
        ("timestamp", "<u8"),
        ("channel", "<u2"),
        ("msg_flags", "u1"),
        ("dlc", "u1"),
        ("can_id", "<u4"),
        ("data", "u1", (8,)),
    ]
)  # a CAN_MESSAGE object (type 1) with a version-1 header: 48 bytes


def _read_blf(src: str) -> tuple[FrameArrays | None, bool]:
    """(frames read straight into arrays, or None if the file needs python-can's reader; the file is cut)."""
    from can.io import blf

    try:
        with open(src, "rb") as handle:
            header_bytes = handle.read(blf.FILE_HEADER_STRUCT.size)
            if len(header_bytes) < blf.FILE_HEADER_STRUCT.size:
                raise FlightLogError(f"{src}: not a .blf file ({len(header_bytes)} bytes, shorter than its header)")
            header = blf.FILE_HEADER_STRUCT.unpack(header_bytes)
            if header[0] != b"LOGG":
                raise FlightLogError(f"{src}: not a .blf file (no LOGG signature)")
            start = blf.systemtime_to_timestamp(header[14:22])
            handle.read(max(0, header[1] - blf.FILE_HEADER_STRUCT.size))
            chunks: list[bytes] = []
            base = blf.OBJ_HEADER_BASE_STRUCT
            truncated = False
            fast = True
            while True:
                head = handle.read(base.size)
                if not head:
                    break
                if len(head) < base.size:
                    truncated = True
                    break
                signature, _, _, size, kind = base.unpack(head)
                if signature != b"LOBJ" or size < base.size:
                    truncated = True  # garbage after the last object: read up to here
                    break
                body = handle.read(size - base.size)
                handle.read(size % 4)
                if kind != blf.LOG_CONTAINER:
                    fast = False
                    continue
                if len(body) < size - base.size:
                    truncated = True
                method = struct.unpack_from("<H", body)[0] if len(body) >= 2 else -1
                payload = body[blf.LOG_CONTAINER_STRUCT.size :]
                if method == blf.ZLIB_DEFLATE:
                    try:
                        chunks.append(zlib.decompressobj().decompress(payload))
                    except zlib.error:
                        truncated = True
                        break
                elif method == blf.NO_COMPRESSION:
                    chunks.append(payload)
                else:
                    fast = False
                if truncated:
                    break
    except OSError as exc:
        raise FlightLogError(f"{src}: cannot read: {exc.strerror or exc}") from None
    except struct.error:
        return None, True
    raw = b"".join(chunks)
    whole = len(raw) - len(raw) % _BLF_RECORD.itemsize
    if not fast or not raw:
        return None, truncated
    if whole != len(raw):
        truncated = True  # the last record was cut (or the file holds other objects: checked below)
    rec = np.frombuffer(raw[:whole], dtype=_BLF_RECORD)
    if not (
        np.all(rec["signature"] == b"LOBJ")
        and np.all(rec["object_size"] == _BLF_RECORD.itemsize)
        and np.all(rec["object_type"] == blf.CAN_MESSAGE)
        and np.all(rec["header_version"] == 1)
    ):
        return None, truncated
    factor = np.where(rec["flags"] == blf.TIME_TEN_MICS, 1e-5, 1e-9)
    time_s = rec["timestamp"].astype(np.float64) * factor + start
    dlc = np.minimum(rec["dlc"].astype(np.int64), 8)
    data = rec["data"].copy()
    data[np.arange(8)[None, :] >= dlc[:, None]] = 0
    can_id = rec["can_id"].astype(np.int64)
    frames = FrameArrays(
        time_s,
        can_id & 0x1FFFFFFF,
        (can_id & blf.CAN_MSG_EXT) != 0,
        dlc,
        data,
        (rec["msg_flags"] & blf.REMOTE_FLAG) != 0,
    )
    return frames, truncated


def read_blf_arrays(path: str | os.PathLike[str]) -> FrameArrays | None:
    """Frames of a .blf as arrays without building Message objects, or None if the file holds anything
    but classic CAN messages with version-1 headers (then :func:`read_frames` uses python-can's reader).

    Same layout and timestamps as python-can's BLFReader (start time of the file header plus the
    object's timestamp, 10 us or 1 ns units).
    """
    return _read_blf(str(path))[0]


# --------------------------------------------------------------------------------------------------
# Import into a flight log
# --------------------------------------------------------------------------------------------------


def _signal_specs(dbc_paths: Sequence[Any], smap: Mapping[str, str]) -> list[SignalSpec]:
    """The signal map checked against the DBCs: one SignalSpec per column (``Message.Signal[:unit]``)."""
    dbs = [load_dbc(p) for p in dbc_paths]
    dbc_names = ", ".join(db.path for db in dbs)
    specs = []
    for column, ref in smap.items():
        if column == "time_s" or not _IDENTIFIER.match(column):
            raise ConfigError(f"signal map: key '{column}': output name must be an identifier other than time_s")
        text, _, unit = str(ref).partition(":")
        msg_name, _, sig_name = text.partition(".")
        message = next((m for db in dbs if (m := db.find(msg_name)) is not None), None)
        if message is None:
            raise ConfigError(f"signal map: key '{column}': no message '{msg_name}' in {dbc_names}")
        if sig_name not in {s.name for s in message.signals}:
            raise ConfigError(f"signal map: key '{column}': message '{msg_name}' has no signal '{sig_name}'")
        specs.append(SignalSpec(column, msg_name, sig_name, unit.strip() or "raw"))
    return specs


def import_can_log(
    path: str | os.PathLike[str],
    dbc_paths: Sequence[str | os.PathLike[str]],
    signal_map: Mapping[str, str] | None = None,
    *,
    dt_s: float = 0.1,
) -> FlightLog:
    """Decode a python-can log with DBC files into a flight log.

    ``signal_map`` maps output column -> ``"Message.Signal"`` or ``"Message.Signal:unit"`` (a unit of
    :data:`ecu_monitor.units.UNITS`; without one the DBC's physical value is taken as it is; default
    :data:`DEFAULT_SIGNAL_MAP`, for the shipped engine.dbc). Frames are read by :func:`read_frames` and
    decoded by the service's decoder (the same checks: frames with a bad length, checksum or
    counter, or a value outside the DBC range, are dropped and counted in a warning). Every mapped
    signal is sampled and held onto a uniform grid of step ``dt_s`` (default 0.1 s, the slowest frame
    rate) from the first instant every mapped signal has been seen to the last frame; ``time_s``
    counts from that instant. Grid instants inside a hole of the log (no frame for more than
    :data:`GAP_S`) are left out, so the flight log keeps the hole as a time gap.
    """
    src = str(path)
    if not dbc_paths:
        raise ConfigError(f"{src}: no DBC file given to decode the CAN log")
    if not (math.isfinite(dt_s) and dt_s > 0.0):
        raise FlightLogError(f"{src}: sample step must be a positive number, got {dt_s!r}")
    smap = dict(DEFAULT_SIGNAL_MAP if signal_map is None else signal_map)
    if not smap:
        raise ConfigError(f"{src}: empty signal map")
    specs = _signal_specs(dbc_paths, smap)
    decoder = Decoder(list(dbc_paths), specs)
    frames = read_frames(src)
    clock = np.maximum.accumulate(frames.time_s)
    batch = decoder.decode_batch(
        frames.arbitration_id, frames.is_extended, frames.dlc, frames.data, clock, frames.ignored
    )
    notes: list[str] = []
    counts = batch.counts
    if counts["malformed"]:
        reasons = ", ".join(f"{r} {counts[r]}" for r in MALFORMED_REASONS if counts[r])
        _note(notes, src, f"{counts['malformed']} frame(s) failed to decode and were skipped ({reasons})")
    if counts["ignored"]:
        _note(notes, src, f"{counts['ignored']} error/remote frame(s) ignored")
    for spec in specs:
        if batch.values[spec.name][0].size == 0:
            raise FlightLogError(
                f"{src}: signal '{smap[spec.name]}' for column '{spec.name}' never seen ({len(frames)} frames read)"
            )
    start = max(float(clock[batch.values[spec.name][0][0]]) for spec in specs)
    last_t = float(clock[-1])
    n = math.floor((last_t - start) / dt_s + 1e-9) + 1
    offsets = np.round(dt_s * np.arange(n, dtype=np.float64), 9)
    grid = start + offsets
    keep = np.ones(n, dtype=bool)
    holes = time_gaps(clock)
    for before, after in holes:
        keep &= ~((grid > before + dt_s) & (grid < after))
    if holes:
        longest = max(after - before for before, after in holes)
        _note(notes, src, f"{len(holes)} hole(s) in the log longer than {GAP_S:g} s (longest {longest:.1f} s): no rows")
    out: dict[str, np.ndarray] = {"time_s": offsets[keep]}
    stale_limit = max(1.0, 10.0 * dt_s)
    for spec in specs:
        rows, values = batch.values[spec.name]
        t = clock[rows]
        out[spec.name] = values[np.searchsorted(t, grid[keep] + _TIE_S, side="right") - 1]
        stale = int(np.count_nonzero(np.diff(t) > stale_limit))
        if stale:
            _note(notes, src, f"'{smap[spec.name]}': {stale} silence(s) longer than {stale_limit:g} s held over")
    return FlightLog(out, src, tuple(notes))


def _note(notes: list[str], source: str, message: str) -> None:
    notes.append(message)
    _log.warning("%s: %s", source, message)


# --------------------------------------------------------------------------------------------------
# Any flight log
# --------------------------------------------------------------------------------------------------


def load_flight(
    path: str | os.PathLike[str],
    *,
    mapping: str | os.PathLike[str] | None = None,
    dbc_paths: Sequence[str | os.PathLike[str]] | None = None,
    signal_map: Mapping[str, str] | None = None,
    engine: int | None = None,
    cht: str | int | None = None,
) -> FlightLog:
    """Load any supported flight log by suffix.

    ``.csv``: canonical, or foreign through ``mapping`` (:func:`ecu_monitor.flightlog.load_csv`: None
    or ``"auto"`` detects the layout; ``engine`` and ``cht`` as there). ``.asc/.blf/.log/.trc``:
    :func:`import_can_log` with ``dbc_paths`` (default: the shipped engine.dbc) and ``signal_map``
    (default :data:`DEFAULT_SIGNAL_MAP`), for one engine. ``.tlog``: a MAVLink telemetry log through the
    default MAVLink mapping (:func:`ecu_monitor.bus.mavlink_log.read_tlog`).
    """
    path = Path(path)
    check_input(path, "flight log", FlightLogError)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        if dbc_paths or signal_map:
            raise FlightLogError(f"{path}: DBC files apply to CAN logs, not to a CSV")
        return load_csv(path, mapping, engine=engine, cht=cht)
    if suffix in CAN_LOG_SUFFIXES:
        if mapping is not None:
            raise FlightLogError(f"{path}: a CSV mapping does not apply to a CAN log (give DBC files)")
        if engine not in (None, 1):
            raise FlightLogError(f"{path}: engine {engine} asked for, a CAN log is read for one engine")
        log = import_can_log(path, list(dbc_paths) if dbc_paths else [shipped_dbc("engine.dbc")], signal_map)
        return log if cht is None else choose_cht(log, cht)
    if suffix == ".tlog":
        if mapping is not None or dbc_paths or signal_map:
            raise FlightLogError(f"{path}: a MAVLink log is read through the MAVLink mapping (no DBC, no CSV mapping)")
        if engine not in (None, 1):
            raise FlightLogError(f"{path}: engine {engine} asked for, a MAVLink log is read for one engine")
        from ecu_monitor.bus.mavlink_log import read_tlog

        return read_tlog(path)
    known = ", ".join((".csv", *CAN_LOG_SUFFIXES, ".tlog"))
    raise FlightLogError(f"{path}: unknown log type {path.suffix or '(no suffix)'!r} (known: {known})")
