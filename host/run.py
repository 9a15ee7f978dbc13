"""One host run from start to end: connect, reset, start, replay, stop, and the result (the log is closed
and renamed into place only if the run got that far; a run that fails before leaves no log)."""

from __future__ import annotations

import gc
from collections.abc import Callable, Sequence
from pathlib import Path

import can
import numpy as np

from host.canlog import FrameLog
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
                alive: Callable[[], str | None] | None = None, progress: Progress | None = None) -> HostResult:
    """Replay `drive` (rows, 4: torque, speed, coolant, ambient) to the target on `bus`."""
    if mode not in MODES:
        raise ValueError(f"mode {mode!r} is not one of {', '.join(MODES)}")
    drive = np.asarray(drive, dtype=float)
    check_drive_range(drive)
    log = FrameLog(log_path) if log_path is not None else None
    gc.freeze()  # the loaded data and modules stay out of the collector's scans during the replay
    try:
        session = HostSession(bus, log=log, expected_model_id=model_id)
        session.connect(connect_timeout_s, alive)
        session.reset(initial)
        session.start()
        if mode == "lockstep":
            stats = run_lockstep(session, drive, reply_timeout_s=reply_timeout_s, abort_after=abort_after,
                                 progress=progress)
        else:
            stats = run_realtime(session, drive, sample_period_s=sample_period_s, speed=speed,
                                 reply_timeout_s=max(reply_timeout_s, 2 * sample_period_s / speed),
                                 progress=progress)
        session.stop()
    except BaseException:
        if log is not None:
            log.close(commit=False)
        raise
    final = str(log.close()) if log is not None else None
    return build_result(session, stats, rows=len(drive), speed=speed if mode == "realtime" else None,
                        log_path=final)


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
