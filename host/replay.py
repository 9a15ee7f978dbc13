"""Replaying data rows (or a recorded log's host frames) onto the bus.

Dataset replay, one DriveInputs + DriveTemps pair per data row, Step = row number (mod 65536), followed by the
row's DriveCurrents when the drive matrix carries the d/q currents (6 columns; with 4 nothing else is sent):

* `lockstep`: send row n, wait for its Temperatures1 + Temperatures2 (up to `reply_timeout_s`), then row n+1.
  A row without both replies in time is missing; the run goes on (a silent heartbeat, or `abort_after`
  missing rows in a row, ends it). The next row's frames are encoded and the log is written while the target
  works, so neither is on the round trip.
* `realtime`: row n is sent at t0 + n·T_s/speed by a deadline scheduler (wait in `recv` until 1 ms before the
  deadline, then spin on perf_counter: the same thread receives replies between sends). python-can's periodic
  sending does not fit: every frame carries a new Step, alive counter and CRC. Send-time jitter (actual − planned)
  is recorded per row.

Log replay (`bench replay`) re-sends a log's host frames byte for byte (same counters and CRCs), either with the
recorded timing (`can.MessageSync`, scaled by `speed`, each row's DriveInputs held back until the previous row is
answered) or as fast as possible in lockstep (after each row's last frame, DriveTemps or, in a log with currents,
DriveCurrents, wait for that row's replies).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cache
from typing import Protocol

import can
import numpy as np

from dbc.codec import FrameCodec
from dbc.contract import (
    CHANNEL_NAMES,
    CURRENT_MESSAGE,
    DRIVE_SIGNALS,
    MEASUREMENT_CHANNELS,
    MEASUREMENT_SLOTS,
    FaultBit,
    MeasurementStatus,
    TargetState,
    measurement_messages,
    row_messages,
    row_signals,
    step_of,
)
from dbc.database import frame_id, host_frame_ids, signal_ranges
from dbc.xcp import cmd_id
from host.errors import HostError
from host.session import HOST_PAUSE_S, HostSession, RowBook, SessionError

Progress = Callable[[int, int], None]
DEFAULT_ABORT_AFTER = 25


class DataRangeError(HostError, ValueError):
    """A data value the DBC cannot carry."""


ROW_VALUE_NAMES = ("torque", "speed", "coolant temperature", "ambient temperature", "d-axis current",
                   "q-axis current")


def check_drive_range(drive: np.ndarray) -> None:
    """Every value must be finite and inside its DBC signal range (the codec refuses to wrap); `drive` has the 4
    drive columns, or 6 with the d/q currents."""
    if drive.ndim != 2 or drive.shape[1] not in (len(DRIVE_SIGNALS), len(ROW_VALUE_NAMES)):
        raise DataRangeError(f"the drive data has shape {drive.shape}, not (rows, {len(DRIVE_SIGNALS)}) or "
                             f"(rows, {len(ROW_VALUE_NAMES)}) with the d/q currents")
    signals = row_signals(drive.shape[1])
    for column, ((message, signal), name) in enumerate(zip(signals, ROW_VALUE_NAMES, strict=False)):
        low, high = signal_ranges(message)[signal]
        values = drive[:, column]
        bad = np.flatnonzero(~np.isfinite(values) | (values < low) | (values > high))
        if bad.size:
            row = int(bad[0])
            raise DataRangeError(f"data row {row} has {name} {float(values[row])!r}, outside what "
                                 f"{message}.{signal} can carry ({low:g} to {high:g}); fix or clip the data")


def check_measurements(measurements: np.ndarray | None, rows: int) -> None:
    """The measurement matrix: one row per data row, one column per `dbc.contract.MEASUREMENT_CHANNELS` — the two
    Measurements slots, or all four with the d/q voltages of DriveVoltages (NaN: absent; a value the DBC cannot
    carry goes out flagged INVALID)."""
    if measurements is None:
        return
    widths = (len(MEASUREMENT_SLOTS), len(CHANNEL_NAMES))
    if measurements.ndim != 2 or measurements.shape[0] != rows or measurements.shape[1] not in widths:
        raise DataRangeError(f"the measurements have shape {measurements.shape}, not ({rows}, {widths[0]}) or "
                             f"({rows}, {widths[1]}): one column per channel ({', '.join(CHANNEL_NAMES)})")


@cache
def _channel_limits(message: str) -> dict[str, tuple[float, float]]:
    return signal_ranges(message)


def _status(value: float, limits: tuple[float, float]) -> MeasurementStatus:
    if math.isnan(value):
        return MeasurementStatus.ABSENT
    return MeasurementStatus.VALID if limits[0] <= value <= limits[1] else MeasurementStatus.INVALID


def measurement_signals(step: int, values: Sequence[float]) -> dict[str, dict[str, float | int]]:
    """The measurement frames of a row, {message: signals} (`dbc.contract.measurement_messages` of len(values)):
    per status signal VALID when every value under it is one the DBC carries, else ABSENT when one is NaN, else
    INVALID; a value that does not go out VALID is sent as its signal's minimum."""
    out: dict[str, dict[str, float | int]] = {}
    for channel, value in zip(CHANNEL_NAMES, values, strict=False):
        message, value_signal, status_signal = MEASUREMENT_CHANNELS[channel]
        signals = out.setdefault(message, {"Step": step})
        status = _status(value, _channel_limits(message)[value_signal])
        signals[status_signal] = min(int(status), int(signals.get(status_signal, status)),
                                     key=lambda s: (s != MeasurementStatus.ABSENT, s == MeasurementStatus.VALID))
        signals[value_signal] = value
    for channel in CHANNEL_NAMES[:len(values)]:      # a status that is not VALID: every value under it unused
        message, value_signal, status_signal = MEASUREMENT_CHANNELS[channel]
        if out[message][status_signal] != MeasurementStatus.VALID:
            out[message][value_signal] = _channel_limits(message)[value_signal][0]
    return out


