"""heartbeat_losses: silences of the target's heartbeat (Status) longer than its timeout, at most `max`.

    [criteria.heartbeat]
    kind = "heartbeat_losses"
    max = 0
"""

from __future__ import annotations

from bench.acceptance.kinds import register
from bench.acceptance.kinds._base import Criterion, Kind, Subject, judged
from bench.analysis.results import CheckResult


def judge(criterion: Criterion, subject: Subject) -> CheckResult:
    return judged(criterion, "", "heartbeat losses", float(subject.results.integrity.heartbeat.losses))


KIND = Kind("heartbeat_losses", "silences of the target's heartbeat longer than its timeout", "", judge)

register(KIND)
