"""Airframes compared at the same inputs: can a type model carry to an airframe with no flight of its own?

A model reads only its inputs (rpm, fuel flow, airspeed, the air); if two airframes hold the same steady
operating point and their heads sit at different temperatures above the air, no form of the model can
predict both from their inputs: the difference is the airframe's own (its cooling, its probes, a fuel-flow
transducer that reads differently), and only its own data can set it. :func:`matched_rise` measures that
difference for each airframe against the others, from the flights alone (no model): the steady samples
(the CHT moving less than :data:`STEADY_C` over :data:`STEADY_WINDOW_S`) are binned by rpm, fuel flow and
airspeed (:data:`BIN_WIDTHS`), and in every bin where the airframe and at least one other airframe each
held :data:`MIN_BIN_S` seconds, the airframe's median CHT rise above the OAT is compared with the median of
the other airframes' samples there. Where both log them, the mean EGT (probe level and mixture together) and
the oil temperature's rise above the OAT (the heat the whole engine rejects: a head cooler with its oil
cooler too is the engine running cooler, not its CHT probes reading low) and the fuel flow are compared the
same way (:data:`COMPARED`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ecu_monitor.errors import ParameterError
from ecu_monitor.flightlog import FlightLog

__all__ = [
    "BIN_WIDTHS",
    "COMPARED",
    "MATCH_COLUMNS",
    "MIN_BIN_S",
    "STEADY_C",
    "STEADY_WINDOW_S",
    "MatchedRise",
    "matched_rise",
]

#: The operating point's inputs and their bin widths: rpm (rev/min), fuel flow (L/h), airspeed (m/s).
BIN_WIDTHS: dict[str, float] = {"rpm": 150.0, "fuel_flow_lph": 6.0, "airspeed_mps": 10.0}
#: The columns :func:`matched_rise` needs (those of :data:`COMPARED` too where logged).
MATCH_COLUMNS: tuple[str, ...] = (*BIN_WIDTHS, "cht_c", "oat_c")
#: The other columns compared where logged (:class:`MatchedRise`'s egt_offset_c, oil_offset_c and fuel_offset_lph),
#: each with whether its rise above the OAT is compared (else its level).
COMPARED: dict[str, bool] = {"egt_c": False, "oil_temp_c": True, "fuel_flow_lph": False}
#: A sample is steady when the CHT changes by less than this over the window centred on it, degC.
STEADY_C = 2.0
#: That window, s.
STEADY_WINDOW_S = 60.0
#: Steady time an airframe must hold in a bin for the bin to count, s.
MIN_BIN_S = 30.0


@dataclass(frozen=True)
class MatchedRise:
    """One airframe against the others at the operating points they share.

    offset_c: time-weighted mean over the shared bins of (its median CHT rise above the OAT - the other
        airframes' median there), degC; positive: its head runs hotter at the same inputs.
    spread_c: time-weighted standard deviation of those per-bin differences, degC.
    egt_offset_c: the same for the mean EGT, degC (NaN where a side logs none).
    oil_offset_c: the same for the oil temperature's rise above the OAT, degC (NaN where a side logs none).
    fuel_offset_lph: the same for the fuel flow, L/h (binned without the fuel flow: a transducer that reads
        differently, or another mixture, at the same rpm and airspeed).
    matched_s: its steady time in the shared bins, s; steady_s: all its steady time, s.
    bins: how many bins it shares.
    """

    offset_c: float
    spread_c: float
    egt_offset_c: float
    oil_offset_c: float
    fuel_offset_lph: float
    matched_s: float
    steady_s: float
    bins: int


@dataclass(frozen=True)
class _Samples:
    keys: NDArray[np.int64]  # (n, len(widths)) bin indices
    rise: NDArray[np.float64]
    compared: NDArray[np.float64]  # (n, len(COMPARED)), NaN where not logged
    weight: NDArray[np.float64]  # seconds each sample stands for


def _steady_samples(log: FlightLog, widths: Mapping[str, float], cht_column: str) -> _Samples:
    t = np.asarray(log.time_s, dtype=float)
    cht = np.asarray(log[cht_column], dtype=float)
    half = 0.5 * STEADY_WINDOW_S
    change = np.interp(t + half, t, cht) - np.interp(t - half, t, cht)
    inside = (t - half >= t[0]) & (t + half <= t[-1])
    steady = inside & (np.abs(change) < STEADY_C) & np.isfinite(cht)
    weight = np.gradient(t) if t.size > 1 else np.ones_like(t)
    keys = np.stack([np.floor(np.asarray(log[n], dtype=float) / w) for n, w in widths.items()], axis=1)
    oat = np.asarray(log["oat_c"], dtype=float)
    compared = np.stack(
        [
            np.asarray(log[name], dtype=float) - (oat if above_air else 0.0)
            if log.has(name)
            else np.full(t.size, np.nan)
            for name, above_air in COMPARED.items()
        ],
        axis=1,
    )
    rise = cht - oat
    keep = steady & np.all(np.isfinite(keys), axis=1) & np.isfinite(rise)
    return _Samples(keys[keep].astype(np.int64), rise[keep], compared[keep], weight[keep])


def _by_bin(samples: Sequence[_Samples]) -> dict[tuple[int, ...], tuple[NDArray, NDArray, float]]:
    """bin -> (CHT rises, the compared columns (n, len(COMPARED)), seconds) pooled over ``samples``."""
    keys = np.concatenate([s.keys for s in samples])
    rise = np.concatenate([s.rise for s in samples])
    compared = np.concatenate([s.compared for s in samples])
    weight = np.concatenate([s.weight for s in samples])
    out: dict[tuple[int, ...], tuple[NDArray, NDArray, float]] = {}
    if not keys.size:
        return out
    unique, inverse = np.unique(keys, axis=0, return_inverse=True)
    for k, key in enumerate(unique):
        member = inverse.ravel() == k
        out[tuple(int(v) for v in key)] = (rise[member], compared[member], float(weight[member].sum()))
    return out


def _median(values: NDArray) -> float:
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if finite.size else float("nan")


def _mean_offset(differences: NDArray, weights: NDArray) -> float:
    """Time-weighted mean of the per-bin differences that are finite (NaN when none is)."""
    finite = np.isfinite(differences)
    return float(np.average(differences[finite], weights=weights[finite])) if finite.any() else float("nan")


def matched_rise(
    flights: Sequence[FlightLog],
    airframes: Sequence[str],
    widths: Mapping[str, float] = BIN_WIDTHS,
    cht_column: str = "cht_c",
) -> dict[str, MatchedRise]:
    """Each airframe's head against the other airframes' at the steady operating points they share (module
    doc); flights need :data:`MATCH_COLUMNS` (:data:`COMPARED`'s where logged). ``widths``: the operating
    point's columns and bin widths (other inputs than :data:`BIN_WIDTHS` ask whether those carry the
    difference); ``cht_column``: the head's column (one cylinder's, ``cht2_c``, instead of the mean)."""
    if len(flights) != len(airframes):
        raise ParameterError("matched_rise: one airframe per flight")
    names = sorted(set(airframes))
    if len(names) < 2:
        raise ParameterError(f"matched_rise: needs flights of two airframes or more, got {', '.join(names) or 'none'}")
    if not widths:
        raise ParameterError("matched_rise: no column to bin the operating points by")
    samples = [_steady_samples(log, widths, cht_column) for log in flights]
    out = {}
    for name in names:
        own = _by_bin([s for s, a in zip(samples, airframes, strict=True) if a == name])
        others = _by_bin([s for s, a in zip(samples, airframes, strict=True) if a != name])
        shared = [b for b, (_r, _c, s) in own.items() if s >= MIN_BIN_S and b in others and others[b][2] >= MIN_BIN_S]
        weights = np.array([own[b][2] for b in shared])
        rise = np.array([_median(own[b][0]) - _median(others[b][0]) for b in shared])
        steady_s = float(sum(sec for _r, _c, sec in own.values()))
        if not shared:
            nan = float("nan")
            out[name] = MatchedRise(nan, nan, nan, nan, nan, 0.0, steady_s, 0)
            continue
        offset = float(np.average(rise, weights=weights))
        spread = float(np.sqrt(np.average((rise - offset) ** 2, weights=weights)))
        egt, oil, fuel = (
            _mean_offset(np.array([_median(own[b][1][:, k]) - _median(others[b][1][:, k]) for b in shared]), weights)
            for k in range(len(COMPARED))
        )
        out[name] = MatchedRise(offset, spread, egt, oil, fuel, float(weights.sum()), steady_s, len(shared))
    return out
