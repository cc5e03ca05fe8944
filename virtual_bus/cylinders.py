"""Engines with N cylinders for the virtual ECU: cylinders whose models differ, flown on shared inputs.

Real cylinders of one engine do not run at one temperature: the G1000 exports of a four-cylinder
Lycoming (docs/results/real.md) differ by 8-30 degC and keep their order through a flight, from the
mixture distribution, the cooling air each head gets behind the baffles and the head's own mass.
:func:`cylinder_models` makes N such cylinders from one model: cylinder n's heat map is scaled by a
factor ``1 + heat_spread * u_n`` (the heat each cylinder gets) and its wall capacity by
``1 + mass_spread * v_n`` (its thermal mass), with u, v drawn uniformly in [-1, 1] from ``seed``.

:func:`fly_cylinders` integrates every cylinder over one control period of the truth plant with the
model layer's own RK4 step, each with its own degradation schedule (events with ``cylinder=n`` or for
every cylinder, :class:`~virtual_bus.faults.Degradation`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ecu_monitor.errors import ParameterError
from ecu_monitor.model import (
    Drive,
    InputSeries,
    ThermalParams,
    coefficients,
    compute_drive,
    initial_pade_state,
    rk4_step,
    sensor_step,
)
from virtual_bus.faults import Degradation, gamma_schedule

__all__ = ["MAX_CYLINDERS", "CylinderState", "cylinder_models", "fly_cylinders"]

#: Most cylinders the virtual ECU flies (cylinders.dbc carries eight CHT signals).
MAX_CYLINDERS = 8


def cylinder_models(
    base: ThermalParams, count: int, *, heat_spread: float = 0.08, mass_spread: float = 0.05, seed: int = 0
) -> tuple[ThermalParams, ...]:
    """``count`` cylinder models made from ``base`` (module docstring); count 1 gives ``(base,)``."""
    if type(count) is not int or not 1 <= count <= MAX_CYLINDERS:
        raise ParameterError(f"cylinders: expected a number of cylinders 1 .. {MAX_CYLINDERS}, got {count!r}")
    for name, value in (("heat_spread", heat_spread), ("mass_spread", mass_spread)):
        if not 0.0 <= value < 0.5:
            raise ParameterError(f"cylinders.{name}: expected a fraction in [0, 0.5), got {value!r}")
    if count == 1:
        return (base,)
    rng = np.random.default_rng(np.random.SeedSequence([seed, count]))
    heat = 1.0 + heat_spread * rng.uniform(-1.0, 1.0, count)
    mass = 1.0 + mass_spread * rng.uniform(-1.0, 1.0, count)
    hm = base.heat_map
    out = []
    for h, m in zip(heat.tolist(), mass.tolist(), strict=True):
        values = tuple(tuple(v * h for v in row) for row in hm.values_w)
        heat_map = type(hm)(hm.x_axis, hm.y_axis, hm.x_breakpoints, hm.y_breakpoints, values)
        out.append(base.replace(heat_map=heat_map, c_w=base.c_w * m))
    return tuple(out)


@dataclass
class CylinderState:
    """One cylinder of the truth plant between control periods: head and probe temperature (degC),
    the heat-path Pade state (None before the first step)."""

    cht_c: float
    probe_c: float
    pade: Any = None


def fly_cylinders(
    states: list[CylinderState],
    models: Sequence[ThermalParams],
    inputs: InputSeries,
    time_s: np.ndarray,
    degradation: Sequence[Degradation],
    dt_s: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Integrate every cylinder over the steps ``time_s`` (inputs held per step, arrays of that length).

    Returns (head temperature, probe temperature, gamma_Q, gamma_D), each (cylinders, steps), the
    values at each step's start; ``states`` is advanced in place.
    """
    steps = time_s.size
    shape = (len(models), steps)
    cht_out, probe_out, gq_out, gd_out = (np.empty(shape) for _ in range(4))
    for c, (state, params) in enumerate(zip(states, models, strict=True)):
        coeffs = coefficients(params)
        probe_gain = float(sensor_step(0.0, 1.0, coeffs, dt_s))
        drive = compute_drive(inputs, coeffs)
        q, g, amb, cond, gain = (np.broadcast_to(v, (steps,)).tolist() for v in drive)
        mine = [e for e in degradation if e.applies_to(c + 1)]
        gq_out[c] = gamma_schedule(mine, "gamma_q", time_s)
        gd_out[c] = gamma_schedule(mine, "gamma_d", time_s)
        gq, gd = gq_out[c].tolist(), gd_out[c].tolist()
        cht: Any = state.cht_c
        probe = state.probe_c
        pade: Any = state.pade
        if pade is None:
            pade = float(initial_pade_state(Drive(q[0], g[0], amb[0], cond[0], gain[0])))
        for k in range(steps):
            cht_out[c, k] = cht
            probe_out[c, k] = probe
            cht, pade = rk4_step(cht, pade, Drive(q[k], g[k], amb[k], cond[k], gain[k]), coeffs, dt_s, gq[k], gd[k])
            probe = probe + probe_gain * (cht - probe)
        state.cht_c, state.probe_c, state.pade = float(cht), float(probe), pade
    return cht_out, probe_out, gq_out, gd_out
