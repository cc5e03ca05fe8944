"""The one step: every fixed step of the schedule, for every cylinder, the supervision, the estimator and
the isolation filter (every filter period), the detector and the headroom; then the cross-cylinder
detectors. Compiled with numba into one entry point, :func:`replay_loop` (for each frame: :func:`advance_to`
its time, then :func:`feed_values` its decoded values): replay runs it over a whole log's frames, the live
pipeline over each frame as it comes. Nothing here is written twice, or compiled twice.

Compiled, numba counts a reference to an array atomically every time it is passed or read from a tuple;
the per-frame path avoids that: the entry point (:func:`replay_loop`) takes :func:`borrowed` views of the
records' arrays (the caller keeps them alive for the call), and the per-frame and per-step functions are
inlined into it (no argument copies or calls);
each function binds the arrays it uses to locals once (``eng_values = eng.values``).

Everything lives in named records (numpy structured dtypes, read by field name in the compiled code):
:data:`CYLINDER_SETTINGS` (what the config and the model say, fixed), :data:`CYLINDER_STATE` (what one
step carries to the next), :data:`CLOCK` (the schedule), :class:`Engine` (the arrays of one engine: held
inputs, stale checks, the cylinders) and :class:`Rows` (the output table the steps write to).

The rules, in the order a step applies them:

* staleness: an input is stale when never seen or silent longer than its ``stale_after_s``;
* supervision (:func:`~ecu_monitor.pipeline.supervision.supervise`): UNAVAILABLE, INPUT_STALE,
  SENSOR_FAULT or "the detector decides";
* every filter period: the model's drive at the held inputs (once, for every filter), the open-loop
  reference (the model alone: the stuck-probe test's model), then the estimator and
  the isolation filter with the reading the supervisor lets through;
* the detector (a CUSUM over block means of the symptom, :func:`detector_step`), fed the symptom on
  NOMINAL steps and NaN otherwise, from the cylinder's first initialisation on; DEGRADED latches. Two
  tests, the more severe verdict wins: against the in-flight adaptive baseline (after its warm-up), and,
  once ``calibrate`` has learned the engine's reference, against the symptom's nominal level in the
  step's operating region (estimation/regions.py, the time since the first initialisation being the
  engine's start) wherever the reference has a level (``calibrate`` learns none for the start region: from
  5 min after engine start), which no baseline can absorb; ``detector_armed`` says which run;
* isolation: the gammas are published only where they can be told apart (``not_isolable`` False): a
  degradation is declared (DEGRADED: something to isolate), cruise or high power airborne, both standard
  deviations of the isolation filter at most ISOLATION_SD_MAX and their correlation above
  ISOLATION_CORRELATION_MIN (only the product seen); elsewhere they are nan ("not isolable"). A fault
  present from engine start is named instead from the dynamics: the open-loop reference's residual fitted to
  its sensitivities to gamma_Q and gamma_D over the cold start (where a heat fault shows alone), the settle
  after it and the flight, against the fits' nominal spreads (:func:`start_fault_call`; nothing in the first
  10 min); the filter's product gamma_Q gamma_D is then published on the factor it names, 1 on the other;
* every headroom period: the time to the CHT limit at the held inputs (:func:`headroom_s`);
* several cylinders: each cylinder's symptom minus the median of the others' feeds its cross-cylinder
  detector; the more severe verdict wins;
* every filter period, the engine events (:func:`events_step`): shock cooling, divergence, exceedances and
  the exhaust-valve advisory, into ``Engine.events``: a start record once a condition has held for its
  minimum time, an end record when it ends.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numba.core import cgutils, types
from numba.extending import intrinsic, overload

from ecu_monitor.estimation.detection import NOMINAL_SPREAD_Z, START_FIT_NAMES
from ecu_monitor.estimation.detection import _cusum_step as cusum_step
from ecu_monitor.estimation.ekf import live_steps as live_ekf
from ecu_monitor.estimation.isolation import live_steps as live_isolation
from ecu_monitor.estimation.quantiser import level_of
from ecu_monitor.estimation.regions import (
    REGION_COUNT,
    START_S,
    isolable_region,
    power_fraction,
    region_of,
)
from ecu_monitor.model.effects import fuel_air_index
from ecu_monitor.model.equations import derivatives, dissipation, rk4
from ecu_monitor.model.kernels import njit
from ecu_monitor.model.thermal import drive_at, unpack_coefficients
from ecu_monitor.pipeline.events import EVENT_KINDS
from ecu_monitor.pipeline.output_table import HEADROOM_CAP_S, output_fields
from ecu_monitor.pipeline.schedule import MAX_CLOCK_GAP_S, MAX_CLOCK_S, clock_tick
from ecu_monitor.pipeline.supervision import (
    ACTION_INITIALISE,
    ACTION_NONE,
    CODE_DEGRADED,
    CODE_NOMINAL,
    CODE_UNAVAILABLE,
    SupervisorState,
    supervise,
)

__all__ = [
    "ARMED_BASELINE",
    "ARMED_REFERENCE",
    "CLOCK",
    "CYLINDER_OUTPUT",
    "CYLINDER_SETTINGS",
    "CYLINDER_STATE",
    "DETECTOR_SETTINGS",
    "DETECTOR_STATE",
    "EVENT",
    "EVENT_SETTINGS",
    "EVENT_TRACKER",
    "ISOLATION_CORRELATION_MIN",
    "ISOLATION_SD_MAX",
    "START_CALL_HEAT",
    "START_CALL_LOSS",
    "START_CALL_NOT_FROM_START",
    "START_CALL_UNTOLD",
    "Engine",
    "Rows",
    "Traces",
    "compiled",
    "start_fault_call",
]

#: ``armed`` bits: the test against the engine's reference (calibrated nominal levels) is running
ARMED_REFERENCE = 1
#: ``armed`` bits: the test against the in-flight adaptive baseline is running (after its warm-up)
ARMED_BASELINE = 2
#: The isolation's standard deviation of either gamma above which the split is not told (1).
ISOLATION_SD_MAX = 0.05
#: The correlation of the gamma_Q and gamma_D estimates at and below which only their product is seen (1).
ISOLATION_CORRELATION_MIN = -0.9
#: The cold start, where a heat fault shows alone: from engine start while the open-loop reference's sensitivity
#: to gamma_D is at most this share of its sensitivity to gamma_Q (the head near the air: its dissipation small
#: against its heating; about the first minute of a cold ground run).
COLD_START_LOSS_SHARE = 0.3
#: The cold start does not end before the heat's sensitivity has reached this, degC per unit gamma_Q (a doubled
#: heat would have moved the head by a reading's quantum): in the first seconds both sensitivities are tiny and
#: the heat path's first-order delay, undershooting a throttle step, can flip their ratio.
COLD_START_MIN_C = 1.0
#: The cold start's course (CYLINDER_STATE's ``cold``): not begun (the engine not heating yet), holds, over.
COLD_BEFORE = 0
COLD_HOLDS = 1
COLD_OVER = 2
#: The settle window (from the cold start's end) closes this long after engine start, s; the start call waits for it.
SETTLE_END_S = 2.0 * START_S
#: The start fits' windows (rows of CYLINDER_STATE's fit_sums, places of its start_fit: START_FIT_NAMES).
_FIT_COLD = 0
_FIT_SETTLE = 1
_FIT_FLIGHT = 2
_FIT_SUMS = 10
START_FIT_COUNT = len(START_FIT_NAMES)

#: The RK4 step of the headroom's march to the limit, s.
HEADROOM_STEP_S = 2.0
#: A Newton iterate of the steady state this far below the limit (degC) settles that the steady state is below it.
_SETTLED_C = 1e-6
_COMPLEX_STEP = 1e-30

DETECTOR_SETTINGS = np.dtype(
    [
        ("on", "?"),
        ("threshold", "f8"),
        ("reference", "f8"),
        ("warmup_s", "f8"),
        ("suspect_fraction", "f8"),
        ("block_s", "f8"),
        ("baseline_s", "f8"),
        ("delay_blocks", "i8"),
        ("freeze", "?"),
        ("scale_s", "f8"),
        ("scale_floor", "f8"),
    ]
)
DETECTOR_STATE = np.dtype(
    [
        ("started", "?"),
        ("start_s", "f8"),
        ("block_end_s", "f8"),
        ("sum", "f8"),
        ("count", "i8"),
        ("statistic", "f8"),
        ("baseline", "f8"),
        ("scale", "f8"),
        ("learned", "f8"),
        ("steady", "?"),
        ("alarm_s", "f8"),
        ("queued", "i8"),  # block means in the baseline's delay line (the ring)
        ("head", "i8"),  # the oldest of them in the ring
    ]
)
#: A cylinder's engine-event limits (config ``events:``, under its keys' names; pipeline/events.py) and the
#: inputs only the events read.
EVENT_SETTINGS = np.dtype(
    [
        ("enabled", "?"),
        ("shock_cooling_c_per_min", "f8"),  # the CHT rate below minus this is shock cooling
        ("shock_cooling_min_s", "f8"),
        ("cht_divergence_c", "f8"),  # the CHT estimate this far from the median of the others' diverges
        ("divergence_min_s", "f8"),
        ("cht_limit_c", "f8"),
        ("exceedance_min_s", "f8"),
        ("egt_slot", "i8"),  # its EGT in Engine.values (-1: not mapped)
        ("egt_stale_s", "f8"),
        ("egt_divergence_c", "f8"),  # beyond the cylinder's normal offset from the others' median (learned)
        ("egt_divergence_from_c", "f8"),  # counted while the median EGT is above this (at power)
        ("egt_normal_s", "f8"),  # the normal offset's averaging time, and how long it learns before counting
        ("egt_limit_c", "f8"),
        ("oil_slot", "i8"),  # the oil temperature (-1: not mapped; watched on cylinder 1's record)
        ("oil_stale_s", "f8"),
        ("oil_limit_c", "f8"),
        ("valve_amplitude_c", "f8"),  # the exhaust-valve advisory: EGT oscillation, peak to peak
        ("valve_min_s", "f8"),
    ]
)
#: One condition of one cylinder being watched: since when it holds, when it last held, its worst value, and
#: whether its start was written (it has held for its minimum time).
EVENT_TRACKER = np.dtype([("active", "?"), ("start_s", "f8"), ("last_s", "f8"), ("peak", "f8"), ("announced", "?")])
#: One event record (pipeline/events.py: the kind is an index into EVENT_KINDS, the cylinder 1-based;
#: ``ongoing``: its start, written once the condition has held for its minimum time, else its end).
EVENT = np.dtype(
    [("time_s", "f8"), ("kind", "i8"), ("cylinder", "i8"), ("value", "f8"), ("limit", "f8"), ("duration_s", "f8"),
     ("ongoing", "?")]
)  # fmt: skip
_SHOCK_COOLING = EVENT_KINDS.index("shock_cooling")
_CHT_DIVERGENCE = EVENT_KINDS.index("cht_divergence")
_CHT_EXCEEDANCE = EVENT_KINDS.index("cht_exceedance")
_EGT_DIVERGENCE = EVENT_KINDS.index("egt_divergence")
_EGT_EXCEEDANCE = EVENT_KINDS.index("egt_exceedance")
_OIL_EXCEEDANCE = EVENT_KINDS.index("oil_exceedance")
_VALVE_ADVISORY = EVENT_KINDS.index("valve_advisory")
#: EGT divergence: each cylinder's normal EGT offset is learned per power band (the power fraction of the
#: heat map's x input, estimation/regions.py: below 0.5, below 0.8, above; unknown: the middle one), and
#: only at steady power: the fraction within EGT_STEADY_FRACTION of where it was when it last moved by more,
#: for EGT_STEADY_S or longer (a power change moves the cylinders' EGTs at different speeds).
EGT_BANDS = 3
EGT_BAND_EDGES = (0.5, 0.8)
EGT_STEADY_S = 30.0
EGT_STEADY_FRACTION = 0.05
#: The exhaust-valve advisory's band, 0.5-3 cycles/min: the EGT's low-pass at 3 cycles/min minus its low-pass
#: at 0.5 cycles/min (first-order, time constants 60 / (2 pi f), s); their difference passes the band at a
#: gain of 0.58-0.70, VALVE_BAND_GAIN its middle, by which the amplitude is divided.
VALVE_FAST_S = 60.0 / (2.0 * math.pi * 3.0)
VALVE_SLOW_S = 60.0 / (2.0 * math.pi * 0.5)
VALVE_BAND_GAIN = 0.64
#: The band's mean square is a first-order average with this time constant, s; the amplitude is known once
#: the band-pass has run twice as long.
VALVE_WINDOW_S = 30.0
CYLINDER_SETTINGS = np.dtype(
    [
        ("cht_slot", "i8"),  # its CHT reading in Engine.values
        ("cht_check", "i8"),  # its CHT's stale check (bit of the stale mask)
        ("dt_s", "f8"),
        ("process_var", "f8"),
        ("measurement_var", "f8"),
        ("sigmoid_a", "f8"),
        ("sigmoid_b", "f8"),
        ("quantum_c", "f8"),
        ("deviation_time_s", "f8"),
        ("initial_var", "f8"),
        ("use_deviation", "?"),
        ("reset_code", "i8"),
        ("iso_estimator", "?"),  # cbekf-iso: the estimator is the isolation filter itself
        ("iso_initial_cht_var", "f8"),
        ("iso_initial_gamma_var", "f8"),
        ("stale_limit_s", "f8"),
        ("stuck_after_s", "f8"),
        ("stuck_change_c", "f8"),
        ("cht_limit_c", "f8"),
        ("estimator_symptom", "?"),  # the detector watches the estimator's deviation (else the isolation's)
        ("n_x", "i8"),  # heat-map breakpoints (the padded coefficient arrays' used part)
        ("n_y", "i8"),
        ("detector", DETECTOR_SETTINGS),
        ("cross", DETECTOR_SETTINGS),
        ("nominal", DETECTOR_SETTINGS),  # the test against the engine's reference (on: calibrated)
        ("nominal_level", "f8", (REGION_COUNT,)),  # its level per region, symptom unit (nan: none there)
        ("start_fit_mean", "f8", (START_FIT_COUNT,)),  # the reference's start fits (START_FIT_NAMES; nan: none)
        ("start_fit_spread", "f8", (START_FIT_COUNT,)),  # their spread across its nominal flights
        ("events", EVENT_SETTINGS),
    ]
)
CYLINDER_STATE = np.dtype(
    [
        ("running", "?"),  # supervisor: the filters are initialised
        ("stale_since_s", "f8"),
        ("changed_s", "f8"),
        ("last_reading_c", "f8"),
        ("model_low_c", "f8"),
        ("model_high_c", "f8"),
        ("readings", "i8"),  # valid CHT values fed
        ("readings_used", "i8"),
        ("pending", "?"),  # a reading arrived since the last filter call
        ("last_call_s", "f8"),
        ("ref", "f8", (7,)),  # the open-loop reference: its CHT [0] and heat path [2] (FilterState places)
        ("ref_drive", "f8", (5,)),
        ("est", "f8", (7,)),
        ("est_drive", "f8", (5,)),
        ("iso", "f8", (13,)),
        ("iso_drive", "f8", (5,)),
        ("cht_est_c", "f8"),  # held between filter calls
        ("deviation", "f8"),
        ("gamma_q", "f8"),
        ("gamma_d", "f8"),
        ("iso_deviation", "f8"),
        ("model_c", "f8"),
        ("headroom_s", "f8"),
        ("cht_rate_c_per_min", "f8"),
        ("detector_on", "?"),  # since the first initialisation
        ("on_s", "f8"),  # when: the engine's start for the regions, s
        ("sensitivity", "f8", (2,)),  # the open-loop reference's CHT per unit gamma_Q and gamma_D, degC
        ("cold", "i8"),  # the cold start (COLD_START_LOSS_SHARE): COLD_BEFORE, COLD_HOLDS, COLD_OVER
        ("fit_sums", "f8", (3, _FIT_SUMS)),  # per window (cold start, settle, flight) its least squares' sums
        ("start_fit", "f8", (START_FIT_COUNT,)),  # the fits so far (START_FIT_NAMES; nan: not yet)
        ("detector", DETECTOR_STATE),
        ("cross", DETECTOR_STATE),
        ("nominal", DETECTOR_STATE),
        ("shock", EVENT_TRACKER),  # the engine events' conditions (events_step)
        ("divergence", EVENT_TRACKER),
        ("cht_high", EVENT_TRACKER),
        ("egt_divergence", EVENT_TRACKER),
        ("egt_high", EVENT_TRACKER),
        ("oil_high", EVENT_TRACKER),
        ("valve", EVENT_TRACKER),
        ("egt_fast", "f8"),  # the EGT's band-pass (valve_band): two low-passes, the mean square of their difference
        ("egt_slow", "f8"),
        ("egt_band_ms", "f8"),
        ("egt_band_s", "f8"),  # how long the band-pass has run, s
        ("egt_offset", "f8", (EGT_BANDS,)),  # its EGT's normal offset from the others' median per power band, degC
        ("egt_offset_s", "f8", (EGT_BANDS,)),  # how long each has been learned, s
        ("power_held", "f8"),  # cylinder 1's record: the power fraction the steady power holds near (nan: none yet)
        ("power_steady_s", "f8"),  # cylinder 1's record: how long the power has stayed near it, s
    ]
)
#: One cylinder's result of a step: a field per ``cylinder`` row of the output table (what the health
#: outputs are made of; a state as its code), then what the replay's traces keep.
CYLINDER_OUTPUT = np.dtype(
    [
        *output_fields(),
        ("code", "i8"),  # the supervisor's code
        ("fed", "f8"),  # what its detector was fed (nan: nothing)
        ("cross_fed", "f8"),
        ("region", "i8"),  # the operating region (estimation/regions.py; -1: not started)
        ("start_fit", "f8", (START_FIT_COUNT,)),  # the start fits so far (calibrate learns their nominal spread)
    ]
)
#: The schedule and its counters.
CLOCK = np.dtype(
    [
        ("started", "?"),
        ("origin_s", "f8"),
        ("now_s", "f8"),
        ("k", "i8"),
        ("steps", "i8"),
        ("restarts", "i8"),
        ("dt_s", "f8"),
        ("filter_period", "i8"),
        ("headroom_period", "i8"),
        ("row_period", "i8"),
        ("status_slot", "i8"),  # the ECU's CHT sensor status (-1: none)
        ("min_c", "f8"),  # a plausible CHT reading
        ("max_c", "f8"),
        ("mixture", "i8"),  # the model's mixture index: 0 none (nan), 1 EGT, 2 fuel per revolution, 3 EGT - OAT,
        # 4 the log of the fuel/air ratio
        ("cross", "?"),  # cross-cylinder detectors on
    ]
)


class Engine(NamedTuple):
    """The arrays of one engine's pipeline (built by :mod:`ecu_monitor.pipeline.engine`)."""

    clock: Any  # CLOCK[1]
    values: Any  # float64[slots]: the held value of each decoded input
    stamps: Any  # float64[slots]: when it was fed (nan: never)
    early: Any  # bool[slots]: fed before the clock started
    check_slot: Any  # int64[checks]: the stale checks (bit j of the stale mask)
    check_limit_s: Any  # float64[checks]
    check_model: Any  # bool[checks]: a model input (stale: every cylinder's inputs are)
    model_slots: Any  # int64[5]: heat-map x, y, altitude, airspeed, OAT
    mixture_slots: Any  # int64[5]: the index's columns (model/effects.py MIXTURE_COLUMNS), unused ones 0
    open_values: Any  # float64[]: the CHT sensor status values meaning "open"
    settings: Any  # CYLINDER_SETTINGS[cylinders]
    state: Any  # CYLINDER_STATE[cylinders]
    rings: Any  # float64[cylinders, 2, capacity]: each detector's baseline delay line
    coeff_scalars: Any  # float64[cylinders, n]: each model's packed coefficients
    heat_values: Any  # float64[cylinders, n_x, n_y] (padded)
    x_breakpoints: Any  # float64[cylinders, n_x]
    y_breakpoints: Any  # float64[cylinders, n_y]
    iso_model: Any  # float64[cylinders, 4]
    iso_config: Any  # float64[cylinders, 7]
    output: Any  # CYLINDER_OUTPUT[cylinders]: this step's results
    scratch: Any  # float64[24]: the filters' scratch (10 free, out 3, a drive 5, the inputs u 6)
    symptoms: Any  # float64[2, cylinders]: the cross-cylinder step's scratch
    events: Any  # EVENT[capacity]: the events written since the owner last took them
    event_count: Any  # int64[2]: events written, events dropped (the buffer was full)


