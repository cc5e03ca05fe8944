"""One compiled call per filter period of a cylinder on the live path (the pipeline's hot step).

On a step where the filters are called (every ``FILTER_PERIOD_S``) a running cylinder needs, in this
order: the open-loop reference EKF (its CHT is the supervisor's model for the stuck-probe test), the
supervision step, then the estimator (EKF, CBEKF or CBEKF-AU) and the isolation filter with the
reading the supervisor lets through (with ``cbekf-iso`` the estimator is an isolation filter equal to the
other one, run once for both). Done as three compiled calls with Python between them, each call
entered the numba dispatcher with ~25 arguments, and a step paced one frame per 20 ms (caches cold)
paid ~25-45 us per entry (docs/performance.md, "Live p99"). :class:`LiveCall` does the same in one
compiled call with one argument: a float64 workspace holding the three filters' states and held
drives, their settings, the model's packed coefficients, the supervisor state and the call's inputs
and results.

The compiled function calls the very functions the filters' own calls run (``ekf.live_steps``,
the isolation filter's ``_live``, :func:`~ecu_monitor.service.supervision.supervise`), compiled from
the same source with the same types, so its results are those of the separate calls bit for bit
(tests/test_live_call.py). The workspace is filled from the filters once, after they are initialised
(:meth:`LiveCall.of`); from then on it holds their state and the filter objects are not used.
"""

from __future__ import annotations

import functools
import math
import struct
import sys
from typing import Any, cast

import numpy as np

from ecu_monitor.errors import EstimationError
from ecu_monitor.estimation.ekf import _RESET_CODES, ThermalEKF
from ecu_monitor.estimation.isolation import IsolationFilter
from ecu_monitor.model import Coefficients, Drive, InputSeries, pack_coefficients
from ecu_monitor.service import supervision
from ecu_monitor.service.supervision import ACTION_NONE, CODE_NOMINAL, SupervisorState

__all__ = ["LiveCall"]

# Workspace layout (float64 offsets). Filter states and drives in the order of their own arrays.
_REF = 0  # reference EKF: FilterState (7), then its held Drive (5)
_EST = 12  # estimator EKF: FilterState (7), Drive (5)
_ISO = 24  # isolation filter: state (13), Drive (5)
_ISO_MODEL = 42  # (4) C_w, tau_w, 1/(alpha R_e), radiation offset
_ISO_CFG = 46  # (7) IsolationSettings.vector()
# dt, Q, R, a, b, c, tau, use_deviation, reset_code, stale limit, stuck after, stuck change, then the
# reference's use_deviation, reset code and "measured" (all 0), then 1 when the estimator is the isolation
# filter (cbekf-iso: the estimate is the isolation filter's own, _EST unused) (16)
_SET = 53
_INPUTS = 69  # scratch (6, 1) of the drive kernel
_ROWS = 75  # scratch (4, 1)
_OUT = 79  # scratch (3) of the filter calls
_ARGS = 82  # time, u (6), reading, new_reading, reading_bad, any_stale, pending, steps (13)
_SV = 95  # supervisor state (6): in, and out after the call
_RESULT = 101  # code, action, model_c, cht_est_c, deviation, gamma_q, gamma_d, iso_deviation (8)
_COEFFS = 109  # n scalars, n x, n y, then the packed coefficients: scalars, heat values (row-major), x, y
_EKF_STATE, _DRIVE, _ISO_STATE = 7, 5, 13
#: The call's arguments and the supervisor state as they lie in the workspace from _ARGS on (one write per call).
_ARGUMENTS = struct.Struct(f"={_RESULT - _ARGS}d")


