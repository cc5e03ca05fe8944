"""What the training flights pin about the heat map: breakpoints, observed rise, visited time, reference point."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import FlightLogError, ParameterError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.identify.flights import measured_cht, model_inputs
from ecu_monitor.model import HeatMap
from ecu_monitor.model.heatmap import heat_cells

__all__ = ["heat_map_breakpoints", "observed_rise_map", "reference_point", "tied_axes", "visited_weight_s"]

# --------------------------------------------------------------------------------------------------
# Heat-map grid from the data
# --------------------------------------------------------------------------------------------------


#: Heat-map axes that are a flow of fuel: the heat they drive grows in proportion (heat_map_breakpoints).
FUEL_AXES: tuple[str, ...] = ("fuel_flow_lph",)
#: The top breakpoint of a fuel axis, as a multiple of the largest flow the training flights logged.
FUEL_HEADROOM = 1.25


def heat_map_breakpoints(
    flights: Sequence[FlightLog], heat_axes: tuple[str, str], grid: tuple[int, int]
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Breakpoints of an n x m heat map for a new axis pair, from the training data.

    Each axis gets n (or m) breakpoints at the quantiles linspace(1 %, 99 %) of its pooled samples, so
    every breakpoint sits where the engine actually ran (the 1 % tails are clamped, not extrapolated).
    Where the quantiles collide (a mostly constant input) the breakpoints fall back to even spacing
    between the 1 % and 99 % quantiles. An axis of :data:`FUEL_AXES` with two breakpoints (a map linear in
    the fuel) spans instead from no fuel (0: no heat) to :data:`FUEL_HEADROOM` times the largest flow logged:
    the heat of burnt fuel grows in proportion to the fuel, so the line carries on past the training
    flights' largest flow (another mission's full-power climb) instead of clamping there. A finer fuel axis
    keeps its breakpoints where the engine ran (its shape is resolved there; stretching its ends cost the
    real N550ND flights 0.1 degC held out, docs/results/jsbsim.md).

    A count of 1 is an axis the heat does not depend on (:func:`tied_axes`): it gets two breakpoints as for 2
    (the map is always at least 2 x 2), whose values identification ties together.
    """
    out = []
    for axis, count in zip(heat_axes, grid, strict=True):
        if count < 1:
            raise ParameterError(f"heat-map grid: expected at least 1 breakpoint per axis, got {count}")
        values = np.concatenate([np.asarray(model_inputs(f, heat_axes)[heat_axes.index(axis)]) for f in flights])
        points = np.quantile(values, np.linspace(0.01, 0.99, max(count, 2)))
        if axis in FUEL_AXES and count == 2:
            points[0], points[-1] = 0.0, FUEL_HEADROOM * float(np.max(values))
        low, high = float(points[0]), float(points[-1])
        if count == 1 and high - low <= 1e-9 * max(1.0, abs(high)):
            points = np.array([low, low + max(1.0, abs(low))])  # tied: any two points
            low, high = float(points[0]), float(points[-1])
        if high - low <= 1e-9 * max(1.0, abs(high)):
            raise ParameterError(f"heat-map axis '{axis}': the data hold one value only ({low:g}); choose another axis")
        if np.any(np.diff(points) <= 1e-6 * (high - low)):
            points = np.linspace(low, high, count)
        out.append(tuple(float(round(p, 6)) for p in points))
    return out[0], out[1]


def tied_axes(grid: tuple[int, int] | None) -> tuple[bool, bool]:
    """Which heat-map axes the heat does not depend on: those given 1 breakpoint in ``grid`` (``--grid 2x1``: the
    heat follows the first axis alone, e.g. the fuel burnt, and engine speed acts only through the effects that
    read it). Their breakpoints' values are one value, identified once."""
    return (False, False) if grid is None else (grid[0] == 1, grid[1] == 1)


def observed_rise_map(flights: Sequence[FlightLog], heat_map: HeatMap) -> NDArray[np.float64]:
    """The temperature rise CHT - OAT the flights show at each breakpoint (degC): the mean over the
    samples weighted by their bilinear weight, made non-decreasing along the first (power) axis;
    a breakpoint the flights never reach takes the median rise. The identification's starting map."""
    xb = np.asarray(heat_map.x_breakpoints)
    yb = np.asarray(heat_map.y_breakpoints)
    total = np.zeros(heat_map.shape)
    weight = np.zeros(heat_map.shape)
    rises = []
    for log in flights:
        series = model_inputs(log, (heat_map.x_axis, heat_map.y_axis))
        rise = measured_cht(log) - np.asarray(series.oat_c)
        rises.append(rise)
        i, j, fx, fy = heat_cells(series.heat_x, series.heat_y, xb, yb)
        for di, wx in ((0, 1.0 - fx), (1, fx)):
            for dj, wy in ((0, 1.0 - fy), (1, fy)):
                np.add.at(total, (i + di, j + dj), wx * wy * rise)
                np.add.at(weight, (i + di, j + dj), wx * wy)
    median = max(5.0, float(np.median(np.concatenate(rises))))
    seen = weight > 1.0
    out = np.where(seen, total / np.maximum(weight, 1e-12), median)
    return np.maximum(np.maximum.accumulate(np.maximum(out, 1.0), axis=0), 1.0)


def reference_point(flights: Sequence[FlightLog]) -> tuple[float, float]:
    """(OAT, CHT - OAT) of the reference operating point, degC: the flights' medians (rise at least 5)."""
    for log in flights:
        if not log.has("oat_c"):
            raise FlightLogError(f"{log.source}: no column 'oat_c' (model input; columns: {', '.join(log.names)})")
    oat = np.concatenate([np.asarray(log["oat_c"], dtype=float) for log in flights])
    rise = np.concatenate([measured_cht(log) - np.asarray(log["oat_c"], dtype=float) for log in flights])
    return float(np.median(oat)), max(5.0, float(np.median(rise)))


def visited_weight_s(flights: Sequence[FlightLog], heat_map: HeatMap) -> NDArray[np.float64]:
    """Time (s) each heat-map breakpoint carries over the flights: sum of its bilinear weight x sample interval."""
    xb = np.asarray(heat_map.x_breakpoints)
    yb = np.asarray(heat_map.y_breakpoints)
    total = np.zeros(heat_map.shape)
    for log in flights:
        series = model_inputs(log, (heat_map.x_axis, heat_map.y_axis))
        t = np.asarray(log.time_s, dtype=float)
        interval = np.diff(t, append=t[-1] + (float(np.median(np.diff(t))) if t.size > 1 else 1.0))
        xi, yi, xf, yf = heat_cells(series.heat_x, series.heat_y, xb, yb)
        for di, wx in ((0, 1.0 - xf), (1, xf)):
            for dj, wy in ((0, 1.0 - yf), (1, yf)):
                np.add.at(total, (xi + di, yi + dj), wx * wy * interval)
    return total