class Rows(NamedTuple):
    """The output table: one row per ``row_period`` steps (the steps ``k`` with ``k % row_period == 0``)."""

    count: Any  # int64[1]: rows written
    k: Any  # int64[capacity]: the step
    time_s: Any  # float64[capacity]
    stale: Any  # int64[capacity]: the stale mask (bit j: stale check j)
    cylinders: Any  # CYLINDER_OUTPUT[capacity, cylinders]


class Traces(NamedTuple):
    """Per step (replay, when asked): the step time and each cylinder's result (the detectors' feeds);
    capacity 0 = off."""

    count: Any  # int64[1]
    time_s: Any  # float64[capacity]
    restart: Any  # int64[capacity]: the clock restarts before the step
    model_c: Any  # float64[capacity, cylinders]: the open-loop reference, held
    oat_c: Any  # float64[capacity]: the held OAT
    detector_on: Any  # bool[capacity, cylinders]
    cylinders: Any  # CYLINDER_OUTPUT[capacity, cylinders]


def borrowed(records: Any) -> Any:
    """The records (a tuple of arrays) as borrowed views: the same data, no reference counted (compiled:
    the arrays' meminfo and parent pointers cleared, as numba's own views of a record's nested arrays).
    Only for the duration of a call whose caller holds the arrays; never returned to Python."""
    return records


