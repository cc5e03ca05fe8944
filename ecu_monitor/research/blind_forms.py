"""Blind cases that are not circular: truths of a form the gap library does not contain exactly.

The blind cases of :mod:`ecu_monitor.research.blind` switch on the library's own effects in the
truth, so a right verdict there partly proves that the library can fit itself. Here the truth holds
a term of ANOTHER form (:class:`virtual_bus.plant.TruthForm`): an airspeed power law with a
slipstream floor on the whole dissipation, a sigmoid enrichment, a cooling loss that grows with run
time, an oil-temperature coupling (a second, slow state); plus, for comparison, cases with one
library effect and cases with nothing switched on.

Each case flies a TRAIN and a TEST flight on two different random missions and hands the diagnosis
the measured columns with a perturbed nominal model (as the library cases: C_w, R_Ce, tau_w, a and
the heat map perturbed the way an identification leaves them). It is not told what is on.

Scoring rule (fixed before the reported runs): the right verdict is the *nearest* library effect when
it shrinks the held-out error, null when none does. Nearest and "shrinks" are decided by an ORACLE
that knows what the diagnosis does not: it refits the control and every candidate on the train flight
from the TRUE nominal model (not the perturbed one), scores each on the test flight, and takes the
candidate with the lowest held-out RMS. The expected verdict is that candidate when it shrinks the
held-out RMS against the oracle's control by at least ``ORACLE_MIN_SHRINK_PCT`` = 20 % and
``ORACLE_MIN_DROP_C`` = 0.3 degC (the diagnosis's own materiality bar), otherwise null (the truth
term's own RMS contribution on the test flight, truth with minus without it on the same inputs, is
reported beside it, not used). The diagnosis is right when the set of effects it names equals the expected set (a
pair named where one effect is expected is wrong). The oracle runs no significance test and competes
with no perturbed nominal model: those are what the diagnosis must get through on its own.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ecu_monitor.flightlog import FlightLog
from ecu_monitor.gap.diagnose import GapDiagnosis, GapSettings, diagnose
from ecu_monitor.identify.library import candidate, flight_references
from ecu_monitor.identify.refit import prepare_flight, refit, simulate_probe
from ecu_monitor.model import Effects, ThermalParams, coefficients, paper_table_a1
from ecu_monitor.model.compiled import simulate_compiled
from ecu_monitor.research.blind import MEASURED_COLUMNS, perturbed_nominal
from virtual_bus.plant import TRUTH_FORM_KINDS, TruthForm, fly, random_effects, random_truth_form
from virtual_bus.random_missions import random_mission

__all__ = [
    "FORM_CASE_KINDS",
    "ORACLE_MIN_SHRINK_PCT",
    "FormCase",
    "FormResult",
    "form_case",
    "forms_markdown",
    "forms_summary",
    "oracle_expected",
    "run_form_case",
    "run_form_cases",
]

ORACLE_MIN_SHRINK_PCT = 20.0
ORACLE_MIN_DROP_C = 0.3
#: Kinds in the order they cycle over case indices: the four truth forms, one library effect, none.
FORM_CASE_KINDS: tuple[str, ...] = (*TRUTH_FORM_KINDS, "library", "none")


@dataclass(frozen=True)
class FormCase:
    """One generated case: the truth term (hidden from the diagnosis), the flights, the expectation."""

    index: int
    kind: str
    form: TruthForm | None
    effects: Effects
    nominal: ThermalParams
    train: FlightLog  # measured columns only
    test: FlightLog
    contribution_rms_c: float  # the truth term's RMS contribution on the test flight, degC
    oracle: dict[str, float]  # candidate id -> held-out shrink vs the oracle's control, %
    nearest: str | None  # the oracle's best candidate (whether or not it shrinks enough)
    expected: tuple[str, ...]  # the rule's verdict (empty: null)


@dataclass(frozen=True)
class FormResult:
    """A case and what the diagnosis said about it."""

    case: FormCase
    diagnosis: GapDiagnosis
    verdict: tuple[str, ...]
    right: bool

    def to_dict(self) -> dict[str, Any]:
        """One row of the case table."""
        c = self.case
        d = self.diagnosis
        return {
            "index": c.index,
            "kind": c.kind,
            "form": dict(c.form.params) if c.form is not None else None,
            "effects": c.effects.to_dict(),
            "contribution_rms_c": c.contribution_rms_c,
            "oracle_shrink_pct": c.oracle,
            "nearest": c.nearest,
            "expected": list(c.expected),
            "verdict": list(self.verdict),
            "right": self.right,
            "baseline_test_rms_c": float(np.sqrt(np.mean(d.baseline_test_residual**2))),
            "verdict_shrink_pct": d.winner.shrink_pct if d.winner is not None else None,
            "tried": [
                {
                    "id": e.label,
                    "test_rms_c": e.test_rms_c,
                    "shrink_vs_reference_pct": e.versus.shrink_pct if e.versus else None,
                    "p_value": e.versus.p_value if e.versus else None,
                    "test_level": e.versus.level if e.versus else None,
                    "train_rms_c": e.fit.train_rms_c,
                    "counts": e.counts,
                }
                for e in d.effects
            ],
        }


def _measured(log: FlightLog) -> FlightLog:
    return FlightLog({k: log[k] for k in MEASURED_COLUMNS if log.has(k)}, source=log.source)


def _contribution(truth: ThermalParams, full: FlightLog, dt_s: float) -> float:
    """RMS of truth-with minus truth-without the term on ``full`` (a flight with its truth columns),
    open loop on its inputs, degC."""
    flight = prepare_flight(full, truth.heat_axes, dt_s)
    grid = flight.grid
    times = float(full.time_s[0]) + grid.dt_s * np.arange(np.size(grid.inputs.heat_x))

    def held(name: str) -> np.ndarray | float:
        if not full.has(name):
            return 1.0
        index = np.clip(np.searchsorted(full.time_s, times, side="right") - 1, 0, len(full) - 1)
        return np.asarray(full[name], dtype=float)[index]

    def run(params: ThermalParams, gamma_q: np.ndarray | float, gamma_d: np.ndarray | float) -> np.ndarray:
        out = simulate_compiled(
            grid.inputs,
            coefficients(params),
            grid.dt_s,
            grid.initial_c,
            gamma_q=gamma_q,
            gamma_d=gamma_d,
            record_every=grid.record_every,
        )
        return np.asarray(grid.sample(out.probe_c), dtype=float)

    bare = run(truth.replace(effects=Effects()), 1.0, 1.0)
    with_term = run(truth, held("form_gamma_q"), held("form_gamma_d"))
    return float(np.sqrt(np.mean((with_term - bare) ** 2)))


def oracle_expected(
    true_nominal: ThermalParams,
    train: FlightLog,
    test: FlightLog,
    candidates: Sequence[str],
    settings: GapSettings,
) -> tuple[dict[str, float], str | None, tuple[str, ...]]:
    """The rule's verdict (module doc): shrink of each candidate vs the oracle's control, the nearest
    candidate, and the expected verdict (empty: null)."""
    axes = true_nominal.heat_axes
    dt = settings.refit.dt_s
    train_flight = prepare_flight(train, axes, dt)
    test_flight = prepare_flight(test, axes, dt)
    references = flight_references(train, settings.segments.ground_airspeed_mps)
    fits = [refit(true_nominal, train_flight, [], references, settings.refit)]
    fits += [refit(true_nominal, train_flight, [candidate(cid)], references, settings.refit) for cid in candidates]
    probe = simulate_probe([f.params for f in fits], test_flight, settings.refit.engine)
    residual = np.where(np.isfinite(probe), test_flight.cht_c[:, None] - probe, 1e3)
    rms = np.sqrt(np.mean(residual**2, axis=0))
    control = float(rms[0])
    shrink = {cid: 100.0 * (1.0 - float(r) / control) for cid, r in zip(candidates, rms[1:], strict=True)}
    best = int(np.argmin(rms[1:]))
    nearest = candidates[best]
    drop = control - float(rms[1 + best])
    if shrink[nearest] >= ORACLE_MIN_SHRINK_PCT and drop >= ORACLE_MIN_DROP_C:
        return shrink, nearest, (nearest,)
    return shrink, nearest, ()


def form_case(
    index: int,
    seed: int,
    duration_s: float = 3600.0,
    settings: GapSettings | None = None,
    record_dt_s: float = 1.0,
) -> FormCase:
    """Generate case ``index`` of the series ``seed`` and its expected verdict (deterministic)."""
    settings = settings or GapSettings()
    rng = np.random.default_rng([seed, 7919, index])
    kind = FORM_CASE_KINDS[index % len(FORM_CASE_KINDS)]
    draw = int(rng.integers(0, 2**31))
    form = random_truth_form(draw, kind) if kind in TRUTH_FORM_KINDS else None
    effects = Effects()
    if kind == "library":
        effects = random_effects(draw, [str(rng.choice(settings.candidates))])
    truth = paper_table_a1().replace(effects=effects)
    forms = (form,) if form is not None else ()
    train_mission, test_mission = (int(v) for v in rng.integers(0, 10**6, size=2))
    common: dict[str, Any] = {"dt_s": 0.02, "record_dt_s": record_dt_s, "truth_forms": forms}
    train = fly(random_mission(train_mission, duration_s), truth, seed=train_mission, **common)
    test = fly(random_mission(test_mission, duration_s), truth, seed=test_mission, **common)
    true_nominal = truth.replace(effects=Effects())
    contribution = _contribution(truth, test, 0.1) if kind != "none" else 0.0
    train_m, test_m = _measured(train), _measured(test)
    oracle, nearest, expected = oracle_expected(true_nominal, train_m, test_m, settings.candidates, settings)
    nominal = perturbed_nominal(true_nominal, rng)
    return FormCase(index, kind, form, effects, nominal, train_m, test_m, contribution, oracle, nearest, expected)


def run_form_case(case: FormCase, settings: GapSettings | None = None) -> FormResult:
    """Diagnose one case without telling it the truth, and score the verdict by the rule."""
    diagnosis = diagnose(case.nominal, case.train, case.test, settings)
    verdict = diagnosis.verdict_ids
    return FormResult(case, diagnosis, verdict, set(verdict) == set(case.expected))


def run_form_cases(
    n: int,
    seed: int = 0,
    duration_s: float = 3600.0,
    settings: GapSettings | None = None,
    progress: Callable[[FormResult], None] | None = None,
) -> list[FormResult]:
    """Generate and diagnose ``n`` cases of series ``seed``; ``progress`` is called after each."""
    settings = settings or GapSettings()
    results = []
    for index in range(n):
        result = run_form_case(form_case(index, seed, duration_s, settings), settings)
        if progress is not None:
            progress(result)
        results.append(result)
    return results


def forms_summary(results: Sequence[FormResult]) -> dict[str, dict[str, Any]]:
    """Verdicts right by case kind, split by what the rule expected (an effect or null)."""
    out: dict[str, dict[str, Any]] = {}
    for kind in FORM_CASE_KINDS:
        group = [r for r in results if r.case.kind == kind]
        if not group:
            continue
        effect = [r for r in group if r.case.expected]
        null = [r for r in group if not r.case.expected]
        out[kind] = {
            "cases": len(group),
            "right": sum(r.right for r in group),
            "expect_effect": len(effect),
            "expect_effect_right": sum(r.right for r in effect),
            "expect_null": len(null),
            "expect_null_right": sum(r.right for r in null),
        }
    out["all"] = {
        "cases": len(results),
        "right": sum(r.right for r in results),
        "expect_effect": sum(bool(r.case.expected) for r in results),
        "expect_effect_right": sum(r.right for r in results if r.case.expected),
        "expect_null": sum(not r.case.expected for r in results),
        "expect_null_right": sum(r.right for r in results if not r.case.expected),
    }
    return out


def _label(ids: Sequence[str]) -> str:
    return "+".join(ids) if ids else "null"


def forms_markdown(results: Sequence[FormResult], command: str | None = None) -> str:
    """A Markdown page: scores by kind and one row per case."""
    lines = ["# Gap diagnosis: non-circular blind cases (truth forms outside the library)", ""]
    if command:
        lines += [f"Command: `{command}`", ""]
    lines += [
        "Rule: the right verdict is the nearest library effect (the oracle's best refit from the true nominal "
        "model) when it shrinks the "
        f"held-out RMS by >= {ORACLE_MIN_SHRINK_PCT:.0f} % and {ORACLE_MIN_DROP_C} degC vs the oracle's control; "
        "null otherwise.",
        "",
        "| kind | cases | right | expected an effect (right) | expected null (right) |",
        "|---|---|---|---|---|",
    ]
    for kind, s in forms_summary(results).items():
        lines.append(
            f"| {kind} | {s['cases']} | {s['right']}/{s['cases']} | {s['expect_effect_right']}/{s['expect_effect']}"
            f" | {s['expect_null_right']}/{s['expect_null']} |"
        )
    lines += [
        "",
        "| # | kind | truth term | contribution RMS, degC | oracle shrink of the nearest | expected | verdict"
        " | verdict shrink | right |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        c = r.case
        term = (
            ", ".join(f"{k} {v:.3g}" for k, v in c.form.params)
            if c.form is not None
            else (", ".join(c.effects.active) or "-")
        )
        near = f"{c.nearest} {c.oracle[c.nearest]:+.0f} %" if c.nearest else "-"
        shrink = f"{r.diagnosis.winner.shrink_pct:.0f} %" if r.diagnosis.winner is not None else "-"
        lines.append(
            f"| {c.index} | {c.kind} | {term} | {c.contribution_rms_c:.2f} | {near} | {_label(c.expected)}"
            f" | {_label(r.verdict)} | {shrink} | {'yes' if r.right else 'NO'} |"
        )
    return "\n".join(lines) + "\n"
