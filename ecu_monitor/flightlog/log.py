"""The flight log itself: :class:`FlightLog` and the column vocabulary every reader checks against
(canonical and optional columns, engine and per-cylinder columns, physical limits, blank-run and gap
thresholds)."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from ecu_monitor.errors import FlightLogError

#: The canonical columns, in contract order (docs/contracts.md section 1).
CANONICAL_COLUMNS: tuple[str, ...] = (
    "time_s",
    "throttle_pct",
    "rpm",
    "altitude_m",
    "airspeed_mps",
    "oat_c",
    "cht_c",
)
#: Known optional columns; ``cht_true_c`` is the virtual ECU's truth (unquantised, noiseless) CHT.
OPTIONAL_COLUMNS: tuple[str, ...] = ("fuel_flow_lph", "vspeed_mps", "cht_true_c")
#: Engine-monitor columns an import may carry (all degC / kPa): mean and hottest EGT, manifold
#: pressure, oil temperature. Per-cylinder ``cht1_c .. chtN_c`` and ``egt1_c .. egtN_c`` sit beside them.
ENGINE_COLUMNS: tuple[str, ...] = ("egt_c", "egt_max_c", "manifold_pressure_kpa", "oil_temp_c")
#: How ``cht_c`` is made from the cylinders: their mean, the hottest per row, or one cylinder (1-based).
CHT_CHOICES: tuple[str, ...] = ("mean", "hottest")
#: A per-cylinder column name: ``cht3_c`` -> ("cht", "3").
CYLINDER_COLUMN = re.compile(r"^(cht|egt)([1-9][0-9]?)_c$")

#: Physically possible range of a column, inclusive; a value outside is an input error.
PHYSICAL_LIMITS: Mapping[str, tuple[float, float]] = MappingProxyType(
    {
        "rpm": (0.0, 30000.0),
        "throttle_pct": (-1.0, 101.0),
        "cht_c": (-60.0, 500.0),
        "cht_true_c": (-60.0, 500.0),
        "cht_max_c": (-60.0, 500.0),
        "oat_c": (-80.0, 70.0),
        "egt_c": (-60.0, 1300.0),
        "egt_max_c": (-60.0, 1300.0),
        "oil_temp_c": (-60.0, 250.0),
        "manifold_pressure_kpa": (0.0, 400.0),
    }
)
#: Longest run of blank fields that is filled by interpolation.
MAX_BLANK_RUN = 5
#: Time gaps longer than this are kept but reported.
GAP_WARN_S = 5.0
#: A flight log whose rows come further apart than this (median, s) or that lasts longer than
#: MAX_FLIGHT_S is refused: its time is not in seconds (an engine monitor logs every 6 s at the slowest;
#: no piston aircraft flies 48 h), and replaying it would run 50 steps a second over months.
MAX_MEDIAN_STEP_S = 30.0
MAX_FLIGHT_S = 48.0 * 3600.0

_REQUIRED_ALWAYS = tuple(c for c in CANONICAL_COLUMNS if c != "throttle_pct")
_STRICT = frozenset(CANONICAL_COLUMNS + OPTIONAL_COLUMNS)


@dataclass(frozen=True, eq=False)
class FlightLog:
    """An immutable flight log: float64 columns of equal length on a strictly increasing ``time_s``.

    The arrays are read-only copies. ``notes`` holds the warnings raised while the log was read
    (repairs made to the input); they are not part of the data.
    """

    columns: Mapping[str, np.ndarray]
    source: str = "<memory>"
    notes: tuple[str, ...] = field(default=(), repr=False)

    def __post_init__(self) -> None:
        if "time_s" not in self.columns:
            raise FlightLogError(f"{self.source}: no 'time_s' column")
        frozen: dict[str, np.ndarray] = {}
        length: int | None = None
        for name, values in self.columns.items():
            try:
                arr = np.array(values, dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise FlightLogError(f"{self.source}: column '{name}' is not numeric: {exc}") from exc
            if arr.ndim != 1:
                raise FlightLogError(f"{self.source}: column '{name}' is not one-dimensional")
            if length is None:
                length = arr.size
            elif arr.size != length:
                raise FlightLogError(f"{self.source}: column '{name}' has {arr.size} values, expected {length}")
            arr.flags.writeable = False
            frozen[name] = arr
        t = frozen["time_s"]
        if t.size == 0:
            raise FlightLogError(f"{self.source}: no samples")
        if not np.all(np.isfinite(t)):
            raise FlightLogError(f"{self.source}: column 'time_s' holds non-finite values")
        if t.size > 1 and not np.all(np.diff(t) > 0.0):
            k = int(np.argmax(np.diff(t) <= 0.0))
            raise FlightLogError(
                f"{self.source}: column 'time_s' is not strictly increasing at sample {k + 1}"
                f" ({t[k + 1]!r} after {t[k]!r})"
            )
        object.__setattr__(self, "columns", MappingProxyType(frozen))
        object.__setattr__(self, "notes", tuple(self.notes))

    def __len__(self) -> int:
        return int(self.columns["time_s"].size)

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise FlightLogError(f"{self.source}: no column '{name}' (columns: {', '.join(self.columns)})") from None

    def has(self, name: str) -> bool:
        """True if the log carries column ``name``."""
        return name in self.columns

    @property
    def names(self) -> tuple[str, ...]:
        """Column names, in storage order."""
        return tuple(self.columns)

    @property
    def time_s(self) -> np.ndarray:
        """Sample times, s (strictly increasing)."""
        return self.columns["time_s"]

    @property
    def duration_s(self) -> float:
        """Last minus first sample time, s."""
        t = self.time_s
        return float(t[-1] - t[0])

    def select(self, start_s: float, stop_s: float) -> FlightLog:
        """The samples with ``start_s <= time_s <= stop_s``; times stay absolute."""
        t = self.time_s
        keep = (t >= start_s) & (t <= stop_s)
        if not np.any(keep):
            raise FlightLogError(
                f"{self.source}: no samples between {start_s} s and {stop_s} s (log spans {t[0]} s to {t[-1]} s)"
            )
        return FlightLog({k: v[keep] for k, v in self.columns.items()}, self.source, self.notes)

    def with_columns(self, **cols: Any) -> FlightLog:
        """A copy with columns added or replaced (each must have ``len(self)`` values)."""
        merged: dict[str, Any] = dict(self.columns)
        merged.update(cols)
        return FlightLog(merged, self.source, self.notes)

    def resample(self, dt_s: float) -> FlightLog:
        """Linear interpolation of every column onto ``t0, t0 + dt_s, ...`` up to the last sample."""
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise FlightLogError(f"{self.source}: resample step must be a positive number, got {dt_s!r}")
        t = self.time_s
        n = math.floor((t[-1] - t[0]) / dt_s + 1e-9) + 1
        grid = t[0] + dt_s * np.arange(n, dtype=np.float64)
        cols = {k: (grid if k == "time_s" else np.interp(grid, t, v)) for k, v in self.columns.items()}
        return FlightLog(cols, self.source, self.notes)
