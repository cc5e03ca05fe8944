"""The detector on a real engine: leave-one-flight-out over nominal flights with degradations overlaid.

    nice -n 10 .venv/bin/python benchmarks/bench_detect_real.py FLIGHT.csv FLIGHT.csv ... \\
        [--mapping g1000] [--heat-axes fuel_flow_lph,rpm] [--onset-every 900] [--jobs 2] [--json OUT.json]

For each flight in turn (the held-out flight), as a user commissioning the monitor would:

1. ``ecu-monitor identify`` on the other flights (``--heat-axes``, ``--identify-args``) -> model.yaml;
2. calibrate's choice of the detector's baseline, nested: ``service.calibration.choose_settings`` (what
   ``ecu-monitor calibrate`` runs) on the other flights only, each replayed by ``flight_feeds`` nominal
   and with its own overlays; the held-out flight is never seen by the choice;
3. the detector threshold calibrated on the other flights through the service's replay path, for the
   chosen baseline and for each fixed variant;
4. the held-out flight replayed nominal (any crossing of h = a false DEGRADED), and with a degradation
   overlaid (``detection.overlay_degradation``: CHT + k (CHT - OAT)(1 - exp(-(t - t0)/240 s))) for
   k = 0.2 and 0.1 at onsets t0 every ``--onset-every`` s from the end of the warm-up (or
   ``--first-onset``) to 600 s before the end of the flight; detected = the statistic crosses h at or
   after t0 (targets: k = 0.2 within 300 s, k = 0.1 within 600 s). The onsets that count: those
   in the airborne part with at least 600 s of it after them (take-off <= t0 <= landing - 600 s, airborne
   = airspeed >= ``calibration.AIRBORNE_MPS``, the rule calibrate's own overlays follow); the totals over
   all onsets, ground and landing included, are printed too.

The replays run the service's batch path on the frames the ECU would have sent for each flight
(``frames_from_flight`` + ``replay_frames``); the detector's input (``ReplayResult.detector_feed``) is
kept, so the CUSUM of each detector variant (calibrate's choice, the config's detector, then each
``--variant baseline_s:delay_s:reference[:freeze]``) is evaluated on the same feeds, each with its
own calibrated threshold. Inputs may be canonical CSVs or foreign CSVs with ``--mapping`` (e.g. raw
G1000 exports). Work files go to a temporary folder. Prints calibrate's table per fold and one table per
variant; ``--json`` keeps every delay. ``--replays R.pkl`` keeps every replay (keyed by flight, model
content and config) and reuses those it holds, so detector variants are compared on the same replays
without replaying; ``--plot-misses`` draws each counted onset calibrate's choice detects late (the
flight's CHT and power, the symptom with the baseline, the statistic with h).

Two offline analyses on the same replays (nothing in the service changes): ``--oracle`` adds per
variant the counts with h set to 1.01 x the held-out flight's own nominal maximum, the lowest h that
raises no false DEGRADED on it (what no calibration can know: an upper bound on what a better
calibration of h could reach with this symptom and these settings); ``--heat-rate-floor F``
(repeatable) evaluates calibrate's choice, nested as above, and each ``--variant`` on the symptom
divided by the model's heat-input rate (the steady Q_in / C of the fold's model at the flight's
logged inputs, relative to its median over the training flights' airborne part, floored at F x that
median): the overlay adds k Q_in / C to the symptom, so the normalised symptom gains about k x the
median rate at every power. ``--rise-profile`` prints how the overlay moves the symptom over the
windows after its onsets (the overlaid minus the nominal replay), beside k Q_in / C.

``--scale S`` (repeatable) evaluates the self-normalised detector (``detector.scale_s`` S, ``scale_floor``
learned per fold from the training flights: the median of their online spread), calibrate's choice nested
on candidates that all carry it, and each ``--variant`` with it. ``--separability`` prints per variant the
hindsight separability (the held-out flights' largest nominal statistic over the smallest statistic a
counted overlay reaches within its target: below 1, one h would have served every held-out flight);
``--glr DELTA[:flat]`` (repeatable) the same for a GLR over the onsets of the last ``--glr-window`` s
matched to a rise DELTA (1 - exp(-t/240 s)) (flat: a CUSUM that forgets older onsets), offline.

``--soak TAU[,TAU...]`` screens a heat-soak term the model lacks, at the detector: per fold, on the training
flights' nominal replays only, the symptom is regressed (least squares, one intercept per flight, over
``--soak-bin`` s bins) on lag(q, tau) - q, q the fold model's heat-input rate Q_in / C at the logged inputs
(``--soak-input``: or the fuel flow, or the airspeed), lag a first-order lag of time constant tau, tau the
grid's best fit; b x that regressor is subtracted from every replay of the fold (an overlay changes the CHT
only, so the regressor is the same), and calibrate's choice (nested) and each ``--variant`` are evaluated on
the result. A soak (head warmer than the model after a power reduction) gives b > 0. ``--soak-coef B`` gives
b instead of fitting it (hindsight, one tau); ``--soak-even`` regresses on |lag(q, tau) - q| instead (the head
warmer than the model after a change of either sign).

``--level residual|relative`` (repeatable) screens a level symptom in place of the derivative one: the replays keep
their open-loop reference (``replay_frames(..., keep_reference=True)``: per step the held CHT, the reference model's
CHT and the held OAT), and the detector is fed the open-loop residual r = CHT - model CHT (degC) or rho = r / (model
CHT - OAT) (dimensionless), which an overlay moves by k (CHT - OAT)(1 - exp(-(t - t0)/240 s)) and about k (1 -
exp(...)) at every power. The allowance was fixed before the screen (:data:`RHO_ALLOWANCE`: half what k = 0.1 adds
to rho at 300 s; r: that x the training flights' median airborne CHT - OAT); calibrate's choice (nested, the
candidates and rule unchanged) and each ``--variant`` run on it. ``residual-scaled`` / ``relative-scaled``: the
same symptom in units of its allowance x the config's reference, so that the floor of h (1 x s) means what it means
for the derivative symptom. ``--plot-level P.png`` draws rho and the statistics of calibrate's choice on each.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import shlex
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numba
import numpy as np

LIMITS = {0.2: 300.0, 0.1: 600.0}  # overlay gain -> detection target, s
UNBOUNDED = 1e300
#: --effects: start value of the parameter each effect frees (listed first; the others keep their defaults)
EFFECT_STARTS = {"airspeed_cooling": {"gain_per_mps": 0.01}, "density_cooling": {"exponent": 0.3}}


#: The frame --egt adds to the bus: the mean EGT (degC), 100 ms (the DBC's default cycle in flight_frames).
EGT_DBC = """VERSION ""

NS_ :

BS_:

BU_: ECU EcuMonitor

BO_ 258 ECU_Exhaust: 8 ECU
 SG_ EGT : 0|16@1+ (0.1,-40) [-40|1200] "degC" EcuMonitor
"""


def _config_with_egt(config_path: str, work: Path) -> str:
    """A copy of the config (written to ``work``) whose bus also carries the mean EGT: :data:`EGT_DBC` added to
    its DBCs and ``egt_c`` mapped to it, so a model with the mixture index is fed. Returns the copy's path."""
    import yaml

    from ecu_monitor.config import load_config

    config = load_config(config_path)
    raw = yaml.safe_load(config.source.read_text(encoding="utf-8"))
    dbc = (work / "egt.dbc").resolve()  # absolute: the copy of the config lives in work, not in the cwd
    dbc.write_text(EGT_DBC, encoding="utf-8")
    raw["dbc"] = [str(path) for path in config.dbc_paths] + [str(dbc)]
    raw["inputs"]["egt_c"] = {"signal": "ECU_Exhaust.EGT", "unit": "degC", "stale_after_s": 1.0}
    out = work / f"{config.source.stem}_egt.yaml"
    out.write_text(yaml.safe_dump(raw, sort_keys=False), encoding="utf-8")
    return str(out)