@intrinsic
def _borrowed_views(typingctx: Any, records: Any) -> Any:
    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        value = args[0]
        for index, member in enumerate(records.types):
            if isinstance(member, types.Array):
                array = context.make_array(member)(context, builder, builder.extract_value(value, index))
                array.meminfo = cgutils.get_null_value(array.meminfo.type)
                array.parent = cgutils.get_null_value(array.parent.type)
                value = builder.insert_value(value, array._getvalue(), index)
        return value  # a new value that owns no reference: nothing to count

    return records(records), codegen


@overload(borrowed)
def _borrowed_compiled(records: Any) -> Any:
    def implementation(records: Any) -> Any:  # the same parameters as borrowed's, as numba asks
        return _borrowed_views(records)  # type: ignore[call-arg]  # typingctx: numba passes it

    return implementation


# ------------------------------------------------------------------------------------------------ the rules


@njit(nogil=False)
def _reset_detector(d: Any) -> None:
    d["started"] = False
    d["start_s"] = np.nan
    d["block_end_s"] = np.nan
    d["sum"] = 0.0
    d["count"] = 0
    d["statistic"] = 0.0
    d["baseline"] = np.nan
    d["scale"] = np.nan
    d["learned"] = 0.0
    d["steady"] = True
    d["alarm_s"] = np.nan
    d["queued"] = 0
    d["head"] = 0


@njit(nogil=False)
def detector_verdict(d: Any, s: Any) -> int:
    """The detector's state: 0 NOMINAL, 1 SUSPECT, 2 DEGRADED (latched from the first alarm)."""
    if not math.isnan(d["alarm_s"]):
        return 2
    return 1 if d["statistic"] >= s["suspect_fraction"] * s["threshold"] else 0


@njit(nogil=False)
def detector_step(d: Any, s: Any, ring: Any, t_s: float, symptom: float) -> int:
    """Feed one symptom sample (nan: skipped) at t_s (s) to the CUSUM ``d`` (DETECTOR_STATE) with
    settings ``s``; returns the state. Samples are averaged over blocks [start + warmup + i block_s, ...
    + block_s); a block closes at the first sample at or after its end, blocks without a sample count
    as empty; the statistic moves once per closed block (estimation/detection.py: the CUSUM update)."""
    if not d["started"]:
        d["started"] = True
        d["start_s"] = t_s
        d["block_end_s"] = t_s + s["warmup_s"] + s["block_s"]
    if t_s < d["start_s"] + s["warmup_s"]:
        return detector_verdict(d, s)
    if t_s >= d["block_end_s"] - 1e-9:  # this sample opens a new block: close the previous one(s)
        closed = math.floor((t_s - d["block_end_s"]) / s["block_s"] + 1e-9) + 1
        capacity = ring.shape[0]
        for j in range(closed):
            mean = np.nan
            if j == 0 and d["count"] > 0:
                mean = d["sum"] / d["count"]
            ring[(d["head"] + d["queued"]) % capacity] = mean  # into the delay line
            d["queued"] += 1
            lagged = np.nan
            if d["queued"] > s["delay_blocks"]:  # the oldest leaves it for the baseline
                lagged = ring[d["head"]]
                d["head"] = (d["head"] + 1) % capacity
                d["queued"] -= 1
            d["statistic"], d["baseline"], d["scale"], d["learned"] = cusum_step(
                d["statistic"],
                d["baseline"],
                d["scale"],
                d["learned"],
                mean,
                lagged,
                s["reference"],
                s["block_s"],
                s["baseline_s"],
                d["steady"] or math.isnan(mean),
                s["freeze"],
                s["scale_s"],
                s["scale_floor"],
            )
            d["steady"] = True
            if d["statistic"] >= s["threshold"] and math.isnan(d["alarm_s"]):
                d["alarm_s"] = t_s
        d["sum"] = 0.0
        d["count"] = 0
        d["block_end_s"] += s["block_s"] * closed
    if math.isfinite(symptom):
        d["sum"] += symptom
        d["count"] += 1
    return detector_verdict(d, s)


@njit(nogil=False)
def _steady_state_c(
    heat: float, ambient: float, conductance: float, radiative: float, offset: float, below: float
) -> float:
    """The CHT where heat in (W) equals heat out (Newton on the balance from the convective-only solution,
    an upper bound; complex-step slope); stops once a step is below 1e-9 degC or an iterate below ``below``."""
    temp = ambient + heat / conductance
    for _ in range(60):
        lost = dissipation(complex(temp, _COMPLEX_STEP), ambient, conductance, radiative, offset)
        change = (lost.real - heat) / (lost.imag / _COMPLEX_STEP)
        temp = temp - change
        if not abs(change) > 1e-9 or temp < below:
            break
    return temp


@njit(nogil=False)
def headroom_s(cht_c: float, drive: Any, coeffs: Any, gamma_q: float, gamma_d: float, limit_c: float) -> float:
    """Seconds until the CHT reaches ``limit_c`` at the held drive (Drive order: q_sl0, altitude gain,
    ambient, conductance, heat gain), the heat path in steady state: 0 at or over the limit,
    HEADROOM_CAP_S when the steady state is below it; else the model's RK4 march (HEADROOM_STEP_S) with
    the crossing interpolated linearly inside the step."""
    if not limit_c - cht_c > 0.0:
        return 0.0
    q_sl0, altitude_gain, ambient, conductance, heat_gain = drive[0], drive[1], drive[2], drive[3], drive[4]
    heat = gamma_q * gamma_d * heat_gain * altitude_gain * q_sl0
    if heat >= 0.0 and conductance != 0.0 and ambient + heat / conductance < limit_c:
        return HEADROOM_CAP_S  # the convective-only solution bounds the steady state from above
    radiative = coeffs.radiative_conductance
    offset = coeffs.radiation_offset_c
    if _steady_state_c(heat, ambient, conductance, radiative, offset, limit_c - _SETTLED_C) < limit_c:
        return HEADROOM_CAP_S
    if _steady_state_c(heat, ambient, conductance, radiative, offset, -np.inf) < limit_c:
        return HEADROOM_CAP_S
    temp = cht_c
    pade = 2.0 * q_sl0
    elapsed = 0.0
    while elapsed < HEADROOM_CAP_S:
        new_temp, pade = rk4(
            temp,
            pade,
            q_sl0,
            heat_gain * altitude_gain,
            ambient,
            conductance,
            coeffs.c_w,
            coeffs.tau_w,
            radiative,
            offset,
            gamma_q,
            gamma_d,
            HEADROOM_STEP_S,
        )
        if new_temp >= limit_c:
            fraction = (limit_c - temp) / (new_temp - temp) if new_temp > temp else 1.0
            crossing = elapsed + fraction * HEADROOM_STEP_S
            return crossing if crossing <= HEADROOM_CAP_S else HEADROOM_CAP_S
        temp = new_temp
        elapsed += HEADROOM_STEP_S
    return HEADROOM_CAP_S


@njit(nogil=False)
def _cht_rate(st: Any, cfg: Any, coeffs: Any) -> float:
    """The rate of change of the estimated CHT, degC/min: the model's heat balance at the estimate (its CHT
    and heat-path state, the drive of the latest inputs, the isolation filter's gammas)."""
    if cfg["iso_estimator"]:
        pade = st["iso"][3]
        drive = st["iso_drive"]
    else:
        pade = st["est"][2]
        drive = st["est_drive"]
    rate, _ = derivatives(
        st["cht_est_c"], pade, drive[0], drive[4] * drive[1], drive[2], drive[3], coeffs.c_w, coeffs.tau_w,
        coeffs.radiative_conductance, coeffs.radiation_offset_c, st["gamma_q"], st["gamma_d"],
    )  # fmt: skip
    return 60.0 * rate