def encode_row(codec: FrameCodec, row: int, values: Sequence[float],
               measurement: Sequence[float] | None = None) -> list[can.Message]:
    """The frames of data row `row` (values in DRIVE_SIGNALS order: torque, speed, coolant, ambient; then i_d, i_q
    for DriveCurrents when there are 6), in the order of `dbc.contract.row_messages`; with `measurement` (one value
    per measurement channel) the row's measurement frames go first (Measurements, then DriveVoltages)."""
    step = step_of(row)
    signals: dict[str, dict[str, float]] = {}
    for (message, signal), value in zip(row_signals(len(values)), values, strict=True):
        signals.setdefault(message, {"Step": step})[signal] = value
    frames = [codec.encode(message, values) for message, values in signals.items()]
    if measurement is not None:
        measured = measurement_signals(step, measurement)
        frames[:0] = [codec.encode(message, measured[message]) for message in measurement_messages(len(measurement))]
    return frames


class RowValues:
    """`frames(codec, n)`: the frames of row n of the drive matrix (and of the measurement matrix, if any), its values
    made Python floats when it is encoded (a list of lists of the whole run would cost about 200 bytes a row)."""

    def __init__(self, drive: np.ndarray, measurements: np.ndarray | None = None) -> None:
        self.drive = drive
        self.measurements = measurements

    def frames(self, codec: FrameCodec, row: int) -> list[can.Message]:
        measured = self.measurements
        return encode_row(codec, row, self.drive[row].tolist(), None if measured is None else measured[row].tolist())


@dataclass
class ReplayStats:
    mode: str
    rows_sent: int
    wall_time_s: float
    aborted: str | None = None
    send_jitter_s: np.ndarray | None = None