def _feeds(args: tuple[str, str, str, list[tuple[float, float]] | None, bool]) -> Any:
    """Replay one flight nominal (onset nan) and with each overlay; returns the detector feeds and timings.

    overlays None (a training flight): what ``ecu-monitor calibrate`` replays to choose the baseline
    (``service.calibration.flight_feeds``: nominal, and k = 0.2 / 0.1 at its airborne onsets), returned
    as a FlightFeeds. Else (the held-out flight): the nominal replay and one per (onset, gain), through
    ``service.calibration.overlay_replays`` (only the CHT's message re-encoded per overlay), each as
    (onset, gain, log start, detector feed, open-loop reference). keep_reference (the last argument): the
    replays keep the open-loop reference (``ReplayResult.reference_feed``, for ``--level``; else empty)."""
    flight, model, config_path, overlays, keep = args
    from ecu_monitor.bus.canlog import load_flight
    from ecu_monitor.config import load_config
    from ecu_monitor.model import load_model
    from ecu_monitor.offline.calibration import flight_feeds, overlay_replays
    from ecu_monitor.offline.replay import frames_from_flight, replay_frames
    from ecu_monitor.pipeline.engine import model_input_names

    config = load_config(config_path)
    params = load_model(model)
    began = time.perf_counter()
    if overlays is None:
        return flight_feeds(flight, config, params, keep_reference=keep), {"training_s": time.perf_counter() - began}
    log = load_flight(flight)
    nominal = frames_from_flight(log, config, (*model_input_names(params, config.input_names), "cht_c"))
    timing = {"all_frames_s": time.perf_counter() - began}
    began = time.perf_counter()
    result = replay_frames(config, params, nominal, keep_feeds=True, keep_reference=keep)
    out = [(math.nan, 0.0, float(log.time_s[0]), result.detector_feed, result.reference_feed)]
    timing["replay_s"] = time.perf_counter() - began
    began = time.perf_counter()
    shifted = [(onset, gain) for onset, gain in overlays if math.isfinite(onset)]
    results = overlay_replays(log, config, params, shifted, nominal, keep_reference=keep)
    timing["overlay_s"] = (time.perf_counter() - began) / max(len(shifted), 1)
    start = float(log.time_s[0])
    out += [
        (onset, gain, start, r.detector_feed, r.reference_feed)
        for (onset, gain), r in zip(shifted, results, strict=True)
    ]
    return out, timing


def _replay_key(job: tuple[str, str, str, Any, bool]) -> tuple[str, str, str]:
    """A job's flight (file name), model (file content) and config: what its replays depend on."""
    flight, model, config_path, _, _ = job
    return Path(flight).name, Path(model).read_text(encoding="utf-8"), config_path


def _load_replays(path: str | None) -> dict[Any, Any]:
    if not path or not Path(path).exists():
        return {}
    import pickle

    with open(path, "rb") as f:
        return dict(pickle.load(f))


def _cached(cache: dict[Any, Any], job: tuple[str, str, str, Any, bool]) -> Any:
    """The cached result of a job (training: its FlightFeeds; held out: the nominal replay and those of
    the overlays asked), or None when the cache lacks any of it (or its open-loop reference, when the
    job keeps it: pickles written before the reference was kept hold 4-tuples and FlightFeeds without it)."""
    entry = cache.get(_replay_key(job))
    overlays, keep = job[3], job[4]
    if entry is None:
        return None
    if overlays is None:
        if "training" not in entry:
            return None
        f = entry["training"]
        kept = bool(f.reference) and all(r.reference for r in f.overlays)
        return (f, {}) if kept or not keep else None
    runs = entry.get("held_out", {})
    keys = [(math.nan, 0.0), *overlays]
    if not all((round(o, 3), g) in runs for o, g in keys if math.isfinite(o)) or "nominal" not in entry:
        return None
    out = [entry["nominal"], *(runs[(round(o, 3), g)] for o, g in overlays)]
    if keep and not all(len(r) == 5 and r[4] for r in out):
        return None
    return [(*r[:4], r[4] if len(r) == 5 else ()) for r in out], {}


def _save_replays(path: str, cache: dict[Any, Any], jobs: list[Any], results: list[Any]) -> None:
    import pickle

    for job, (result, _) in zip(jobs, results, strict=True):
        entry = cache.setdefault(_replay_key(job), {})
        if job[3] is None:
            entry["training"] = result
        else:
            entry["nominal"] = result[0]
            entry.setdefault("held_out", {}).update({(round(r[0], 3), r[1]): r for r in result[1:]})
    with open(path, "wb") as f:
        pickle.dump(cache, f)


def _heat_rate(model: Path, flight: Path) -> tuple[Any, Any, Any]:
    """(log times s, the model's steady heat-input rate Q_in / C in degC/s at the logged inputs, airborne
    mask): g(z) x the effects' heat factor x Q_SL0 / C_w (the Pade state at its steady value 2 Q_SL0)."""
    from ecu_monitor.bus.canlog import load_flight
    from ecu_monitor.model import load_model
    from ecu_monitor.model.inputs import flight_inputs
    from ecu_monitor.model.thermal import coefficients, compute_drive
    from ecu_monitor.offline.calibration import AIRBORNE_MPS

    params = load_model(model)
    log = load_flight(flight)
    c = coefficients(params)
    d = compute_drive(flight_inputs(log, params), c)
    rate = np.asarray(d.altitude_gain) * np.asarray(d.heat_gain) * np.asarray(d.q_sl0_w) / float(c.c_w)
    return log.time_s, rate, np.nan_to_num(log["airspeed_mps"], nan=0.0) >= AIRBORNE_MPS


def _heat_rate_feeds(feeds: dict[Any, Any], models: list[Path], flights: list[Path], floor: float) -> dict[Any, Any]:
    """The replays' detector feeds with the symptom divided by the fold model's heat-input rate relative
    to its median over the fold's training flights' airborne part, the rate floored at ``floor`` x that
    median (the same weight for the nominal and the overlaid replays of a flight)."""

    n = len(flights)
    out: dict[Any, Any] = {}
    for i in range(n):
        rates = [_heat_rate(models[i], flights[j]) for j in range(n)]
        median = float(np.median(np.concatenate([r[mask] for j, (_, r, mask) in enumerate(rates) if j != i])))
        for j in range(n):
            t_log, rate, _ = rates[j]
            weight = median / np.maximum(rate, floor * median)

            def weigh(feed: Any, t_log: Any = t_log, weight: Any = weight) -> Any:
                return tuple((t, x * np.interp(t, t_log, weight)) for t, x in feed)

            out[(i, j)] = _map_feeds(feeds[(i, j)], weigh, held_out=j == i)
    return out


def _map_feeds(f: Any, change: Any, held_out: bool) -> Any:
    """One fold's feeds of one flight with ``change`` applied to every symptom feed: the held-out flight's
    [(onset, gain, start, feed)] runs, or a training flight's FlightFeeds (nominal and overlays)."""
    from ecu_monitor.offline.calibration_replays import FlightFeeds, OverlayRun

    if held_out:
        return [(onset, gain, start, change(feed)) for onset, gain, start, feed in f]
    runs = tuple(OverlayRun(r.onset_s, r.gain, change(r.feed)) for r in f.overlays)
    return FlightFeeds(f.name, change(f.feed), f.first_row_s, f.last_row_s, f.log_start_s, runs)


#: --soak: the width of the bins the heat-soak fit averages the symptom and its regressor over, s.
SOAK_BIN_S = 10.0


def first_order_lag(t: Any, q: Any, tau_s: float) -> Any:
    """A first-order lag of ``q`` sampled at times ``t`` (s), time constant ``tau_s`` (s), started at rest at
    q's first finite value: y_k = y_(k-1) + (1 - exp(-(t_k - t_(k-1))/tau)) (q_(k-1) - y_(k-1)) (q held between
    samples). Non-finite values of q are filled from the finite ones (linear interpolation)."""
    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float)
    finite = np.isfinite(q)
    if not finite.any():
        return np.full(q.size, np.nan)
    q = np.interp(t, t[finite], q[finite])
    gain = 1.0 - np.exp(-np.diff(t) / tau_s)
    y = np.empty(q.size)
    y[0] = q[0]
    for k in range(1, q.size):
        y[k] = y[k - 1] + gain[k - 1] * (q[k - 1] - y[k - 1])
    return y


def _binned(t: Any, x: Any, r: Any, bin_s: float) -> tuple[Any, Any]:
    """(x, r) averaged over bins of ``bin_s`` seconds where x is finite (bins without a finite x dropped)."""
    ok = np.isfinite(x) & np.isfinite(r)
    if not ok.any():
        return np.empty(0), np.empty(0)
    t, x, r = t[ok], x[ok], r[ok]
    bins = np.floor((t - t[0]) / bin_s).astype(np.int64)
    count = np.bincount(bins)
    used = count > 0
    return np.bincount(bins, x)[used] / count[used], np.bincount(bins, r)[used] / count[used]


