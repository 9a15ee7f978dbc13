"""deadline_misses: model steps that overran their period (the target's Timing overrun count: a step that took
longer than Δt), plus in a run with injected faults the rows that missed their deadline unexplained; at most `max`.

    [criteria.deadlines]
    kind = "deadline_misses"
    max = 0
"""

from __future__ import annotations

from bench.acceptance.kinds import register
from bench.acceptance.kinds._base import Criterion, Kind, Subject, judged
from bench.analysis.results import CheckResult


def judge(criterion: Criterion, subject: Subject) -> CheckResult:
    results = subject.results
    faults = results.faults
    unexplained = (faults.unexplained_deadline_misses or 0) if faults is not None else 0
    return judged(criterion, "", "deadline misses (steps over Δt)", float(results.timing.overruns + unexplained))


KIND = Kind("deadline_misses", "model steps that took longer than their period Δt", "", judge)

register(KIND)
