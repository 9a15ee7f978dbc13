"""The host's side of one session with the target: handshake, sending, receiving, monitoring.

Handshake: wait for a Status heartbeat whose ModelId is the artifact's (else one sentence naming both ids);
send ResetTemps1, ResetTemps2 and Control RESET (Step 0) and wait for Status READY (up to three tries: a target
that saw an earlier session resynchronizes its alive counters on the first try); Control START (Step 0) and wait
for RUNNING. At the end Control STOP, wait for STOPPED, and collect the trailing frames.

Every frame the host sends or receives (its own loopback copies excepted) is written to the log. Received
frames are validated (`dbc.FrameValidator`); rejected ones are counted per kind. Status frames feed the
heartbeat monitor: a gap longer than `heartbeat_timeout_s` is a heartbeat loss. A checkpoint (StateCheckpoint,
ObserverCheckpoint) is believed as a reply is: one of whose frames repeats the alive counter of the frame before it
(and is not a copy of it), or gives an element a second, other value, is *contested* (one of them is not the
target's: a forged or replayed frame) and is never echoed back in a RESTORE (`contested_checkpoints`).

With a fault layer (`host.faults.FaultyBus`) as the bus, the layer reports each frame as it actually goes on the
bus (altered, duplicated or late) and that is what the log gets. `marker` puts a BenchEvent (an injected fault,
a lost target, a re-initialization, a retransmitted row) on the bus, past the fault layer, and into the log.
"""

from __future__ import annotations

import os
import time
from array import array
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import can
import numpy as np

from dbc.codec import DecodedFrame, FrameCodec, FrameValidator, decode_any
from dbc.contract import (
    CHECKPOINT_STEP_LOW_MODULO,
    FIRMWARE_TIMING_MESSAGE,
    FRAME_ERROR_KINDS,
    HEARTBEAT_TIMEOUT_S,
    OBSERVER_CHECKPOINT_MESSAGE,
    REPLY_COMPLETE,
    REPLY_SIGNALS,
    RESET_SIGNALS,
    RESTORE_OBSERVER_MESSAGE,
    STATE_SIZE,
    BenchEvent,
    Command,
    FaultBit,
    FaultKind,
    FrameError,
    TargetState,
    latest_row,
    place_temperatures,
    rx_error_counts,
    split_temperatures,
    step_of,
    target_info,
)
from dbc.database import frame_id, host_frame_ids
from dbc.transport import OwnFrameFilter, SpinPolicy
from dbc.xcp import res_id, xcp_ids
from host.canlog import FrameLog
from host.errors import HostError

DEFAULT_CONNECT_TIMEOUT_S = 15.0
# A wait that ended this much later than asked for: the host's own clock jumped, the host was not running (SIGSTOP
# and SIGCONT, a suspended machine, a starved scheduler), and the target's silence meanwhile is not the target's.
HOST_PAUSE_S = 0.25
MAX_REJECTIONS_KEPT = 100_000   # refused frames recorded one by one (counted beyond)
SPIN_S = float(os.environ.get("HOST_SPIN_S", "0.0003"))  # lockstep: the longest busy-poll for a reply (0: never)


def _same_float(a: float, b: float) -> bool:
    """The same float32 bits (a checkpoint element sent twice by the target is the same value)."""
    return bool(np.float32(a).view(np.uint32) == np.float32(b).view(np.uint32))


class SessionError(HostError):
    """The session cannot go on (wrong model, silent target, refused reset); one sentence."""


class TimingSeries:
    """(row, value) pairs of one timing figure, kept in two columns (16 bytes a model step, not a tuple each)."""

    def __init__(self) -> None:
        self.rows = array("q")
        self._values = array("d")

    def append(self, pair: tuple[int, float]) -> None:
        self.rows.append(pair[0])
        self._values.append(pair[1])

    def values(self) -> np.ndarray:
        return np.frombuffer(self._values, dtype=np.float64).copy()


