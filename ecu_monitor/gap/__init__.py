"""Sim-to-real gap diagnosis: where the model departs from a flight, which unmodelled effect explains
it, and how far the held-out error shrinks once it is added.

Start with :func:`diagnose` (nominal model + train and test flights -> :class:`GapDiagnosis`) and
:func:`write_report` (gap.json, report.md, plots, model.yaml); the blind cases are in
:mod:`ecu_monitor.research.blind`. The run is in :mod:`.diagnose`, its settings and results in
:mod:`.diagnosis`, the held-out scoring of refitted candidates in :mod:`.scoring`.
"""

from ecu_monitor.gap.diagnose import EffectScore, GapDiagnosis, GapSettings, cross_validate, diagnose
from ecu_monitor.gap.report import gap_json, write_report
from ecu_monitor.gap.segments import SEGMENT_NAMES, SegmentSettings, segment_flight
from ecu_monitor.gap.significance import SignificanceSettings, improvement_test
from ecu_monitor.identify.library import CANDIDATE_IDS, CANDIDATES, Candidate, FreeParameter
from ecu_monitor.identify.refit import FitResult, RefitSettings, refit

__all__ = [
    "CANDIDATES",
    "CANDIDATE_IDS",
    "SEGMENT_NAMES",
    "Candidate",
    "EffectScore",
    "FitResult",
    "FreeParameter",
    "GapDiagnosis",
    "GapSettings",
    "RefitSettings",
    "SegmentSettings",
    "SignificanceSettings",
    "cross_validate",
    "diagnose",
    "gap_json",
    "improvement_test",
    "refit",
    "segment_flight",
    "write_report",
]
