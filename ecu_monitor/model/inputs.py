"""The one mapping from a flight log to the model's inputs: which columns the model reads, and how.

:func:`input_columns` names the flight columns a model needs (its heat-map axes, altitude, airspeed,
OAT, and the columns of its mixture index when the mixture_index effect is on); :func:`flight_inputs`
reads them from a log into an :class:`~ecu_monitor.model.thermal.InputSeries` at the log's own sample
times. Identification, the gap diagnosis, the estimators' runner and replay all call these, so a
model reads the same inputs everywhere; putting them on a simulation step (held or interpolated) is
the caller's choice.

The log is anything with ``has(name)``, ``log[name]``, ``names`` and ``source`` (a
:class:`ecu_monitor.flightlog.FlightLog`); the model layer does not import the flight-log module.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import FlightLogError
from ecu_monitor.model.effects import MIXTURE_COLUMNS, MixtureIndex, mixture_index
from ecu_monitor.model.params import ThermalParams
from ecu_monitor.model.thermal import InputSeries

__all__ = [
    "AMBIENT_COLUMNS",
    "MIXTURE_COLUMNS",
    "ColumnSource",
    "flight_inputs",
    "input_columns",
    "mixture_index",
    "read_inputs",
    "series_of",
]

#: Flight columns every model reads besides its heat-map axes (InputSeries order).
AMBIENT_COLUMNS: tuple[str, ...] = ("altitude_m", "airspeed_mps", "oat_c")


class ColumnSource(Protocol):
    """What :func:`flight_inputs` reads: a flight log's named columns."""

    @property
    def source(self) -> str: ...

    def has(self, name: str) -> bool: ...

    def __getitem__(self, name: str) -> Any: ...

    @property
    def names(self) -> tuple[str, ...]: ...


def input_columns(params: ThermalParams) -> tuple[str, ...]:
    """Flight columns the model ``params`` reads, without repeats: heat-map axes, altitude_m,
    airspeed_mps, oat_c, then the mixture index's columns if the mixture_index effect is on."""
    return _columns(params.heat_axes, params.effects.mixture_index)


def _columns(heat_axes: tuple[str, str], mixture: MixtureIndex | None) -> tuple[str, ...]:
    names = [*heat_axes, *AMBIENT_COLUMNS]
    if mixture is not None:
        names.extend(MIXTURE_COLUMNS[mixture.source])
    return tuple(dict.fromkeys(names))


def flight_inputs(log: ColumnSource, params: ThermalParams) -> InputSeries:
    """The model's inputs at the log's sample times (arrays of length N, float64).

    Raises FlightLogError naming the log and the first missing or non-finite column. Without the
    mixture_index effect the mixture input is NaN (not used).
    """
    return read_inputs(log, params.heat_axes, params.effects.mixture_index)


def read_inputs(log: ColumnSource, heat_axes: tuple[str, str], mixture: MixtureIndex | None = None) -> InputSeries:
    """:func:`flight_inputs` for a model known only by its heat-map axes and mixture_index effect."""
    columns: dict[str, NDArray[np.float64]] = {}
    for name in _columns(heat_axes, mixture):
        if not log.has(name):
            role = "heat-map axis" if name in heat_axes else "model input"
            raise FlightLogError(f"{log.source}: no column '{name}' ({role}; columns: {', '.join(log.names)})")
        values = np.asarray(log[name], dtype=float)
        if not np.all(np.isfinite(values)):
            raise FlightLogError(f"{log.source}: model input '{name}' holds blank or non-finite values")
        columns[name] = values
    if mixture is None:
        columns["mixture_index"] = np.full(columns[heat_axes[0]].size, np.nan)
    return series_of(columns, heat_axes, mixture)


def series_of(columns: Mapping[str, Any], heat_axes: tuple[str, str], mixture: MixtureIndex | None) -> InputSeries:
    """The model's inputs from columns already read and checked (arrays, or floats for one step): the
    heat-map axes, altitude_m, airspeed_mps, oat_c and the mixture index computed from its columns
    (without the mixture_index effect: ``columns["mixture_index"]`` if given, else NaN)."""
    x_axis, y_axis = heat_axes
    if mixture is not None:
        index: Any = mixture_index(mixture.source, {name: columns[name] for name in MIXTURE_COLUMNS[mixture.source]})
        if np.ndim(index) == 0:
            index = float(index)  # one step: a float, as the live filters take it
    else:
        index = columns.get("mixture_index", math.nan)
    return InputSeries(
        columns[x_axis], columns[y_axis], columns["altitude_m"], columns["airspeed_mps"], columns["oat_c"], index
    )
