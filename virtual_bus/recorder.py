"""Recorder of the virtual ECU: one flight to a canonical CSV and/or python-can logs, in one pass.

Outputs are chosen by suffix: ``.csv`` (canonical flight CSV through
:func:`ecu_monitor.flightlog.write_csv`, measured columns plus ``cht_true_c``, ``gamma_q``,
``gamma_d``), ``.asc``, ``.blf`` or ``.log`` (candump) through ``can.Logger``. Every output of a call
comes from the same flight (the same seed, the same frames). The flight is streamed: frames go to the
log writers block by block and only the CSV's samples (every ``record_dt_s``) are kept in memory, so
a 16 h flight records in constant memory for the CAN logs. ``protocol="dronecan"`` writes the
frames of :class:`~virtual_bus.dronecan_emitter.DroneCanFrameEncoder` into the CAN logs instead of
engine.dbc's (the CSV is the same). ``protocol="mavlink"`` writes the autopilot's MAVLink stream of
:class:`~virtual_bus.mavlink_emitter.MavlinkFrameEncoder` to ``.tlog`` outputs (MAVLink is not on CAN:
no CAN log then, and a .tlog only with it).
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import can
import numpy as np

from ecu_monitor.errors import ConfigError
from ecu_monitor.flightlog import FlightLog, write_csv
from ecu_monitor.model import Effects, ThermalParams, paper_table_a1
from ecu_monitor.userfiles import atomic_output
from virtual_bus.dronecan_emitter import DroneCanFrameEncoder
from virtual_bus.emitter import FrameEncoder
from virtual_bus.mavlink_emitter import MavlinkFrameEncoder, TlogWriter
from virtual_bus.missions import Mission
from virtual_bus.plant import LOG_COLUMNS, Degradation, StepBlock, block_rows, iter_steps, record_every
from virtual_bus.sensors import SensorModel

__all__ = ["CAN_SUFFIXES", "OUTPUT_SUFFIXES", "PROTOCOLS", "RecordSummary", "check_outputs", "frame_encoder", "record"]

#: Suffixes written as python-can logs, the MAVLink telemetry log, and every suffix the recorder accepts.
CAN_SUFFIXES: tuple[str, ...] = (".asc", ".blf", ".log")
TLOG_SUFFIX = ".tlog"
OUTPUT_SUFFIXES: tuple[str, ...] = (".csv", *CAN_SUFFIXES, TLOG_SUFFIX)
#: What the virtual ECU speaks: engine.dbc frames, DroneCAN messages, or an autopilot's MAVLink stream.
PROTOCOLS: tuple[str, ...] = ("dbc", "dronecan", "mavlink")


def frame_encoder(
    protocol: str, *, cht_limit_c: float, start_time_s: float = 0.0, cylinders: int = 1
) -> FrameEncoder | DroneCanFrameEncoder:
    """The virtual ECU's frame encoder for ``protocol`` (one of :data:`PROTOCOLS`); ``cylinders``: an
    engine flown with cylinders (DBC: the frames of cylinders.dbc too; DroneCAN: one CylinderStatus each)."""
    if protocol == "dbc":
        return FrameEncoder(cht_limit_c=cht_limit_c, start_time_s=start_time_s, cylinders=cylinders)
    if protocol == "dronecan":
        return DroneCanFrameEncoder(cht_limit_c=cht_limit_c, start_time_s=start_time_s)
    if protocol == "mavlink":
        raise ConfigError("--protocol mavlink: MAVLink is not on CAN (virtual_bus.mavlink_emitter.MavlinkFrameEncoder)")
    raise ConfigError(f"--protocol: expected one of {', '.join(PROTOCOLS)}, got {protocol!r}")


@dataclass
class RecordSummary:
    """What a recording produced: flight duration (s), CHT peaks (degC), rows and frames per file."""

    duration_s: float = 0.0
    max_cht_c: float = -math.inf
    max_cht_true_c: float = -math.inf
    rows: int = 0
    frames: int = 0
    files: dict[str, str] = field(default_factory=dict)


def check_outputs(outputs: Sequence[str | Path]) -> list[Path]:
    """The output paths, checked: known suffixes, no duplicates, existing parent directories."""
    if not outputs:
        raise ConfigError("--out: give at least one output file (.csv, .asc, .blf, .log or .tlog)")
    paths = [Path(p) for p in outputs]
    for path in paths:
        if path.suffix.lower() not in OUTPUT_SUFFIXES:
            raise ConfigError(
                f"{path}: unknown output type {path.suffix or '(none)'!r} (known: {', '.join(OUTPUT_SUFFIXES)})"
            )
        if not path.parent.is_dir():
            raise ConfigError(f"{path}: directory {path.parent} does not exist")
    if len({p.resolve() for p in paths}) != len(paths):
        raise ConfigError("--out: the same file is named twice")
    return paths


def record(
    mission: Mission,
    outputs: Sequence[str | Path],
    params: ThermalParams | None = None,
    *,
    effects: Effects | None = None,
    degradation: Sequence[Degradation] = (),
    seed: int = 0,
    dt_s: float = 0.02,
    record_dt_s: float = 0.1,
    sensors: SensorModel | None = None,
    start_time_s: float = 0.0,
    progress: Callable[[float], None] | None = None,
    protocol: str = "dbc",
    cylinders: Sequence[ThermalParams] = (),
) -> RecordSummary:
    """Fly ``mission`` once and write every output; ``progress`` gets the mission time (s) per block.
    ``cylinders``: fly an engine with one head per model (:func:`virtual_bus.plant.iter_steps`): the
    CSV gets ``cht1_c .. chtN_c`` and the per-cylinder truth, the CAN logs the frames of cylinders.dbc."""
    paths = check_outputs(outputs)
    params = params or paper_table_a1()
    every = record_every(dt_s, record_dt_s)
    csv_paths = [p for p in paths if p.suffix.lower() == ".csv"]
    can_paths = [p for p in paths if p.suffix.lower() in CAN_SUFFIXES]
    tlog_paths = [p for p in paths if p.suffix.lower() == TLOG_SUFFIX]
    if tlog_paths and protocol != "mavlink":
        raise ConfigError(f"{tlog_paths[0]}: a MAVLink telemetry log: give --protocol mavlink")
    if can_paths and protocol == "mavlink":
        raise ConfigError(f"{can_paths[0]}: a CAN log, and MAVLink is not on CAN: write a .tlog")
    count = len(cylinders) if len(cylinders) > 1 else 1
    encoder: FrameEncoder | DroneCanFrameEncoder | MavlinkFrameEncoder
    if protocol == "mavlink":
        encoder = MavlinkFrameEncoder(start_time_s=start_time_s)
    else:
        encoder = frame_encoder(protocol, cht_limit_c=params.cht_limit_c, start_time_s=start_time_s, cylinders=count)
    summary = RecordSummary()
    parts: dict[str, list[np.ndarray]] = {name: [] for name in LOG_COLUMNS}
    writers: list[Any] = []
    with contextlib.ExitStack() as outputs:  # each log written atomically: nothing left if the run fails
        for path in can_paths:
            writers.append(_can_writer(path, outputs.enter_context(atomic_output(path, ConfigError))))
            outputs.callback(writers[-1].stop)  # before its file is renamed (or removed)
        for path in tlog_paths:
            writers.append(TlogWriter(path, outputs.enter_context(atomic_output(path, ConfigError))))
        blocks = iter_steps(
            mission,
            params,
            effects=effects,
            degradation=degradation,
            seed=seed,
            dt_s=dt_s,
            sensors=sensors,
            cylinders=cylinders,
        )
        for block in blocks:
            _take(block, every, parts, summary, bool(csv_paths))
            if writers:
                for msg in encoder.frames(block):
                    for writer in writers:
                        writer.on_message_received(msg)
                    summary.frames += 1
            if progress is not None:
                progress(float(block.time_s[-1]))
    source = f"virtual-ecu:{mission.name}:seed={seed}"
    if csv_paths:
        log = FlightLog({name: np.concatenate(chunks) for name, chunks in parts.items()}, source=source)
        summary.rows = len(log)
        for path in csv_paths:
            write_csv(log, path)
            summary.files[str(path)] = f"{len(log)} rows"
    for path in (*can_paths, *tlog_paths):
        summary.files[str(path)] = f"{summary.frames} {'messages' if path in tlog_paths else 'frames'}"
    return summary


def _can_writer(path: Path, handle: BinaryIO) -> Any:
    """python-can's writer of ``path``'s suffix over ``handle`` (through a duplicate of its descriptor:
    the writer closes its own file when it stops, the handle stays for :func:`atomic_output`'s fsync)."""
    writer_class = can.io.logger.MESSAGE_WRITERS[path.suffix.lower()]
    binary = issubclass(writer_class, can.io.generic.BinaryIOMessageWriter)
    duplicate = os.fdopen(os.dup(handle.fileno()), "wb" if binary else "w", **({} if binary else {"newline": ""}))
    return writer_class(duplicate)


def _take(block: StepBlock, every: int, parts: dict[str, list[np.ndarray]], summary: RecordSummary, keep: bool) -> None:
    summary.duration_s = float(block.time_s[-1])
    summary.max_cht_c = max(summary.max_cht_c, float(np.max(block.measured.cht_c)))
    summary.max_cht_true_c = max(summary.max_cht_true_c, float(np.max(block.cht_true_c)))
    if keep:
        for name, values in block_rows(block, every).items():
            parts.setdefault(name, []).append(values)