def _live_call(ws: Any) -> None:
    """The compiled step (see module docstring); everything in and out through ``ws``."""
    n_s = int(ws[_COEFFS])
    n_x = int(ws[_COEFFS + 1])
    n_y = int(ws[_COEFFS + 2])
    at = _COEFFS + 3
    cs = ws[at : at + n_s]
    at += n_s
    hv = ws[at : at + n_x * n_y].reshape((n_x, n_y))
    at += n_x * n_y
    xb = ws[at : at + n_x]
    yb = ws[at + n_x : at + n_x + n_y]
    inputs = ws[_INPUTS : _INPUTS + 6].reshape((6, 1))
    rows = ws[_ROWS : _ROWS + 4].reshape((4, 1))
    out = ws[_OUT : _OUT + 3]
    dt, q, r = ws[_SET], ws[_SET + 1], ws[_SET + 2]
    a, b, c, tau = ws[_SET + 3], ws[_SET + 4], ws[_SET + 5], ws[_SET + 6]
    use_deviation = ws[_SET + 7] != 0.0
    reset_code = int(ws[_SET + 8])
    time_s = ws[_ARGS]
    u0, u1, u2, u3, u4, u5 = ws[_ARGS + 1], ws[_ARGS + 2], ws[_ARGS + 3], ws[_ARGS + 4], ws[_ARGS + 5], ws[_ARGS + 6]
    reading = ws[_ARGS + 7]
    new_reading = ws[_ARGS + 8] != 0.0
    reading_bad = ws[_ARGS + 9] != 0.0
    any_stale = ws[_ARGS + 10] != 0.0
    pending = ws[_ARGS + 11] != 0.0
    steps = int(ws[_ARGS + 12])
    # the open-loop reference (an EKF: no deviation, no reset, no reading). Its flags are read from ws, not
    # written as constants: numba would type constants as literals and compile a second copy of the filter
    # for them, where this way both calls run one copy (the second call finds it in the cache)
    ref_use_deviation = ws[_SET + 12] != 0.0
    ref_reset_code = int(ws[_SET + 13])
    ref_measured = ws[_SET + 14] != 0.0
    ekf_live(ws[_REF : _REF + 7], ws[_REF + 7 : _REF + 12], inputs, rows, out, u0, u1, u2, u3, u4, u5, np.nan,
             ref_measured, cs, hv, xb, yb, dt, q, r, a, b, c, tau, ref_use_deviation, ref_reset_code,
             steps)  # fmt: skip
    model_c = ws[_REF]
    sv = SupervisorState(ws[_SV] != 0.0, ws[_SV + 1], ws[_SV + 2], ws[_SV + 3], ws[_SV + 4], ws[_SV + 5])
    sv, code, action = supervise(sv, time_s, any_stale, new_reading, reading, reading_bad, model_c, ws[_SET + 9],
                                 ws[_SET + 10], ws[_SET + 11])  # fmt: skip
    ws[_SV] = 1.0 if sv.running else 0.0
    ws[_SV + 1] = sv.stale_since_s
    ws[_SV + 2] = sv.changed_s
    ws[_SV + 3] = sv.last_reading_c
    ws[_SV + 4] = sv.model_low_c
    ws[_SV + 5] = sv.model_high_c
    ws[_RESULT] = code
    ws[_RESULT + 1] = action
    ws[_RESULT + 2] = model_c
    if action == ACTION_NONE:
        return
    measured = pending and code == CODE_NOMINAL and np.isfinite(reading)
    z = reading if measured else np.nan
    iso_estimator = ws[_SET + 15] != 0.0
    if not iso_estimator:
        ekf_live(ws[_EST : _EST + 7], ws[_EST + 7 : _EST + 12], inputs, rows, out, u0, u1, u2, u3, u4, u5, z,
                 measured, cs, hv, xb, yb, dt, q, r, a, b, c, tau, use_deviation, reset_code, steps)  # fmt: skip
        ws[_RESULT + 3] = ws[_EST]
        ws[_RESULT + 4] = ws[_EST + 3] / dt if use_deviation else 0.0
    iso = ws[_ISO : _ISO + 13]
    iso_live(iso, ws[_ISO + 13 : _ISO + 18], inputs, rows, out, u0, u1, u2, u3, u4, u5, z, measured, steps,
             ws[_ISO_MODEL : _ISO_MODEL + 4], ws[_ISO_CFG : _ISO_CFG + 7], cs, hv, xb, yb)  # fmt: skip
    if iso_estimator:  # the estimator is an isolation filter equal to this one: its estimate is this one's
        ws[_RESULT + 3] = iso[0]
        ws[_RESULT + 4] = out[2]
    ws[_RESULT + 5] = iso[1]
    ws[_RESULT + 6] = iso[2]
    ws[_RESULT + 7] = out[2]


