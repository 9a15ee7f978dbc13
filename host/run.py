"""One host run from start to end: connect, reset, start, replay, stop, and the result (the log is closed
and renamed into place only if the run got that far; a run that fails before leaves no log).

With a fault spec (`host.faults`), the bus is wrapped in a `FaultyBus`, the replay is the fault-surviving
lockstep loop (`host.faults.lockstep`), a last RxErrors is read after STOP, the target's detection journal (if
given) is matched against the injections, and the summary goes into the result and into `<log>.faults.json`."""

from __future__ import annotations

import gc
from collections.abc import Callable, Sequence
from pathlib import Path

import can
import numpy as np

from host.canlog import FrameLog
from host.faults import (
    DELAY_FACTOR,
    FaultPlan,
    FaultSpec,
    FaultSpecError,
    FaultyBus,
    ProcessControl,
    read_journal,
    reconcile,
    run_lockstep_with_faults,
    write_sidecar,
)
from host.replay import (
    DEFAULT_ABORT_AFTER,
    Progress,
    check_drive_range,
    host_frames,
    replay_frames,
    run_lockstep,
    run_realtime,
)
from host.results import HostResult, build_result
from host.session import DEFAULT_CONNECT_TIMEOUT_S, DEFAULT_REPLY_TIMEOUT_S, HostSession

MODES = ("lockstep", "realtime")


def run_dataset(bus: can.BusABC, drive: np.ndarray, initial: Sequence[float], *, model_id: int | None,
                mode: str = "lockstep", speed: float = 1.0, sample_period_s: float = 0.2,
                log_path: str | Path | None = None, reply_timeout_s: float = DEFAULT_REPLY_TIMEOUT_S,
                abort_after: int = DEFAULT_ABORT_AFTER, connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S,
                alive: Callable[[], str | None] | None = None, progress: Progress | None = None,
                faults: FaultSpec | None = None, control: ProcessControl | None = None,
                target_events: str | Path | None = None, events_since: float | None = None) -> HostResult:
    """Replay `drive` (rows, 4: torque, speed, coolant, ambient) to the target on `bus`.

    `faults` (active) injects faults (lockstep only; kill/freeze need `control`); `target_events` is the target's
    detection journal, read from `events_since` on.
    """
    if mode not in MODES:
        raise ValueError(f"mode {mode!r} is not one of {', '.join(MODES)}")
    drive = np.asarray(drive, dtype=float)
    check_drive_range(drive)
    faulty = plan = None
    if faults is not None and faults.active:
        if mode != "lockstep":
            raise FaultSpecError("fault injection runs in lockstep mode only; drop --mode realtime")
        plan = FaultPlan(faults, len(drive))
        if plan.process_rows and control is None:
            raise FaultSpecError("kill and freeze faults need the bench runner, which owns the target process: "
                                 "use 'bench run'")
        faulty = FaultyBus(bus, plan, delay_s=DELAY_FACTOR * reply_timeout_s)
    log = FrameLog(log_path) if log_path is not None else None
    gc.freeze()  # the loaded data and modules stay out of the collector's scans during the replay
    fault_run = None
    try:
        session = HostSession(faulty or bus, log=log, expected_model_id=model_id)
        session.connect(connect_timeout_s, alive)
        session.reset(initial)
        session.start()
        if faulty is not None and plan is not None:
            stats, fault_run = run_lockstep_with_faults(
                session, drive, initial, faulty=faulty, plan=plan, control=control, reply_timeout_s=reply_timeout_s,
                connect_timeout_s=connect_timeout_s, abort_after=abort_after, progress=progress)
        elif mode == "lockstep":
            stats = run_lockstep(session, drive, reply_timeout_s=reply_timeout_s, abort_after=abort_after,
                                 progress=progress)
        else:
            stats = run_realtime(session, drive, sample_period_s=sample_period_s, speed=speed,
                                 reply_timeout_s=max(reply_timeout_s, 2 * sample_period_s / speed),
                                 progress=progress)
        session.stop()
        if fault_run is not None:  # the target's final counters: a RxErrors sent after it stopped
            session.wait_for(lambda f: f.name == "RxErrors", 0.3)
            session.flush_log()
    except BaseException:
        if log is not None:
            log.close(commit=False)
        raise
    log_frames = log.count if log is not None else None
    final = str(log.close()) if log is not None else None
    summary = None
    if fault_run is not None:
        journal = read_journal(target_events, since=events_since) if target_events is not None else None
        summary = reconcile(fault_run, journal, heartbeat_losses=session.monitor.heartbeat_losses,
                            final_rx_errors=session.monitor.rx_errors)
        if final is not None:
            write_sidecar(final, summary, fault_run.injections)
    return build_result(session, stats, rows=len(drive), speed=speed if mode == "realtime" else None,
                        log_path=final, log_frames=log_frames, faults=summary)


def replay_log(bus: can.BusABC, messages: Sequence[can.Message], *, model_id: int | None, timed: bool,
               speed: float = 1.0, log_path: str | Path | None = None,
               reply_timeout_s: float = DEFAULT_REPLY_TIMEOUT_S, connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S,
               alive: Callable[[], str | None] | None = None, progress: Progress | None = None) -> HostResult:
    """Re-send the host frames of a recorded log; the result's arrays hold the new replies by row."""
    frames = host_frames(messages)
    log = FrameLog(log_path) if log_path is not None else None
    try:
        session = HostSession(bus, log=log, expected_model_id=model_id)
        session.connect(connect_timeout_s, alive)
        stats = replay_frames(session, frames, timed=timed, speed=speed, reply_timeout_s=reply_timeout_s,
                              progress=progress)
        # collect the last heartbeat and the trailing frames
        session.wait_for(lambda f: f.name == "RxErrors", 0.3)
        session.flush_log()
    except BaseException:
        if log is not None:
            log.close(commit=False)
        raise
    final = str(log.close()) if log is not None else None
    return build_result(session, stats, rows=stats.rows_sent, speed=speed if timed else None, log_path=final)
