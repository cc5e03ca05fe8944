"""One flight for identification: model inputs, the uniform grid, open-loop simulation and error statistics."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import FlightLogError, ParameterError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.model import Coefficients, InputSeries, ThermalParams, coefficients
from ecu_monitor.model.compiled import simulate_compiled
from ecu_monitor.model.effects import MixtureIndex
from ecu_monitor.model.inputs import read_inputs

__all__ = [
    "IDENTIFICATION_DT_S",
    "PCT_FLOOR_C",
    "REFERENCE_DT_S",
    "ErrorStats",
    "FlightGrid",
    "flight_errors",
    "measured_cht",
    "model_inputs",
    "prepare_flight",
    "run_grid",
    "simulate_flight",
]

#: Integration step of the reference simulation (the paper's and the estimators' step), s.
REFERENCE_DT_S = 0.02
#: Integration step used inside identification, s; chosen by measurement (docs/results/identification.md).
IDENTIFICATION_DT_S = 0.5
#: Percent errors are relative to the measured CHT in degC, floored at this value to avoid dividing by ~0.
PCT_FLOOR_C = 1.0

# --------------------------------------------------------------------------------------------------
# Errors and open-loop simulation of one flight
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ErrorStats:
    """Model error on one flight: |simulated - measured| CHT.

    mean_c, peak_c, rms_c: mean, largest and RMS absolute error, degC.
    mean_pct, peak_pct: mean and largest error in percent of the measured CHT in degC, sample by sample
        (the paper's metric; the measured value is floored at 1 degC). Undefined in spirit near 0 degC:
        a cold start at a few degC turns 1-2 degC of error into tens of percent.
    mean_rise_pct, peak_rise_pct: mean and largest error in percent of the flight's mean temperature
        rise above OAT (mean of measured CHT - OAT, floored at 1 degC): one scale per flight, so a
        cold start weighs what it weighs in degC. NaN when no OAT is given.
    """

    mean_c: float
    peak_c: float
    rms_c: float
    mean_pct: float
    peak_pct: float
    mean_rise_pct: float = math.nan
    peak_rise_pct: float = math.nan

    @classmethod
    def from_series(
        cls,
        simulated_c: NDArray[np.float64],
        measured_c: NDArray[np.float64],
        ambient_c: NDArray[np.float64] | None = None,
    ) -> ErrorStats:
        """Error statistics of a simulated against a measured CHT series (same samples); ambient_c
        (OAT, degC, same samples) gives the rise-relative percentages."""
        error = np.abs(np.asarray(simulated_c, dtype=float) - np.asarray(measured_c, dtype=float))
        if error.size == 0 or not np.all(np.isfinite(error)):
            nan = math.nan
            return cls(nan, nan, nan, nan, nan)
        pct = 100.0 * error / np.maximum(np.abs(measured_c), PCT_FLOOR_C)
        rise = math.nan
        if ambient_c is not None:
            rise = max(float(np.mean(np.asarray(measured_c, dtype=float) - np.asarray(ambient_c, dtype=float))), 1.0)
        return cls(
            mean_c=float(error.mean()),
            peak_c=float(error.max()),
            rms_c=float(np.sqrt(np.mean(error**2))),
            mean_pct=float(pct.mean()),
            peak_pct=float(pct.max()),
            mean_rise_pct=100.0 * float(error.mean()) / rise,
            peak_rise_pct=100.0 * float(error.max()) / rise,
        )


def model_inputs(log: FlightLog, heat_axes: tuple[str, str], mixture: MixtureIndex | None = None) -> InputSeries:
    """The model inputs of a flight at its own sample times (:func:`ecu_monitor.model.inputs.read_inputs`).

    Raises FlightLogError naming the first missing or non-finite column.
    """
    return read_inputs(log, heat_axes, mixture)


def measured_cht(log: FlightLog) -> NDArray[np.float64]:
    if not log.has("cht_c"):
        raise FlightLogError(f"{log.source}: no column 'cht_c' (measured CHT; columns: {', '.join(log.names)})")
    cht = np.asarray(log["cht_c"], dtype=float)
    if not np.all(np.isfinite(cht)):
        raise FlightLogError(f"{log.source}: column 'cht_c' holds blank or non-finite values")
    return cht


class FlightGrid(NamedTuple):
    """A flight prepared for simulation on a uniform step: inputs held (zero-order hold) on the grid,
    and where each measured sample falls between the recorded states."""

    inputs: InputSeries  # on the uniform grid t0 + k dt, k < steps
    dt_s: float
    record_every: int  # states recorded every record_every steps
    sample_row: NDArray[np.intp]  # per measured sample: recorded row just before it
    sample_weight: NDArray[np.float64]  # linear interpolation weight towards the next row
    measured_c: NDArray[np.float64]  # measured CHT at the log's sample times
    initial_c: float  # initial CHT = the first measured sample
    source: str

    def sample(self, recorded: NDArray[np.float64]) -> NDArray[np.float64]:
        """Recorded states (rows, ...) interpolated at the measured sample times."""
        w = self.sample_weight.reshape((-1,) + (1,) * (recorded.ndim - 1))
        return (1.0 - w) * recorded[self.sample_row] + w * recorded[self.sample_row + 1]


def prepare_flight(
    log: FlightLog,
    heat_axes: tuple[str, str],
    dt_s: float,
    record_period_s: float = 1.0,
    mixture: MixtureIndex | None = None,
) -> FlightGrid:
    """Put a flight on a uniform grid of step ``dt_s`` (inputs held from the last sample at or before
    each grid time), recording the state every ``record_period_s`` (rounded to a whole number of steps).
    ``mixture``: the model's mixture_index effect, whose index column is then read too."""
    if not (math.isfinite(dt_s) and dt_s > 0.0):
        raise ParameterError(f"integration step: expected a positive number of seconds, got {dt_s!r}")
    if len(log) < 2:
        raise FlightLogError(f"{log.source}: at least 2 samples are needed to identify or simulate")
    series = model_inputs(log, heat_axes, mixture)
    measured = measured_cht(log)
    t = np.asarray(log.time_s, dtype=float)
    span = float(t[-1] - t[0])
    every = max(1, round(record_period_s / dt_s))
    rows = max(1, math.ceil(span / (every * dt_s) - 1e-9))
    steps = rows * every + 1
    grid = t[0] + dt_s * np.arange(steps)
    index = np.clip(np.searchsorted(t, grid + 1e-9 * dt_s, side="right") - 1, 0, t.size - 1)
    held = InputSeries(*(np.ascontiguousarray(np.asarray(v)[index]) for v in series))
    position = (t - t[0]) / (every * dt_s)
    row = np.clip(np.floor(position).astype(np.intp), 0, rows - 1)
    weight = np.clip(position - row, 0.0, 1.0)
    return FlightGrid(held, float(dt_s), every, row, weight, measured, float(measured[0]), log.source)


def run_grid(grid: FlightGrid, coeffs: Coefficients) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Probe CHT at the measured samples: (N,) or (N, P), and the failure mask () or (P,)."""
    run = simulate_compiled(grid.inputs, coeffs, grid.dt_s, grid.initial_c, record_every=grid.record_every)
    return grid.sample(run.probe_c), run.failed


def simulate_flight(params: ThermalParams, log: FlightLog, dt_s: float | None = None) -> NDArray[np.float64]:
    """Open-loop model CHT (what the probe reads, degC) at the log's sample times.

    Driven by the log's inputs held on a uniform step ``dt_s`` (default :data:`REFERENCE_DT_S`), RK4,
    starting from the first measured CHT with the heat-path delay in steady state. NaN from the sample
    where the trajectory stops being finite (reported by :func:`flight_errors` as NaN errors).
    """
    grid = prepare_flight(
        log, params.heat_axes, REFERENCE_DT_S if dt_s is None else dt_s, mixture=params.effects.mixture_index
    )
    probe, _ = run_grid(grid, coefficients(params))
    return probe


def flight_errors(params: ThermalParams, log: FlightLog, dt_s: float | None = None) -> ErrorStats:
    """Error statistics of the open-loop model against the log's measured CHT."""
    oat = np.asarray(log["oat_c"], dtype=float) if log.has("oat_c") else None
    return ErrorStats.from_series(simulate_flight(params, log, dt_s), measured_cht(log), oat)