# The compiled callees of _live_call; _compiled() binds them.
ekf_live: Any = None
iso_live: Any = None
supervise: Any = None


@functools.cache
def _compiled() -> Any:
    """:func:`_live_call` compiled with the filters' and the supervisor's compiled functions (cached on disk,
    keyed by every source it embeds), for its one argument type: the compiled function itself, not numba's
    dispatcher, which would type the argument at every call (~7 us of a cold call, docs/performance.md)."""
    from ecu_monitor.estimation import ekf, isolation, quantiser
    from ecu_monitor.model import compiled as compiled_model
    from ecu_monitor.model import thermal
    from ecu_monitor.model.kernels import fingerprint, jit

    modules = (ekf, isolation, quantiser, thermal, compiled_model, supervision, sys.modules[__name__])
    tag = fingerprint([str(m.__file__) for m in modules])
    initial = jit(supervision.initial_supervisor, tag)
    step = jit(supervision.supervise, tag, initial_supervisor=initial)
    dispatcher = jit(
        _live_call, tag, nogil=False, ekf_live=ekf.compiled_filter().live, iso_live=isolation.compiled_kernels().live,
        supervise=step,
    )  # fmt: skip
    return dispatcher.compile("(float64[::1],)")  # the workspace: float64, one dimension, contiguous


