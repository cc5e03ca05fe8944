"""Flight segments found from the data: ground, climb, cruise, descent.

A sample is *ground* while the airspeed is below ``ground_airspeed_mps`` (or, in a log without
airspeed, while the altitude is within ``ground_altitude_band_m`` of the lowest altitude and the rpm
is below its median). Airborne samples are *climb* or *descent* when the vertical speed (the
``vspeed_mps`` column, or the altitude derivative smoothed over ``smoothing_s``) exceeds
``vspeed_threshold_mps`` up or down, otherwise *cruise*. Runs shorter than their minimum duration
are merged into the longer neighbour, shortest first, so a gust or a level-off of a few seconds does
not make a segment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ecu_monitor.errors import ParameterError
from ecu_monitor.flightlog import FlightLog

__all__ = ["SEGMENT_NAMES", "Segment", "SegmentSettings", "Segmentation", "segment_flight"]

SEGMENT_NAMES: tuple[str, ...] = ("ground", "climb", "cruise", "descent")


@dataclass(frozen=True)
class SegmentSettings:
    """Thresholds of the segmentation (units in the names)."""

    ground_airspeed_mps: float = 12.0
    ground_altitude_band_m: float = 30.0
    vspeed_threshold_mps: float = 0.75
    smoothing_s: float = 20.0
    min_ground_s: float = 30.0
    min_airborne_s: float = 60.0

    def __post_init__(self) -> None:
        for name in (
            "ground_airspeed_mps",
            "ground_altitude_band_m",
            "vspeed_threshold_mps",
            "smoothing_s",
            "min_ground_s",
            "min_airborne_s",
        ):
            value = getattr(self, name)
            if not isinstance(value, int | float) or not math.isfinite(value) or value < 0.0:
                raise ParameterError(f"segments.{name}: expected a number >= 0, got {value!r}")


@dataclass(frozen=True)
class Segment:
    """One contiguous run of samples ``[start, stop)`` with one label."""

    name: str
    start: int
    stop: int
    start_s: float
    stop_s: float

    @property
    def duration_s(self) -> float:
        """Length of the segment, s."""
        return self.stop_s - self.start_s


@dataclass(frozen=True)
class Segmentation:
    """Per-sample labels (index into SEGMENT_NAMES) and the runs they form."""

    labels: np.ndarray  # (N,) int, index into SEGMENT_NAMES
    segments: tuple[Segment, ...]

    def names(self) -> np.ndarray:
        """Per-sample segment names, (N,) str."""
        return np.asarray(SEGMENT_NAMES, dtype=object)[self.labels]

    def mask(self, name: str) -> np.ndarray:
        """Boolean mask of the samples labelled ``name``."""
        return self.labels == SEGMENT_NAMES.index(name)


def _moving_average(values: np.ndarray, width: int) -> np.ndarray:
    if width <= 1:
        return values.copy()
    kernel = np.ones(width) / width
    padded = np.pad(values, (width // 2, width - 1 - width // 2), mode="edge")
    return np.convolve(padded, kernel, mode="valid")


def _vertical_speed(log: FlightLog, smoothing_s: float) -> np.ndarray:
    t = log.time_s
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    width = max(1, round(smoothing_s / max(dt, 1e-6)))
    if log.has("vspeed_mps") and np.all(np.isfinite(log["vspeed_mps"])):
        return _moving_average(np.asarray(log["vspeed_mps"], dtype=float), width)
    altitude = _moving_average(np.asarray(log["altitude_m"], dtype=float), width)
    if t.size < 2:
        return np.zeros_like(altitude)
    return np.gradient(altitude, t)


def _runs(labels: np.ndarray) -> list[tuple[int, int, int]]:
    """(label, start, stop) of each run of equal labels."""
    edges = np.flatnonzero(np.diff(labels)) + 1
    starts = np.concatenate([[0], edges])
    stops = np.concatenate([edges, [labels.size]])
    return [(int(labels[a]), int(a), int(b)) for a, b in zip(starts, stops, strict=True)]


def _merge_short(labels: np.ndarray, t: np.ndarray, minimum: dict[int, float]) -> np.ndarray:
    labels = labels.copy()
    while True:
        runs = _runs(labels)
        if len(runs) <= 1:
            return labels

        def duration(run: tuple[int, int, int]) -> float:
            _, a, b = run
            return float(t[b - 1] - t[a]) + (float(t[1] - t[0]) if t.size > 1 else 0.0)

        short = [(duration(r), i) for i, r in enumerate(runs) if duration(r) < minimum[r[0]]]
        if not short:
            return labels
        _, i = min(short)
        _, a, b = runs[i]
        neighbours = [runs[j] for j in (i - 1, i + 1) if 0 <= j < len(runs)]
        target = max(neighbours, key=duration)[0]
        labels[a:b] = target


def segment_flight(log: FlightLog, settings: SegmentSettings | None = None) -> Segmentation:
    """Label every sample of ``log`` ground/climb/cruise/descent (see the module docstring)."""
    settings = settings or SegmentSettings()
    t = log.time_s
    n = t.size
    if log.has("airspeed_mps"):
        ground = np.asarray(log["airspeed_mps"], dtype=float) < settings.ground_airspeed_mps
    else:
        altitude = np.asarray(log["altitude_m"], dtype=float)
        rpm = np.asarray(log["rpm"], dtype=float)
        ground = (altitude < np.min(altitude) + settings.ground_altitude_band_m) & (rpm < np.median(rpm))
    vs = _vertical_speed(log, settings.smoothing_s)
    labels = np.full(n, SEGMENT_NAMES.index("cruise"), dtype=int)
    labels[vs > settings.vspeed_threshold_mps] = SEGMENT_NAMES.index("climb")
    labels[vs < -settings.vspeed_threshold_mps] = SEGMENT_NAMES.index("descent")
    labels[ground] = SEGMENT_NAMES.index("ground")
    minimum = {i: settings.min_airborne_s for i in range(len(SEGMENT_NAMES))}
    minimum[SEGMENT_NAMES.index("ground")] = settings.min_ground_s
    labels = _merge_short(labels, t, minimum)
    segments = tuple(Segment(SEGMENT_NAMES[label], a, b, float(t[a]), float(t[b - 1])) for label, a, b in _runs(labels))
    return Segmentation(labels, segments)
