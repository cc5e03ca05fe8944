"""The sea-level heat map Q_SL0 (W): heat into the cylinder-head wall on an n x m grid of two inputs.

By default the axes are throttle (%) x engine speed (rpm), as in the paper (Figure A4). A log with no
throttle (a light aircraft's engine monitor) uses fuel flow (L/h) x rpm instead: the axes are named in
the map, so a model knows which flight columns drive it.

Lookup is bilinear and clamped at the edges (no extrapolation). ``bilinear`` broadcasts over leading
dimensions of ``values`` (a swarm of maps, shape (P, n, m)) and over arrays of query points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numba.extending import register_jitable
from numpy.typing import ArrayLike, NDArray

from ecu_monitor.errors import ParameterError
from ecu_monitor.model.equations import blend

__all__ = ["HeatMap", "bilinear", "heat_cell", "heat_cells", "reference_heat_map"]


@dataclass(frozen=True)
class HeatMap:
    """Sea-level heat into the wall, ``values_w[i][j]`` at (``x_breakpoints[i]``, ``y_breakpoints[j]``).

    x_axis, y_axis: canonical flight-CSV column names of the two inputs (e.g. "throttle_pct", "rpm").
    x_breakpoints, y_breakpoints: strictly increasing grid points in the axis units.
    values_w: n x m heat power into the wall at sea level, W (>= 0).
    """

    x_axis: str
    y_axis: str
    x_breakpoints: tuple[float, ...]
    y_breakpoints: tuple[float, ...]
    values_w: tuple[tuple[float, ...], ...]

    def __post_init__(self) -> None:
        for name in ("x_breakpoints", "y_breakpoints"):
            points = np.asarray(getattr(self, name), dtype=float)
            if points.ndim != 1 or points.size < 2 or not np.all(np.diff(points) > 0):
                raise ParameterError(f"heat_map.{name}: expected at least 2 strictly increasing numbers")
        values = np.asarray(self.values_w, dtype=float)
        expected = (len(self.x_breakpoints), len(self.y_breakpoints))
        if values.shape != expected:
            raise ParameterError(f"heat_map.values_w: expected shape {expected}, got {values.shape}")
        if not np.all(np.isfinite(values)) or np.any(values < 0):
            raise ParameterError("heat_map.values_w: expected finite values >= 0 (W)")
        if not self.x_axis or not self.y_axis or self.x_axis == self.y_axis:
            raise ParameterError("heat_map axes: expected two different column names")

    @property
    def shape(self) -> tuple[int, int]:
        """(n, m): number of x and y breakpoints."""
        return len(self.x_breakpoints), len(self.y_breakpoints)

    def values_array(self) -> np.ndarray:
        """The n x m values as a float array (W)."""
        return np.asarray(self.values_w, dtype=float)

    def with_values(self, values_w: ArrayLike) -> HeatMap:
        """A copy with new values (same axes and breakpoints)."""
        array = np.asarray(values_w, dtype=float).reshape(self.shape)
        return HeatMap(
            self.x_axis,
            self.y_axis,
            self.x_breakpoints,
            self.y_breakpoints,
            tuple(tuple(float(v) for v in row) for row in array),
        )

    def __call__(self, x: ArrayLike, y: ArrayLike) -> np.ndarray | float:
        """Q_SL0 (W) at the given axis values (bilinear, clamped)."""
        result = bilinear(
            self.values_array(),
            np.asarray(self.x_breakpoints),
            np.asarray(self.y_breakpoints),
            x,
            y,
        )
        return float(result) if np.ndim(result) == 0 else result


@register_jitable(inline="always")
def heat_cell(x: float, y: float, xb: NDArray[np.float64], yb: NDArray[np.float64]) -> tuple[int, int, float, float]:
    """The heat-map cell of the point (x, y), clamped to the breakpoints ``xb``, ``yb``: its lower corner
    (i, j) and the fractions (fx, fy) in [0, 1] across it, for :func:`~ecu_monitor.model.equations.blend`.
    Inlined into every compiled function that reads the heat map, so each does the same arithmetic."""
    nx = xb.shape[0]
    ny = yb.shape[0]
    x = min(max(x, xb[0]), xb[nx - 1])
    y = min(max(y, yb[0]), yb[ny - 1])
    i = 0
    while i < nx - 2 and x >= xb[i + 1]:
        i += 1
    j = 0
    while j < ny - 2 and y >= yb[j + 1]:
        j += 1
    return i, j, (x - xb[i]) / (xb[i + 1] - xb[i]), (y - yb[j]) / (yb[j + 1] - yb[j])


@numba.njit(cache=True)
def _heat_cells(
    x: NDArray[np.float64], y: NDArray[np.float64], xb: NDArray[np.float64], yb: NDArray[np.float64]
) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64], NDArray[np.float64]]:  # pragma: no cover
    n = x.shape[0]
    i = np.empty(n, dtype=np.intp)
    j = np.empty(n, dtype=np.intp)
    fx = np.empty(n)
    fy = np.empty(n)
    for k in range(n):
        i[k], j[k], fx[k], fy[k] = heat_cell(x[k], y[k], xb, yb)
    return i, j, fx, fy


def heat_cells(
    x: ArrayLike, y: ArrayLike, xb: ArrayLike, yb: ArrayLike
) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64], NDArray[np.float64]]:
    """:func:`heat_cell` at every point of ``x``, ``y`` (broadcast together), compiled: the cells' lower
    corners (i, j) and the fractions (fx, fy) across them, each of the broadcast shape."""
    xs, ys = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    flat = _heat_cells(
        np.ascontiguousarray(xs).ravel(),
        np.ascontiguousarray(ys).ravel(),
        np.ascontiguousarray(xb, dtype=np.float64),
        np.ascontiguousarray(yb, dtype=np.float64),
    )
    return tuple(part.reshape(xs.shape) for part in flat)  # type: ignore[return-value]


def bilinear(
    values: np.ndarray, x_breakpoints: np.ndarray, y_breakpoints: np.ndarray, x: ArrayLike, y: ArrayLike
) -> np.ndarray:
    """Bilinear lookup of ``values[..., n, m]`` at (x, y), clamped; broadcasts x, y and leading dims.

    With values of shape (P, n, m) and scalar x, y the result has shape (P,) (one per particle); with
    values (n, m) and x, y of shape (N,) it has shape (N,) (a whole flight at once).
    """
    i, j, fx, fy = heat_cells(x, y, x_breakpoints, y_breakpoints)
    return blend(values[..., i, j], values[..., i, j + 1], values[..., i + 1, j], values[..., i + 1, j + 1], fx, fy)


# The reference engine: 29 cc single-cylinder air-cooled 2-stroke, 0.4-1.9 kW shaft power over
# 2000-9000 rpm, cruise 6000 rpm / 0.8 kW (paper Tables 1-2). At 500 g/kWh its brake efficiency is
# ~16 %, and an air-cooled head takes a similar share of the fuel energy as the shaft, so the
# reference map puts the heat into the wall at about the shaft power of each operating point:
#   Q_SL0(throttle, rpm) = 1900 W * L(throttle) * S(rpm)
#   L(th) = 0.12 + 0.88 (th/100)^0.95      (load: residual heat at closed throttle)
#   S(n)  = (n / 9000)^0.7                  (speed)
# giving ~0.82 kW at the cruise point (50 %, 6000 rpm) and 1.9 kW at full throttle and 9000 rpm.
_REF_THROTTLE = (0.0, 25.0, 50.0, 75.0, 100.0)
_REF_RPM = (2000.0, 3750.0, 5500.0, 7250.0, 9000.0)


def reference_heat_map() -> HeatMap:
    """The documented 5 x 5 heat map of the reference UAV engine (throttle % x rpm, W)."""
    values = [
        [1900.0 * (0.12 + 0.88 * (th / 100.0) ** 0.95) * (n / 9000.0) ** 0.7 for n in _REF_RPM] for th in _REF_THROTTLE
    ]
    rounded = tuple(tuple(round(v, 1) for v in row) for row in values)
    return HeatMap("throttle_pct", "rpm", _REF_THROTTLE, _REF_RPM, rounded)