def fit_soak(flights: list[tuple[Any, Any, dict[float, Any]]], bin_s: float = SOAK_BIN_S) -> dict[float, Any]:
    """The heat-soak coefficient per time constant, by least squares on nominal flights: symptom = c_f + b r_tau,
    one intercept c_f per flight, r_tau the regressor (lag(q, tau) - q) at the symptom's times; both first
    averaged over ``bin_s`` bins. ``flights``: (times s, symptom, tau -> regressor at those times) per flight
    (concatenate a flight's clock segments). Returns tau -> (b, residual sum of squares, that sum with b = 0)."""
    out: dict[float, Any] = {}
    for tau in flights[0][2]:
        xs, rs = [], []
        for t, x, regressors in flights:
            xb, rb = _binned(np.asarray(t, dtype=float), np.asarray(x, dtype=float), regressors[tau], bin_s)
            if xb.size:
                xs.append(xb - xb.mean())
                rs.append(rb - rb.mean())
        x_all, r_all = np.concatenate(xs), np.concatenate(rs)
        denominator = float(r_all @ r_all)
        b = float(r_all @ x_all) / denominator if denominator > 0.0 else 0.0
        residual = x_all - b * r_all
        out[tau] = (b, float(residual @ residual), float(x_all @ x_all))
    return out


def _soak_input(model: Path, flight: Path, source: str) -> tuple[Any, Any]:
    """(log times s, the input the soak lags): the fold model's heat-input rate Q_in / C (degC/s, ``heat``), the
    logged fuel flow (l/h, ``fuel``) or airspeed (m/s, ``airspeed``: a lagged cooling, not a soak)."""
    if source == "heat":
        t_log, rate, _ = _heat_rate(model, flight)
        return t_log, rate
    from ecu_monitor.bus.canlog import load_flight

    log = load_flight(flight)
    return log.time_s, np.asarray(log["fuel_flow_lph" if source == "fuel" else "airspeed_mps"], dtype=float)


def _soak_feeds(
    feeds: dict[Any, Any],
    models: list[Path],
    flights: list[Path],
    taus: list[float],
    source: str,
    bin_s: float = SOAK_BIN_S,
    coefficient: float | None = None,
    even: bool = False,
) -> tuple[dict[Any, Any], list[tuple[float, float, dict[float, Any], list[Any]]]]:
    """The replays' detector feeds less the fitted heat-soak term b (lag(q, tau) - q), per fold: b and tau fitted
    (:func:`fit_soak`, tau the grid's best) on the fold's training flights' nominal replays only, then subtracted
    from every replay of the fold (training nominal and overlaid, held-out nominal and overlaid: an overlay
    changes the CHT only, so the regressor is the same). ``coefficient``: b given, not fitted (hindsight; tau
    then the grid's only value); ``even``: the regressor |lag(q, tau) - q|. Returns the feeds and per fold (b,
    tau, the fit, per flight (log times s, tau -> regressor))."""

    n = len(flights)
    out: dict[Any, Any] = {}
    fits = []
    for i in range(n):
        regressors = []
        for j in range(n):
            t_log, q = _soak_input(models[i], flights[j], source)
            lagged = {tau: first_order_lag(t_log, q, tau) - q for tau in taus}
            regressors.append((t_log, {tau: np.abs(r) if even else r for tau, r in lagged.items()}))
        training = []
        for j in range(n):
            if j == i:
                continue
            segments = feeds[(i, j)].feed
            t = np.concatenate([s[0] for s in segments])
            x = np.concatenate([s[1] for s in segments])
            t_log, per_tau = regressors[j]
            training.append((t, x, {tau: np.interp(t, t_log, r) for tau, r in per_tau.items()}))
        fit = fit_soak(training, bin_s)
        tau = min(fit, key=lambda k: fit[k][1])
        b = fit[tau][0] if coefficient is None else coefficient
        fits.append((b, tau, fit, regressors))
        for j in range(n):
            t_log, per_tau = regressors[j]
            term = b * per_tau[tau]

            def less(feed: Any, t_log: Any = t_log, term: Any = term) -> Any:
                return tuple((t, x - np.interp(t, t_log, term)) for t, x in feed)

            out[(i, j)] = _map_feeds(feeds[(i, j)], less, held_out=j == i)
    return out, fits


def _print_excursions(flights: list[Path], feeds: dict[Any, Any], per_fold: list[Any], fits: list[Any]) -> None:
    """Per held-out flight, the largest excursions of its nominal statistic (calibrate's choice, the symptom as
    replayed): when S rose from 0 and peaked, the peak, the mean block excess over the baseline, and the mean
    soak regressor (lag(q, tau) - q, the fold's) over the excursion for each tau of the grid: a soak explains
    an excursion when its regressor has the excess's sign and size / b."""
    print("largest nominal excursions (calibrate's choice, before the soak term) and the regressor over each:")
    for i, flight in enumerate(flights):
        start, settings = feeds[(i, i)][0][2], per_fold[i]
        t_log, per_tau = fits[i][3][i]
        rows = []
        for t, x in next(feed for onset, _, _, feed in feeds[(i, i)] if not math.isfinite(onset)):
            ends, means, stat, baseline = _baseline_path(t, x, settings)
            rising = np.flatnonzero((stat > 0.0) & (np.concatenate(([0.0], stat[:-1])) == 0.0))
            for a in rising:
                back = np.flatnonzero(stat[a:] == 0.0)
                b = a + (back[0] if back.size else stat.size - a)
                peak = a + int(np.argmax(stat[a:b]))
                window = slice(a, peak + 1)
                regressors = {tau: float(np.mean(np.interp(ends[window], t_log, r))) for tau, r in per_tau.items()}
                excess = float(np.nanmean(means[window] - baseline[window]))
                rows.append(
                    (float(stat[peak]), (ends[a] - start) / 60.0, (ends[peak] - start) / 60.0, excess, regressors)
                )
        for peak, a, b, excess, regressors in sorted(rows, key=lambda row: -row[0])[:3]:
            shown = ", ".join(f"{tau:g} s {v:+.3f}" for tau, v in regressors.items())
            where = f"S {peak:5.1f} at {b:5.1f} min (from {a:5.1f} min)"
            print(f"  {flight.name}: {where}, excess {excess:+.3f} degC/s; regressor {shown}")


#: --level: the allowance of the relative residual rho (dimensionless), fixed before the screen was run: half of
#: what the k = 0.1 overlay adds to rho 300 s after its onset, 0.1 (1 - exp(-300/240)) / 2 = 0.0357 (Page's rule,
#: half the change to detect). The residual r's allowance is this times the median CHT - OAT over the fold's
#: training flights' airborne part (degC).
RHO_ALLOWANCE = 0.5 * 0.1 * (1.0 - math.exp(-300.0 / 240.0))
#: --level relative: the reference model's rise above OAT in rho's denominator is floored at this, degC (a cold
#: engine at start; the warm-up covers it).
RHO_FLOOR_C = 20.0


def level_symptom(reference: Any, relative: bool, floor_c: float = RHO_FLOOR_C) -> tuple[Any, Any]:
    """A level symptom per step from a replay's open-loop reference (``ReferenceFeed`` of one clock segment):
    (step times s, r = measured CHT - the reference model's CHT, degC), or with ``relative`` rho = r / max(model
    CHT - OAT, floor_c) (dimensionless). nan where the reference is nan (the supervisor not NOMINAL). An overlay
    CHT + k (CHT - OAT) f(t) adds k (CHT - OAT) f(t) to r and about k f(t) to rho."""
    model = np.asarray(reference.model_c, dtype=float)
    r = np.asarray(reference.cht_c, dtype=float) - model
    if relative:
        r = r / np.maximum(model - np.asarray(reference.oat_c, dtype=float), floor_c)
    return np.asarray(reference.time_s, dtype=float), r


def _level_feeds(
    feeds: dict[Any, Any], references: dict[int, list[Any]], n: int, relative: bool, scales: list[float]
) -> dict[Any, Any]:
    """The replays' feeds with the detector's symptom replaced by the level symptom (:func:`level_symptom`) of each
    replay's own open-loop reference (the nominal and every overlaid replay, training and held out), times the
    fold's ``scales[i]``."""
    from ecu_monitor.offline.calibration_replays import FlightFeeds, OverlayRun

    out: dict[Any, Any] = {}
    for i in range(n):

        def level(reference: Any, scale: float = scales[i]) -> Any:
            return tuple((t, scale * x) for t, x in (level_symptom(segment, relative) for segment in reference))

        for j in range(n):
            f = feeds[(i, j)]
            if j == i:
                out[(i, j)] = [
                    (o, g, start, level(ref)) for (o, g, start, _), ref in zip(f, references[i], strict=True)
                ]
            else:
                runs = tuple(OverlayRun(r.onset_s, r.gain, level(r.reference)) for r in f.overlays)
                out[(i, j)] = FlightFeeds(
                    f.name, level(f.reference), f.first_row_s, f.last_row_s, f.log_start_s, runs, f.reference
                )
    return out