def wait_for_reply(session: HostSession, book: RowBook, row: int, timeout: float) -> bool:
    """Receive until both temperature replies of `row` are in or `timeout` s have passed.

    Reads what already waits first, then polls for up to `session.spin.budget()` (`dbc.transport.SpinPolicy`: in
    lockstep the reply is usually less than 0.3 ms away, and blocking costs more, unless the machine is loaded),
    then blocks.
    """
    perf = time.perf_counter
    answered = book.is_answered
    deadline = perf() + timeout
    while not answered(row) and session.receive(0.0) is not None:
        pass
    if answered(row):
        return True
    spin = session.spin
    started = perf()
    spin_until = started + spin.budget()
    while not answered(row) and perf() < spin_until:
        session.receive(0.0)
    blocked = not answered(row)
    fresh = True
    while not answered(row):
        remaining = deadline - perf()
        if remaining <= 0:
            if fresh and -remaining > HOST_PAUSE_S:   # the host was paused: what came meanwhile, a fresh timeout
                fresh = False
                session.host_paused(-remaining)
                deadline = perf() + timeout
                continue
            break
        session.receive(remaining)
    if not answered(row):
        return False
    if fresh:   # a wait the host sat through (not one it was paused in): the spin policy learns from it
        spin.waited(perf() - started, blocked=blocked)
    return True


def _silent(session: HostSession) -> bool:
    """No heartbeat for longer than the timeout, counting what already waits in the socket (a host that was not
    reading for a while finds the target's heartbeats there)."""
    session.drain()
    return session.monitor.silent_for() > session.monitor.heartbeat_timeout_s


def run_lockstep(session: HostSession, drive: np.ndarray, *, reply_timeout_s: float,
                 abort_after: int = DEFAULT_ABORT_AFTER, progress: Progress | None = None,
                 measurements: np.ndarray | None = None) -> ReplayStats:
    rows = len(drive)
    book = session.book = RowBook(rows)
    values = RowValues(drive, measurements)
    codec = session.codec
    perf, perf_ns = time.perf_counter, time.perf_counter_ns
    consecutive = 0
    aborted = None
    next_frames = values.frames(codec, 0) if rows else []
    started = perf()
    sent = 0
    for n in range(rows):
        frames = next_frames
        session.last_sent_row = n
        book.sent_ns[n] = perf_ns()
        session.send(frames)
        sent += 1
        session.flush_log()
        if n + 1 < rows:
            next_frames = values.frames(codec, n + 1)
        if not wait_for_reply(session, book, n, reply_timeout_s):
            # rows without any reply yet: a late reply is an answer (a deadline below the round trip is late on
            # every row, and the target that answers them all has not stopped answering)
            consecutive = unanswered_streak(book, n, abort_after)
            if _silent(session):
                aborted = (f"the target went silent (no heartbeat for more than "
                           f"{session.monitor.heartbeat_timeout_s:g} s) at row {n}")
                break
            if session.monitor.state == TargetState.FAULT:   # it answers nothing until a RESET: stop now
                aborted = (f"the target reported an internal fault at row {n} (state FAULT, fault bits "
                           f"{_fault_names(session.monitor.faults)}); its own log names the cause")
                break
            if consecutive >= abort_after:
                aborted = f"the target stopped answering: {consecutive} rows in a row without a reply (row {n})"
                break
        else:
            consecutive = 0
        if progress is not None and (n & 127) == 0:
            progress(n, rows)
    elapsed = perf() - started
    session.flush_log()
    if progress is not None:
        progress(sent, rows)
    return ReplayStats("lockstep", sent, elapsed, aborted)


def unanswered_streak(book: RowBook, row: int, limit: int) -> int:
    """How many rows up to `row` in a row have no reply at all (late ones count as replies), at most `limit`."""
    streak = 0
    while streak < limit and row - streak >= 0 and not book.is_answered(row - streak):
        streak += 1
    return streak


def _fault_names(bits: int) -> str:
    return ", ".join(bit.name for bit in FaultBit if bit & bits) or "none"


class RowHooks(Protocol):
    """What a fault layer does around the send of each row (`begin` before, `end` after)."""

    def begin(self, row: int) -> None: ...

    def end(self, row: int) -> None: ...


