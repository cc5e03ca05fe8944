"""``ecu-monitor results [--out results-out]``: reproduce the paper's Section 3.2 on the virtual ECU.

Flies steady cruises with gamma_Q / gamma_D injected at t = 150 s and compares EKF, CBEKF and
CBEKF-AU; writes the paper's Figures 7-11 and paper_reproduction.md (ecu_monitor.research.paper).
"""

from __future__ import annotations

import argparse
from typing import Any

from ecu_monitor.compile_cache import announce_compiles

__all__ = ["add_subparser"]


def add_subparser(subparsers: Any) -> None:
    """Register the ``results`` subcommand."""
    parser = subparsers.add_parser(
        "results",
        help="reproduce the paper's Section 3.2 on the virtual ECU (figures + paper_reproduction.md)",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument(
        "--out",
        default="results-out",
        metavar="DIR",
        help="output directory (default ./results-out: a new folder, never the checkout's docs/results;"
        " give --out docs/results to regenerate those)",
    )
    parser.add_argument("--seeds", type=int, default=4, metavar="N", help="flights per degradation level (4)")
    parser.set_defaults(func=announce_compiles(_run))  # a first run says it compiles


def _run(args: argparse.Namespace) -> int:
    from ecu_monitor.research.paper import generate
    from ecu_monitor.userfiles import prepare_output_dir

    out = prepare_output_dir(args.out, "--out")
    md = generate(out, seeds=max(1, int(args.seeds)))
    print(f"{md}: written with the figures in {out}/")
    return 0