@dataclass
class RowBook:
    """What came back for each data row: temperatures (yoke, winding, tooth, magnet) and when."""

    rows: int
    temps: np.ndarray = field(init=False)
    got: np.ndarray = field(init=False)        # the reply bits of the messages in (dbc.contract.REPLY_BIT)
    sent_ns: np.ndarray = field(init=False)
    replied_ns: np.ndarray = field(init=False)         # when the row's reply was last complete
    first_replied_ns: np.ndarray = field(init=False)   # when it was first complete
    reply_frames: np.ndarray = field(init=False)       # per row, how many of each reply message came (up to 255)

    def __post_init__(self) -> None:
        self.temps = np.full((self.rows, STATE_SIZE), np.nan)
        self.got = np.zeros(self.rows, dtype=np.uint8)
        self.sent_ns = np.zeros(self.rows, dtype=np.int64)
        self.replied_ns = np.zeros(self.rows, dtype=np.int64)
        self.first_replied_ns = np.zeros(self.rows, dtype=np.int64)
        self.reply_frames = np.zeros((self.rows, REPLY_COMPLETE.bit_length()), dtype=np.uint8)

    def book_reply(self, row: int, bit: int, now_ns: int) -> None:
        """One reply message (its bit) of `row` came at `now_ns`."""
        index = bit.bit_length() - 1
        if index >= 0 and self.reply_frames[row, index] < 255:
            self.reply_frames[row, index] += 1
        before = self.got[row]
        self.got[row] = before | bit
        if self.got[row] == REPLY_COMPLETE:
            self.replied_ns[row] = now_ns
            if before != REPLY_COMPLETE:
                self.first_replied_ns[row] = now_ns

    def replies(self, row: int) -> int:
        """How many complete replies `row` got (each reply message counted; a retransmitted row can get several)."""
        return int(self.reply_frames[row].min())

    def clear(self, start: int, stop: int) -> None:
        """Forget what came for rows start..stop-1 (they are replayed from a restored target)."""
        self.got[start:stop] = 0
        self.temps[start:stop] = np.nan
        self.first_replied_ns[start:stop] = 0
        self.reply_frames[start:stop] = 0

    def answered(self) -> np.ndarray:
        return self.got == REPLY_COMPLETE

    def is_answered(self, row: int) -> bool:
        return bool(self.got[row] == REPLY_COMPLETE)

    def unanswered(self, stop: int | None = None) -> int:
        """Rows before `stop` (all rows: None) without both replies."""
        return int(np.count_nonzero(self.got[:stop] != REPLY_COMPLETE))


@dataclass
class Monitor:
    """Heartbeat, target state and error counters as last seen."""

    heartbeat_timeout_s: float
    last_status_s: float | None = None
    excused_at_s: float | None = None   # the host was not running until then: silence counts from there
    host_paused_s: list[list[float]] = field(default_factory=list)   # wall-clock [start, end] the host was not running
    max_gap_s: float = 0.0
    heartbeat_losses: int = 0
    state: TargetState | None = None
    faults: int = 0
    faults_seen: int = 0
    model_id: int | None = None
    rx_errors: dict[str, int] = field(default_factory=dict)
    target_info: dict[str, object] = field(default_factory=dict)

    def status(self, signals: dict, now_s: float) -> None:
        if self.last_status_s is not None:
            # the time the host was not running is not the target's silence: a frame that waited in the socket
            # may carry the time it was read (not when it came), so the gap spans the pause
            gap = now_s - self.last_status_s - self._paused_within(self.last_status_s, now_s)
            self.max_gap_s = max(self.max_gap_s, gap)
            if gap > self.heartbeat_timeout_s:
                self.heartbeat_losses += 1
        self.last_status_s = now_s
        self.state = TargetState(int(signals["State"]))
        self.faults = int(signals["FaultBits"])
        self.faults_seen |= self.faults
        self.model_id = int(signals["ModelId"])

    def silent_for(self, now_s: float | None = None) -> float:
        """Seconds since the last Status frame was received (wall clock, like the frames' timestamps), or since
        the host resumed after a pause (`excuse`), whichever is later."""
        now_s = time.time() if now_s is None else now_s
        if self.last_status_s is None:
            return 0.0
        return now_s - max(self.last_status_s, self.excused_at_s or self.last_status_s)

    def excuse(self, now_s: float | None = None) -> None:
        """The host itself was not running (paused): the target gets a fresh heartbeat timeout from now."""
        self.excused_at_s = time.time() if now_s is None else now_s

    def host_was_paused(self, seconds: float, now_s: float | None = None) -> None:
        """The host was not running for the `seconds` up to now (overlapping windows merge)."""
        end = time.time() if now_s is None else now_s
        start = end - seconds
        if self.host_paused_s and start <= self.host_paused_s[-1][1]:
            last = self.host_paused_s[-1]
            last[0], last[1] = min(last[0], start), max(last[1], end)
        else:
            self.host_paused_s.append([start, end])

    def _paused_within(self, start: float, end: float) -> float:
        """Seconds of [start, end] during which the host was not running."""
        return sum(max(0.0, min(e, end) - max(s, start)) for s, e in self.host_paused_s)


