"""The blind cases with three train flights: is the verdict right when it is chosen by a leave-one-flight-out
over the train flights (``GapSettings.choose_on_train_from=3``, ``gap --choose-on-train``) and when it is
chosen on the test flight (the default)?

    nice -n 10 .venv/bin/python benchmarks/bench_gap_choice.py [--cases 10] [--seed 1] [--duration 1800]

Each case is the blind case ``index`` of series ``seed`` (:func:`ecu_monitor.research.blind.blind_case`: its
hidden effects, its perturbed nominal model, its test flight and the expected verdict by the size rule), with
two more train flights flown on other random missions with the same truth (and, for an out-of-library case,
the same stuck-door schedule as its train flight: a worn actuator that sticks on every flight). Both rules
get the same three train flights and the same test flight, local refits from the nominal model (as the
blind series). Prints one line per case and the verdicts right under each rule.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from ecu_monitor.gap import GapSettings, diagnose
from ecu_monitor.model import paper_table_a1
from ecu_monitor.research.blind import _measured, blind_case
from virtual_bus.plant import fly
from virtual_bus.random_missions import random_mission


def main() -> None:
    """Run the cases under both rules and print the table rows."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=10)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--duration", type=float, default=1800.0)
    args = parser.parse_args()
    rules = {
        "train leave-one-out": GapSettings(whiteness_estimator=None, choose_on_train_from=3),
        "on the test flight": GapSettings(whiteness_estimator=None),
    }
    right = dict.fromkeys(rules, 0)
    for index in range(args.cases):
        case = blind_case(index, args.seed, args.duration)
        truth = paper_table_a1()
        rng = np.random.default_rng([args.seed, index, 28])
        extra = [
            _measured(
                fly(
                    random_mission(int(m), args.duration),
                    truth,
                    effects=case.effects,
                    degradation=case.train_degradation,
                    seed=int(m),
                    dt_s=0.02,
                    record_dt_s=1.0,
                )
            )
            for m in rng.integers(0, 10**6, size=2)
        ]
        line = [f"case {index} {case.kind}: expected {'+'.join(case.expected) or 'null'}"]
        for name, settings in rules.items():
            started = time.perf_counter()
            diag = diagnose(case.nominal, [case.train, *extra], case.test, settings)
            ok = set(diag.verdict_ids) == set(case.expected)
            right[name] += ok
            shrink = f", {diag.winner.shrink_pct:.0f} %" if diag.winner is not None else ""
            line.append(
                f"{name}: {'+'.join(diag.verdict_ids) or 'null'}{shrink} {'ok' if ok else 'WRONG'}"
                f" ({time.perf_counter() - started:.0f} s)"
            )
        print("; ".join(line), flush=True)
    print("; ".join(f"{name}: {n}/{args.cases} right" for name, n in right.items()))


if __name__ == "__main__":
    main()
