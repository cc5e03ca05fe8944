"""FLEET.yaml: the engines of a fleet and their logs, validated into frozen settings.

::

    defaults:                      # optional: every engine's setting unless it gives its own
      config: example.yaml         # the service config the logs are replayed with (shipped name or path)
      model: model.yaml            # the thermal model (default: the config's); a type model is a model file too
      detector: detector.yaml      # what ``ecu-monitor calibrate --out`` wrote (detector:, wear:, cylinders:)
    engines:
      - serial: UAV-ENG-0007
        logs: ["logs/0007/*.blf", "logs/0007/*.csv", "state/0007/ecu-monitor.sqlite3"]
        tbo_hours: 2000            # optional: hours between overhauls (TBO)
        overhaul_hours: 412        # optional: hours since overhaul before the first log (engine.overhaul_hours)
        mapping: g1000             # optional: the layout of foreign CSVs (default: recognised from the header)

Paths (config, model, detector, mapping files, the logs' globs) are relative to FLEET.yaml's folder.
Errors are one line naming the file and the key (:func:`ecu_monitor.config.validation_error`).
"""

from __future__ import annotations

import glob
import hashlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import msgspec

from ecu_monitor.config import MODEL_PRESETS, validation_error
from ecu_monitor.errors import ConfigError
from ecu_monitor.shipped import DEFAULT_CONFIG, resolve_file
from ecu_monitor.userfiles import read_input_bytes
from ecu_monitor.yamlfile import load_yaml_file

__all__ = ["EngineSettings", "Fleet", "LogJob", "load_fleet"]

#: An engine serial: it names the engine's partition folder (``serial=...``), so no path characters.
_SERIAL = Annotated[
    str,
    msgspec.Meta(
        pattern=r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$",
        description="a serial of letters, digits, '.', '_', '-' (at most 64)",
    ),
]
_HOURS = Annotated[float, msgspec.Meta(ge=0.0, le=1e6)]