class HostSession:
    """Sends and receives for one run; knows nothing of datasets (see host.replay)."""

    def __init__(self, bus: can.BusABC, *, log: FrameLog | None = None, expected_model_id: int | None = None,
                 heartbeat_timeout_s: float = HEARTBEAT_TIMEOUT_S):
        self.bus = bus
        self.log = log
        self.expected_model_id = expected_model_id
        self.codec = FrameCodec("HOST")
        self.validator = FrameValidator("HOST")
        self._xcp_ids, self._xcp_res = xcp_ids(), res_id()
        self.xcp_answers = 0     # XCP command answers (RES, ERR) received: a replayed master waits for each one
        self.own = OwnFrameFilter(host_frame_ids())
        self.monitor = Monitor(heartbeat_timeout_s)
        self.spin = SpinPolicy(SPIN_S)   # how long a lockstep wait polls before it blocks (host.replay)
        self.invalid = dict.fromkeys(FRAME_ERROR_KINDS, 0)
        self.rejections: list[dict] = []   # each refused frame (kind, id, data): the evidence of reply faults
        self.book: RowBook | None = None
        self.last_sent_row = -1
        self.late_replies = 0
        self.host_pauses: list[tuple[int, float]] = []   # (row, seconds) the host itself was not running
        self._on_bus_at = time.perf_counter()   # when the host last sent or received: a jump is a paused host
        self._paused_s = 0.0                    # a pause seen in a receive, not caught up with yet
        # per model step, as (row, value) pairs: measured µs, overruns, est. C28x cycles, est. µs, CPU load %, and
        # (firmware engine only) the Cortex-M4F cycles counted in the emulated core and their µs at 90 MHz
        self.timing: dict[str, TimingSeries] = {
            key: TimingSeries() for key in ("measured_us", "overruns", "cycles", "exec_us", "cpu_load", "m4_cycles",
                                            "m4_exec_us")}
        self.on_frame: Callable[[DecodedFrame], None] | None = None
        # the target's state checkpoints: elements per row until all four are in, then the complete ones by row
        self._checkpoint_parts: dict[int, dict[int, float]] = {}
        self.checkpoints: dict[int, list[float]] = {}
        # an observer's checkpoints (DBC 1.7.0): row -> {Index: value}, echoed as they came (the target judges them)
        self.observer_checkpoints: dict[int, dict[int, float]] = {}
        # rows whose checkpoint a contested frame belongs to (never restored from), and the row of the last
        # checkpoint frame accepted per id (a frame that repeats its counter contests that one too)
        self.contested_checkpoints: set[int] = set()
        self._last_checkpoint_row: dict[int, int] = {}
        self._last_checkpoint_data: dict[int, bytes] = {}
        self._checkpoint_ids = {frame_id(name): name for name in ("StateCheckpoint", OBSERVER_CHECKPOINT_MESSAGE)}
        self._pending_log: list[can.Message] = []
        # a fault layer logs what it really transmits; a plain bus sends what it is given
        self._log_sends = not getattr(bus, "reports_transmissions", False)
        if not self._log_sends and log is not None:
            bus.on_transmit = self._pending_log.append

    # ------------------------------------------------------------------ sending
    def _catch_up(self) -> bool:
        """A host that has not been on the bus for longer than it can be without being stopped (its clock jumped)
        first reads what the target sent meanwhile, so the log keeps the bus's order and the target's heartbeats
        count (a frame stamped after the pause must not precede them). Whether it did."""
        now = time.perf_counter()
        self._note_late(now - self._on_bus_at)
        self._on_bus_at = now
        if self._paused_s <= HOST_PAUSE_S:
            return False
        self.host_paused(self._paused_s)
        return True

    def _stamp(self, frame: can.Message) -> None:
        """Stamp one of the host's frames with the time it goes on the bus, after catching up with a pause.

        The pause is looked for after the stamp, and again after each catch-up, until none came between: a host
        stopped after the look but before the stamp (in the send of a row's first frame: SIGSTOP takes effect as
        that system call returns) stamped the row's next frame after the pause and logged it before the frames that
        waited in its socket; the log, whose times never go back, then gave all the target's heartbeats of the
        pause that frame's time, a silence as long as the pause (a heartbeat loss in the report)."""
        frame.timestamp = time.time()
        while self._catch_up():
            frame.timestamp = time.time()
        frame.is_rx = False

    def send(self, frames: Sequence[can.Message]) -> None:
        for frame in frames:
            self._stamp(frame)
            try:
                self.bus.send(frame)
            except can.CanError as exc:
                raise SessionError(f"sending on the CAN bus failed ({exc}); is the bus still up?") from None
            if self.log is not None and self._log_sends:
                self._pending_log.append(frame)

    def marker(self, event: BenchEvent, row: int, kind: FaultKind = FaultKind.NONE,
               frame_id: int | None = None) -> None:
        """Put a BenchEvent mark on the bus (past any fault layer) and into the log."""
        frame = self.codec.encode("BenchEvent", {"Step": step_of(row), "Event": int(event),
                                                 "FaultKind": int(kind), "FrameId": int(frame_id or 0)})
        self._stamp(frame)
        direct = getattr(self.bus, "send_direct", None)
        try:
            (direct or self.bus.send)(frame)
        except can.CanError as exc:
            raise SessionError(f"sending on the CAN bus failed ({exc}); is the bus still up?") from None
        if self.log is not None and (direct is None or self._log_sends):
            self._pending_log.append(frame)

    def host_paused(self, seconds: float) -> None:
        """The host was not running for `seconds` (its clock jumped): read what waited in the socket meanwhile
        and give the target a fresh heartbeat timeout."""
        self.host_pauses.append((self.last_sent_row, seconds))
        self.monitor.host_was_paused(seconds)   # merges with the window a receive may have noted already
        self._paused_s = 0.0
        self.drain()
        self.monitor.excuse()

    def _note_late(self, late_s: float) -> None:
        """The host was not running for `late_s` (if longer than a scheduler's hiccup)."""
        if late_s > HOST_PAUSE_S:
            self.monitor.host_was_paused(late_s)
            self._paused_s = max(self._paused_s, late_s)

    def drain(self) -> None:
        """Read every frame already waiting (without blocking)."""
        while self.receive(0.0) is not None:
            pass

    def flush_log(self) -> None:
        if self.log is not None:
            for frame in self._pending_log:
                self.log.write(frame)
        self._pending_log.clear()

    def control(self, command: Command, step: int = 0) -> can.Message:
        return self.codec.encode("Control", {"Command": int(command), "Step": step})

    # ------------------------------------------------------------------ receiving
    def receive(self, timeout: float) -> DecodedFrame | None:
        """One frame from the target (validated and dispatched), or None when `timeout` passes without one."""
        deadline = time.perf_counter() + timeout
        while True:
            asked, before = max(0.0, deadline - time.perf_counter()), time.perf_counter()
            # stopped since it was last on the bus (e.g. between a send and this receive), or while waiting: the
            # window is noted now, before the frames that waited are counted; catch up before sending
            self._note_late(before - self._on_bus_at)
            msg = self.bus.recv(asked)
            self._on_bus_at = time.perf_counter()
            self._note_late(self._on_bus_at - before - asked)
            if msg is None:
                return None
            if self.own.is_own(msg):
                continue
            frame = self.accept(msg)
            if frame is not None:
                return frame

    def accept(self, msg: can.Message) -> DecodedFrame | None:
        """Log, validate and dispatch one received frame; None if it was rejected (and counted)."""
        if self.log is not None:
            self._pending_log.append(msg)
        if msg.arbitration_id in self._xcp_ids and not msg.is_extended_id:
            # a calibration master's XCP traffic (dbc/xcp.toml): logged, not a frame of the contract; a command's
            # answer is counted (RES 0xFF or ERR 0xFE: a DAQ packet's identifier is an ODT number, below 0xFC)
            self.xcp_answers += msg.arbitration_id == self._xcp_res and msg.data[:1] in (b"\xff", b"\xfe")
            return None
        previous = self.validator.last_counter(msg.arbitration_id)
        try:
            frame = self.validator.validate(msg)
        except FrameError as exc:
            self.invalid[exc.kind] += 1
            if exc.kind == "counter" and msg.arbitration_id in self._checkpoint_ids \
                    and msg.data[1] & 0x0F == previous and bytes(msg.data) != self._last_checkpoint_data.get(
                        msg.arbitration_id):      # a copy of the frame before it is harmless
                self._contest_checkpoint(msg)
            if len(self.rejections) < MAX_REJECTIONS_KEPT:
                self.rejections.append({"kind": exc.kind, "id": msg.arbitration_id, "data": bytes(msg.data).hex(),
                                        "t": msg.timestamp})
            return None
        if msg.arbitration_id in self._checkpoint_ids:
            self._last_checkpoint_data[msg.arbitration_id] = bytes(msg.data)
        self._dispatch(frame)
        return frame

    def _dispatch(self, frame: DecodedFrame) -> None:
        name, s = frame.name, frame.signals
        if name in REPLY_SIGNALS:
            self._reply(name, s)
        elif name == "Status":
            self.monitor.status(s, frame.timestamp)  # the receive time stamped by the bus (wall clock)
        elif name == "Timing1":
            row = self._row_of(int(s["Step"]))
            self.timing["measured_us"].append((row, float(s["StepTimeMeasured"])))
            self.timing["overruns"].append((row, int(s["Overruns"])))
        elif name == "Timing2":
            row = self._row_of(int(s["Step"]))
            self.timing["cycles"].append((row, int(s["EstCycles"])))
            self.timing["exec_us"].append((row, float(s["EstExecTime"])))
        elif name == "Timing3":
            self.timing["cpu_load"].append((self._row_of(int(s["Step"])), float(s["CpuLoad"])))
        elif name == FIRMWARE_TIMING_MESSAGE:
            row = self._row_of(int(s["Step"]))
            self.timing["m4_cycles"].append((row, int(s["M4Cycles"])))
            self.timing["m4_exec_us"].append((row, float(s["M4ExecTime"])))
        elif name == "StateCheckpoint":
            self._checkpoint(int(s["Step"]), int(s["StateIndex"]), float(s["StateValue"]))
        elif name == OBSERVER_CHECKPOINT_MESSAGE:
            self._observer_checkpoint(int(s["StepLow"]), int(s["Index"]), float(s["Value"]))
        elif name == "RxErrors":
            self.monitor.rx_errors = rx_error_counts(s)
        elif name == "TargetInfo":
            self.monitor.target_info = target_info(s)
        if self.on_frame is not None:
            self.on_frame(frame)

    def _checkpoint_row(self, name: str, s: dict) -> int:
        """The row a checkpoint frame names (an ObserverCheckpoint: by its StepLow)."""
        if name == OBSERVER_CHECKPOINT_MESSAGE:
            last = self.last_sent_row
            return last - ((last - int(s["StepLow"])) % CHECKPOINT_STEP_LOW_MODULO)
        return self._row_of(int(s["Step"]))

    def _contest_checkpoint(self, msg: can.Message) -> None:
        """A checkpoint frame that repeats the alive counter of the frame before it: neither checkpoint is
        believed."""
        name = self._checkpoint_ids[msg.arbitration_id]
        try:
            signals = decode_any(msg).signals
        except FrameError:
            return
        self.contested_checkpoints.add(self._checkpoint_row(name, signals))
        if msg.arbitration_id in self._last_checkpoint_row:
            self.contested_checkpoints.add(self._last_checkpoint_row[msg.arbitration_id])

    def _checkpoint(self, step: int, index: int, value: float) -> None:
        """Collect one element; four valid elements of one Step make a checkpoint of that row's state."""
        row = self._row_of(step)     # by row: a Step names a row only up to 65536 (a long run repeats it)
        self._last_checkpoint_row[frame_id("StateCheckpoint")] = row
        parts = self._checkpoint_parts.setdefault(row, {})
        if index in parts and not _same_float(parts[index], value):
            self.contested_checkpoints.add(row)      # an element twice, with another value
        parts[index] = value
        if len(parts) == STATE_SIZE:
            del self._checkpoint_parts[row]
            self.checkpoints[row] = [parts[i] for i in range(STATE_SIZE)]
        if len(self._checkpoint_parts) > 4:  # elements of checkpoints that never completed (a lost frame)
            self._checkpoint_parts.pop(next(iter(self._checkpoint_parts)))

    def _observer_checkpoint(self, step_low: int, index: int, value: float) -> None:
        """Collect one element of an observer's checkpoint under the latest row whose Step it names."""
        row = self._checkpoint_row(OBSERVER_CHECKPOINT_MESSAGE, {"StepLow": step_low})
        self._last_checkpoint_row[frame_id(OBSERVER_CHECKPOINT_MESSAGE)] = row
        elements = self.observer_checkpoints.setdefault(row, {})
        if index in elements and not _same_float(elements[index], value):
            self.contested_checkpoints.add(row)
        elements[index] = value
        if len(self.observer_checkpoints) > 8:   # keep the newest few
            self.observer_checkpoints.pop(min(self.observer_checkpoints))

    def _forget_checkpoints(self, from_row: int) -> None:
        """Forget the checkpoints (and their contest) of rows `from_row` and later, and every incomplete one."""
        self._checkpoint_parts.clear()
        for book in (self.checkpoints, self.observer_checkpoints):
            for row in [r for r in book if r >= from_row]:
                del book[row]
        self.contested_checkpoints = {r for r in self.contested_checkpoints if r < from_row}
        self._last_checkpoint_row.clear()

    def last_checkpoint(self, before_row: int) -> tuple[int, list[float]] | None:
        """(row, state) of the newest complete checkpoint taken after a row before `before_row`, or None; a
        contested one never."""
        rows = [row for row in self.checkpoints if row < before_row and row not in self.contested_checkpoints]
        return (max(rows), self.checkpoints[max(rows)]) if rows else None

    def _row_of(self, step: int) -> int:
        """The most recent row sent with this Step."""
        return latest_row(step, self.last_sent_row)

    def _reply(self, name: str, s: dict) -> None:
        book = self.book
        if book is None:
            return
        row = self._row_of(int(s["Step"]))
        if row < 0 or row >= book.rows:
            self.late_replies += 1
            return
        book.book_reply(row, place_temperatures(name, s, book.temps[row]), time.perf_counter_ns())

    def wait_for(self, predicate: Callable[[DecodedFrame], bool], timeout: float) -> DecodedFrame | None:
        deadline = time.perf_counter() + timeout
        while (remaining := deadline - time.perf_counter()) > 0:
            frame = self.receive(remaining)
            if frame is not None and predicate(frame):
                return frame
        return None

    # ------------------------------------------------------------------ handshake
    def connect(self, timeout: float = DEFAULT_CONNECT_TIMEOUT_S,
                alive: Callable[[], str | None] | None = None) -> DecodedFrame:
        """Wait for a heartbeat of the expected model; `alive()` returns a reason when the target has died."""
        deadline = time.perf_counter() + timeout
        while time.perf_counter() < deadline:
            frame = self.wait_for(lambda f: f.name == "Status", 0.25)
            if frame is None:
                reason = alive() if alive else None
                if reason:
                    raise SessionError(reason)
                continue
            model_id = int(frame.signals["ModelId"])
            if self.expected_model_id is not None and model_id != self.expected_model_id:
                raise SessionError(f"the target runs model {model_id:08x}, not {self.expected_model_id:08x} of the "
                                   "artifact given; start it with the same --model")
            return frame
        raise SessionError(f"no heartbeat from the target within {timeout:g} s on this bus; start "
                           "'python -m target_sim' with the same bus options")

    def _await_state(self, state: TargetState, timeout: float) -> bool:
        return self.wait_for(lambda f: f.name == "Status" and int(f.signals["State"]) == state, timeout) is not None

    def reset(self, initial: Sequence[float], step: int = 0, tries: int = 3) -> None:
        """Send the initial temperatures [yoke, winding, tooth, magnet] and RESET; wait for READY."""
        frames = split_temperatures([round(float(v), 2) for v in initial], RESET_SIGNALS)
        for _ in range(tries):
            self.send([self.codec.encode(name, {"Step": step, **signals}) for name, signals in frames.items()]
                      + [self.control(Command.RESET, step)])
            self.flush_log()
            if self._await_state(TargetState.READY, 0.5):
                return
        faults = FaultBit(self.monitor.faults)
        raise SessionError(f"the target did not become READY after {tries} RESETs (state "
                           f"{self.monitor.state.name if self.monitor.state is not None else 'unknown'}, faults "
                           f"{faults!r}); check that no other host is on this bus")

    def restore(self, state: Sequence[float], step: int, tries: int = 3,
                observer: dict[int, float] | None = None) -> None:
        """Echo a checkpointed state vector in RestoreState frames (and an observer's checkpoint of the same row in
        RestoreObserver frames) and RESTORE at `step`; wait for READY. The checkpoints of the rows from there on are
        forgotten: the restored target sends them again (from a covariance P0 without `observer`: other values)."""
        self._forget_checkpoints(self._row_of(step))
        low = step % CHECKPOINT_STEP_LOW_MODULO
        for _ in range(tries):
            self.send([self.codec.encode("RestoreState", {"Step": step, "StateIndex": index, "StateValue": value})
                       for index, value in enumerate(state)]
                      + [self.codec.encode(RESTORE_OBSERVER_MESSAGE, {"Index": index, "StepLow": low, "Value": value})
                         for index, value in sorted((observer or {}).items())]
                      + [self.control(Command.RESTORE, step)])
            self.flush_log()
            if self._await_state(TargetState.READY, 0.5):
                return
        raise SessionError(f"the target did not become READY after {tries} RESTOREs (state "
                           f"{self.monitor.state.name if self.monitor.state is not None else 'unknown'}); check that "
                           "no other host is on this bus")

    def start(self, step: int = 0) -> None:
        self.send([self.control(Command.START, step)])
        self.flush_log()
        if not self._await_state(TargetState.RUNNING, 1.0):
            raise SessionError("the target did not start RUNNING after START")

    def stop(self, drain_s: float = 0.15) -> None:
        """STOP, wait for STOPPED (best effort), and collect what is still on the way."""
        self.send([self.control(Command.STOP)])
        self.flush_log()
        self._await_state(TargetState.STOPPED, 1.0)
        deadline = time.perf_counter() + drain_s
        while (remaining := deadline - time.perf_counter()) > 0:
            self.receive(remaining)
        self.flush_log()