def _airborne_rise(flight: Path) -> Any:
    """The logged CHT - OAT (degC) where airborne (airspeed >= ``AIRBORNE_MPS``)."""
    from ecu_monitor.bus.canlog import load_flight
    from ecu_monitor.offline.calibration import AIRBORNE_MPS

    log = load_flight(flight)
    rise = np.asarray(log["cht_c"], dtype=float) - np.asarray(log["oat_c"], dtype=float)
    return rise[(np.nan_to_num(log["airspeed_mps"], nan=0.0) >= AIRBORNE_MPS) & np.isfinite(rise)]


def _print_level(name: str, flights: list[Path], levelled: dict[Any, Any], warmup_s: float) -> None:
    """Per held-out flight, the nominal level symptom after the warm-up: RMS, 1st and 99th percentiles, range."""
    print(f"{name}, nominal held-out flights after the {warmup_s:g} s warm-up: RMS, 1-99 %, min-max")
    for i, flight in enumerate(flights):
        nominal = next(feed for onset, _, _, feed in levelled[(i, i)] if not math.isfinite(onset))
        x = np.concatenate([x[t >= t[0] + warmup_s] for t, x in nominal])
        x = x[np.isfinite(x)]
        low, high = np.percentile(x, [1, 99])
        print(
            f"  {flight.name}: RMS {math.sqrt(float(np.mean(x * x))):.4g}, {low:+.4g} .. {high:+.4g},"
            f" {x.min():+.4g} .. {x.max():+.4g}"
        )


def _learned_floor(training: list[Any], detector: Any, scale_s: float) -> float:
    """The self-normalised detector's ``scale_floor`` learned from training flights: the median of its online
    spread (``detection.scale_blocks``, the excess weighed in full while learning) over their nominal replays."""
    from ecu_monitor.estimation.detection import block_means, scale_blocks

    probe = dataclasses.replace(detector, scale_s=scale_s, scale_floor=UNBOUNDED)
    spreads = [scale_blocks(block_means(t, x, probe)[1], probe) for f in training for t, x in f.feed]
    return float(np.nanmedian(np.concatenate(spreads)))


def _identify(train: list[str], held_out: Path, model: Path, options: list[str]) -> None:
    """``ecu-monitor identify`` (skipped when ``model`` exists); prints its error table."""
    if model.exists():
        return
    cmd = [sys.executable, "-m", "ecu_monitor.cli", "identify", *train, "--validate", str(held_out)]
    cmd += ["--out", str(model), "--quiet", *options]
    shown = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    rows = [line for line in shown.splitlines() if line.startswith(("train", "validate"))]
    print(f"{model.name}:", *rows, sep="\n  ")


def _plot(path: Path, flights: list[Path], variants: list[Any], thresholds: dict[str, Any], level: Any = None) -> None:
    """One row per held-out flight, one column per variant (name, per-fold settings, its feeds): the statistic
    (no alarm) of the nominal flight and of the k = 0.1 overlay at the second onset, with the calibrated h and the
    onset. ``level``: feeds of rho (``--level relative``), drawn first in a column of their own (60 s means,
    nominal and overlaid) beside what the k = 0.1 overlay adds to rho 300 s and 600 s after its onset."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ecu_monitor.estimation.detection import cusum_path

    n = len(flights)
    first = 1 if level is not None else 0
    columns = len(variants) + first
    fig, axes = plt.subplots(n, columns, figsize=(5.5 * columns, 2.6 * n), squeeze=False)
    for i in range(n):
        if level is not None:
            ax = axes[i][0]
            runs = level[(i, i)]
            nominal = next(r for r in runs if not math.isfinite(r[0]))
            overlays = [r for r in runs if math.isfinite(r[0]) and r[1] == 0.1]
            chosen = overlays[min(1, len(overlays) - 1)] if overlays else None
            for run, style, label in ((nominal, "0.5", "rho, nominal"), (chosen, "tab:red", "rho, k = 0.1 overlay")):
                if run is None:
                    continue
                for j, (t, x) in enumerate(run[3]):
                    blocks = np.floor((t - t[0]) / 60.0).astype(np.int64)
                    ok = np.isfinite(x)
                    count = np.bincount(blocks[ok], minlength=blocks[-1] + 1)
                    mean = np.bincount(blocks[ok], x[ok], minlength=blocks[-1] + 1) / np.maximum(count, 1)
                    minutes = (t[0] - run[2]) / 60.0 + np.arange(mean.size) + 0.5
                    mean[count == 0] = np.nan
                    ax.plot(minutes, mean, color=style, lw=0.9, label=label if j == 0 else None)
            for after, style in ((300.0, ":"), (600.0, "--")):
                added = 0.1 * (1.0 - math.exp(-after / 240.0))
                ax.axhline(added, color="tab:blue", ls=style, lw=1.0, label=f"k = 0.1 adds {added:.3f} in {after:g} s")
            if chosen is not None:
                ax.axvline(chosen[0] / 60.0, color="tab:red", ls=":", lw=1.0)
            ax.set_ylim(-0.15, 0.25)
            ax.set_title(f"{flights[i].stem[-13:]}, rho = (CHT - model) / (model - OAT), 60 s means", fontsize=9)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=6, loc="upper left")
            ax.set_ylabel("rho")
            if i == n - 1:
                ax.set_xlabel("time since the start of the log (min)")
        for col, (name, per_fold, feeds) in enumerate(variants, start=first):
            runs = feeds[(i, i)]
            nominal = next(r for r in runs if not math.isfinite(r[0]))
            overlays = [r for r in runs if math.isfinite(r[0]) and r[1] == 0.1]
            chosen = overlays[min(1, len(overlays) - 1)] if overlays else None
            ax = axes[i][col]
            settings = per_fold[i]
            unbounded = dataclasses.replace(settings, threshold=UNBOUNDED)
            for run, style, label in ((nominal, "0.5", "nominal"), (chosen, "tab:red", "k = 0.1 overlay")):
                if run is None:
                    continue
                for j, (t, x) in enumerate(run[3]):
                    ends, stat, _ = cusum_path(t, x, unbounded)
                    ax.plot((ends - run[2]) / 60.0, stat, color=style, lw=0.9, label=label if j == 0 else None)
            h = thresholds[name][i]
            ax.axhline(h, color="black", ls="--", lw=1.0, label=f"h = {h:.1f}")
            if chosen is not None:
                ax.axvline(chosen[0] / 60.0, color="tab:red", ls=":", lw=1.0)
            ax.set_ylim(0.0, 2.5 * h)
            ax.set_title(f"{flights[i].stem[-13:]}, {name} (baseline {settings.baseline_s:g} s)", fontsize=9)
            ax.grid(alpha=0.3)
            if i == n - 1:
                ax.set_xlabel("time since the start of the log (min)")
            if col == first:
                ax.set_ylabel("statistic (symptom x s)")
            ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _baseline_path(t: Any, x: Any, settings: Any) -> tuple[Any, Any, Any, Any]:
    """(block end times, block means, statistic, baseline) of the detector over a feed segment: the
    compiled CUSUM's own statistic, and its baseline re-traced in Python (the compiled test does not
    return it)."""
    from ecu_monitor.estimation.detection import block_means, cusum_blocks

    ends, means = block_means(t, x, settings)
    stat, _ = cusum_blocks(means, dataclasses.replace(settings, threshold=UNBOUNDED))
    baseline = np.full(means.size, np.nan)
    b = math.nan
    for n in range(means.size):
        lagged = means[n - settings.delay_blocks] if n >= settings.delay_blocks else math.nan
        if not math.isnan(lagged):
            if math.isnan(b):
                b = lagged
            elif not (settings.baseline_freeze and stat[n] > 0.0):
                b += settings.block_s / settings.baseline_s * (lagged - b)
        baseline[n] = b
    return ends, means, stat, baseline


def _plot_misses(path: Path, flights: list[Path], feeds: dict[Any, Any], misses: list[Any]) -> None:
    """One column per missed counted onset of calibrate's choice: CHT and CHT - OAT; fuel flow and
    airspeed; the symptom (30 s mean) nominal and overlaid with the overlaid run's baseline; the
    statistic nominal and overlaid with h; onset (dotted) and target time (dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ecu_monitor.bus.canlog import load_flight

    if not misses:
        return
    fig, axes = plt.subplots(4, len(misses), figsize=(4.2 * len(misses), 10), squeeze=False)
    for c, (i, onset, gain, delay, settings) in enumerate(misses):
        log = load_flight(flights[i])
        minutes = (log.time_s - log.time_s[0]) / 60.0
        runs = feeds[(i, i)]
        nominal = next(r for r in runs if not math.isfinite(r[0]))
        overlaid = next(r for r in runs if r[0] == onset and r[1] == gain)
        top, power, symptom, statistic = axes[:, c]
        top.plot(minutes, log["cht_c"], "0.3", lw=0.8, label="CHT")
        top.plot(minutes, log["cht_c"] - log["oat_c"], "tab:purple", lw=0.8, label="CHT - OAT")
        top.set_title(f"{flights[i].stem[-13:]}, k = {gain:g} from {onset / 60:.0f} min: {delay:.0f} s", fontsize=9)
        power.plot(minutes, log["fuel_flow_lph"], "tab:green", lw=0.7, label="fuel flow (l/h)")
        power.plot(minutes, log["airspeed_mps"], "tab:cyan", lw=0.7, label="airspeed (m/s)")
        for run, colour, label in ((nominal, "0.5", "nominal"), (overlaid, "tab:red", f"k = {gain:g}")):
            for n, (t, x) in enumerate(run[3]):
                ends, means, stat, baseline = _baseline_path(t, x, settings)
                m = (ends - run[2]) / 60.0
                smooth = np.convolve(np.nan_to_num(means), np.ones(30) / 30.0, mode="same")
                symptom.plot(m, smooth, colour, lw=0.8, label=label if n == 0 else None)
                statistic.plot(m, stat, colour, lw=0.8, label=label if n == 0 else None)
                if run is overlaid:
                    symptom.plot(m, baseline, "k", lw=0.9, label="baseline (overlaid)" if n == 0 else None)
        statistic.axhline(settings.threshold, color="k", ls="--", lw=1.0, label=f"h = {settings.threshold:.1f}")
        symptom.set_ylim(-0.3, 0.4)
        statistic.set_ylim(0.0, 1.5 * settings.threshold)
        for ax in (top, power, symptom, statistic):
            ax.axvline(onset / 60.0, color="tab:red", ls=":", lw=1.0)
            ax.axvline((onset + LIMITS[gain]) / 60.0, color="tab:red", ls="--", lw=0.6)
            ax.set_xlim(onset / 60.0 - 15.0, onset / 60.0 + 25.0)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=6, loc="upper left")
        if c == 0:
            top.set_ylabel("degC")
            symptom.set_ylabel("symptom (degC/s)")
            statistic.set_ylabel("CUSUM statistic (degC)")
        statistic.set_xlabel("time since the start of the log (min)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _separability(
    runs_per_flight: list[Any], per_fold: list[Any], spans: list[Any], statistic: Any
) -> dict[float, Any]:
    """Hindsight separability per gain: the largest statistic of the held-out flights' nominal replays over the
    smallest statistic a counted overlay reaches within its target time (no alarm; < 1: one h would have served
    every held-out flight). ``statistic(t, x, settings)`` -> (block end times, statistic); per fold its settings.
    Returns gain -> (G, per flight (nominal max, smallest reach))."""
    out: dict[float, Any] = {}
    rows = []
    for i, runs in enumerate(runs_per_flight):
        nominal = next(feed for onset, _, _, feed in runs if not math.isfinite(onset))
        peak = max((float(np.max(statistic(t, x, per_fold[i])[1], initial=0.0)) for t, x in nominal), default=0.0)
        reach: dict[float, list[float]] = {g: [] for g in LIMITS}
        first, last = spans[i]
        for onset, gain, start, feed in runs:
            if not (math.isfinite(onset) and first <= onset <= last):
                continue
            best = 0.0
            for t, x in feed:
                ends, stat = statistic(t, x, per_fold[i])
                window = (ends - start >= onset) & (ends - start <= onset + LIMITS[gain])
                best = max(best, float(np.max(stat[window], initial=0.0)))
            reach[gain].append(best)
        rows.append((peak, reach))
    for gain in LIMITS:
        per_flight = [(peak, min(reach[gain], default=math.inf)) for peak, reach in rows]
        reach = min(r for _, r in per_flight)  # 0: an overlay the statistic never saw within its target
        out[gain] = (max(p for p, _ in per_flight) / reach if reach > 0.0 else math.inf, per_flight)
    return out