class _Settings(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    config: str | None = None
    model: str | None = None
    detector: str | None = None
    mapping: str | None = None
    engine: Annotated[int, msgspec.Meta(ge=1, le=8)] | None = None  # the engine of a twin's export
    tbo_hours: Annotated[float, msgspec.Meta(gt=0.0, le=1e6)] | None = None


class _Engine(_Settings, frozen=True, forbid_unknown_fields=True):
    serial: _SERIAL = ""
    logs: Annotated[list[str], msgspec.Meta(min_length=1)] = msgspec.field(default_factory=list)
    overhaul_hours: _HOURS = 0.0


class FleetFile(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The schema of FLEET.yaml (module docstring)."""

    engines: Annotated[list[_Engine], msgspec.Meta(min_length=1)]
    defaults: _Settings = _Settings()


@dataclass(frozen=True)
class EngineSettings:
    """What a worker needs to replay one engine's logs: absolute paths (None: the default), picklable."""

    serial: str
    config: Path
    model: str | None  # a model file's absolute path or a preset's name (MODEL_PRESETS); None: the config's
    detector: Path | None
    mapping: str | None
    engine: int | None
    tbo_hours: float | None
    overhaul_hours: float

    @property
    def digest(self) -> str:
        """sha256 of the settings and the content of their files: a log replayed with other settings is new."""
        h = hashlib.sha256(f"{self.serial}|{self.mapping}|{self.engine}".encode())
        for path in (self.config, self.detector, self.model):
            if path is None or (isinstance(path, str) and path in MODEL_PRESETS):
                h.update(f"|{path}".encode())
            else:
                h.update(b"|" + read_input_bytes(path, "fleet file", ConfigError))
        return h.hexdigest()


@dataclass(frozen=True)
class LogJob:
    """One log of one engine: its path, its name (relative to the fleet's folder; absolute outside it), its
    position in the engine's listing (globs in order, each sorted) and its key (content and engine settings)."""

    serial: str
    path: Path
    name: str
    position: int
    key: str


@dataclass(frozen=True)
class Fleet:
    """A loaded FLEET.yaml: its engines in file order and the folder its paths are relative to."""

    source: Path
    engines: tuple[EngineSettings, ...]
    globs: dict[str, tuple[str, ...]]

    def jobs(self) -> tuple[list[LogJob], list[str]]:
        """Every log of every engine (keys hashed from content; a log listed twice for an engine counts once),
        and one line per glob that matched nothing."""
        base = self.source.parent
        out: list[LogJob] = []
        empty: list[str] = []
        for engine in self.engines:
            seen: set[Path] = set()
            digest = engine.digest
            for pattern in self.globs[engine.serial]:
                full = os.path.join(base, os.path.expanduser(pattern))
                matched = sorted(Path(p) for p in glob.glob(full, recursive=True) if Path(p).is_file())
                if not matched:
                    empty.append(f"{self.source}: engine {engine.serial}: no log matches {pattern!r}")
                for path in matched:
                    resolved = path.resolve()
                    if resolved in seen:
                        continue
                    seen.add(resolved)
                    key = _key(path, digest)
                    inside = path.resolve().is_relative_to(base.resolve())
                    name = os.path.relpath(path, base) if inside else str(path.resolve())
                    out.append(LogJob(engine.serial, path, name, len(seen) - 1, key))
        return out, empty

    def engine(self, serial: str) -> EngineSettings:
        """The settings of engine ``serial``."""
        return next(e for e in self.engines if e.serial == serial)


def _key(path: Path, digest: str) -> str:
    """24 hex digits of sha256(log content, engine settings digest)."""
    h = hashlib.sha256(digest.encode())
    with path.open("rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()[:24]


def load_fleet(path: str | os.PathLike[str]) -> Fleet:
    """Read and validate FLEET.yaml (module docstring); ConfigError in one line naming the file and key."""
    src = Path(path)
    data = load_yaml_file(src, "fleet file", ConfigError)
    try:
        file = msgspec.convert(data, FleetFile)
    except msgspec.ValidationError as exc:
        raise validation_error(src, exc, data, FleetFile) from None
    base = src.resolve().parent
    engines: list[EngineSettings] = []
    globs: dict[str, tuple[str, ...]] = {}
    for i, entry in enumerate(file.engines):
        if not entry.serial:
            raise ConfigError(f"{src}: engines[{i}].serial: missing")
        if not entry.logs:
            raise ConfigError(f"{src}: engines[{i}].logs: missing")
        if entry.serial in globs:
            raise ConfigError(f"{src}: engines[{i}].serial: {entry.serial!r} is listed twice")
        merged = {k: getattr(entry, k) if getattr(entry, k) is not None else getattr(file.defaults, k)
                  for k in _Settings.__struct_fields__}  # fmt: skip
        where = f"{src}: engines[{i}]"
        engines.append(
            EngineSettings(
                serial=entry.serial,
                config=_file(base, merged["config"] or str(DEFAULT_CONFIG), "config", f"{where}.config"),
                model=_model(base, merged["model"], f"{where}.model"),
                detector=_file(base, merged["detector"], None, f"{where}.detector") if merged["detector"] else None,
                mapping=_mapping(base, merged["mapping"]),
                engine=merged["engine"],
                tbo_hours=merged["tbo_hours"],
                overhaul_hours=entry.overhaul_hours,
            )
        )
        globs[entry.serial] = tuple(entry.logs)
    return Fleet(src, tuple(engines), globs)


def _file(base: Path, value: str, kind: str | None, where: str) -> Path:
    """A file named relative to the fleet's folder, or (``kind``) a shipped file's name; ConfigError if absent."""
    given = Path(os.path.expanduser(value))
    path = given if given.is_absolute() else base / given
    if path.is_file():
        return path
    if kind is not None and not given.is_absolute():
        try:
            return resolve_file(value, kind)
        except ConfigError:
            pass
    raise ConfigError(f"{where}: no such file {value!r} (relative to {base})")


def _model(base: Path, value: str | None, where: str) -> str | None:
    """A model file relative to the fleet's folder (absolute path), a preset's name, or None."""
    if value is None or value in MODEL_PRESETS:
        return value
    return str(_file(base, value, None, where).resolve())


def _mapping(base: Path, value: str | None) -> str | None:
    """A mapping file relative to the fleet's folder, else as given (a shipped mapping's name, or None)."""
    if value is None:
        return None
    path = base / os.path.expanduser(value)
    return str(path) if path.is_file() else value