def run_realtime(session: HostSession, drive: np.ndarray, *, sample_period_s: float, speed: float = 1.0,
                 reply_timeout_s: float, progress: Progress | None = None,
                 hooks: RowHooks | None = None, measurements: np.ndarray | None = None) -> ReplayStats:
    rows = len(drive)
    book = session.book = RowBook(rows)
    values = RowValues(drive, measurements)
    codec = session.codec
    perf, perf_ns = time.perf_counter, time.perf_counter_ns
    interval = sample_period_s / speed
    margin = min(0.001, interval / 4)
    jitter = np.zeros(rows)
    aborted = None
    frames = values.frames(codec, 0) if rows else []
    start = perf() + 0.05
    sent = 0
    previous = start - interval   # when the previous row went out
    for n in range(rows):
        deadline = start + n * interval
        while (remaining := deadline - perf()) > margin:
            session.receive(remaining - margin)
        while perf() < deadline:
            pass
        actual = perf()
        if (away := actual - max(deadline, previous + interval)) > HOST_PAUSE_S:
            start += away   # the host was paused: on at the data rate from here, not in a burst of late rows
        previous = actual
        session.last_sent_row = n
        book.sent_ns[n] = perf_ns()
        if hooks is not None:
            hooks.begin(n)
        session.send(frames)
        if hooks is not None:
            hooks.end(n)
        jitter[n] = actual - deadline
        sent += 1
        session.flush_log()
        if n + 1 < rows:
            frames = values.frames(codec, n + 1)
        if (n & 63) == 0:
            if _silent(session):
                aborted = (f"the target went silent (no heartbeat for more than "
                           f"{session.monitor.heartbeat_timeout_s:g} s) at row {n}")
                break
            if progress is not None:
                progress(n, rows)
    if sent:  # the last replies
        wait_for_reply(session, book, sent - 1, reply_timeout_s)
    elapsed = perf() - start
    session.flush_log()
    if progress is not None:
        progress(sent, rows)
    return ReplayStats("realtime", sent, elapsed, aborted, send_jitter_s=jitter[:sent])


# ---------------------------------------------------------------------------------------------- log replay
def host_frames(messages: Sequence[can.Message], also: frozenset[int] = frozenset()) -> list[can.Message]:
    """The frames a host sent (standard ids of the DBC's HOST node, and the ids in `also`), as fresh copies with
    the recorded bytes."""
    keep = host_frame_ids() | also
    out = []
    for m in messages:
        if m.is_extended_id or m.is_error_frame or m.is_remote_frame or m.arbitration_id not in keep:
            continue
        out.append(can.Message(timestamp=m.timestamp, arbitration_id=m.arbitration_id, is_extended_id=False,
                               dlc=m.dlc, data=bytes(m.data)))
    return out


def count_rows(frames: Sequence[can.Message]) -> int:
    drive_inputs = frame_id("DriveInputs")
    return sum(1 for f in frames if f.arbitration_id == drive_inputs)


def replay_frames(session: HostSession, frames: Sequence[can.Message], *, timed: bool, speed: float = 1.0,
                  reply_timeout_s: float, progress: Progress | None = None) -> ReplayStats:
    """Re-send recorded host frames; replies land in `session.book` by row (the n-th DriveInputs is row n)."""
    rows = count_rows(frames)
    book = session.book = RowBook(rows)
    started = time.perf_counter()
    if not timed:
        _replay_lockstep(session, frames, book, reply_timeout_s, progress)
    else:
        _replay_timed(session, frames, book, speed, reply_timeout_s, progress)
    return ReplayStats("timed" if timed else "lockstep", rows, time.perf_counter() - started)


def last_row_frame_id(frames: Sequence[can.Message]) -> int:
    """The id of a row's last frame in these recorded frames: DriveCurrents when the log's rows carry the currents
    (its target answered a row only after it), else DriveTemps."""
    currents = frame_id(CURRENT_MESSAGE)
    with_currents = any(f.arbitration_id == currents for f in frames)
    return currents if with_currents else frame_id(row_messages(len(DRIVE_SIGNALS))[-1])