@njit(nogil=False)
def _drive_at(u: Any, coeffs: Any, drive: Any) -> None:
    """The model's drive at the inputs u (6) into drive (5, Drive order)."""
    drive[0], drive[1], drive[2], drive[3], drive[4] = drive_at(u, coeffs)


@njit(nogil=False)
def _stop_cylinder(st: Any) -> None:
    """Estimation and detection start afresh (at start and after a clock restart)."""
    st["running"] = False
    st["stale_since_s"] = np.nan
    st["changed_s"] = np.nan
    st["last_reading_c"] = np.nan
    st["model_low_c"] = np.nan
    st["model_high_c"] = np.nan
    st["pending"] = False
    st["last_call_s"] = np.nan
    st["cht_est_c"] = np.nan
    st["deviation"] = np.nan
    st["gamma_q"] = np.nan
    st["gamma_d"] = np.nan
    st["iso_deviation"] = np.nan
    st["model_c"] = np.nan
    st["headroom_s"] = np.nan
    st["cht_rate_c_per_min"] = np.nan
    st["detector_on"] = False
    st["sensitivity"][:] = 0.0
    st["cold"] = COLD_BEFORE
    st["fit_sums"][:] = 0.0
    st["start_fit"][:] = np.nan
    _reset_detector(st["detector"])
    _reset_detector(st["cross"])
    _reset_detector(st["nominal"])
    st["on_s"] = np.nan


@njit(nogil=False)
def _initialise_filters(eng: Engine, i: int, u: Any, time_s: float, reading: float, coeffs: Any) -> None:
    """The reference, the estimator and the isolation filter start from the reading at the inputs u."""
    eng_settings = eng.settings
    eng_state = eng.state
    st = eng_state[i]
    cfg = eng_settings[i]
    _drive_at(u, coeffs, st["ref_drive"])
    pade = 2.0 * st["ref_drive"][0]
    level = level_of(reading, cfg["quantum_c"])
    for filt, drive in ((st["ref"], st["ref_drive"]), (st["est"], st["est_drive"])):
        filt[0] = reading
        filt[1] = cfg["initial_var"]
        filt[2] = pade
        filt[3] = 0.0
        filt[4] = reading
        filt[5] = 0.0
        filt[6] = level
        drive[:] = st["ref_drive"]
    st["iso"][:] = 0.0
    st["iso"][0] = reading
    st["iso"][1] = 1.0
    st["iso"][2] = 1.0
    st["iso"][3] = pade
    st["iso"][4] = cfg["iso_initial_cht_var"]
    st["iso"][8] = cfg["iso_initial_gamma_var"]
    st["iso"][12] = cfg["iso_initial_gamma_var"]
    st["iso_drive"][:] = st["ref_drive"]
    st["sensitivity"][:] = 0.0  # the reference starts afresh from the reading
    st["last_call_s"] = time_s


@njit(nogil=False)
def _ekf_call(state: Any, drive: Any, next_drive: Any, cfg: Any, cs: Any, hv: Any, xb: Any, yb: Any, z: float,
              measured: bool, result: Any, use_deviation: bool, reset_code: int, steps: int) -> None:  # fmt: skip
    """One filter period of an EKF-family filter (the reference or the estimator) on its record fields."""
    live_ekf(state, drive, next_drive, result, z, measured, cs, hv, xb, yb, cfg["dt_s"], cfg["process_var"],
             cfg["measurement_var"], cfg["sigmoid_a"], cfg["sigmoid_b"], cfg["quantum_c"], cfg["deviation_time_s"],
             use_deviation, reset_code, steps)  # fmt: skip


@njit(nogil=False)
def _reference_steps(ref: Any, drive: Any, next_drive: Any, coeffs: Any, dt_s: float, steps: int) -> None:
    """The open-loop reference (the model alone, no reading): ``steps`` RK4 steps of dt_s (s) of its CHT
    (``ref[0]``, degC) and heat path (``ref[2]``, W) with the held ``drive``; then ``next_drive`` is held."""
    x = ref[0]
    w = ref[2]
    for _ in range(steps):
        x, w = rk4(x, w, drive[0], drive[4] * drive[1], drive[2], drive[3], coeffs.c_w, coeffs.tau_w,
                   coeffs.radiative_conductance, coeffs.radiation_offset_c, 1.0, 1.0, dt_s)  # fmt: skip
    ref[0] = x
    ref[2] = w
    drive[:] = next_drive


@njit(nogil=False, inline=True)
def cylinder_step(
    eng: Engine, i: int, u: Any, time_s: float, any_stale: bool, reading_bad: bool, call: bool, headroom_due: bool
) -> None:
    """One step of cylinder i at time_s (s) with the model inputs u (6): its result in ``eng.output[i]``."""
    eng_coeff_scalars = eng.coeff_scalars
    eng_heat_values = eng.heat_values
    eng_iso_config = eng.iso_config
    eng_iso_model = eng.iso_model
    eng_output = eng.output
    eng_rings = eng.rings
    eng_scratch = eng.scratch
    eng_settings = eng.settings
    eng_state = eng.state
    eng_values = eng.values
    eng_x_breakpoints = eng.x_breakpoints
    eng_y_breakpoints = eng.y_breakpoints
    st = eng_state[i]
    cfg = eng_settings[i]
    out = eng_output[i]
    n_x = cfg["n_x"]
    n_y = cfg["n_y"]
    cs = eng_coeff_scalars[i]
    hv = eng_heat_values[i, :n_x, :n_y]
    xb = eng_x_breakpoints[i, :n_x]
    yb = eng_y_breakpoints[i, :n_y]
    coeffs = unpack_coefficients(cs, hv, xb, yb)
    result = eng_scratch[10:13]
    reading = eng_values[cfg["cht_slot"]]
    new_reading = st["readings"] > st["readings_used"]
    st["readings_used"] = st["readings"]
    call = call and st["running"]
    sv = SupervisorState(
        st["running"], st["stale_since_s"], st["changed_s"], st["last_reading_c"], st["model_low_c"], st["model_high_c"]
    )
    est_c = deviation = gamma_q = gamma_d = iso_deviation = np.nan
    drive = eng_scratch[13:18]  # the model's drive at this step's inputs, once for every filter and headroom
    drive_fresh = False
    if call:  # the filter period: the open-loop reference first (its CHT is the stuck-probe test's model)
        steps = round((time_s - st["last_call_s"]) / cfg["dt_s"])
        _drive_at(u, coeffs, drive)
        drive_fresh = True
        _sensitivity_steps(st, coeffs, steps * cfg["dt_s"])
        _reference_steps(st["ref"], st["ref_drive"], drive, coeffs, cfg["dt_s"], steps)
        model_c = st["ref"][0]
    else:
        model_c = st["model_c"] if st["running"] else reading
    st["pending"] = st["pending"] or new_reading
    sv, code, action = supervise(sv, time_s, any_stale, new_reading, reading, reading_bad, model_c,
                                 cfg["stale_limit_s"], cfg["stuck_after_s"], cfg["stuck_change_c"])  # fmt: skip
    if call:  # then the estimator and the isolation filter, with the reading the supervisor lets through
        if action != ACTION_NONE:
            measured = st["pending"] and code == CODE_NOMINAL and math.isfinite(reading)
            z = reading if measured else np.nan
            if not cfg["iso_estimator"]:
                _ekf_call(st["est"], st["est_drive"], drive, cfg, cs, hv, xb, yb, z, measured, result,
                          cfg["use_deviation"], cfg["reset_code"], steps)  # fmt: skip
                est_c = st["est"][0]
                deviation = st["est"][3] / cfg["dt_s"] if cfg["use_deviation"] else 0.0
            live_isolation(st["iso"], st["iso_drive"], drive, result, z, measured, steps, eng_iso_model[i],
                           eng_iso_config[i])  # fmt: skip
            if cfg["iso_estimator"]:  # its estimate is the isolation filter's own
                est_c = st["iso"][0]
                deviation = result[2]
            gamma_q = st["iso"][1]
            gamma_d = st["iso"][2]
            iso_deviation = result[2]
            if measured and st["detector_on"]:
                _add_fit_sample(st, coeffs, z, time_s - st["on_s"], cfg["measurement_var"])
        st["last_call_s"] = time_s
    st["running"] = sv.running
    st["stale_since_s"] = sv.stale_since_s
    st["changed_s"] = sv.changed_s
    st["last_reading_c"] = sv.last_reading_c
    st["model_low_c"] = sv.model_low_c
    st["model_high_c"] = sv.model_high_c
    if action == ACTION_NONE:
        st["cht_est_c"] = st["deviation"] = st["gamma_q"] = st["gamma_d"] = st["iso_deviation"] = st["model_c"] = np.nan
        st["cht_rate_c_per_min"] = np.nan
    elif action == ACTION_INITIALISE:
        _initialise_filters(eng, i, u, time_s, reading, coeffs)
        st["cht_est_c"] = reading
        st["deviation"] = 0.0
        st["gamma_q"] = 1.0
        st["gamma_d"] = 1.0
        st["iso_deviation"] = 0.0
        st["model_c"] = reading
        st["pending"] = False
        st["headroom_s"] = np.nan
        if not st["detector_on"]:
            st["on_s"] = time_s
        st["detector_on"] = True
        st["cht_rate_c_per_min"] = _cht_rate(st, cfg, coeffs)
    elif call:
        st["pending"] = False
        st["cht_est_c"] = est_c
        st["deviation"] = deviation
        st["gamma_q"] = gamma_q
        st["gamma_d"] = gamma_d
        st["iso_deviation"] = iso_deviation
        st["model_c"] = model_c
        st["cht_rate_c_per_min"] = _cht_rate(st, cfg, coeffs)
    if action != ACTION_NONE and not math.isfinite(st["cht_est_c"]):
        code = CODE_UNAVAILABLE  # the filter cannot estimate (it diverged): never NOMINAL, the detector not fed
    state = code
    fed = np.nan
    region = -1
    armed = 0
    if st["detector_on"]:
        power = power_fraction(u[0], xb[0], xb[n_x - 1])
        region = region_of(time_s - st["on_s"], u[3], power)
        symptom = st["deviation"] if cfg["estimator_symptom"] else st["iso_deviation"]
        fed = symptom if code == CODE_NOMINAL else np.nan
        verdict = detector_step(st["detector"], cfg["detector"], eng_rings[i, 0], time_s, fed)
        baseline = st["detector"]["baseline"]
        if time_s >= st["detector"]["start_s"] + cfg["detector"]["warmup_s"] and (
            cfg["detector"]["baseline_s"] <= 0.0 or not math.isnan(baseline)
        ):
            armed |= ARMED_BASELINE
        if cfg["nominal"]["on"]:  # against the engine's own reference, where it has a level (nan: not tested)
            level = cfg["nominal_level"][region]
            if not math.isnan(level):
                armed |= ARMED_REFERENCE
            verdict = max(verdict, detector_step(st["nominal"], cfg["nominal"], eng_rings[i, 2], time_s, fed - level))
        if code == CODE_NOMINAL:
            state = verdict
    if action == ACTION_NONE or not (
        math.isfinite(st["cht_est_c"]) and math.isfinite(st["gamma_q"]) and math.isfinite(st["gamma_d"])
    ):
        st["headroom_s"] = np.nan
    elif headroom_due:
        if not drive_fresh:
            _drive_at(u, coeffs, drive)
        st["headroom_s"] = headroom_s(st["cht_est_c"], drive, coeffs, st["gamma_q"], st["gamma_d"], cfg["cht_limit_c"])
    out["cht_meas_c"] = reading
    out["cht_est_c"] = st["cht_est_c"]
    out["deviation"] = st["deviation"]
    out["state"] = state
    out["gamma_q"] = st["gamma_q"]
    out["gamma_d"] = st["gamma_d"]
    out["headroom_s"] = st["headroom_s"]
    out["cht_rate_c_per_min"] = st["cht_rate_c_per_min"]
    out["code"] = code
    out["fed"] = fed
    out["cross_fed"] = np.nan
    out["region"] = region
    out["detector_armed"] = armed
    out["start_fit"][:] = st["start_fit"]
    gamma_q_sd = gamma_d_sd = np.nan
    isolable = False
    if st["running"] and math.isfinite(st["gamma_q"]):
        iso = st["iso"]
        gamma_q_sd = math.sqrt(max(iso[8], 0.0))
        gamma_d_sd = math.sqrt(max(iso[12], 0.0))
        declared = state == CODE_DEGRADED and region >= 0 and isolable_region(region)  # something to isolate, here
        call = start_fault_call(st, cfg, time_s - st["on_s"]) if declared else START_CALL_UNTOLD
        if call == START_CALL_NOT_FROM_START:  # the filter's split, where it can be told
            product = gamma_q_sd * gamma_d_sd
            correlation = iso[9] / product if product > 0.0 else -1.0
            isolable = (
                declared
                and gamma_q_sd <= ISOLATION_SD_MAX
                and gamma_d_sd <= ISOLATION_SD_MAX
                and correlation > ISOLATION_CORRELATION_MIN
            )
        elif call != START_CALL_UNTOLD:  # present from engine start: the product on the factor the regions name
            isolable = declared
            product = st["gamma_q"] * st["gamma_d"]
            out["gamma_q"] = product if call == START_CALL_HEAT else 1.0
            out["gamma_d"] = 1.0 if call == START_CALL_HEAT else product
    out["gamma_q_sd"] = gamma_q_sd
    out["gamma_d_sd"] = gamma_d_sd
    out["not_isolable"] = not isolable
    if not isolable:
        out["gamma_q"] = np.nan
        out["gamma_d"] = np.nan


