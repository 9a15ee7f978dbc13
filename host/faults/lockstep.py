"""Lockstep replay that survives faults: retransmission of unanswered rows and re-initialization of a target that
was lost, with BenchEvent marks in the log.

Per data row n (as `host.replay.run_lockstep`): send (Measurements +) DriveInputs + DriveTemps (+ DriveCurrents),
wait for
Temperatures1 + 2 up to the reply timeout. When the deadline passes (the row's *deadline miss*, recorded with the
row's pass; a row answered after its deadline, which the wait can see when the deadline is shorter than its spin,
is a miss too, and is not sent again):

1. Retransmit: mark RETRANSMIT, send row n twice more with fresh alive counters (and again every RETRY_FACTOR
   reply timeouts, but no sooner than RETRY_MIN_S, while it stays unanswered: the reply to the retransmission may be
   lost too). After a lost or
   rejected frame the target's validator refuses the next frame of that id (its counter jumps) and
   resynchronizes on it, so the first copy may be refused; the second is then accepted. A target that already
   used row n answers it again without stepping (its reply was lost on the way back). Either way row n reaches
   the model exactly once, with the values the clean run has, so the estimates stay equal to the clean run's.
2. Wait for the reply. If instead the target is *lost* — no Status for longer than the heartbeat timeout, or a
   Status whose state is no longer RUNNING (it restarted) — re-initialize it:
   mark TARGET_LOST (Step = n, the first row without a reply), forget the target's alive counters (a restarted
   target starts its own at 0), let the runner restart a dead target (`ProcessControl.ensure_running`), wait for
   its heartbeat (model id checked), then start a new *segment* at row s from the last good estimate: the newest
   complete StateCheckpoint the target sent for a row c < n (every 20 model steps: its float32 state vector, bit
   for bit), so s = c + 1, the first row of a model step interval; mark REINIT (Step = s), echo the checkpoint in
   RestoreState, RESTORE and START at Step s, and replay on from row s. Without a checkpoint yet, s is the
   session's first row and the target is RESET to the session's initial temperatures. The replies of rows s..n
   are cleared and come again from the new segment. Either way the restarted target runs the very float32
   arithmetic of an uninterrupted run, so its replies equal the clean run's exactly; the offline reference
   restarts the same way (`bench.analysis.canmetrics`).
3. A target that keeps its heartbeat but does not answer for `abort_after` reply timeouts ends the run (aborted),
   as does a re-initialization that fails.

Process faults are applied before the first send of their row: the runner kills the target (SIGKILL) or freezes it
(SIGSTOP, SIGCONT after `freeze_s`, twice the heartbeat timeout), and a FAULT mark (KILL/FREEZE) goes into the log.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import NamedTuple

import numpy as np

from dbc.contract import BenchEvent, FaultKind, TargetState, step_of
from host.replay import Progress, ReplayStats, RowValues, wait_for_reply
from host.session import HostSession, RowBook, SessionError

from .bus import FaultyBus, Injection
from .plan import FaultPlan
from .spec import FaultSpec

DELAY_FACTOR = 1.5        # a delayed row is held this many reply timeouts: it misses its deadline, not the next
FREEZE_FACTOR = 2.0       # a freeze lasts this many heartbeat timeouts
RETRY_FACTOR = 4.0        # an unanswered retransmission is sent again after this many reply timeouts,
RETRY_MIN_S = 0.02        # and no sooner than this: a deadline of 10 µs sent each row ~25 times over (every 40 µs
                          # until the target, answering in milliseconds, got a word in) and flooded the udp bus


@dataclass
class ProcessControl:
    """What the bench runner (which owns the target process) lets the host do to it."""

    kill: Callable[[], None]
    freeze: Callable[[float], None]
    ensure_running: Callable[[], None]
    exit_reason: Callable[[], str | None] | None = None


class RowPass(NamedTuple):
    """One pass of a data row: 0 the first time the row goes out, 1 after a re-initialization replays it, ... (a
    deadline miss is one: a row misses at most once per pass, at its first send)."""

    row: int
    pass_: int = 0


@dataclass
class Recovery:
    """One re-initialization: the target was lost at `lost_row` (in pass `lost_pass` of it) and restarted at
    `restart_row` from the checkpoint of `checkpoint_row` (its state vector `state`), or, with no checkpoint yet,
    from the initial temperatures."""

    lost_row: int
    restart_row: int
    reason: str
    silent_s: float
    lost_at: float
    reinit_at: float
    checkpoint_row: int | None
    state: list[float] | None
    reset_temps: list[float] | None
    lost_pass: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class FaultRun:
    """What the fault-mode replay did and saw (the host's side of the evidence)."""

    spec: FaultSpec
    injections: list[Injection] = field(default_factory=list)
    recoveries: list[Recovery] = field(default_factory=list)
    deadline_misses: list[RowPass] = field(default_factory=list)
    retransmitted_rows: int = 0
    started_at: float = 0.0
    frames_transmitted: int = 0
    mode: str = "lockstep"      # realtime: nothing is sent again, a fault also costs the next row
    # lockstep: how often each row went out (first sends and retransmitted copies, since its segment began), the
    # book its replies go to (read when the run is reconciled, after the last replies came), and how late a reply
    # may be and still count as late rather than a stall (the heartbeat timeout)
    sends: np.ndarray | None = None
    book: RowBook | None = None
    stall_limit_s: float | None = None
    # lockstep: the misses of abandoned passes, judged before a re-initialization cleared their replies (seconds to
    # the first reply of a pass answered at every send, None for one that was not), and when each replayed pass of
    # a row began (wall clock: the target's reply faults know their Step and time, not the pass)
    settled: dict[RowPass, float | None] = field(default_factory=dict)
    replayed_at: dict[RowPass, float] = field(default_factory=dict)

    def late_replies(self) -> dict[RowPass, float]:
        """Deadline misses whose pass the target answered at every send, the first one included (nothing was lost
        on the way; the reply came late), with the seconds until the first reply."""
        if self.sends is None or self.book is None:
            return {}
        out = {}
        for miss in dict.fromkeys(self.deadline_misses):
            late = self.settled[miss] if miss in self.settled else self._late(miss.row)
            if late is not None:
                out[miss] = late
        return out

    def settle(self, start: int, stop: int) -> None:
        """Judge the misses of rows start..stop-1 from the book and the send counts now: their pass is abandoned,
        and a re-initialization is about to clear both."""
        for miss in self.deadline_misses:
            if start <= miss.row < stop and miss not in self.settled:
                self.settled[miss] = self._late(miss.row)

    def _late(self, row: int) -> float | None:
        """Seconds from the first send to the first reply of `row`'s current pass if every send of it was
        answered, else None."""
        book, sends = self.book, int(self.sends[row])
        if sends and book.replies(row) >= sends and book.first_replied_ns[row]:
            return (int(book.first_replied_ns[row]) - int(book.sent_ns[row])) / 1e9
        return None


def mark_new_injections(session: HostSession, faulty: FaultyBus, row: int) -> None:
    """A BenchEvent FAULT mark in the log for each fault the layer injected since the last call."""
    for injection in faulty.take_new_injections():
        session.marker(BenchEvent.FAULT, row, FaultKind[injection.kind.upper()], injection.frame_id)


class FaultLockstep:
    """The fault-surviving lockstep replay of one run (see the module docstring): `run()` sends every row once,
    retransmits unanswered ones, and re-initializes a lost target from its last checkpoint."""

    def __init__(self, session: HostSession, drive: np.ndarray, initial, *, faulty: FaultyBus, plan: FaultPlan,
                 control: ProcessControl | None, reply_timeout_s: float, connect_timeout_s: float,
                 abort_after: int, progress: Progress | None = None,
                 measurements: np.ndarray | None = None) -> None:
        self.session = session
        self.values = RowValues(drive, measurements)
        self.rows = len(drive)
        self.book = session.book = RowBook(self.rows)
        self.initial = [float(v) for v in initial]
        self.faulty = faulty
        self.plan = plan
        self.control = control
        self.reply_timeout_s = reply_timeout_s
        self.connect_timeout_s = connect_timeout_s
        self.progress = progress
        monitor = session.monitor
        self.freeze_s = FREEZE_FACTOR * monitor.heartbeat_timeout_s
        self.give_up_s = max(abort_after * reply_timeout_s, 2.5 * monitor.heartbeat_timeout_s)
        self.fault_run = FaultRun(plan.spec, injections=faulty.injections, started_at=time.time(),
                                  sends=np.zeros(self.rows, dtype=np.int32), book=self.book,
                                  stall_limit_s=monitor.heartbeat_timeout_s)
        self.passes: dict[int, int] = {}   # how often each row has gone out as a first send (a pass of it)

    def run(self) -> tuple[ReplayStats, FaultRun]:
        perf = time.perf_counter
        aborted: str | None = None
        sent_rows = 0
        started = perf()
        n = segment_start = 0
        while n < self.rows:
            pass_ = self.passes.get(n, 0)
            self.passes[n] = pass_ + 1
            process = self.plan.process_fault(n, pass_)
            if process is not None:
                self._process_fault(process, n, pass_)
            pauses = self._pauses()
            self._send_row(n, pass_, eligible=n != segment_start and process is None)
            sent_rows = max(sent_rows, n + 1)
            if not wait_for_reply(self.session, self.book, n, self.reply_timeout_s):
                self.fault_run.deadline_misses.append(RowPass(n, pass_))
                outcome = self._retry(n, pass_)
                if outcome == "lost":
                    try:
                        n = segment_start = self._recover(n)
                    except SessionError as exc:
                        aborted = f"the target was lost at row {n} and could not be re-initialized: {exc}"
                        break
                    continue
                if outcome == "unanswered":
                    aborted = (f"the target stopped answering: row {n} got no reply in {self.give_up_s:g} s although "
                               "its heartbeat went on")
                    break
            elif self._answered_late(n, pauses):
                self.fault_run.deadline_misses.append(RowPass(n, pass_))   # answered: nothing to send again
            n += 1
            if self.progress is not None and (n & 127) == 0:
                self.progress(n, self.rows)
        elapsed = perf() - started
        self.faulty.flush_held()
        self.session.flush_log()
        self.fault_run.frames_transmitted = self.faulty.transmitted
        if self.progress is not None:
            self.progress(sent_rows, self.rows)
        return ReplayStats("lockstep", sent_rows, elapsed, aborted), self.fault_run

    def _process_fault(self, kind: str, n: int, pass_: int) -> None:
        """Kill or freeze the target before row n goes out, marked in the log."""
        if self.control is None:
            raise SessionError(f"a {kind} fault needs the bench runner, which owns the target process")
        self.faulty.record(kind, None, row=n, pass_=pass_)
        mark_new_injections(self.session, self.faulty, n)
        self.session.flush_log()
        if kind == "kill":
            self.control.kill()
        else:
            self.control.freeze(self.freeze_s)

    def _send_row(self, n: int, pass_: int, *, eligible: bool) -> None:
        """Row n's first send in this pass, through the fault layer (faulted where the plan says so)."""
        self.session.last_sent_row = n
        self.book.sent_ns[n] = time.perf_counter_ns()
        if pass_:
            self.fault_run.replayed_at[RowPass(n, pass_)] = time.time()
        self.fault_run.sends[n] += 1
        self.faulty.begin_row(n, pass_, eligible=eligible)
        self.session.send(self.values.frames(self.session.codec, n))
        self.faulty.end_row()
        mark_new_injections(self.session, self.faulty, n)
        self.session.flush_log()

    def _pauses(self) -> tuple[int, float]:
        """Where the host's own pauses stand (how many windows, the last one's end): a change means a pause."""
        windows = self.session.monitor.host_paused_s
        return len(windows), windows[-1][1] if windows else 0.0

    def _answered_late(self, n: int, pauses: tuple[int, float]) -> bool:
        """Row n was answered, but after its deadline: a miss (as in real time), unless the host itself was paused
        meanwhile. The wait polls for up to its spin budget (0.3 ms) whatever the deadline, and a blocked receive
        can return late, so at a 10 µs deadline a row answered in 0.2 ms, a delayed one too, counted as in time."""
        late_ns = int(self.book.first_replied_ns[n]) - int(self.book.sent_ns[n])
        return late_ns > self.reply_timeout_s * 1e9 and self._pauses() == pauses

    def _lost(self) -> str | None:
        """Why the target counts as lost (silent, or no longer RUNNING: it restarted), or None."""
        monitor = self.session.monitor
        silent = monitor.silent_for()
        if silent > monitor.heartbeat_timeout_s:
            return f"no heartbeat for {silent:.2f} s"
        if monitor.state is not None and monitor.state != TargetState.RUNNING:
            return f"the target reports state {monitor.state.name}"
        return None

    def _retry(self, n: int, pass_: int) -> str:
        """Send row n again (twice) until it is answered, the target is lost, or `give_up_s` passes: the reply
        to a retransmission can itself be lost (a reply fault on the row's first use by the target)."""
        session, perf = self.session, time.perf_counter
        self.fault_run.retransmitted_rows += 1
        deadline = perf() + self.give_up_s
        while perf() < deadline:
            session.marker(BenchEvent.RETRANSMIT, n)
            self.faulty.begin_row(n, pass_, retransmission=True)
            row = self.values.frames(session.codec, n)
            session.send(row + self.values.frames(session.codec, n))
            self.fault_run.sends[n] += 2
            self.faulty.end_row()
            session.flush_log()
            again_at = min(deadline, perf() + max(RETRY_FACTOR * self.reply_timeout_s, RETRY_MIN_S))
            while (remaining := again_at - perf()) > 0:
                session.receive(min(remaining, 0.02))
                if self.book.is_answered(n):
                    return "answered"
                if self._lost() is not None:
                    return "lost"
        return "unanswered"

    def _recover(self, n: int) -> int:
        """Re-initialize a lost target from its newest checkpoint before row n (or RESET it); the row to go on."""
        session, control = self.session, self.control
        reason = self._lost() or "lost"
        silent = session.monitor.silent_for()
        lost_at = time.time()
        session.marker(BenchEvent.TARGET_LOST, n)
        session.flush_log()
        session.validator.reset_counters()
        if control is not None:
            control.ensure_running()
        session.connect(self.connect_timeout_s, control.exit_reason if control is not None else None)
        checkpoint = session.last_checkpoint(n)
        s = 0 if checkpoint is None else checkpoint[0] + 1
        session.marker(BenchEvent.REINIT, s)
        if checkpoint is None:
            session.reset(self.initial, step=0)
        else:
            session.restore(checkpoint[1], step=step_of(s),
                            observer=session.observer_checkpoints.get(checkpoint[0]))
        session.start(step=step_of(s))
        self.fault_run.settle(s, n + 1)   # the pass of rows s..n is abandoned: judge its misses before the clear
        self.book.clear(s, n + 1)
        self.fault_run.sends[s:n + 1] = 0
        self.fault_run.recoveries.append(Recovery(
            n, s, reason, round(silent, 4), lost_at, time.time(), None if checkpoint is None else checkpoint[0],
            None if checkpoint is None else checkpoint[1], self.initial if checkpoint is None else None,
            lost_pass=self.passes[n] - 1))
        return s


def run_lockstep_with_faults(session: HostSession, drive: np.ndarray, initial, *, faulty: FaultyBus,
                             plan: FaultPlan, control: ProcessControl | None, reply_timeout_s: float,
                             connect_timeout_s: float, abort_after: int,
                             progress: Progress | None = None,
                             measurements: np.ndarray | None = None) -> tuple[ReplayStats, FaultRun]:
    """Replay `drive` (with `measurements`, if any) in lockstep through the fault layer `faulty` (see
    `FaultLockstep`)."""
    return FaultLockstep(session, drive, initial, faulty=faulty, plan=plan, control=control,
                         reply_timeout_s=reply_timeout_s, connect_timeout_s=connect_timeout_s,
                         abort_after=abort_after, progress=progress, measurements=measurements).run()