XCP_ANSWER_POLL_S = 0.002    # how long one receive waits while a replayed XCP command waits for its answer


def send_xcp_command(session, frame: can.Message, timeout_s: float) -> bool:
    """Send a calibration master's logged XCP command and wait for its answer (RES or ERR, at most `timeout_s`), as
    the master did (XCP has one command outstanding): the target gets the commands in their logged order among the
    rows, and the new log pairs each command with its answer. False when none came (the slave ignores a command
    while not connected)."""
    before = session.xcp_answers
    session.send([frame])
    deadline = time.perf_counter() + timeout_s
    while session.xcp_answers == before:
        remaining = deadline - time.perf_counter()
        if remaining <= 0:
            return False
        session.receive(min(remaining, XCP_ANSWER_POLL_S))    # an XCP frame is no frame of the contract: None
    return True


def _replay_lockstep(session, frames, book, reply_timeout_s, progress) -> None:
    drive_inputs, control, xcp_command = frame_id("DriveInputs"), frame_id("Control"), cmd_id()
    last_of_row = last_row_frame_id(frames)
    row = -1
    for frame in frames:
        if frame.arbitration_id == drive_inputs:
            row += 1
            session.last_sent_row = row
            book.sent_ns[row] = time.perf_counter_ns()
        if frame.arbitration_id == xcp_command:
            send_xcp_command(session, frame, reply_timeout_s)
        else:
            session.send([frame])
        session.flush_log()
        if frame.arbitration_id == last_of_row and row >= 0:
            if not wait_for_reply(session, book, row, reply_timeout_s) and _silent(session):
                raise SessionError(f"the target went silent during the replay (row {row})")
            if progress is not None and (row & 1023) == 0:
                progress(row, book.rows)
        elif frame.arbitration_id == control:
            # a command: give the target its turn (state changes are answered by a Status frame); the other frames
            # (ResetTemps, RestoreState, BenchEvent marks, a faulted drive frame) change no state on their own
            session.wait_for(lambda f: f.name == "Status", 0.02)
    session.flush_log()


def _replay_timed(session, frames, book, speed, reply_timeout_s, progress) -> None:
    """Recorded timing through can.MessageSync, gated by the replies: a row's DriveInputs waits until the
    previous row is answered (or `reply_timeout_s` passes). A log recorded in lockstep was paced by its round
    trips, so it has no slack: without the gate one slow moment of the target would queue frames until the
    socket drops some. In the gaps MessageSync sleeps, replies wait in the socket and are read before the next
    send, so the log stays in time order."""
    base = frames[0].timestamp if frames else 0.0
    scaled = [can.Message(timestamp=base + (f.timestamp - base) / speed, arbitration_id=f.arbitration_id,
                          is_extended_id=False, dlc=f.dlc, data=f.data) for f in frames]
    drive_inputs, xcp_command = frame_id("DriveInputs"), cmd_id()
    row = -1
    for frame in can.MessageSync(scaled, timestamps=True, gap=0.0, skip=60.0):
        while session.receive(0.0) is not None:  # what arrived while MessageSync slept
            pass
        if frame.arbitration_id == drive_inputs:
            if row >= 0:
                if not wait_for_reply(session, book, row, reply_timeout_s) and _silent(session):
                    raise SessionError(f"the target went silent during the replay (row {row})")
            row += 1
            session.last_sent_row = row
            book.sent_ns[row] = time.perf_counter_ns()
            if progress is not None and (row & 1023) == 0:
                progress(row, book.rows)
        session.flush_log()
        if frame.arbitration_id == xcp_command:
            send_xcp_command(session, frame, reply_timeout_s)
        else:
            session.send([frame])
        session.flush_log()
    if book.rows:
        wait_for_reply(session, book, book.rows - 1, reply_timeout_s)
    session.flush_log()