#: :func:`start_fault_call`'s answers: not a fault from engine start (the isolation filter's split holds),
#: present from start but not told apart, gamma_Q (the heat in), gamma_D (the heat out).
START_CALL_NOT_FROM_START = 0
START_CALL_UNTOLD = 1
START_CALL_HEAT = 2
START_CALL_LOSS = 3


@njit(nogil=False)
def _sensitivity_steps(st: Any, coeffs: Any, dt_s: float) -> None:
    """Before the open-loop reference's ``dt_s`` (s) with its held drive: its sensitivities to gamma_Q and gamma_D
    (degC per unit gamma, at gamma = 1) over the same time, C_w ds/dt = u - D'(T) s with u the heat in (gamma_Q)
    or the heat out D(T) (gamma_D), exact for u and D' held at the period's start; the cold start ends the first
    time the loss's sensitivity exceeds COLD_START_LOSS_SHARE of the heat's, the heat's at least COLD_START_MIN_C
    (its fit is then final); it begins once the heat's exceeds the loss's by that share (the engine heats the
    head: not before it runs)."""
    ref = st["ref"]
    drive = st["ref_drive"]
    c_w = coeffs.c_w
    heat = drive[4] * drive[1] * (ref[2] - drive[0]) / c_w
    lost = dissipation(complex(ref[0], _COMPLEX_STEP), drive[2], drive[3], coeffs.radiative_conductance,
                       coeffs.radiation_offset_c)  # fmt: skip
    rate = lost.imag / _COMPLEX_STEP / c_w
    decay = math.exp(-rate * dt_s)
    gain = (1.0 - decay) / rate if rate > 0.0 else dt_s
    sens = st["sensitivity"]
    sens[0] = sens[0] * decay + heat * gain
    sens[1] = sens[1] * decay + lost.real / c_w * gain
    if st["cold"] == COLD_BEFORE and sens[1] < COLD_START_LOSS_SHARE * sens[0]:
        st["cold"] = COLD_HOLDS
    elif st["cold"] == COLD_HOLDS and sens[0] >= COLD_START_MIN_C and sens[1] > COLD_START_LOSS_SHARE * sens[0]:
        st["cold"] = COLD_OVER


@njit(nogil=False)
def _add_sums(sums: Any, x0: float, x1: float, x2: float, r: float) -> None:
    """One sample into a window's sums: count, the products of its regressors x (upper triangle) and x times r."""
    sums[0] += 1.0
    sums[1] += x0 * x0
    sums[2] += x0 * x1
    sums[3] += x0 * x2
    sums[4] += x1 * x1
    sums[5] += x1 * x2
    sums[6] += x2 * x2
    sums[7] += x0 * r
    sums[8] += x1 * r
    sums[9] += x2 * r


@njit(nogil=False)
def _fit2(sums: Any, noise_var: float) -> tuple[float, float, float]:
    """A window's least squares of r on x0 and x1: x0's factor for r, the same for x2 taken as r (what a fault in
    x2 would read as), and the factor's standard error for white noise of ``noise_var``; nan with fewer than 3
    samples or x0, x1 not independent."""
    det = sums[1] * sums[4] - sums[2] * sums[2]
    if sums[0] < 3.0 or not det > 1e-12 * sums[1] * sums[4]:
        return np.nan, np.nan, np.nan
    value = (sums[4] * sums[7] - sums[2] * sums[8]) / det
    other = (sums[4] * sums[3] - sums[2] * sums[5]) / det
    return value, other, math.sqrt(noise_var * sums[4] / det)


@njit(nogil=False)
def _product_fit(sums: Any, noise_var: float) -> tuple[float, float]:
    """The flight window's least squares of r on (s_Q, s_D, probe lag): the sum of the two gammas' factors (the
    product's excess, gamma_Q gamma_D - 1 to first order) and its standard error for white noise of ``noise_var``."""
    a, b, c, d, e, f = sums[1], sums[2], sums[3], sums[4], sums[5], sums[6]
    c11, c12, c13 = d * f - e * e, c * e - b * f, b * e - c * d  # the cofactors of the symmetric 3 x 3 matrix
    c22, c23 = a * f - c * c, b * c - a * e
    det = a * c11 + b * c12 + c * c13
    if sums[0] < 4.0 or not det > 1e-12 * a * d * f:
        return np.nan, np.nan
    value = ((c11 + c12) * sums[7] + (c12 + c22) * sums[8] + (c13 + c23) * sums[9]) / det
    return value, math.sqrt(max(noise_var * (c11 + 2.0 * c12 + c22) / det, 0.0))


@njit(nogil=False)
def _add_fit_sample(st: Any, coeffs: Any, reading: float, elapsed_s: float, noise_var: float) -> None:
    """One reading fed to the filters (the supervisor let it through), ``elapsed_s`` after engine start, into the
    start fits' windows: its residual over the open-loop reference against the reference's sensitivities and its
    rate (the probe lag's regressor: a lagging probe reads T - lag dT/dt). The cold start fits (s_Q, lag), the
    settle (from the cold start's end to SETTLE_END_S) fits (s_D, lag), the flight after the start region (from
    START_S: a fault that began in the first minutes is there in full by then) fits (s_Q, s_D, lag);
    ``start_fit`` holds each fit once its window has closed (the flight's: so far)."""
    ref = st["ref"]
    drive = st["ref_drive"]
    rate, _ = derivatives(ref[0], ref[2], drive[0], drive[4] * drive[1], drive[2], drive[3], coeffs.c_w,
                          coeffs.tau_w, coeffs.radiative_conductance, coeffs.radiation_offset_c, 1.0, 1.0)  # fmt: skip
    lag = -rate
    residual = reading - ref[0]
    s_q = st["sensitivity"][0]
    s_d = st["sensitivity"][1]
    sums = st["fit_sums"]
    fit = st["start_fit"]
    if st["cold"] == COLD_HOLDS:
        _add_sums(sums[_FIT_COLD], s_q, lag, s_d, residual)
    elif st["cold"] == COLD_OVER:
        if math.isnan(fit[_FIT_COLD]):
            fit[_FIT_COLD] = _fit2(sums[_FIT_COLD], noise_var)[0]
        if elapsed_s < SETTLE_END_S:
            _add_sums(sums[_FIT_SETTLE], s_d, lag, s_q, residual)
        elif math.isnan(fit[_FIT_SETTLE]):
            fit[_FIT_SETTLE] = _fit2(sums[_FIT_SETTLE], noise_var)[0]
    if elapsed_s >= START_S:
        _add_sums(sums[_FIT_FLIGHT], s_q, s_d, lag, residual)
        fit[_FIT_FLIGHT] = _product_fit(sums[_FIT_FLIGHT], noise_var)[0]


