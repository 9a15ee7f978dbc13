"""cycles: CPU cycles per model step, at most `max`: counted on the firmware engine (the emulated Cortex-M4F's
Timing4 figures), estimated otherwise (the C28x cost table, `target_sim/costs.py`); the check says which.

    [criteria.step_cycles]
    kind = "cycles"
    statistic = "max"         # "max" (default) or "p50"; the estimate has one figure, its max
    counted = false           # true: an estimate fails the check (only the firmware engine's count will do)
    max = 2000
"""

from __future__ import annotations

from bench.acceptance.kinds import register
from bench.acceptance.kinds._base import Criterion, Kind, Subject, judged
from bench.analysis.results import CheckResult, RunResults
from bench.tomlspec import choice, flag

COUNTED = "counted on the firmware engine (emulated Cortex-M4F)"
ESTIMATED = "estimated from the C28x cost table: the python engine counts none"


def step_cycles(results: RunResults, statistic: str = "max") -> tuple[float | None, str]:
    """Cycles per model step and how they were had: counted (firmware engine) or estimated (python engine)."""
    timing = results.timing
    if timing.engine == "firmware" and timing.m4_cycles is not None:
        value = getattr(timing.m4_cycles, statistic)
        return (None if value is None else float(value)), COUNTED
    return (None if timing.est_cycles is None else float(timing.est_cycles)), ESTIMATED


def judge(criterion: Criterion, subject: Subject) -> CheckResult:
    statistic = criterion.params["statistic"]
    figure, source = step_cycles(subject.results, statistic)
    if criterion.params["counted"] and source != COUNTED:
        return judged(criterion, "cycles", "cycles per model step", None, source=source,
                      why_none="counted = true and the run's engine counts none; run it with --engine firmware")
    what = f"cycles per model step ({statistic if source == COUNTED else 'max'})"
    return judged(criterion, "cycles", what, figure, source=source, why_none="no timing frames in the log")


KIND = Kind("cycles", "CPU cycles per model step (counted on the firmware engine, estimated otherwise)", "cycles",
            judge, options={"statistic": choice("max", "p50"), "counted": flag},
            defaults={"statistic": "max", "counted": False})

register(KIND)
