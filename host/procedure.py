"""The host's procedure for one run, from start to end: connect, reset, start, replay, stop, and the result (the
log is closed and renamed into place only if the run got that far; a run that fails before leaves no log).

With a fault spec (`host.faults`), the bus is wrapped in a `FaultyBus`, the replay is the fault-surviving
lockstep loop (`host.faults.lockstep`), a last RxErrors is read after STOP, the target's detection journal (if
given) is matched against the injections, and the summary goes into the result and into `<log>.faults.json`."""

from __future__ import annotations

import gc
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import can
import numpy as np

from dbc.codec import decode_any
from dbc.contract import DEFAULT_REPLY_TIMEOUT_S, FrameError, measurement_messages, row_messages
from dbc.database import frame_id, host_frame_ids
from dbc.mutations import FAULTED_HOST_MESSAGES, foreign_ids
from dbc.transport import OwnFrameFilter
from dbc.xcp import cmd_id
from host.canlog import FrameLog
from host.faults import (
    DELAY_FACTOR,
    FaultPlan,
    FaultSpec,
    FaultSpecError,
    FaultyBus,
    ProcessControl,
    check_realtime_faults,
    read_journal,
    reconcile,
    run_lockstep_with_faults,
    run_realtime_with_faults,
    write_sidecar,
)
from host.replay import (
    DEFAULT_ABORT_AFTER,
    Progress,
    check_drive_range,
    check_measurements,
    host_frames,
    replay_frames,
    run_lockstep,
    run_realtime,
)
from host.results import HostResult, build_result
from host.session import DEFAULT_CONNECT_TIMEOUT_S, HostSession

MODES = ("lockstep", "realtime")


@contextmanager
def discarded_on_error(log: FrameLog | None) -> Iterator[None]:
    """Nothing half-written: a run that fails leaves no log behind (its temporary file is deleted)."""
    try:
        yield
    except BaseException:
        if log is not None:
            log.close(commit=False)
        raise


def run_dataset(bus: can.BusABC, drive: np.ndarray, initial: Sequence[float], *, model_id: int | None,
                mode: str = "lockstep", speed: float = 1.0, sample_period_s: float = 0.2,
                log_path: str | Path | None = None, reply_timeout_s: float = DEFAULT_REPLY_TIMEOUT_S,
                abort_after: int = DEFAULT_ABORT_AFTER, connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S,
                alive: Callable[[], str | None] | None = None, progress: Progress | None = None,
                faults: FaultSpec | None = None, control: ProcessControl | None = None,
                target_events: str | Path | None = None, events_since: float | None = None,
                measurements: np.ndarray | None = None) -> HostResult:
    """Replay `drive` (rows, 4: torque, speed, coolant, ambient; or rows, 6 with i_d, i_q, which then go out in
    DriveCurrents) to the target on `bus`; with `measurements` (rows, one column per `dbc.contract.
    MEASUREMENT_CHANNELS`: 2, or 4 with the d/q voltages; NaN: absent) each row's Measurements (and DriveVoltages)
    frame goes out before its DriveInputs.

    `faults` (active) injects faults (kill/freeze: lockstep only, with `control`); `target_events` is the target's
    detection journal, read from `events_since` on.
    """
    if mode not in MODES:
        raise ValueError(f"mode {mode!r} is not one of {', '.join(MODES)}")
    drive = np.asarray(drive, dtype=float)
    check_drive_range(drive)
    if measurements is not None:
        measurements = np.asarray(measurements, dtype=float)
        check_measurements(measurements, len(drive))
    faulty = plan = None
    if faults is not None and faults.active:
        plan = FaultPlan(faults, len(drive), frames_per_row=len(row_messages(drive.shape[1])),
                         measurements=0 if measurements is None else len(measurement_messages(measurements.shape[1])))
        if mode == "realtime":
            check_realtime_faults(plan, sample_period_s, speed, reply_timeout_s)
        if plan.process_rows and control is None:
            raise FaultSpecError("kill and freeze faults need the bench runner, which owns the target process: "
                                 "use 'bench run'")
        faulty = FaultyBus(bus, plan, delay_s=DELAY_FACTOR * reply_timeout_s)
    log = FrameLog(log_path) if log_path is not None else None
    gc.freeze()  # the loaded data and modules stay out of the collector's scans during the replay
    fault_run = None
    with discarded_on_error(log):
        session = HostSession(faulty or bus, log=log, expected_model_id=model_id)
        session.connect(connect_timeout_s, alive)
        session.reset(initial)
        session.start()
        if faulty is not None and plan is not None and mode == "realtime":
            stats, fault_run = run_realtime_with_faults(
                session, drive, faulty=faulty, plan=plan, sample_period_s=sample_period_s, speed=speed,
                reply_timeout_s=reply_timeout_s, progress=progress, measurements=measurements)
        elif faulty is not None and plan is not None:
            stats, fault_run = run_lockstep_with_faults(
                session, drive, initial, faulty=faulty, plan=plan, control=control, reply_timeout_s=reply_timeout_s,
                connect_timeout_s=connect_timeout_s, abort_after=abort_after, progress=progress,
                measurements=measurements)
        elif mode == "lockstep":
            stats = run_lockstep(session, drive, reply_timeout_s=reply_timeout_s, abort_after=abort_after,
                                 progress=progress, measurements=measurements)
        else:
            stats = run_realtime(session, drive, sample_period_s=sample_period_s, speed=speed,
                                 reply_timeout_s=max(reply_timeout_s, 2 * sample_period_s / speed),
                                 progress=progress, measurements=measurements)
        session.stop()
        if fault_run is not None:  # the target's final counters: a RxErrors sent after it stopped
            session.wait_for(lambda f: f.name == "RxErrors", 0.3)
            session.flush_log()
    log_frames = log.count if log is not None else None
    final = str(log.close()) if log is not None else None
    summary = None
    if fault_run is not None:
        journal = read_journal(target_events, since=events_since) if target_events is not None else None
        summary = reconcile(fault_run, journal, heartbeat_losses=session.monitor.heartbeat_losses,
                            final_rx_errors=session.monitor.rx_errors, host_rejections=session.rejections)
        if final is not None:
            write_sidecar(final, summary, fault_run.injections + (journal.injections if journal else []))
    return build_result(session, stats, rows=len(drive), speed=speed if mode == "realtime" else None,
                        log_path=final, log_frames=log_frames, faults=summary)