@njit(nogil=False)
def start_fault_call(st: Any, cfg: Any, elapsed_s: float) -> int:
    """The cause of a fault present from engine start, ``elapsed_s`` (s) after engine start, from the start fits
    (the open-loop residual against the model's sensitivities to gamma_Q and gamma_D, :func:`_add_fit_sample`)
    measured against their nominal mean and spread (``cfg``'s start_fit_mean and start_fit_spread, learned by
    calibrate; each spread widened by the fit's own standard error for the reading noise): START_CALL_HEAT
    (gamma_Q), START_CALL_LOSS (gamma_D), START_CALL_UNTOLD (not told apart), or START_CALL_NOT_FROM_START (the
    isolation filter's split holds: nothing at the start, a later onset; also without a reference).

    Untold until the settle window has closed (SETTLE_END_S). In the cold start the head is near the air: a heat
    fault g (the flight's product excess) reads as g on the heat's factor, a dissipation fault as k g (k: what a
    unit loss fault reads as there, small). A cause is named when the other's prediction misses by
    NOMINAL_SPREAD_Z^2 more in chi-square (a likelihood ratio of exp(NOMINAL_SPREAD_Z^2 / 2)) and its own
    prediction is not missed by more than NOMINAL_SPREAD_Z spreads (for gamma_Q: from below; a cold start above
    it is more heat, not another cause); gamma_D only when, besides, the settle (after the cold start) carries the
    fault in full (an onset after the cold start would not). Not from start when neither the cold start nor the
    settle is above NOMINAL_SPREAD_Z spreads."""
    mean = cfg["start_fit_mean"]
    spread = cfg["start_fit_spread"]
    if not (spread[0] >= 0.0 and spread[1] >= 0.0 and spread[2] >= 0.0):
        return START_CALL_NOT_FROM_START
    if elapsed_s < SETTLE_END_S:
        return START_CALL_UNTOLD
    sums = st["fit_sums"]
    noise_var = cfg["measurement_var"]
    heat_excess, loss_share, heat_se = _fit2(sums[_FIT_COLD], noise_var)
    settle, _, settle_se = _fit2(sums[_FIT_SETTLE], noise_var)
    product, product_se = _product_fit(sums[_FIT_FLIGHT], noise_var)
    if not (math.isfinite(heat_excess) and math.isfinite(loss_share) and math.isfinite(settle)
            and math.isfinite(product)):  # fmt: skip
        return START_CALL_UNTOLD
    a = heat_excess - mean[_FIT_COLD]
    c = settle - mean[_FIT_SETTLE]
    g = product - mean[_FIT_FLIGHT]
    var_a = spread[_FIT_COLD] ** 2 + heat_se**2
    var_c = spread[_FIT_SETTLE] ** 2 + settle_se**2
    var_g = spread[_FIT_FLIGHT] ** 2 + product_se**2
    bound = NOMINAL_SPREAD_Z * NOMINAL_SPREAD_Z
    if a * a <= bound * var_a and c * c <= bound * var_c:
        return START_CALL_NOT_FROM_START
    heat = (a - g) ** 2 / (var_a + var_g)
    loss = (a - loss_share * g) ** 2 / (var_a + loss_share * loss_share * var_g)
    if loss - heat >= bound and (a >= g or heat <= bound):
        return START_CALL_HEAT
    if heat - loss >= bound and loss <= bound and (c - g) ** 2 / (var_c + var_g) <= bound:
        return START_CALL_LOSS
    return START_CALL_UNTOLD


@njit(nogil=False)
def median_of_others(values: Any, i: int, scratch: Any) -> float:
    """The median of ``values`` other than ``values[i]`` (i = -1: of all), nan ones left out (nan: none left);
    ``scratch`` holds them (as long as ``values``)."""
    m = 0
    for j in range(values.shape[0]):
        if j != i and not math.isnan(values[j]):
            scratch[m] = values[j]
            m += 1
    if m == 0:
        return np.nan
    for a in range(1, m):  # sorted in place (an insertion sort: a few values, no allocation)
        x = scratch[a]
        b = a - 1
        while b >= 0 and scratch[b] > x:
            scratch[b + 1] = scratch[b]
            b -= 1
        scratch[b + 1] = x
    mid = m // 2
    return scratch[mid] if m % 2 else (scratch[mid - 1] + scratch[mid]) * 0.5


@njit(nogil=False)
def cross_step(eng: Engine, time_s: float) -> None:
    """The cross-cylinder detectors: each cylinder's symptom minus the median of the other cylinders'
    usable symptoms; a cylinder's state becomes the more severe of its two detectors' verdicts. The model
    error common to every cylinder (the operating point, the day) cancels; the median keeps one degraded
    cylinder out of the others' reference (docs/detection_isolation.md, section 10)."""
    eng_output = eng.output
    eng_rings = eng.rings
    eng_settings = eng.settings
    eng_state = eng.state
    eng_symptoms = eng.symptoms
    n = eng_state.shape[0]
    own = eng_symptoms[0]
    others = eng_symptoms[1]
    for i in range(n):
        st = eng_state[i]
        usable = st["detector_on"] and eng_output[i]["state"] <= CODE_DEGRADED
        symptom = st["deviation"] if eng_settings[i]["estimator_symptom"] else st["iso_deviation"]
        own[i] = symptom if usable else np.nan
    for i in range(n):
        cross = own[i] - median_of_others(own, i, others)
        st = eng_state[i]
        cfg = eng_settings[i]
        if not st["detector_on"] or not cfg["cross"]["on"]:
            continue
        eng_output[i]["cross_fed"] = cross
        verdict = detector_step(st["cross"], cfg["cross"], eng_rings[i, 1], time_s, cross)
        if eng_output[i]["state"] < verdict <= CODE_DEGRADED:
            eng_output[i]["state"] = verdict


@njit(nogil=False, inline=True)
def _reading_bad(eng: Engine, reading: float) -> bool:
    """An implausible CHT reading: outside [min_c, max_c], or the ECU's status says the probe is open."""
    eng_clock = eng.clock
    eng_open_values = eng.open_values
    eng_values = eng.values
    clock = eng_clock[0]
    if math.isnan(reading):
        return False
    if not clock["min_c"] <= reading <= clock["max_c"]:
        return True
    if clock["status_slot"] >= 0:
        status = eng_values[clock["status_slot"]]
        if not math.isnan(status):
            code = float(int(status))
            for value in eng_open_values:
                if code == value:
                    return True
    return False


@njit(nogil=False, inline=True)
def engine_step(eng: Engine, time_s: float, k: int) -> int:
    """Step k (1-based, at time_s) of every cylinder; returns the stale mask (bit j: stale check j)."""
    eng_check_limit_s = eng.check_limit_s
    eng_check_model = eng.check_model
    eng_check_slot = eng.check_slot
    eng_clock = eng.clock
    eng_mixture_slots = eng.mixture_slots
    eng_model_slots = eng.model_slots
    eng_scratch = eng.scratch
    eng_settings = eng.settings
    eng_stamps = eng.stamps
    eng_state = eng.state
    eng_values = eng.values
    clock = eng_clock[0]
    stale = 0
    model_stale = False
    for j in range(eng_check_slot.shape[0]):
        if not time_s - eng_stamps[eng_check_slot[j]] <= eng_check_limit_s[j]:  # never seen: nan, stale
            stale |= 1 << j
            model_stale = model_stale or eng_check_model[j]
    u = eng_scratch[18:24]
    for j in range(5):
        u[j] = eng_values[eng_model_slots[j]]
    if clock["mixture"] == 1:
        u[5] = eng_values[eng_mixture_slots[0]]
    elif clock["mixture"] == 2:  # fuel per revolution, mL/rev
        u[5] = eng_values[eng_mixture_slots[0]] * (1000.0 / 60.0) / max(eng_values[eng_mixture_slots[1]], 100.0)
    elif clock["mixture"] == 3:  # the EGT's rise over the intake air, degC
        u[5] = eng_values[eng_mixture_slots[0]] - eng_values[eng_mixture_slots[1]]
    elif clock["mixture"] == 4:  # the log of the fuel/air ratio (no fuel: -inf, the model's factor 1)
        u[5] = fuel_air_index(eng_values[eng_mixture_slots[0]], eng_values[eng_mixture_slots[1]],
                              eng_values[eng_mixture_slots[2]], eng_values[eng_mixture_slots[3]],
                              eng_values[eng_mixture_slots[4]])  # fmt: skip
    else:
        u[5] = np.nan
    call = k % clock["filter_period"] == 0
    headroom_due = k % clock["headroom_period"] == 0
    for i in range(eng_state.shape[0]):
        cfg = eng_settings[i]
        any_stale = model_stale or (stale >> cfg["cht_check"]) & 1 == 1
        reading_bad = _reading_bad(eng, eng_values[cfg["cht_slot"]])
        cylinder_step(eng, i, u, time_s, any_stale, reading_bad, call, headroom_due)
    if clock["cross"]:
        cross_step(eng, time_s)
    if call:  # the filter period: the CHT rate is new
        events_step(eng, time_s)
    return stale