def _print_separability(label: str, result: dict[float, Any]) -> None:
    cells = "; ".join(f"k = {g:g}: G {g_value:.2f}" for g, (g_value, _) in result.items())
    flights = ", ".join(f"{p:.1f}/{r:.1f}" for p, r in result[0.1][1])
    print(f"{label:<40} separability {cells}  (per flight nominal max / smallest k = 0.1 reach: {flights})")


@numba.njit(cache=True)
def _glr_blocks(means: Any, delta: float, shaped: bool, window: int, tau_blocks: float, baseline_blocks: float,
                delay: int, freeze: bool) -> Any:  # fmt: skip
    """A GLR over the onset times of the last ``window`` blocks for a rise delta (1 - exp(-t/tau)) of the symptom
    over its baseline (shaped False: delta flat, a CUSUM with allowance delta / 2 that remembers ``window``
    blocks): the statistic after each block, max over the onset of sum f (x - b - delta f / 2), at least 0.
    The baseline as the detector's (a moving average of the block means ``delay`` blocks old, time constant
    ``baseline_blocks``), frozen while the statistic is above 0 when ``freeze``."""
    n = means.shape[0]
    stat = np.zeros(n)
    shape = np.ones(window)
    if shaped:
        for j in range(window):
            shape[j] = 1.0 - math.exp(-(j + 0.5) / tau_blocks)
    allowance = np.cumsum(shape * delta * shape / 2.0)
    sums = np.zeros(window)  # per onset (block index modulo window): the weighed excess since it
    baseline = np.nan
    for i in range(n):
        excess = 0.0 if (math.isnan(means[i]) or math.isnan(baseline)) else means[i] - baseline
        sums[i % window] = 0.0
        best = 0.0
        for lag in range(min(window, i + 1)):
            slot = (i - lag) % window
            sums[slot] += shape[lag] * excess
            best = max(best, sums[slot] - allowance[lag])
        stat[i] = best
        lagged = means[i - delay] if i >= delay else np.nan
        if not math.isnan(lagged):
            if math.isnan(baseline):
                baseline = lagged
            elif not (freeze and best > 0.0):
                baseline += (lagged - baseline) / baseline_blocks
    return stat


def _glr_statistic(delta: float, shaped: bool, window_s: float) -> Any:
    """statistic(t, x, settings) of :func:`_glr_blocks` with the detector's blocks and baseline settings."""
    from ecu_monitor.estimation.detection import block_means

    def statistic(t: Any, x: Any, settings: Any) -> Any:
        ends, means = block_means(t, x, settings)
        blocks = max(round(window_s / settings.block_s), 1)
        baseline = max(settings.baseline_s / settings.block_s, 1.0)
        stat = _glr_blocks(means, delta, shaped, blocks, 240.0 / settings.block_s, baseline, settings.delay_blocks,
                           settings.baseline_freeze)  # fmt: skip
        return ends, stat

    return statistic


def _count_oracle(counts: dict[float, list[int]], runs: Any, unbounded: Any, span: Any, cusum_path: Any) -> float:
    """Add to ``counts`` (gain -> [in time, counted]) the held-out flight's counted onsets detected in time
    with h = 1.01 x the largest statistic of its own nominal replay (the lowest h without a false DEGRADED
    on it); returns that h."""
    nominal = next(feed for onset, _, _, feed in runs if not math.isfinite(onset))
    h = 1.01 * max((float(np.max(cusum_path(t, x, unbounded)[1], initial=0.0)) for t, x in nominal), default=0.0)
    tuned = dataclasses.replace(unbounded, threshold=max(h, 1e-9))
    first, last = span
    for onset, gain, start, feed in runs:
        if not (math.isfinite(onset) and first <= onset <= last):
            continue
        alarms = [a - start for t, x in feed for a in cusum_path(t, x, tuned)[2]]
        after = [a for a in alarms if a >= onset]
        counts[gain][1] += 1
        counts[gain][0] += bool(after) and not any(a < onset for a in alarms) and after[0] - onset <= LIMITS[gain]
    return h


#: Windows after an onset over which --rise-profile averages the overlay's effect on the symptom, s.
RISE_WINDOWS_S = ((0.0, 30.0), (30.0, 120.0), (120.0, 240.0), (240.0, 420.0), (420.0, 600.0))


