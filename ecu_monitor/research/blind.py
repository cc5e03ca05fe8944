"""Blind cases: the diagnosis run on virtual-ECU flights whose unmodelled effect it is not told.

Each case flies a TRAIN and a TEST flight on two different random missions through the virtual
ECU's truth plant (the paper's Table A1 model plus the case's effects, quantised 1 degC probe), and
hands the diagnosis the measured columns only (the truth columns are stripped) with a *nominal
model* that is the truth's nominal part perturbed the way an identification leaves it: C_w x
U(0.92, 1.08), R_Ce x U(0.95, 1.05), tau_w x U(0.7, 1.3), the exponent a x U(0.95, 1.05), the heat
map x U(0.95, 1.05) overall and x (1 + N(0, 0.015)) per cell.

Case kinds (cycled, so any n holds every kind): ``single`` (one library effect at a random size drawn
by :func:`virtual_bus.plant.random_effects`), ``none``, ``out_of_library`` (a cooling door that sticks
part-shut mid-flight: gamma_D ramps to U(1.12, 1.3) over 60-300 s, from a random time in the middle
third of the test flight and, independently drawn, from a random time between 15 % and 85 % of the
train flight: a worn actuator that sticks on every flight, not at the same moment), and ``pair``
(two library effects).

Scoring rule (fixed before the runs): a library effect counts as *present* when its RMS contribution
on the test flight (truth with minus truth without the effect, same inputs, open loop) is at least
``min_effect_rms_c`` = 1.0 degC, the quantisation step. The expected verdict is the set of present
library effects (empty = null; an out-of-library case always expects null). The expected segment is
the test-flight segment holding the largest share of the squared contribution of everything
switched on (including the stuck door).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ecu_monitor.flightlog import FlightLog
from ecu_monitor.gap.diagnose import GapDiagnosis, GapSettings, diagnose
from ecu_monitor.gap.segments import SEGMENT_NAMES, segment_flight
from ecu_monitor.identify.library import DEFAULT_CANDIDATE_IDS as CANDIDATE_IDS
from ecu_monitor.identify.refit import prepare_flight
from ecu_monitor.model import Effects, ThermalParams, coefficients, paper_table_a1
from ecu_monitor.model.compiled import simulate_compiled
from virtual_bus.plant import Degradation, fly, gamma_schedule, random_effects
from virtual_bus.random_missions import random_mission

__all__ = [
    "CASE_KINDS",
    "MIN_EFFECT_RMS_C",
    "BlindCase",
    "BlindResult",
    "blind_case",
    "blind_markdown",
    "confusion_matrix",
    "perturbed_nominal",
    "run_blind_case",
    "run_blind_cases",
    "summary",
]

MIN_EFFECT_RMS_C = 1.0
#: Kinds in the order they cycle over case indices (10 cases: 5 single, 2 none, 2 out-of-library, 1 pair).
CASE_KINDS: tuple[str, ...] = (
    "single",
    "single",
    "none",
    "single",
    "out_of_library",
    "single",
    "pair",
    "single",
    "none",
    "out_of_library",
)
MEASURED_COLUMNS = (
    "time_s",
    "throttle_pct",
    "rpm",
    "altitude_m",
    "airspeed_mps",
    "oat_c",
    "cht_c",
    "fuel_flow_lph",
    "vspeed_mps",
)


@dataclass(frozen=True)
class BlindCase:
    """One generated case: what is switched on (hidden from the diagnosis) and the two flights."""

    index: int
    kind: str
    effects: Effects
    train_degradation: tuple[Degradation, ...]
    test_degradation: tuple[Degradation, ...]
    nominal: ThermalParams
    train: FlightLog  # measured columns only
    test: FlightLog
    contribution_rms_c: dict[str, float]  # per switched-on effect (and "stuck_door"), on the test flight
    expected: tuple[str, ...]  # library effects present by the size rule (empty: null)
    expected_segment: str | None


@dataclass(frozen=True)
class BlindResult:
    """A case and what the diagnosis said about it."""

    case: BlindCase
    diagnosis: GapDiagnosis
    verdict: tuple[str, ...]
    verdict_right: bool
    segment: str
    segment_right: bool | None  # None when there is nothing to locate (no-effect case)
    shrink_pct: float | None  # held-out shrink vs the baseline when an effect was named

    def to_dict(self) -> dict[str, Any]:
        """One row of the blind-case table."""
        c = self.case
        return {
            "index": c.index,
            "kind": c.kind,
            "switched_on": list(c.effects.active) + (["stuck_door"] if c.test_degradation else []),
            "sizes": c.effects.to_dict(),
            "door_gamma_d": c.test_degradation[0].value if c.test_degradation else None,
            "contribution_rms_c": c.contribution_rms_c,
            "expected": list(c.expected),
            "expected_segment": c.expected_segment,
            "verdict": list(self.verdict),
            "verdict_right": self.verdict_right,
            "segment": self.segment,
            "segment_right": self.segment_right,
            "where_top_segment": self.diagnosis.where[0].segment,
            "baseline_test_rms_c": float(np.sqrt(np.mean(self.diagnosis.baseline_test_residual**2))),
            "shrink_pct": self.shrink_pct,
            "control_test_rms_c": self.diagnosis.control.test_rms_c,
            "tried": [
                {
                    "id": e.label,
                    "role": e.role,
                    "test_rms_c": e.test_rms_c,
                    "shrink_vs_reference_pct": e.versus.shrink_pct if e.versus else None,
                    "p_value": e.versus.p_value if e.versus else None,
                    "test_level": e.versus.level if e.versus else None,
                    "train_rms_c": e.fit.train_rms_c,
                    "counts": e.counts,
                }
                for e in self.diagnosis.effects
            ],
        }


def perturbed_nominal(truth: ThermalParams, rng: np.random.Generator) -> ThermalParams:
    """The truth's nominal part (effects off) perturbed as an identification leaves it (module doc)."""
    values = truth.heat_map.values_array()
    values = values * rng.uniform(0.95, 1.05) * (1.0 + rng.normal(0.0, 0.015, size=values.shape))
    return truth.replace(
        c_w=truth.c_w * rng.uniform(0.92, 1.08),
        r_ce=truth.r_ce * rng.uniform(0.95, 1.05),
        tau_w=truth.tau_w * rng.uniform(0.7, 1.3),
        a=truth.a * rng.uniform(0.95, 1.05),
        heat_map=truth.heat_map.with_values(np.clip(values, 0.0, None)),
        effects=Effects(),
    )