# ------------------------------------------------------------------------------------------------ the engine events


@njit(nogil=False)
def _events_period_s(eng: Engine) -> float:
    """How often the events are checked, s: every filter period (when the CHT rate is new)."""
    clock = eng.clock[0]
    return clock["dt_s"] * clock["filter_period"]


@njit(nogil=False)
def _held_s(tr: Any, period_s: float) -> float:
    """How long the tracker's condition has held, s: from its start to the end of the last step it held in
    (``period_s``: how often the events are checked, s)."""
    return tr["last_s"] - tr["start_s"] + period_s


@njit(nogil=False)
def _write_event(log: Any, count: Any, tr: Any, kind: int, cylinder: int, limit: float, period_s: float) -> None:
    """The tracker's condition ended: its end record if its start was written (it lasted long enough:
    :func:`_track`); the tracker is free again."""
    tr["active"] = False
    if tr["announced"]:
        _record_event(log, count, tr, kind, cylinder, limit, False, period_s)


@njit(nogil=False)
def _record_event(
    log: Any, count: Any, tr: Any, kind: int, cylinder: int, limit: float, ongoing: bool, period_s: float
) -> None:
    """One event record of the tracker into ``log`` (``Engine.events``; ``count``: ``Engine.event_count``,
    written and dropped when the log is full)."""
    duration = _held_s(tr, period_s)
    n = count[0]
    if n >= log.shape[0]:
        count[1] += 1
        return
    e = log[n]
    e["time_s"] = tr["start_s"]
    e["kind"] = kind
    e["cylinder"] = cylinder
    e["value"] = tr["peak"]
    e["limit"] = limit
    e["duration_s"] = duration
    e["ongoing"] = ongoing
    count[0] = n + 1


@njit(nogil=False)
def _track(log: Any, count: Any, tr: Any, holds: bool, value: float, time_s: float, kind: int, cylinder: int,
           limit: float, min_s: float, period_s: float) -> None:  # fmt: skip
    """One step of a condition's tracker: it holds (its worst value is the one furthest from zero; its start
    record written into ``log`` when it has held for ``min_s``, s) or it ended (:func:`_write_event`)."""
    if holds:
        if not tr["active"]:
            tr["active"] = True
            tr["announced"] = False
            tr["start_s"] = time_s
            tr["peak"] = value
        elif abs(value) > abs(tr["peak"]):
            tr["peak"] = value
        tr["last_s"] = time_s
        if not tr["announced"] and _held_s(tr, period_s) >= min_s:
            tr["announced"] = True
            _record_event(log, count, tr, kind, cylinder, limit, True, period_s)
    elif tr["active"]:
        _write_event(log, count, tr, kind, cylinder, limit, period_s)


@njit(nogil=False)
def _fresh(values: Any, stamps: Any, slot: int, limit_s: float, time_s: float) -> float:
    """The held value of input ``slot`` (``Engine.values``, fed at ``Engine.stamps``, s) if it is mapped
    (slot >= 0), finite and fed within ``limit_s`` (s) of time_s; else nan."""
    if slot < 0:
        return np.nan
    value = values[slot]
    return value if math.isfinite(value) and time_s - stamps[slot] <= limit_s else np.nan


@njit(nogil=False)
def events_step(eng: Engine, time_s: float) -> None:
    """The engine events of this step (pipeline/events.py). On every cylinder whose CHT reading the
    supervisor lets through (NOMINAL code): shock cooling (the filter's CHT rate below minus its limit),
    CHT divergence (the estimate further than its limit from the median of the other such cylinders') and
    CHT exceedance (the estimate above its limit). On every fresh EGT: EGT divergence (from the median of
    the other fresh EGTs) and exceedance; the fresh oil temperature's exceedance (cylinder 0: the engine)."""
    eng_output = eng.output
    eng_settings = eng.settings
    eng_state = eng.state
    log = eng.events
    count = eng.event_count
    values = eng.values
    stamps = eng.stamps
    period_s = _events_period_s(eng)
    own = eng.symptoms[0]
    others = eng.symptoms[1]
    n = eng_state.shape[0]
    if not eng_settings[0]["events"]["enabled"]:
        return
    for i in range(n):
        cht = eng_state[i]["cht_est_c"]
        own[i] = cht if eng_output[i]["code"] == CODE_NOMINAL and math.isfinite(cht) else np.nan
    for i in range(n):
        es = eng_settings[i]["events"]
        st = eng_state[i]
        cht = own[i]
        usable = not math.isnan(cht)
        rate = st["cht_rate_c_per_min"]
        limit = -es["shock_cooling_c_per_min"]
        _track(log, count, st["shock"], usable and rate < limit, rate, time_s, _SHOCK_COOLING, i + 1, limit,
               es["shock_cooling_min_s"], period_s)  # fmt: skip
        _track(log, count, st["cht_high"], usable and cht > es["cht_limit_c"], cht, time_s, _CHT_EXCEEDANCE, i + 1,
               es["cht_limit_c"], es["exceedance_min_s"], period_s)  # fmt: skip
        apart = cht - median_of_others(own, i, others)
        _track(log, count, st["divergence"], abs(apart) > es["cht_divergence_c"], apart, time_s, _CHT_DIVERGENCE, i + 1,
               es["cht_divergence_c"], es["divergence_min_s"], period_s)  # fmt: skip
    for i in range(n):
        es = eng_settings[i]["events"]
        own[i] = _fresh(values, stamps, es["egt_slot"], es["egt_stale_s"], time_s)
    band, steady = _power_band(eng, period_s)
    at_power = steady and median_of_others(own, -1, others) > eng_settings[0]["events"]["egt_divergence_from_c"]
    for i in range(n):
        es = eng_settings[i]["events"]
        st = eng_state[i]
        egt = own[i]
        _track(log, count, st["egt_high"], egt > es["egt_limit_c"], egt, time_s, _EGT_EXCEEDANCE, i + 1,
               es["egt_limit_c"], es["exceedance_min_s"], period_s)  # fmt: skip
        beyond = egt_beyond_normal(st, egt - median_of_others(own, i, others), at_power, band, es["egt_normal_s"],
                                   period_s)  # fmt: skip
        _track(log, count, st["egt_divergence"], abs(beyond) > es["egt_divergence_c"], beyond, time_s,
               _EGT_DIVERGENCE, i + 1, es["egt_divergence_c"], es["divergence_min_s"], period_s)  # fmt: skip
    valve_advisory(eng, time_s, period_s)
    es = eng_settings[0]["events"]
    oil = _fresh(values, stamps, es["oil_slot"], es["oil_stale_s"], time_s)
    _track(log, count, eng_state[0]["oil_high"], oil > es["oil_limit_c"], oil, time_s, _OIL_EXCEEDANCE, 0,
           es["oil_limit_c"], es["exceedance_min_s"], period_s)  # fmt: skip


@njit(nogil=False)
def _power_band(eng: Engine, dt_s: float) -> tuple[int, bool]:
    """The power band of this step (EGT_BANDS) and whether the power has been steady (EGT_STEADY_S), from the
    heat map's x input (the step's u[0]); unknown power: the middle band, steady."""
    st = eng.state[0]
    xb = eng.x_breakpoints[0]
    power = power_fraction(eng.scratch[18], xb[0], xb[eng.settings[0]["n_x"] - 1])
    if math.isnan(power):
        return 1, True
    if math.isnan(st["power_held"]) or abs(power - st["power_held"]) > EGT_STEADY_FRACTION:
        st["power_held"] = power  # the power moved: steady from here
        st["power_steady_s"] = 0.0
    else:
        st["power_steady_s"] += dt_s
    band = 0 if power < EGT_BAND_EDGES[0] else 1 if power < EGT_BAND_EDGES[1] else 2
    return band, st["power_steady_s"] >= EGT_STEADY_S


@njit(nogil=False)
def egt_beyond_normal(st: Any, apart: float, at_power: bool, band: int, normal_s: float, dt_s: float) -> float:
    """How far cylinder record ``st``'s EGT is from its normal offset to the others' median in power band
    ``band``, degC (``apart``: its EGT minus that median now): the offset is learned at steady power
    (``at_power``), a first-order average with time constant ``normal_s`` (s), not while the cylinder
    diverges; nan otherwise, without an EGT, and until the band's offset has been learned for ``normal_s``
    (an engine's EGTs spread by their own amount, and by another at another power: the divergence is a
    change of it, docs/service.md, "Engine events")."""
    if not at_power or math.isnan(apart):
        return np.nan
    offsets = st["egt_offset"]
    learned = st["egt_offset_s"]
    if math.isnan(offsets[band]):
        offsets[band] = apart
        learned[band] = 0.0
    beyond = apart - offsets[band]
    if not st["egt_divergence"]["active"]:
        offsets[band] += beyond * min(dt_s / normal_s, 1.0)
        learned[band] += dt_s
    return beyond if learned[band] >= normal_s else np.nan


@njit(nogil=False)
def valve_band(st: Any, egt: float, dt_s: float) -> float:
    """One step of cylinder record ``st``'s EGT band-pass (0.5-3 cycles/min) with the fresh EGT (degC; nan:
    not fresh, the filters start afresh): its peak-to-peak amplitude over VALVE_WINDOW_S (degC, a sine's
    2 sqrt(2) RMS, divided by the band's gain; nan for the first 2 VALVE_WINDOW_S)."""
    if math.isnan(egt):
        st["egt_fast"] = st["egt_slow"] = np.nan
        return np.nan
    if math.isnan(st["egt_fast"]):
        st["egt_fast"] = st["egt_slow"] = egt
        st["egt_band_ms"] = 0.0
        st["egt_band_s"] = 0.0
    st["egt_fast"] += (egt - st["egt_fast"]) * min(dt_s / VALVE_FAST_S, 1.0)
    st["egt_slow"] += (egt - st["egt_slow"]) * min(dt_s / VALVE_SLOW_S, 1.0)
    band = st["egt_fast"] - st["egt_slow"]
    st["egt_band_ms"] += (band * band - st["egt_band_ms"]) * min(dt_s / VALVE_WINDOW_S, 1.0)
    st["egt_band_s"] += dt_s
    if st["egt_band_s"] < 2.0 * VALVE_WINDOW_S:
        return np.nan
    return 2.0 * math.sqrt(2.0 * st["egt_band_ms"]) / VALVE_BAND_GAIN