def _rise_profile(feeds: dict[Any, Any], models: list[Path], flights: list[Path], spans: list[Any]) -> None:
    """Print, per gain, the overlaid minus the nominal symptom averaged over :data:`RISE_WINDOWS_S` after
    each counted onset of the held-out flights (median and 10-90 % over the onsets), beside k x the fold
    model's heat-input rate Q_in / C over the same windows: the shape a test matched to the rise would use."""
    for gain in LIMITS:
        rises, rates = [], []
        for i in range(len(flights)):
            runs = feeds[(i, i)]
            nominal = next(feed for onset, _, _, feed in runs if not math.isfinite(onset))
            t_nom = np.concatenate([t for t, _ in nominal])
            x_nom = np.concatenate([x for _, x in nominal])
            t_nom, x_nom = t_nom[np.isfinite(x_nom)], x_nom[np.isfinite(x_nom)]
            t_log, rate, _ = _heat_rate(models[i], flights[i])
            first, last = spans[i]
            for onset, g, start, feed in runs:
                if g != gain or not (math.isfinite(onset) and first <= onset <= last):
                    continue
                t = np.concatenate([t for t, _ in feed])
                x = np.concatenate([x for _, x in feed])
                t, x = t[np.isfinite(x)], x[np.isfinite(x)]
                after = t - start - onset
                excess = x - np.interp(t, t_nom, x_nom)
                windows = [(after >= a) & (after < b) for a, b in RISE_WINDOWS_S]
                rises.append([float(np.mean(excess[w])) for w in windows])
                rates.append([gain * float(np.mean(np.interp(t[w], t_log, rate))) for w in windows])
        if not rises:
            continue
        r, q = np.array(rises), np.array(rates)
        spans_s = ", ".join(f"{a:g}-{b:g}" for a, b in RISE_WINDOWS_S)
        print(f"\nk = {gain:g}: overlaid minus nominal symptom (degC/s) over {spans_s} s after {len(r)} counted onsets")
        print("  median      ", " ".join(f"{v:6.3f}" for v in np.median(r, axis=0)))
        print("  10 %        ", " ".join(f"{v:6.3f}" for v in np.percentile(r, 10, axis=0)))
        print("  90 %        ", " ".join(f"{v:6.3f}" for v in np.percentile(r, 90, axis=0)))
        print("  k Q_in / C  ", " ".join(f"{v:6.3f}" for v in np.median(q, axis=0)), "(median, the model's)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("flights", nargs="+", help="nominal flights of one engine (at least 3)")
    parser.add_argument("--mapping", help="mapping for foreign CSVs (e.g. g1000)")
    parser.add_argument("--heat-axes", default="fuel_flow_lph,rpm")
    parser.add_argument(
        "--effects",
        help="identify with these effects on and free, e.g. airspeed_cooling,density_cooling (what gap finds)",
    )
    parser.add_argument(
        "--identify-args", default="", help='more options for ecu-monitor identify, e.g. "--base B.yaml --free ..."'
    )
    parser.add_argument("--config", default="example.yaml")  # a path, or a shipped config's name
    parser.add_argument(
        "--egt",
        action="store_true",
        help="put the flights' mean EGT (egt_c) on the bus as a frame of its own (a one-message DBC and a copy of"
        " the config mapping it, written to the work folder): what a model with the mixture index needs",
    )
    parser.add_argument("--onset-every", type=float, default=900.0, help="spacing of the overlay onsets, s")
    parser.add_argument(
        "--first-onset", type=float, help="first overlay onset, s after the log's start (default: end of the warm-up)"
    )
    parser.add_argument(
        "--variant", action="append", default=[], help="baseline_s:delay_s:reference[:freeze] (repeatable)"
    )
    parser.add_argument("--rate", type=float, default=1.0, help="false alarms per 100 h for the calibration")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--json", help="write every delay here")
    parser.add_argument(
        "--plot",
        help="PNG: per held-out flight, the statistic nominal and with the k = 0.1 overlay at the second onset",
    )
    parser.add_argument(
        "--plot-level",
        help="PNG (with --level): per held-out flight, rho nominal and overlaid (with --level relative) and the"
        " statistic of calibrate's choice on the derivative symptom and on each --level symptom",
    )
    parser.add_argument(
        "--plot-misses",
        help="PNG: per counted onset calibrate's choice detects late, the flight, the symptom, baseline and statistic",
    )
    parser.add_argument(
        "--work", help="folder for the work files (default: a new temporary folder); models found there are reused"
    )
    parser.add_argument(
        "--replays",
        help="pickle of the replays (detector feeds): reused for the jobs it holds, written with any new ones"
        " (detector variants evaluated on the same replays without replaying again)",
    )
    parser.add_argument(
        "--oracle",
        action="store_true",
        help="also count with h = 1.01 x the held-out flight's own nominal maximum (an upper bound, not a method)",
    )
    parser.add_argument(
        "--heat-rate-floor",
        type=float,
        action="append",
        default=[],
        help="also evaluate calibrate's choice on the symptom divided by the model's Q_in/C, floored at this"
        " fraction of its airborne median (repeatable; offline, on the same replays)",
    )
    parser.add_argument(
        "--scale",
        type=float,
        action="append",
        default=[],
        help="also evaluate calibrate's choice (nested) and each --variant with the self-normalised symptom:"
        " detector.scale_s this (s), scale_floor per fold the median of the online spread over the training"
        " flights' nominal replays (repeatable; on the same replays)",
    )
    parser.add_argument(
        "--soak",
        help="TAU[,TAU...]: also evaluate calibrate's choice (nested) and each --variant on the symptom less a"
        " heat-soak term b (lag(q, tau) - q), b by least squares and tau from this grid (s), both fitted per fold"
        " on the training flights' nominal replays only (offline, on the same replays)",
    )
    parser.add_argument(
        "--soak-input",
        choices=("heat", "fuel", "airspeed"),
        default="heat",
        help="what --soak lags: the fold model's heat-input rate Q_in / C (heat), the logged fuel flow (fuel) or"
        " the logged airspeed (airspeed: a cooling that follows the airspeed late, the same screen)",
    )
    parser.add_argument(
        "--soak-even",
        action="store_true",
        help="the --soak regressor |lag(q, tau) - q| (even in the change's sign: the head warmer than the model"
        " after any change of operating point, not a soak)",
    )
    parser.add_argument(
        "--soak-coef",
        type=float,
        help="hindsight: b given, not fitted (--soak then a single TAU): what a soak term of that size would do",
    )
    parser.add_argument(
        "--soak-bin",
        type=float,
        default=SOAK_BIN_S,
        help="bins (s) the --soak fit averages the symptom and the regressor over first (longer: the fit weighs the"
        " slow part of the symptom more)",
    )
    parser.add_argument(
        "--separability",
        action="store_true",
        help="also print per variant the hindsight separability: the held-out flights' largest nominal statistic"
        " over the smallest a counted overlay reaches within its target (< 1: one h would have served all)",
    )
    parser.add_argument(
        "--glr",
        action="append",
        default=[],
        help="DELTA[:flat]: the separability of a GLR over the onsets of the last --glr-window s for a rise"
        " DELTA (1 - exp(-t/240 s)) (flat: a CUSUM with allowance DELTA/2 remembering that long), with calibrate's"
        " and each variant's baseline (repeatable; offline, on the same replays)",
    )
    parser.add_argument(
        "--level",
        action="append",
        default=[],
        choices=("residual", "relative", "residual-scaled", "relative-scaled"),
        help="also evaluate calibrate's choice (nested) and each --variant on a level symptom: the open-loop"
        " residual r = CHT - the reference model's CHT (residual, degC) or rho = r / (model CHT - OAT) (relative),"
        " allowance fixed in advance (RHO_ALLOWANCE); -scaled: the symptom in units of that allowance x the"
        " config's reference (h's floor then means what it means for the derivative symptom); the replays keep"
        " their open-loop reference (repeatable)",
    )
    parser.add_argument("--glr-window", type=float, default=900.0, help="onsets the --glr test considers, s")
    parser.add_argument(
        "--rise-profile",
        action="store_true",
        help="print how the overlay moves the symptom over the windows after its onsets (held-out flights)",
    )
    args = parser.parse_args(argv)
    if not all(0.0 < f < 1.0 for f in args.heat_rate_floor):
        parser.error("--heat-rate-floor: expected a fraction of the median rate in (0, 1)")
    try:
        soak_taus = [float(v) for v in args.soak.split(",")] if args.soak else []
    except ValueError:
        parser.error(f"--soak: expected time constants in s separated by commas, got {args.soak!r}")
    if not all(math.isfinite(v) and v > 0.0 for v in soak_taus):
        parser.error("--soak: time constants must be positive")
    if args.soak_coef is not None and len(soak_taus) != 1:
        parser.error("--soak-coef: give --soak a single time constant")
    if not (math.isfinite(args.soak_bin) and args.soak_bin > 0.0):
        parser.error("--soak-bin: expected a positive width in s")

    from ecu_monitor.bus.canlog import load_flight
    from ecu_monitor.commands.calibrate import candidate_table
    from ecu_monitor.config import load_config
    from ecu_monitor.estimation.detection import calibrate_threshold, cusum_path
    from ecu_monitor.flightlog import import_mapped_csv, resolve_mapping, write_csv
    from ecu_monitor.identify import DEFAULT_FREE
    from ecu_monitor.model import Effects, load_model, save_model
    from ecu_monitor.offline.calibration import AIRBORNE_MPS, choose_settings

    config = load_config(args.config)
    variants = [("config", config.detector)]
    for text in args.variant:
        parts = text.split(":")
        b, d, k = (float(v) for v in parts[:3])
        freeze = parts[3:] == ["freeze"]
        variants.append(
            (
                text,
                dataclasses.replace(
                    config.detector, baseline_s=b, baseline_delay_s=d, reference=k, baseline_freeze=freeze
                ),
            )
        )
    started = time.perf_counter()
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="bench-detect-real-"))
    work.mkdir(parents=True, exist_ok=True)
    if args.egt:
        args.config = _config_with_egt(args.config, work)
        config = load_config(args.config)
    flights = []
    for path in args.flights:
        log = import_mapped_csv(path, resolve_mapping(args.mapping)) if args.mapping else load_flight(path)
        canonical = work / (Path(path).stem + ".csv")
        write_csv(log, canonical)
        flights.append(canonical)
    n = len(flights)
    if n < 3:
        parser.error("need at least 3 flights (2 to calibrate on, 1 held out)")
    extra = shlex.split(args.identify_args)
    models = []
    for i in range(n):
        train = [str(f) for j, f in enumerate(flights) if j != i]
        model = work / f"model_without_{i}.yaml"
        _identify(train, flights[i], model, [*extra, "--heat-axes", args.heat_axes])
        if args.effects:  # second pass: the nominal model with the effects on, refitted with them free
            names = args.effects.split(",")
            base = work / f"base_with_effects_{i}.yaml"
            nominal = load_model(model)
            starts = {name: EFFECT_STARTS[name] for name in names}
            effects = Effects.from_dict({**nominal.effects.to_dict(), **starts})
            save_model(dataclasses.replace(nominal, effects=effects), base, "bench_detect_real: start with effects")
            free = [*DEFAULT_FREE, *(f"effects.{name}.{next(iter(EFFECT_STARTS[name]))}" for name in names)]
            model = work / f"model_effects_without_{i}.yaml"
            _identify(train, flights[i], model, [*extra, "--base", str(base), "--free", ",".join(free)])
        models.append(model)
    # jobs: per held-out i, the training flights as calibrate replays them and the held-out flight
    # nominal + overlays at onsets every --onset-every s
    jobs = []
    spans = []  # per flight: (take-off, landing - 600 s), s after the log's start: where an onset counts
    for i in range(n):
        log = load_flight(flights[i])
        flying = np.flatnonzero(np.nan_to_num(log["airspeed_mps"], nan=0.0) >= AIRBORNE_MPS)
        t_rel = log.time_s - log.time_s[0]
        spans.append((float(t_rel[flying[0]]), float(t_rel[flying[-1]]) - 600.0) if flying.size else (1.0, 0.0))
        for j in range(n):
            if j == i:
                duration = log.duration_s
                warm = max(v.warmup_s for _, v in variants)
                first = warm if args.first_onset is None else args.first_onset
                onsets = np.arange(first, duration - 600.0 + 1e-9, args.onset_every)
                overlays: list[tuple[float, float]] | None = [(float(t0), k) for t0 in onsets for k in LIMITS]
            else:
                overlays = None
            jobs.append((i, j, (str(flights[j]), str(models[i]), args.config, overlays, bool(args.level))))
    cache = _load_replays(args.replays)
    todo = [job[2] for job in jobs if _cached(cache, job[2]) is None]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        fresh = iter(list(pool.map(_feeds, todo)))
    results = [_cached(cache, job[2]) or next(fresh) for job in jobs]
    if args.replays and todo:
        _save_replays(args.replays, cache, [job[2] for job in jobs], results)
    # held out: (onset, gain, log start, detector feed) per run; the open-loop references kept apart (--level)
    feeds = {(i, j): r if i != j else [run[:4] for run in r] for (i, j, _), (r, _) in zip(jobs, results, strict=True)}
    references = {i: [run[4] for run in r] for (i, j, _), (r, _) in zip(jobs, results, strict=True) if i == j}
    timings = [t for _, t in results]

    # calibrate's choice, nested: made on the three training flights of each fold only
    def nested_choice(feeds: dict[Any, Any], label: str, current: list[Any] | None = None) -> list[Any]:
        chosen = []
        for i in range(n):
            training = [feeds[(i, j)] for j in range(n) if j != i]
            choice = choose_settings(training, config.detector if current is None else current[i], args.rate)
            print(f"\nfold without {flights[i].name}: calibrate's cross-validation on the {n - 1} others{label}")
            print(*candidate_table(choice), f"chosen: {choice.reason}", sep="\n")
            chosen.append(choice)
        return chosen

    chosen = nested_choice(feeds, "")
    fold_variants = [("calibrate's choice", [c.settings for c in chosen], feeds)]
    fold_variants += [(name, [settings] * n, feeds) for name, settings in variants]
    for floor in args.heat_rate_floor:
        weighted = _heat_rate_feeds(feeds, models, flights, floor)
        label = f"calibrate's choice, symptom / heat rate (floor {floor:g})"
        fold_variants.append((label, [c.settings for c in nested_choice(weighted, f" ({label})")], weighted))
        fold_variants += [(f"{name}, heat rate (floor {floor:g})", [v] * n, weighted) for name, v in variants[1:]]
    if soak_taus:
        soaked, fits = _soak_feeds(
            feeds, models, flights, soak_taus, args.soak_input, args.soak_bin, args.soak_coef, args.soak_even
        )
        print(
            f"\nheat soak ({args.soak_input}, {args.soak_bin:g} s bins): b and tau fitted per fold on the training"
            " flights' nominal replays"
        )
        for i, (b, tau, fit, _) in enumerate(fits):
            cells = ", ".join(f"tau {t:g} s: b {v[0]:+.4f}, RSS {v[1] / v[2]:.4f}" for t, v in fit.items())
            print(f"  fold without {flights[i].name}: tau {tau:g} s, b {b:+.4f}  ({cells}; RSS relative to b = 0)")
        given = "" if args.soak_coef is None else f", b {args.soak_coef:g} given"
        given += ", even" if args.soak_even else ""
        _print_excursions(flights, feeds, [c.settings for c in chosen], fits)
        label = f"calibrate's choice, less the heat soak ({args.soak_input}{given})"
        fold_variants.append((label, [c.settings for c in nested_choice(soaked, f" ({label})")], soaked))
        fold_variants += [(f"{name}, less the heat soak", [v] * n, soaked) for name, v in variants[1:]]
    for scale_s in args.scale:
        floors = [
            _learned_floor([feeds[(i, j)] for j in range(n) if j != i], config.detector, scale_s) for i in range(n)
        ]
        current = [dataclasses.replace(config.detector, scale_s=scale_s, scale_floor=f) for f in floors]
        label = f"calibrate's choice, self-normalised (scale {scale_s:g} s)"
        shown = ", ".join(f"{f:.4f}" for f in floors)
        print(f"\nself-normalised, scale_s {scale_s:g} s: floor per fold (training median spread) {shown}")
        fold_variants.append((label, [c.settings for c in nested_choice(feeds, f" ({label})", current)], feeds))
        fold_variants += [
            (f"{name}, self-normalised (scale {scale_s:g} s)", [dataclasses.replace(v, scale_s=scale_s, scale_floor=f)
             for f in floors], feeds) for name, v in variants[1:]
        ]  # fmt: skip
    for kind in args.level:  # the open-loop residual r (degC) or the relative residual rho, as the detector's symptom
        relative = kind.startswith("relative")
        scaled = kind.endswith("-scaled")
        name = ("relative residual rho" if relative else "residual r") + (" (allowance units)" if scaled else "")
        rises = [_airborne_rise(f) for f in flights]
        allowances = [
            RHO_ALLOWANCE * (1.0 if relative else float(np.median(np.concatenate(rises[:i] + rises[i + 1 :]))))
            for i in range(n)
        ]
        unit = "" if relative else " degC"
        shown = ", ".join(f"{a:.4g}{unit}" for a in allowances)
        print(f"\n{name} as the symptom: allowance per fold (fixed in advance, see RHO_ALLOWANCE) {shown}")
        # -scaled: the symptom in units of its allowance x the config's reference, which then is its allowance, so
        # that calibrate_threshold's floor on h (1 symptom unit x s) means the 20 s of allowance it means for the
        # derivative symptom (0.05 degC/s), not 0.2 s of r's
        scales = [config.detector.reference / a if scaled else 1.0 for a in allowances]
        levelled = _level_feeds(feeds, references, n, relative, scales)
        _print_level(name, flights, levelled, config.detector.warmup_s)
        if scaled:
            allowances = [config.detector.reference] * n
        current = [dataclasses.replace(config.detector, reference=a) for a in allowances]
        label = f"calibrate's choice, {name}"
        fold_variants.append((label, [c.settings for c in nested_choice(levelled, f" ({label})", current)], levelled))
        fold_variants += [
            (f"{vname}, {name}", [dataclasses.replace(v, reference=a) for a in allowances], levelled)
            for vname, v in variants[1:]
        ]
    report: dict[str, Any] = {"choices": [c.reason for c in chosen]}
    if soak_taus:  # per fold: the soak term's b and tau, and per tau of the grid (b, RSS, RSS with b = 0)
        report["soak"] = [{"b": b, "tau_s": tau, "fit": {str(k): v for k, v in fit.items()}} for b, tau, fit, _ in fits]
    misses: list[Any] = []  # calibrate's choice: (flight, onset, gain, delay, settings with h) of late counted onsets
    thresholds: dict[str, list[float]] = {}
    for name, per_fold, variant_feeds in fold_variants:
        oracle = {0.2: [0, 0], 0.1: [0, 0]}  # counted onsets with h = 1.01 x the held-out nominal maximum
        oracle_h = []
        first = per_fold[0]
        baselines = ", ".join(f"{s.baseline_s:g}" for s in per_fold)
        delays = ", ".join(f"{s.baseline_delay_s:g}" for s in per_fold)
        freezes = ", ".join("yes" if s.baseline_freeze else "no" for s in per_fold)
        print(f"\nvariant {name}: baseline_s {baselines}, delay_s {delays}, freeze {freezes} (per fold),"
              f" reference {first.reference:g}, warm-up {first.warmup_s:g} s")  # fmt: skip
        print(f"{'held-out flight':<40} {'h':>8}  {'nominal':>18}  {'k=0.2 <=300 s':>14}  {'k=0.1 <=600 s':>14}")
        totals = {"false": 0, 0.2: [0, 0], 0.1: [0, 0], "all 0.2": [0, 0], "all 0.1": [0, 0]}
        per_flight = []
        for i in range(n):
            settings = per_fold[i]
            unbounded = dataclasses.replace(settings, threshold=UNBOUNDED)
            paths = [cusum_path(t, x, unbounded)[1] for j in range(n) if j != i for t, x in variant_feeds[(i, j)].feed]
            h = calibrate_threshold(paths, args.rate, sample_period_s=settings.block_s).threshold
            tuned = dataclasses.replace(settings, threshold=h)
            entry: dict[str, Any] = {"flight": flights[i].name, "baseline_s": settings.baseline_s, "threshold": h}
            entry["delays"] = {}
            for onset, gain, start, feed in variant_feeds[(i, i)]:
                alarms = [a - start for t, x in feed for a in cusum_path(t, x, tuned)[2]]
                if not math.isfinite(onset):
                    entry["false_alarm_s"] = alarms[0] if alarms else None
                    continue
                after = [a for a in alarms if a >= onset]
                before = any(a < onset for a in alarms)
                delay = (after[0] - onset) if after and not before else (math.nan if before else math.inf)
                entry["delays"].setdefault(str(gain), []).append((onset, delay))
            false = entry["false_alarm_s"]
            totals["false"] += false is not None
            if args.oracle:
                oracle_h.append(_count_oracle(oracle, variant_feeds[(i, i)], unbounded, spans[i], cusum_path))
            cells = []
            first, last = spans[i]
            for gain, limit in LIMITS.items():
                pairs = entry["delays"].get(str(gain), [])
                every = np.array([d for _, d in pairs], dtype=float)
                totals[f"all {gain}"][0] += int(np.sum(every <= limit))
                totals[f"all {gain}"][1] += every.size
                delays = np.array([d for t0, d in pairs if first <= t0 <= last], dtype=float)
                hit = int(np.sum(delays <= limit))
                if name == "calibrate's choice":
                    misses += [(i, t0, gain, d, tuned) for t0, d in pairs if first <= t0 <= last and not d <= limit]
                totals[gain][0] += hit
                totals[gain][1] += delays.size
                med = np.median(delays[np.isfinite(delays)]) if np.isfinite(delays).any() else math.inf
                cells.append(f"{hit:>3}/{delays.size:<3} med {med:5.0f}")
            nominal = f"DEGRADED t={false:.0f} s" if false is not None else "no alarm"
            print(f"{flights[i].name:<40} {h:8.2f}  {nominal:>18}  {cells[0]:>14}  {cells[1]:>14}")
            per_flight.append(entry)
        print(f"{'total (airborne onsets)':<40} {'':>8}  {totals['false']:>3} false DEGRADED    "
              f"{totals[0.2][0]:>3}/{totals[0.2][1]:<10} {totals[0.1][0]:>3}/{totals[0.1][1]}")  # fmt: skip
        every_2, every_1 = totals["all 0.2"], totals["all 0.1"]
        print(f"{'total (all onsets, ground and landing too)':<40} {'':>8}  {'':>18}    "
              f"{every_2[0]:>3}/{every_2[1]:<10} {every_1[0]:>3}/{every_1[1]}")  # fmt: skip
        if args.oracle:
            print(f"{'oracle h (1.01 x held-out nominal max)':<40} {'':>8}  {'':>18}    "
                  f"{oracle[0.2][0]:>3}/{oracle[0.2][1]:<10} {oracle[0.1][0]:>3}/{oracle[0.1][1]}"
                  f"   (h {', '.join(f'{v:.1f}' for v in oracle_h)})")  # fmt: skip
            report.setdefault("oracle", {})[name] = {str(k): v for k, v in oracle.items()}
        if args.separability:
            cusum = lambda t, x, settings: cusum_path(t, x, dataclasses.replace(settings, threshold=UNBOUNDED))[:2]  # noqa: E731
            runs = [variant_feeds[(i, i)] for i in range(n)]
            _print_separability("hindsight (no h)", _separability(runs, per_fold, spans, cusum))
        report.setdefault("totals", {})[name] = {str(k): v for k, v in totals.items()}
        report[name] = {"settings": [dataclasses.asdict(s) for s in per_fold], "flights": per_flight}
        thresholds[name] = [entry["threshold"] for entry in per_flight]
    report["counted_onsets_s"] = spans
    for spec in args.glr:  # offline: the GLR matched to the rise (or the flat windowed CUSUM) on the same replays
        shaped = not spec.endswith(":flat")
        delta = float(spec.split(":")[0])
        statistic = _glr_statistic(delta, shaped, args.glr_window)
        kind = f"GLR, rise delta {delta:g} degC/s x (1 - exp(-t/240 s))" if shaped else f"flat, allowance {delta / 2:g}"
        print(f"\n{kind}, onsets over the last {args.glr_window:g} s, baseline as each variant's (hindsight, no h):")
        for name, per_fold, variant_feeds in fold_variants:
            if "heat rate" in name or "self-" in name or "soak" in name or "residual" in name:
                continue
            runs = [variant_feeds[(i, i)] for i in range(n)]
            _print_separability(name, _separability(runs, per_fold, spans, statistic))
    if args.rise_profile:
        _rise_profile(fold_variants[0][2], models, flights, spans)
    held = [t for t in timings if "all_frames_s" in t]
    training = [t["training_s"] for t in timings if "training_s" in t]
    print(f"\n{len(jobs)} jobs, {time.perf_counter() - started:.0f} s in all; work files in {work}")
    if held and training:  # replays run now (not all from --replays)
        print(
            f"median per held-out flight: frames of the whole flight"
            f" {np.median([t['all_frames_s'] for t in held]):.1f} s,"
            f" nominal replay {np.median([t['replay_s'] for t in held]):.1f} s, an overlay (CHT message re-encoded +"
            f" replay) {np.median([t['overlay_s'] for t in held]):.1f} s; a training flight as calibrate replays it"
            f" (nominal + 6 overlays) {np.median(training):.1f} s"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1, default=float), encoding="utf-8")
    if args.plot_misses:
        _plot_misses(Path(args.plot_misses), flights, fold_variants[0][2], misses)
    if args.plot:
        raw = [
            variant
            for variant in fold_variants
            if not any(word in variant[0] for word in ("heat rate", "self-", "soak", "residual"))
        ]
        _plot(Path(args.plot), flights, raw, thresholds)
    if args.plot_level:  # calibrate's choice on the derivative symptom and on each --level symptom; rho itself
        chosen_level = [
            v for v in fold_variants if v[0] == "calibrate's choice" or v[0].startswith("calibrate's choice, re")
        ]
        rho = next((v[2] for v in fold_variants if v[0] == "calibrate's choice, relative residual rho"), None)
        _plot(Path(args.plot_level), flights, chosen_level, thresholds, rho)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