class LiveCall:
    """One cylinder's reference, estimator and isolation filter after initialisation, called as one
    compiled call per filter period (:meth:`call`). Build it with :meth:`of`."""

    __slots__ = ("_call", "_drive_at", "_mv", "_shadow", "_shadow_mv", "_time_s", "dt_s", "ws")

    def __init__(self, ws: np.ndarray, time_s: float, dt_s: float, drive_at: int) -> None:
        self.ws = ws
        self._drive_at = drive_at  # the estimator's held drive in ws (the isolation filter's for cbekf-iso)
        self._mv: Any = memoryview(cast(Any, ws))  # item access on plain floats, without numpy scalars
        self._time_s = time_s
        self.dt_s = dt_s
        self._call = _compiled()
        self._shadow = np.empty_like(ws)  # the rehearsal's copy of the workspace
        self._shadow_mv: Any = memoryview(cast(Any, self._shadow))

    @staticmethod
    def of(
        reference: Any,
        estimator: Any,
        isolation: Any,
        coeffs: Coefficients,
        time_s: float,
        stale_limit_s: float,
        stuck_after_s: float,
        stuck_change_c: float,
    ) -> LiveCall | None:
        """The call of these filters, just initialised at ``time_s`` (s) on the model whose coefficients are
        ``coeffs``, or None when they are not the kinds it runs: a compiled EKF reference, an isolation filter,
        and as estimator a compiled EKF-family filter on the reference's settings or an isolation filter equal
        to ``isolation`` (cbekf-iso: same parameters, settings and state; the call runs it once for both)."""
        if not (
            isinstance(reference, ThermalEKF)
            and isinstance(isolation, IsolationFilter)
            and reference.compiled
            and not reference.use_deviation
            and reference.reset_mode == "none"
            and isolation.params is reference.params
            and isolation.settings.dt_s == reference.settings.dt_s
        ):
            return None
        iso_estimator = isinstance(estimator, IsolationFilter)
        if iso_estimator:
            if not (
                estimator.params is isolation.params
                and estimator.settings == isolation.settings
                and all(map(np.array_equal, estimator.live_arrays(), isolation.live_arrays()))
            ):
                return None
        elif not (
            isinstance(estimator, ThermalEKF)
            and estimator.compiled
            and estimator.settings == reference.settings
            and estimator.params is reference.params
        ):
            return None
        packed = pack_coefficients(coeffs)
        n_x, n_y = packed.heat_values_w.shape
        ws = np.zeros(_COEFFS + 3 + packed.scalars.size + n_x * n_y + n_x + n_y)
        for at, ekf in ((_REF, reference),) if iso_estimator else ((_REF, reference), (_EST, estimator)):
            drive = ekf.held_drive
            if drive is None:
                raise EstimationError(f"{ekf.name}: not initialised")
            ws[at : at + _EKF_STATE] = ekf.state
            ws[at + _EKF_STATE : at + _EKF_STATE + _DRIVE] = drive
        state, iso_drive, model, cfg = isolation.live_arrays()
        ws[_ISO : _ISO + _ISO_STATE] = state
        ws[_ISO + _ISO_STATE : _ISO + _ISO_STATE + _DRIVE] = iso_drive
        ws[_ISO_MODEL : _ISO_MODEL + 4] = model
        ws[_ISO_CFG : _ISO_CFG + 7] = cfg
        s = reference.settings
        use_deviation = False if iso_estimator else estimator.use_deviation
        reset_code = _RESET_CODES["none" if iso_estimator else estimator.reset_mode]
        ws[_SET : _SET + 16] = (s.dt_s, s.process_var, s.measurement_var, s.sigmoid_a, s.sigmoid_b, s.quantum_c,
                                s.deviation_time_s, float(use_deviation), reset_code, stale_limit_s, stuck_after_s,
                                stuck_change_c, float(reference.use_deviation), _RESET_CODES[reference.reset_mode],
                                0.0, float(iso_estimator))  # fmt: skip
        at = _COEFFS
        ws[at : at + 3] = (packed.scalars.size, n_x, n_y)
        at += 3
        for part in packed:
            ws[at : at + part.size] = part.ravel()
            at += part.size
        return LiveCall(ws, float(time_s), s.dt_s, _ISO + _ISO_STATE if iso_estimator else _EST + _EKF_STATE)

    def call(
        self,
        time_s: float,
        u: InputSeries,
        any_stale: bool,
        new_reading: bool,
        reading: float,
        reading_bad: bool,
        pending: bool,
        sv: SupervisorState,
    ) -> tuple[SupervisorState, int, int, float, float, float, float, float, float]:
        """The filter period at ``time_s``: (new supervisor state, state code, action, reference CHT degC,
        estimate degC, deviation degC/s, gamma_Q, gamma_D, isolation deviation degC/s). On ACTION_NONE the
        estimate, deviation and gammas are nan (the filters are to be dropped). ``pending``: a reading
        arrived since the last filter call (the estimator takes it if the state is NOMINAL)."""
        steps = round((time_s - self._time_s) / self.dt_s)
        if steps < 1:
            raise EstimationError(
                f"live call: time must advance by at least one step of {self.dt_s} s (from {self._time_s} to {time_s})"
            )
        # the arguments and the supervisor state, converted to float64 in one call (flags: 1.0 / 0.0)
        _ARGUMENTS.pack_into(self._mv, _ARGS * 8, time_s, *u, reading, bool(new_reading), bool(reading_bad),
                             bool(any_stale), bool(pending), steps, bool(sv.running), *sv[1:])  # fmt: skip
        self._call(self.ws)
        self._time_s = time_s
        values: list[float] = self._mv[_SV : _RESULT + 8].tolist()
        running, since, changed, last, low, high, code, action, model_c, est_c, deviation, gq, gd, iso_dev = values
        if action == ACTION_NONE:
            est_c = deviation = gq = gd = iso_dev = math.nan
        new_sv = SupervisorState(running != 0.0, since, changed, last, low, high)
        return new_sv, int(code), int(action), model_c, est_c, deviation, gq, gd, iso_dev

    def rehearse(self, u: InputSeries) -> None:
        """The work of :meth:`call` (the inputs written, the compiled call, the results read) on a copy of the
        workspace taken now, with the previous call's arguments and the inputs ``u``: no effect on this call's
        state. Run shortly before the call is due, it brings its code and data into the caches
        (docs/performance.md, "Rehearsal")."""
        shadow: Any = self._shadow_mv
        shadow[:] = self._mv
        previous = _ARGUMENTS.unpack_from(shadow, _ARGS * 8)
        _ARGUMENTS.pack_into(shadow, _ARGS * 8, previous[0], *u, *previous[7:])
        self._call(self._shadow)
        shadow[_SV : _RESULT + 8].tolist()

    def estimator_drive(self) -> Drive:
        """The model's drive at the inputs of the latest call, as the estimator holds it (floats, equal bit for
        bit to ``ThermalEKF.held_drive``; for cbekf-iso the isolation filter's, from the same compiled kernel)."""
        return Drive(*self._mv[self._drive_at : self._drive_at + _DRIVE].tolist())