@njit(nogil=False)
def valve_advisory(eng: Engine, time_s: float, dt_s: float) -> None:
    """The exhaust-valve advisory: one cylinder's EGT oscillating in the band (:func:`valve_band`) by at least
    ``valve_amplitude_c`` peak to peak while every other cylinder's with a fresh EGT oscillates by less than
    half of it (steady power: a power change moves every EGT), for ``valve_min_s``; value: the largest
    amplitude (degC)."""
    eng_settings = eng.settings
    eng_state = eng.state
    amplitude = eng.symptoms[0]
    log = eng.events
    count = eng.event_count
    values = eng.values
    stamps = eng.stamps
    n = eng_state.shape[0]
    for i in range(n):
        es = eng_settings[i]["events"]
        amplitude[i] = valve_band(eng_state[i], _fresh(values, stamps, es["egt_slot"], es["egt_stale_s"], time_s), dt_s)
    for i in range(n):
        es = eng_settings[i]["events"]
        limit = es["valve_amplitude_c"]
        holds = n > 1 and amplitude[i] >= limit
        for j in range(n):
            if j != i and not amplitude[j] < 0.5 * limit:  # another oscillates too, or is not known
                holds = False
        _track(log, count, eng_state[i]["valve"], holds, amplitude[i], time_s, _VALVE_ADVISORY, i + 1, limit,
               es["valve_min_s"], dt_s)  # fmt: skip


@njit(nogil=False)
def close_events(eng: Engine) -> None:
    """End every condition still holding (the log ended): their events are written."""
    eng_settings = eng.settings
    eng_state = eng.state
    for i in range(eng_state.shape[0]):
        es = eng_settings[i]["events"]
        st = eng_state[i]
        for tr, kind, number, limit in (
            (st["shock"], _SHOCK_COOLING, i + 1, -es["shock_cooling_c_per_min"]),
            (st["cht_high"], _CHT_EXCEEDANCE, i + 1, es["cht_limit_c"]),
            (st["divergence"], _CHT_DIVERGENCE, i + 1, es["cht_divergence_c"]),
            (st["egt_high"], _EGT_EXCEEDANCE, i + 1, es["egt_limit_c"]),
            (st["egt_divergence"], _EGT_DIVERGENCE, i + 1, es["egt_divergence_c"]),
            (st["oil_high"], _OIL_EXCEEDANCE, 0, es["oil_limit_c"]),
            (st["valve"], _VALVE_ADVISORY, i + 1, es["valve_amplitude_c"]),
        ):
            if tr["active"]:
                _write_event(eng.events, eng.event_count, tr, kind, number, limit, _events_period_s(eng))


@njit(nogil=False)
def _write_row(eng: Engine, rows: Rows, time_s: float, k: int, stale: int) -> None:
    eng_output = eng.output
    rows_count = rows.count
    rows_cylinders = rows.cylinders
    rows_k = rows.k
    rows_stale = rows.stale
    rows_time_s = rows.time_s
    r = rows_count[0]
    rows_k[r] = k
    rows_time_s[r] = time_s
    rows_stale[r] = stale
    for i in range(eng_output.shape[0]):
        rows_cylinders[r, i] = eng_output[i]
    rows_count[0] = r + 1


@njit(nogil=False)
def _write_trace(eng: Engine, traces: Traces, time_s: float, restarts: int) -> None:
    eng_model_slots = eng.model_slots
    eng_output = eng.output
    eng_state = eng.state
    eng_values = eng.values
    traces_count = traces.count
    traces_cylinders = traces.cylinders
    traces_detector_on = traces.detector_on
    traces_model_c = traces.model_c
    traces_oat_c = traces.oat_c
    traces_restart = traces.restart
    traces_time_s = traces.time_s
    n = traces_count[0]
    if n >= traces_time_s.shape[0]:
        return
    traces_time_s[n] = time_s
    traces_restart[n] = restarts
    traces_oat_c[n] = eng_values[eng_model_slots[4]]
    for i in range(eng_state.shape[0]):
        traces_model_c[n, i] = eng_state[i]["model_c"]
        traces_detector_on[n, i] = eng_state[i]["detector_on"]
        traces_cylinders[n, i] = eng_output[i]
    traces_count[0] = n + 1


@njit(nogil=False, inline=True)
def advance_to(eng: Engine, rows: Rows, traces: Traces, t_s: float) -> bool:
    """Run every fixed step at or before t_s (s), rows into ``rows``; False when ``rows`` filled up before
    the last of them (drain it and call again with the same t_s). The first reading starts the clock; a
    jump by more than MAX_CLOCK_GAP_S restarts it (estimation starts afresh); a reading at or before the
    clock's time does nothing."""
    eng, rows, traces = borrowed(eng), borrowed(rows), borrowed(traces)
    eng_clock = eng.clock
    eng_early = eng.early
    eng_stamps = eng.stamps
    eng_state = eng.state
    rows_count = rows.count
    rows_k = rows.k
    traces_time_s = traces.time_s
    clock = eng_clock[0]
    if not (math.isfinite(t_s) and abs(t_s) < MAX_CLOCK_S):
        return True
    t_s = clock_tick(t_s)
    if not clock["started"] or t_s - clock["now_s"] > MAX_CLOCK_GAP_S:
        if clock["started"]:
            clock["restarts"] += 1
        for i in range(eng_state.shape[0]):  # estimation and detection start afresh
            _stop_cylinder(eng_state[i])
        clock["started"] = True
        clock["origin_s"] = t_s
        clock["now_s"] = t_s
        clock["k"] = 0
        for slot in range(eng_early.shape[0]):  # inputs fed before the clock started count as fed at its start
            if eng_early[slot]:
                eng_stamps[slot] = t_s
                eng_early[slot] = False
        return True
    if t_s <= clock["now_s"]:
        return True
    capacity = rows_k.shape[0]
    while True:
        step_time = clock_tick(clock["origin_s"] + (clock["k"] + 1) * clock["dt_s"])
        if step_time > t_s:
            break
        k = clock["k"] + 1
        if k % clock["row_period"] == 0 and rows_count[0] >= capacity:
            return False
        clock["k"] = k
        clock["steps"] += 1
        stale = engine_step(eng, step_time, k)
        if k % clock["row_period"] == 0:
            _write_row(eng, rows, step_time, k, stale)
        if traces_time_s.shape[0] > 0:
            _write_trace(eng, traces, step_time, clock["restarts"])
    clock["now_s"] = t_s
    return True


@njit(nogil=False, inline=True)
def feed_values(eng: Engine, slots: Any, values: Any, count: int) -> None:
    """Hold the first ``count`` decoded (slot, value) pairs of one frame, stamped with the clock's time
    (sample and hold; before the clock starts, at its start); a cylinder's CHT counts a reading."""
    eng = borrowed(eng)
    eng_clock = eng.clock
    eng_early = eng.early
    eng_settings = eng.settings
    eng_stamps = eng.stamps
    eng_state = eng.state
    eng_values = eng.values
    clock = eng_clock[0]
    for j in range(count):
        slot = slots[j]
        eng_values[slot] = values[j]
        if clock["started"]:
            eng_stamps[slot] = clock["now_s"]
        else:
            eng_stamps[slot] = np.nan
            eng_early[slot] = True
        for i in range(eng_state.shape[0]):
            if eng_settings[i]["cht_slot"] == slot:
                eng_state[i]["readings"] += 1


@njit(nogil=False)
def replay_loop(
    eng: Engine, rows: Rows, traces: Traces, frame_time_s: Any, first_value: Any, slots: Any, values: Any, start: int
) -> int:
    """The loop over frames, live (a frame at a time) and replay (a whole log): for each frame from
    ``start``, :func:`advance_to` its time then :func:`feed_values` its decoded values
    (``slots[first_value[f]:first_value[f + 1]]``). Returns the frame to resume from when ``rows`` filled
    up, or the frame count when done. Holds the GIL (the live path's short calls); a whole log's replay
    runs it through :func:`replay_loop_released`."""
    eng, rows, traces = borrowed(eng), borrowed(rows), borrowed(traces)
    n = frame_time_s.shape[0]
    for f in range(start, n):
        if not advance_to(eng, rows, traces, frame_time_s[f]):
            return f
        a = first_value[f]
        feed_values(eng, slots[a:], values[a:], first_value[f + 1] - a)
    return n


@njit(nogil=True)
def replay_loop_released(
    eng: Engine, rows: Rows, traces: Traces, frame_time_s: Any, first_value: Any, slots: Any, values: Any, start: int
) -> int:
    """:func:`replay_loop` with the GIL released, for a whole log: health.csv's writer thread formats the rows
    already written meanwhile."""
    return replay_loop(eng, rows, traces, frame_time_s, first_value, slots, values, start)


# ------------------------------------------------------------------------------------------------ compiling


def compiled() -> Any:
    """The step's compiled entry points (each function here carries ``@njit``; numba compiles it on first
    call or loads it from the disk cache): a namespace with ``replay_loop``, ``replay_loop_released``, ``headroom_s``,
    ``detector_step``, ``stop_cylinder``, ``close_events``."""
    from types import SimpleNamespace

    return SimpleNamespace(
        replay_loop=replay_loop,
        replay_loop_released=replay_loop_released,
        headroom_s=headroom_s,
        detector_step=detector_step,
        stop_cylinder=_stop_cylinder,
        close_events=close_events,
    )
