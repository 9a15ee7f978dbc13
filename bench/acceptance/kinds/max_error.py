"""max_error: a node's largest |CAN − reference| (°C), against the measurement or the float64 model, at most `max`.

    [criteria.pm_peak]
    kind = "max_error"
    nodes = ["winding", "magnet"]
    against = "measured"
    max = 8.0
"""

from __future__ import annotations

from bench.acceptance.kinds import register
from bench.acceptance.kinds._base import Criterion, Kind, Subject, node_check, nodes
from bench.acceptance.kinds.rmse import AGAINST
from bench.analysis.results import CheckResult, NodeValues


def judge(criterion: Criterion, subject: Subject) -> CheckResult:
    accuracy = subject.results.accuracy   # results of an older bench have no max error: every node then fails
    return node_check(criterion, subject, "°C", "max error", accuracy.max_abs_error_C or NodeValues(),
                      accuracy.max_abs_error_vs_float64_C)


KIND = Kind("max_error", "per-node largest |CAN − reference| against the measurement or the float64 model", "°C",
            judge, options={"nodes": nodes, "against": AGAINST}, defaults={"nodes": "all", "against": "reported"})

register(KIND)
