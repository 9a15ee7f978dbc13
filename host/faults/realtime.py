"""Real-time replay with faults: the rows go out on the clock, through the fault layer, and nothing is sent again.

On a vehicle bus a lost sample stays lost: the target leaves a row it never got (or refused) out of its model
step's interval mean and goes on (`target_sim.node`), so its estimate departs from the clean run's — that
departure is what a real-time fault run measures. Each row is sent at t0 + n·T_s/speed as in
`host.replay.run_realtime`; the fault layer alters the drive frames (the target's reply faults come from the
target), and every injection is marked in the log. Detection is the same as in lockstep (the target's journal,
the host's validator), except that the host detects a `delay` by the row's reply coming later than the reply
timeout. A lost or refused frame also costs the next row: the next frame of its id shows the alive-counter jump
(that is how the receiver detects the loss) and is refused itself, so a row after a fault may go unanswered too;
those are consequences, not problems (`host.faults.reconcile`). Process faults need lockstep (a lost target's
rows cannot be sent again on a clock) and are refused, as is a reply timeout that does not fit 4 times into the
sample interval (a delayed row must not reach into the next one).
"""

from __future__ import annotations

import time

import numpy as np

from host.replay import Progress, ReplayStats, run_realtime
from host.session import HostSession

from .bus import FaultyBus
from .lockstep import FaultRun, RowPass, mark_new_injections
from .plan import FaultPlan
from .spec import FaultSpecError

INTERVAL_PER_REPLY_TIMEOUT = 4.0


def check_realtime_faults(plan: FaultPlan, sample_period_s: float, speed: float, reply_timeout_s: float) -> None:
    """FaultSpecError (one sentence) when these faults cannot run on this real-time clock."""
    if plan.process_rows:
        raise FaultSpecError("kill and freeze faults need lockstep mode (a lost target's rows cannot be sent again "
                             "on a real-time clock); drop them from the faults or use --mode lockstep")
    interval = sample_period_s / speed
    if interval < INTERVAL_PER_REPLY_TIMEOUT * reply_timeout_s:
        raise FaultSpecError(f"faults in real time need a sample interval of at least {INTERVAL_PER_REPLY_TIMEOUT:g} "
                             f"reply timeouts ({interval * 1e3:g} ms < {INTERVAL_PER_REPLY_TIMEOUT:g} x "
                             f"{reply_timeout_s * 1e3:g} ms); lower --speed or --reply-timeout")


class _FaultHooks:
    """Around each row's send: the row's faults (the first row is never faulted) and their marks."""

    def __init__(self, session: HostSession, faulty: FaultyBus):
        self.session = session
        self.faulty = faulty

    def begin(self, row: int) -> None:
        self.faulty.begin_row(row, 0, eligible=row > 0)

    def end(self, row: int) -> None:
        self.faulty.end_row()
        mark_new_injections(self.session, self.faulty, row)


def run_realtime_with_faults(session: HostSession, drive: np.ndarray, *, faulty: FaultyBus, plan: FaultPlan,
                             sample_period_s: float, speed: float, reply_timeout_s: float,
                             progress: Progress | None = None,
                             measurements: np.ndarray | None = None) -> tuple[ReplayStats, FaultRun]:
    check_realtime_faults(plan, sample_period_s, speed, reply_timeout_s)
    run = FaultRun(plan.spec, injections=faulty.injections, started_at=time.time(), mode="realtime")
    stats = run_realtime(session, drive, sample_period_s=sample_period_s, speed=speed,
                         reply_timeout_s=max(reply_timeout_s, 2 * sample_period_s / speed), progress=progress,
                         hooks=_FaultHooks(session, faulty), measurements=measurements)
    faulty.flush_held()
    session.flush_log()
    book = session.book
    sent = stats.rows_sent
    late = (book.replied_ns[:sent] - book.sent_ns[:sent]) > reply_timeout_s * 1e9
    run.deadline_misses = [RowPass(row) for row in np.flatnonzero(~book.answered()[:sent] | late).tolist()]
    run.frames_transmitted = faulty.transmitted
    return stats, run
