"""rmse: a node's RMSE (°C) of the CAN values against the measurement or the float64 model, at most `max`.

    [criteria.pm_rmse]
    kind = "rmse"
    nodes = "magnet"          # a node, a list, or "all" (default)
    against = "measured"      # "measured", "float64", or "reported" (default: the run's own, measured where
    max = 3.0                 #  the data measures the node, else the float64 model)
"""

from __future__ import annotations

from bench.acceptance.kinds import register
from bench.acceptance.kinds._base import Criterion, Kind, Subject, node_check, nodes
from bench.analysis.results import CheckResult
from bench.tomlspec import choice

AGAINST = choice("reported", "measured", "float64")


def judge(criterion: Criterion, subject: Subject) -> CheckResult:
    accuracy = subject.results.accuracy
    return node_check(criterion, subject, "°C", "RMSE", accuracy.rmse_C, accuracy.rmse_vs_float64_C)


KIND = Kind("rmse", "per-node RMSE of the CAN values against the measurement or the float64 model", "°C", judge,
            options={"nodes": nodes, "against": AGAINST}, defaults={"nodes": "all", "against": "reported"})

register(KIND)
