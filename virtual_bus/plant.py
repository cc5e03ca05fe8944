"""The truth plant of the virtual ECU: mission -> pilot -> airframe -> thermal model -> sensors.

The cylinder-head temperature is integrated with the model layer's own equations
(:func:`ecu_monitor.model.compute_drive` and :func:`ecu_monitor.model.rk4_step`, fixed step
``dt_s`` = 0.02 s by default, inputs held over each step as in the estimators), with optional
unmodelled effects switched on in the truth (:class:`ecu_monitor.model.Effects`) and a degradation
schedule of gamma_Q (heat in) and gamma_D (dissipation). The CHT probe follows the head through
:func:`ecu_monitor.model.sensor_step` (a first-order lag when the ``sensor_lag`` effect is on), and
:class:`virtual_bus.sensors.SensorModel` adds noise and the 1 degC quantiser.

Speed: the pilot decides once per control period (1 s = 50 steps); the airframe response and the
model's drive quantities for the whole period are computed as numpy arrays, and only the RK4
arithmetic runs per step, on Python floats (figures: docs/performance.md, "Virtual ECU").

:func:`iter_steps` streams :class:`StepBlock` objects (one per control period, every step's truth
and measurements), so a 16 h flight never has to be in memory; :func:`fly` collects them into a
:class:`~ecu_monitor.flightlog.FlightLog` sampled every ``record_dt_s``.

Degradations, effects and truth forms are defined in :mod:`virtual_bus.faults` (re-exported here).
Degradation syntax (:meth:`Degradation.parse`, the CLI's ``--degrade``)::

    gamma_q=1.2@1800            step of gamma_Q to 1.2 at t = 1800 s
    gamma_d=1.1@600:ramp=300    gamma_D ramps linearly from its level at 600 s to 1.1 at 900 s

Events of one factor apply in time order, each starting from the level the factor has reached.

Truth-only forms (:class:`TruthForm`, the blind cases of the gap diagnosis): terms the model library
does not contain exactly (another airspeed law, a mixture effect of another shape, a cooling loss that
grows with run time, an oil-temperature coupling), applied in the truth as factors on the heat in and
the dissipation beside the degradation schedule; :func:`fly` then logs their combined factors as
``form_gamma_q`` and ``form_gamma_d``.
Effect syntax (:func:`parse_effect`, the CLI's ``--effect``): ``NAME`` (default sizes) or
``NAME:key=value,key=value``, e.g. ``sensor_lag:time_constant_s=12``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Sequence
from typing import Any, NamedTuple

import numpy as np

from ecu_monitor.errors import ConfigError, ParameterError
from ecu_monitor.flightlog import FlightLog
from ecu_monitor.model import (
    Drive,
    Effects,
    InputSeries,
    ThermalParams,
    coefficients,
    compute_drive,
    initial_pade_state,
    paper_table_a1,
    rk4_step,
    sensor_step,
)
from virtual_bus.cylinders import CylinderState, fly_cylinders
from virtual_bus.faults import (
    DEGRADATION_FACTORS,
    TRUTH_FORM_KINDS,
    Degradation,
    TruthForm,
    gamma_schedule,
    parse_effect,
    parse_effects,
    random_effects,
    random_truth_form,
)
from virtual_bus.missions import Mission
from virtual_bus.pilot import CONTROL_PERIOD_S, AircraftState, Pilot, fly_period, fuel_flow_lph, propeller_rpm
from virtual_bus.sensors import Measurements, SensorModel

__all__ = [
    "DEGRADATION_FACTORS",
    "LOG_COLUMNS",
    "TRUTH_FORM_KINDS",
    "Degradation",
    "StepBlock",
    "TruthForm",
    "block_rows",
    "collect",
    "fly",
    "gamma_schedule",
    "iter_steps",
    "parse_effect",
    "parse_effects",
    "random_effects",
    "random_truth_form",
    "record_every",
]


class StepBlock(NamedTuple):
    """Truth and measurements of consecutive integration steps (one control period).

    Arrays have one value per step, taken at the step's start time ``time_s``; ``first_step`` is the
    global index of the first step (time_s = step index * dt_s). Truth: the inputs, ``cht_true_c``
    (head temperature), ``probe_c`` (what the probe sees), ``gamma_q``/``gamma_d``. ``measured``: what
    the ECU and the air-data computer report.
    """

    first_step: int
    segment_index: int
    time_s: np.ndarray
    throttle_pct: np.ndarray
    rpm: np.ndarray
    altitude_m: np.ndarray
    airspeed_mps: np.ndarray
    oat_c: np.ndarray
    vspeed_mps: np.ndarray
    fuel_flow_lph: np.ndarray
    cht_true_c: np.ndarray
    probe_c: np.ndarray
    gamma_q: np.ndarray
    gamma_d: np.ndarray
    measured: Measurements
    form_gamma_q: np.ndarray | None = None  # truth forms' factors per step (None: no truth form)
    form_gamma_d: np.ndarray | None = None
    # an engine flown with cylinders: each cylinder's head temperature and gammas, (cylinders, steps);
    # cht_true_c and probe_c are then the cylinders' mean, gamma_q and gamma_d the every-cylinder schedule
    cylinders_true_c: np.ndarray | None = None
    cylinders_gamma_q: np.ndarray | None = None
    cylinders_gamma_d: np.ndarray | None = None


def _check_step(dt_s: float) -> int:
    if not (isinstance(dt_s, int | float) and math.isfinite(dt_s) and 1e-4 <= dt_s <= CONTROL_PERIOD_S):
        raise ParameterError(f"dt_s: expected a step in [0.0001, {CONTROL_PERIOD_S}] s, got {dt_s!r}")
    return max(1, round(CONTROL_PERIOD_S / dt_s))


def iter_steps(
    mission: Mission,
    params: ThermalParams | None = None,
    *,
    effects: Effects | None = None,
    degradation: Sequence[Degradation] = (),
    seed: int = 0,
    dt_s: float = 0.02,
    sensors: SensorModel | None = None,
    max_duration_s: float | None = None,
    truth_forms: Sequence[TruthForm] = (),
    cylinders: Sequence[ThermalParams] = (),
) -> Iterator[StepBlock]:
    """Fly ``mission`` and yield one :class:`StepBlock` per control period until the mission ends.

    ``params`` is the truth model (default the paper's Table A1); ``effects``, if given, replaces its
    unmodelled effects; ``truth_forms`` adds terms the library does not hold (:class:`TruthForm`).
    ``cylinders`` (2 or more models, :func:`virtual_bus.cylinders.cylinder_models`): an engine with
    one head per model on the shared inputs, each probe measured on its own, degradation events with
    ``cylinder=n`` in that cylinder alone; the pilot watches the hottest probe; not with truth forms.
    Deterministic for a seed: the pilot's random variations and the sensor noise
    draw from two independent streams spawned from ``seed``.
    """
    params = params or paper_table_a1()
    if effects is not None:
        params = params.replace(effects=effects)
        cylinders = [c.replace(effects=effects) for c in cylinders]
    multi = len(cylinders) > 1
    if multi and truth_forms:
        raise ParameterError("truth forms apply to a single-cylinder engine (fly cylinders without them)")
    count = len(cylinders) if multi else 1
    wrong = [e for e in degradation if e.cylinder is not None and e.cylinder > count]
    if wrong:
        raise ParameterError(f"degradation {wrong[0]}: the engine has {count} cylinder(s)")
    sensors = sensors or SensorModel()
    steps_per_period = _check_step(dt_s)
    coeffs = coefficients(params)
    # sensor_step is linear in (probe, cht): its gain over one step is its value at (0, 1)
    probe_gain = float(sensor_step(0.0, 1.0, coeffs, dt_s))
    pilot_seq, sensor_seq = np.random.SeedSequence(seed).spawn(2)
    pilot_rng = np.random.default_rng(pilot_seq)
    sensor_rng = np.random.default_rng(sensor_seq)
    pilot = Pilot(mission, params.cht_limit_c, pilot_rng)
    atmosphere = mission.atmosphere
    field = mission.field_elevation_m
    state = AircraftState(time_s=0.0, altitude_m=field)
    x_axis, y_axis = params.heat_axes

    # Any: rk4_step is typed for floats or arrays; here it always gets and returns floats
    cht: Any = float(mission.initial_cht_c if mission.initial_cht_c is not None else atmosphere.oat_c(field))
    probe = cht
    pade: Any = None
    cht_measured = cht
    heads = [CylinderState(cht, cht) for _ in cylinders] if multi else []
    oil_forms = [f for f in truth_forms if f.kind == "oil_coupling"]
    oil = [cht for _ in oil_forms]
    oil_start = list(oil)
    step = 0
    while max_duration_s is None or state.time_s < max_duration_s:
        command = pilot.command(state, cht_measured)
        if command is None:
            return
        kin, next_state = fly_period(state, command, steps_per_period, dt_s, field)
        time_s = np.round((step + np.arange(steps_per_period)) * dt_s, 9)
        rpm = propeller_rpm(kin.throttle_pct, kin.airspeed_mps)
        oat = np.asarray(atmosphere.oat_c(kin.altitude_m), dtype=float)
        fuel = fuel_flow_lph(kin.throttle_pct, rpm, kin.altitude_m, oat)
        columns = {"throttle_pct": kin.throttle_pct, "rpm": rpm, "fuel_flow_lph": fuel}
        heat_x, heat_y = columns[x_axis], columns[y_axis]
        drive = compute_drive(InputSeries(heat_x, heat_y, kin.altitude_m, kin.airspeed_mps, oat), coeffs)
        q, g, amb, cond, gain = (np.broadcast_to(v, (steps_per_period,)).tolist() for v in drive)
        gq_arr = gamma_schedule(degradation, "gamma_q", time_s)
        gd_arr = gamma_schedule(degradation, "gamma_d", time_s)
        form_q = np.ones(steps_per_period)
        form_d = np.ones(steps_per_period)
        for form in truth_forms:
            fq, fd = form.factors(time_s, kin.airspeed_mps, kin.throttle_pct)
            form_q = form_q * fq
            form_d = form_d * fd
        gq, gd = (gq_arr * form_q).tolist(), (gd_arr * form_d).tolist()
        if pade is None:
            pade = float(initial_pade_state(Drive(q[0], g[0], amb[0], cond[0], gain[0])))
        cht_out = np.empty(steps_per_period)
        probe_out = np.empty(steps_per_period)
        for k in range(steps_per_period if not multi else 0):
            cht_out[k] = cht
            probe_out[k] = probe
            gd_k = gd[k]
            for i, form in enumerate(oil_forms):
                conductance = max(0.2, 1.0 - form.value("coupling") * (oil[i] - oil_start[i]) / 100.0)
                gd_k /= conductance
                form_d[k] /= conductance
                oil[i] += dt_s * (cht - oil[i]) / form.value("time_constant_s")
            cht, pade = rk4_step(cht, pade, Drive(q[k], g[k], amb[k], cond[k], gain[k]), coeffs, dt_s, gq[k], gd_k)
            probe = probe + probe_gain * (cht - probe)
        per_cylinder: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        if multi:
            inputs = InputSeries(heat_x, heat_y, kin.altitude_m, kin.airspeed_mps, oat)
            per_cylinder = fly_cylinders(heads, cylinders, inputs, time_s, degradation, dt_s)
            cht_out = per_cylinder[0].mean(axis=0)
            probe_out = per_cylinder[1].mean(axis=0)
            cht = float(np.mean([head.cht_c for head in heads]))
        if not math.isfinite(cht):
            raise ParameterError(f"truth plant diverged at t = {state.time_s:.1f} s (dt_s {dt_s} too large?)")
        measured = sensors.measure(
            sensor_rng,
            probe_c=probe_out,
            throttle_pct=kin.throttle_pct,
            rpm=rpm,
            altitude_m=kin.altitude_m,
            airspeed_mps=kin.airspeed_mps,
            oat_c=oat,
            vspeed_mps=kin.vspeed_mps,
            fuel_flow_lph=fuel,
        )
        if per_cylinder is not None:
            probes = sensors.quantise_cht(per_cylinder[1], sensor_rng)
            measured = measured._replace(cht_c=probes.mean(axis=0), cht_cylinders_c=probes)
            cht_measured = float(probes[:, -1].max())
        else:
            cht_measured = float(measured.cht_c[-1])
        yield StepBlock(
            first_step=step,
            segment_index=pilot.index,
            time_s=time_s,
            throttle_pct=kin.throttle_pct,
            rpm=rpm,
            altitude_m=kin.altitude_m,
            airspeed_mps=kin.airspeed_mps,
            oat_c=oat,
            vspeed_mps=kin.vspeed_mps,
            fuel_flow_lph=fuel,
            cht_true_c=cht_out,
            probe_c=probe_out,
            gamma_q=gq_arr,
            gamma_d=gd_arr,
            measured=measured,
            form_gamma_q=form_q if truth_forms else None,
            form_gamma_d=form_d if truth_forms else None,
            cylinders_true_c=None if per_cylinder is None else per_cylinder[0],
            cylinders_gamma_q=None if per_cylinder is None else per_cylinder[2],
            cylinders_gamma_d=None if per_cylinder is None else per_cylinder[3],
        )
        step += steps_per_period
        state = next_state


#: FlightLog columns written by :func:`fly`: measured canonical + optional columns, then the truth.
LOG_COLUMNS: tuple[str, ...] = (
    "time_s",
    "throttle_pct",
    "rpm",
    "altitude_m",
    "airspeed_mps",
    "oat_c",
    "cht_c",
    "fuel_flow_lph",
    "vspeed_mps",
    "cht_true_c",
    "gamma_q",
    "gamma_d",
)


def block_rows(block: StepBlock, every: int) -> dict[str, np.ndarray]:
    """The samples of ``block`` whose global step index is a multiple of ``every``, as log columns
    (:data:`LOG_COLUMNS`; an engine flown with cylinders adds :func:`cylinder_rows`)."""
    keep = np.nonzero((block.first_step + np.arange(block.time_s.size)) % every == 0)[0]
    return {**_log_rows(block, keep), **cylinder_rows(block, keep)}


def cylinder_rows(block: StepBlock, keep: np.ndarray) -> dict[str, np.ndarray]:
    """Per-cylinder log columns of ``block`` at the steps ``keep``: measured ``cht1_c .. chtN_c`` (the
    flight CSV's cylinder columns), truth ``cylN_cht_true_c``, ``cylN_gamma_q``, ``cylN_gamma_d``;
    none for a single-cylinder engine."""
    m = block.measured
    if m.cht_cylinders_c is None or block.cylinders_true_c is None:
        return {}
    out: dict[str, np.ndarray] = {}
    count = m.cht_cylinders_c.shape[0]
    for c in range(count):
        out[f"cht{c + 1}_c"] = m.cht_cylinders_c[c, keep]
    for c in range(count):
        out[f"cyl{c + 1}_cht_true_c"] = block.cylinders_true_c[c, keep]
        out[f"cyl{c + 1}_gamma_q"] = np.asarray(block.cylinders_gamma_q)[c, keep]
        out[f"cyl{c + 1}_gamma_d"] = np.asarray(block.cylinders_gamma_d)[c, keep]
    return out


def _log_rows(block: StepBlock, keep: np.ndarray) -> dict[str, np.ndarray]:
    m = block.measured
    return {
        "time_s": block.time_s[keep],
        "throttle_pct": m.throttle_pct[keep],
        "rpm": m.rpm[keep],
        "altitude_m": m.altitude_m[keep],
        "airspeed_mps": m.airspeed_mps[keep],
        "oat_c": m.oat_c[keep],
        "cht_c": m.cht_c[keep],
        "fuel_flow_lph": m.fuel_flow_lph[keep],
        "vspeed_mps": m.vspeed_mps[keep],
        "cht_true_c": block.cht_true_c[keep],
        "gamma_q": block.gamma_q[keep],
        "gamma_d": block.gamma_d[keep],
    }


def record_every(dt_s: float, record_dt_s: float) -> int:
    """Steps between recorded samples; record_dt_s must be a whole multiple of dt_s (both checked
    before use: a zero or NaN step is a ParameterError naming it, not a division error)."""
    _check_step(dt_s)
    if not (isinstance(record_dt_s, int | float) and math.isfinite(record_dt_s) and record_dt_s > 0):
        raise ParameterError(f"record_dt_s: expected a positive finite step, s, got {record_dt_s!r}")
    ratio = record_dt_s / dt_s
    every = round(ratio)
    if every < 1 or abs(ratio - every) > 1e-6 * max(1.0, ratio):
        raise ParameterError(f"record_dt_s: expected a whole multiple of dt_s ({dt_s:g} s), got {record_dt_s!r}")
    return int(every)


def collect(blocks: Iterable[StepBlock], every: int, source: str) -> FlightLog:
    """A FlightLog of the samples of ``blocks`` every ``every`` steps."""
    parts: dict[str, list[np.ndarray]] = {name: [] for name in LOG_COLUMNS}
    for block in blocks:
        for name, values in block_rows(block, every).items():
            parts.setdefault(name, []).append(values)
    if not parts["time_s"]:
        raise ConfigError(f"{source}: the mission produced no samples")
    return FlightLog({name: np.concatenate(chunks) for name, chunks in parts.items()}, source=source)


def fly(
    mission: Mission,
    params: ThermalParams | None = None,
    *,
    effects: Effects | None = None,
    degradation: Sequence[Degradation] = (),
    seed: int = 0,
    dt_s: float = 0.02,
    record_dt_s: float = 0.1,
    sensors: SensorModel | None = None,
    max_duration_s: float | None = None,
    truth_forms: Sequence[TruthForm] = (),
    cylinders: Sequence[ThermalParams] = (),
) -> FlightLog:
    """Fly ``mission`` through the truth plant and return the flight sampled every ``record_dt_s``.

    Columns: the canonical ones as measured (time_s, throttle_pct, rpm, altitude_m, airspeed_mps,
    oat_c, cht_c quantised), fuel_flow_lph and vspeed_mps (measured), and the truth for scoring:
    cht_true_c (head temperature), gamma_q, gamma_d; with ``truth_forms`` also form_gamma_q and
    form_gamma_d (their combined factors on the heat in and the dissipation); with ``cylinders`` the
    per-cylinder columns of :func:`cylinder_rows` (cht_c is then the cylinders' mean). Deterministic
    for a seed.
    """
    every = record_every(dt_s, record_dt_s)
    forms: dict[str, list[np.ndarray]] = {"form_gamma_q": [], "form_gamma_d": []}

    def keep_forms(blocks: Iterable[StepBlock]) -> Iterator[StepBlock]:
        for block in blocks:
            if truth_forms:
                keep = np.nonzero((block.first_step + np.arange(block.time_s.size)) % every == 0)[0]
                forms["form_gamma_q"].append(np.asarray(block.form_gamma_q)[keep])
                forms["form_gamma_d"].append(np.asarray(block.form_gamma_d)[keep])
            yield block

    blocks = iter_steps(
        mission,
        params,
        effects=effects,
        degradation=degradation,
        seed=seed,
        dt_s=dt_s,
        sensors=sensors,
        max_duration_s=max_duration_s,
        truth_forms=truth_forms,
        cylinders=cylinders,
    )
    log = collect(keep_forms(blocks), every, source=f"virtual-ecu:{mission.name}:seed={seed}")
    if truth_forms:
        log = log.with_columns(**{name: np.concatenate(chunks) for name, chunks in forms.items()})
    return log