def injected_ids() -> frozenset[int]:
    """The ids the unknown_id fault puts the host's drive frames on (`dbc.mutations.mutate`): a replay of a
    faulted log re-sends those frames too, so the target rejects what it rejected when the log was made."""
    return foreign_ids(FAULTED_HOST_MESSAGES)


class ReplaySession(HostSession):
    """A session that re-sends a log: a reply belongs to the last DriveInputs sent with its Step.

    The log replay numbers rows by DriveInputs frames (`host.replay.replay_frames`); in a log of a faulted run a
    row went out more than once (retransmitted, duplicated), so a reply's Step is not that number any more."""

    def __init__(self, bus: can.BusABC, **kwargs) -> None:
        super().__init__(bus, **kwargs)
        # udp_multicast loops what it sends back to it too: the host's frames, a faulted log's, a master's XCP commands
        self.own = OwnFrameFilter(host_frame_ids() | injected_ids() | {cmd_id()})
        self._drive_inputs = frame_id("DriveInputs")
        self._row_of_step: dict[int, int] = {}

    def send(self, frames: Sequence[can.Message]) -> None:
        for frame in frames:
            if frame.arbitration_id == self._drive_inputs and not frame.is_extended_id:
                try:
                    self._row_of_step[int(decode_any(frame).signals["Step"])] = self.last_sent_row
                except FrameError:
                    pass  # damaged on purpose: the target rejects it, no reply will name it
        super().send(frames)

    def _row_of(self, step: int) -> int:
        return self._row_of_step.get(step, -1)


def replay_log(bus: can.BusABC, messages: Sequence[can.Message], *, model_id: int | None, timed: bool,
               speed: float = 1.0, log_path: str | Path | None = None,
               reply_timeout_s: float = DEFAULT_REPLY_TIMEOUT_S, connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S,
               alive: Callable[[], str | None] | None = None, progress: Progress | None = None) -> HostResult:
    """Re-send the host frames of a recorded log, and a calibration master's XCP commands in their place (its
    DOWNLOADs calibrate the target where they did); the result's arrays hold the new replies by DriveInputs frame."""
    frames = host_frames(messages, also=injected_ids() | {cmd_id()})  # the unknown_id fault's frames too
    log = FrameLog(log_path) if log_path is not None else None
    with discarded_on_error(log):
        session = ReplaySession(bus, log=log, expected_model_id=model_id)
        session.connect(connect_timeout_s, alive)
        stats = replay_frames(session, frames, timed=timed, speed=speed, reply_timeout_s=reply_timeout_s,
                              progress=progress)
        # collect the last heartbeat and the trailing frames
        session.wait_for(lambda f: f.name == "RxErrors", 0.3)
        session.flush_log()
    final = str(log.close()) if log is not None else None
    return build_result(session, stats, rows=stats.rows_sent, speed=speed if timed else None, log_path=final)
