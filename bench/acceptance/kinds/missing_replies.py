"""missing_replies: data rows the target never answered, at most `max`.

    [criteria.every_reply]
    kind = "missing_replies"
    max = 0
"""

from __future__ import annotations

from bench.acceptance.kinds import register
from bench.acceptance.kinds._base import Criterion, Kind, Subject, judged
from bench.analysis.results import CheckResult


def judge(criterion: Criterion, subject: Subject) -> CheckResult:
    counts = subject.results.counts
    return judged(criterion, "", f"missing replies (of {counts.steps_sent} rows)", float(counts.missing))


KIND = Kind("missing_replies", "data rows the target never answered", "", judge)

register(KIND)