def _door(rng: np.random.Generator, start_s: tuple[float, float]) -> tuple[Degradation, ...]:
    value = float(rng.uniform(1.12, 1.3))
    start = float(rng.uniform(*start_s))
    return (Degradation("gamma_d", value, start, float(rng.uniform(60.0, 300.0))),)


def _measured(log: FlightLog) -> FlightLog:
    return FlightLog({k: log[k] for k in MEASURED_COLUMNS if log.has(k)}, source=log.source)


def _contributions(
    truth: ThermalParams, effects: Effects, door: Sequence[Degradation], test: FlightLog, dt_s: float
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Open-loop truth with minus without each switched-on part, at the test samples; and the total."""
    flight = prepare_flight(test, truth.heat_axes, dt_s)
    grid = flight.grid
    times = float(test.time_s[0]) + grid.dt_s * np.arange(np.size(grid.inputs.heat_x))
    gamma_d = np.asarray(gamma_schedule(door, "gamma_d", times), dtype=float)

    def run(params: ThermalParams, with_door: bool) -> np.ndarray:
        out = simulate_compiled(
            grid.inputs,
            coefficients(params),
            grid.dt_s,
            grid.initial_c,
            gamma_d=gamma_d if with_door else 1.0,
            record_every=grid.record_every,
        )
        return np.asarray(grid.sample(out.probe_c), dtype=float)

    bare = run(truth.replace(effects=Effects()), False)
    parts: dict[str, np.ndarray] = {}
    for name in effects.active:
        only = Effects().replace(name, getattr(effects, name))
        parts[name] = run(truth.replace(effects=only), False) - bare
    if door:
        parts["stuck_door"] = run(truth.replace(effects=Effects()), True) - bare
    total = run(truth.replace(effects=effects), bool(door)) - bare
    return parts, total


def blind_case(index: int, seed: int, duration_s: float = 3600.0, record_dt_s: float = 1.0) -> BlindCase:
    """Generate case ``index`` of the series ``seed`` (deterministic)."""
    rng = np.random.default_rng([seed, index])
    kind = CASE_KINDS[index % len(CASE_KINDS)]
    effect_seed = int(rng.integers(0, 2**31))
    if kind == "single":
        singles_before = sum(1 for k in range(index) if CASE_KINDS[k % len(CASE_KINDS)] == "single")
        names: list[str] = [CANDIDATE_IDS[singles_before % len(CANDIDATE_IDS)]]
    elif kind == "pair":
        names = list(rng.choice(CANDIDATE_IDS, size=2, replace=False))
    else:
        names = []
    effects = random_effects(effect_seed, names) if names else Effects()
    truth = paper_table_a1()
    train_mission, test_mission = (int(v) for v in rng.integers(0, 10**6, size=2))
    door = kind == "out_of_library"
    train_door = _door(rng, (0.15 * duration_s, 0.85 * duration_s)) if door else ()
    test_door = _door(rng, (duration_s / 3.0, 2.0 * duration_s / 3.0)) if door else ()
    common: dict[str, Any] = {"effects": effects, "dt_s": 0.02, "record_dt_s": record_dt_s}
    train = fly(random_mission(train_mission, duration_s), truth, degradation=train_door, seed=train_mission, **common)
    test = fly(random_mission(test_mission, duration_s), truth, degradation=test_door, seed=test_mission, **common)
    nominal = perturbed_nominal(truth, rng)
    parts, total = _contributions(truth, effects, test_door, test, 0.1)
    sizes = {name: float(np.sqrt(np.mean(values**2))) for name, values in parts.items()}
    expected = tuple(n for n in CANDIDATE_IDS if n in effects.active and sizes[n] >= MIN_EFFECT_RMS_C)
    segment = None
    if parts:
        seg = segment_flight(test)
        shares = {SEGMENT_NAMES[i]: float(np.sum(total[seg.labels == i] ** 2)) for i in np.unique(seg.labels)}
        segment = max(shares, key=lambda k: shares[k])
    return BlindCase(
        index,
        kind,
        effects,
        train_door,
        test_door,
        nominal,
        _measured(train),
        _measured(test),
        sizes,
        expected,
        segment,
    )


def run_blind_case(case: BlindCase, settings: GapSettings | None = None) -> BlindResult:
    """Diagnose one case without telling it the truth, and score the answer."""
    diagnosis = diagnose(case.nominal, case.train, case.test, settings)
    verdict = diagnosis.verdict_ids
    right = set(verdict) == set(case.expected)
    segment = diagnosis.winner_segment
    segment_right = None if case.expected_segment is None else segment == case.expected_segment
    shrink = diagnosis.winner.shrink_pct if diagnosis.winner is not None else None
    return BlindResult(case, diagnosis, verdict, right, segment, segment_right, shrink)


def run_blind_cases(
    n: int,
    seed: int = 0,
    duration_s: float = 3600.0,
    settings: GapSettings | None = None,
    progress: Callable[[BlindResult], None] | None = None,
) -> list[BlindResult]:
    """Generate and diagnose ``n`` cases of series ``seed``; ``progress`` is called after each."""
    results = []
    for index in range(n):
        result = run_blind_case(blind_case(index, seed, duration_s), settings)
        if progress is not None:
            progress(result)
        results.append(result)
    return results


def _label(ids: Sequence[str]) -> str:
    return "+".join(sorted(ids)) if ids else "null"


def confusion_matrix(results: Sequence[BlindResult]) -> dict[str, dict[str, int]]:
    """Counts of (expected verdict -> verdict given); labels are effect ids, 'a+b' pairs or 'null'."""
    table: dict[str, dict[str, int]] = {}
    for r in results:
        row = table.setdefault(_label(r.case.expected), {})
        key = _label(r.verdict)
        row[key] = row.get(key, 0) + 1
    return table


def summary(results: Sequence[BlindResult]) -> dict[str, Any]:
    """Scores by case kind: verdicts right, segments right, held-out shrink where an effect was found."""
    out: dict[str, Any] = {}
    groups = {
        "single (effect present by the size rule)": [r for r in results if r.case.kind == "single" and r.case.expected],
        "single (effect below the size rule: expects null)": [
            r for r in results if r.case.kind == "single" and not r.case.expected
        ],
        "none": [r for r in results if r.case.kind == "none"],
        "out_of_library": [r for r in results if r.case.kind == "out_of_library"],
        "pair": [r for r in results if r.case.kind == "pair"],
    }
    for name, group in groups.items():
        if not group:
            continue
        located = [r for r in group if r.segment_right is not None]
        found = [r.shrink_pct for r in group if r.verdict_right and r.shrink_pct is not None]
        out[name] = {
            "cases": len(group),
            "verdict_right": sum(r.verdict_right for r in group),
            "segment_right": sum(bool(r.segment_right) for r in located),
            "segment_cases": len(located),
            "min_shrink_pct": float(min(found)) if found else None,
            "median_shrink_pct": float(np.median(found)) if found else None,
        }
    return out


def blind_markdown(results: Sequence[BlindResult], command: str | None = None) -> str:
    """A Markdown page: scores, confusion matrix and one row per case."""
    lines = ["# Gap diagnosis: blind cases", ""]
    if command:
        lines += [f"Command: `{command}`", ""]
    lines += [
        f"Rule: a library effect counts as present when its RMS contribution on the test flight is at least "
        f"{MIN_EFFECT_RMS_C} degC (the quantisation step); expected verdict = the present effects, null otherwise.",
        "",
        "| kind | cases | verdict right | segment right | held-out shrink when found (min / median) |",
        "|---|---|---|---|---|",
    ]
    for name, s in summary(results).items():
        shrink = (
            f"{s['min_shrink_pct']:.0f} % / {s['median_shrink_pct']:.0f} %" if s["min_shrink_pct"] is not None else "-"
        )
        seg = f"{s['segment_right']}/{s['segment_cases']}" if s["segment_cases"] else "-"
        lines.append(f"| {name} | {s['cases']} | {s['verdict_right']}/{s['cases']} | {seg} | {shrink} |")
    matrix = confusion_matrix(results)
    columns = sorted({c for row in matrix.values() for c in row})
    lines += ["", "Confusion matrix (rows: expected, columns: verdict):", ""]
    lines.append("| expected \\ verdict | " + " | ".join(columns) + " |")
    lines.append("|---|" + "---|" * len(columns))
    for row_name in sorted(matrix):
        lines.append(f"| {row_name} | " + " | ".join(str(matrix[row_name].get(c, 0) or "") for c in columns) + " |")
    lines += [
        "",
        "| # | kind | switched on (size) | contribution RMS, degC | expected | verdict | segment (expected) | shrink |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        d = r.to_dict()
        shown = {n: {k: v for k, v in p.items() if not k.startswith("reference")} for n, p in d["sizes"].items()}
        sizes = ", ".join(
            f"{name}({', '.join(f'{k}={v:.3g}' for k, v in params.items())})" for name, params in shown.items()
        )
        if d["door_gamma_d"] is not None:
            sizes = (sizes + ", " if sizes else "") + f"stuck_door(gamma_d={d['door_gamma_d']:.2f})"
        contrib = ", ".join(f"{v:.1f}" for v in d["contribution_rms_c"].values()) or "-"
        mark = "ok" if r.verdict_right else "WRONG"
        seg = f"{d['segment']} ({d['expected_segment'] or '-'})"
        shrink = f"{d['shrink_pct']:.0f} %" if d["shrink_pct"] is not None else "-"
        lines.append(
            f"| {d['index']} | {d['kind']} | {sizes or '-'} | {contrib} | {_label(r.case.expected)} | "
            f"{_label(r.verdict)} {mark} | {seg} | {shrink} |"
        )
    return "\n".join(lines) + "\n"
