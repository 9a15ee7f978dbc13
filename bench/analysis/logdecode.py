"""Decode a bus log (any format the host writes) into arrays: what was sent, what came back, and when.

Rows: a fresh session begins at a Control START not announced by a BenchEvent REINIT (everything before it is
forgotten: the last session of a log wins); its START Step is data row 0, and a drive frame's Step maps to the
row nearest to the last row sent (mod 65536), so a row sent again (a retransmission) is the same row. A data row
is a DriveInputs followed by the DriveTemps of the same Step, and in a log whose host sent the d/q currents (DBC
1.4.0) the DriveCurrents of that Step right after them: such a log's drive matrix has six columns (torque, speed,
coolant, ambient, i_d, i_q; NaN where a row's DriveCurrents never came intact), else four. The initial temperatures
are those of the
ResetTemps frames the session's RESET used. Frames that fail the DBC checks (unknown id, length, CRC, range)
are counted and skipped; the drive values of a row come from its frames that pass them.

Segments: a Control START announced by a BenchEvent REINIT (the host re-initialized a lost target) starts a new
segment of the same session at its Step's row, from the state vector of its RESTORE (an echoed StateCheckpoint,
float32 bit for bit) or from the temperatures of its RESET. Replies belong to the
segment the target was running when it sent them: the target's k-th transition into RUNNING (Status frames)
starts segment k; so the late replies of a target that was frozen are told apart from the new segment's
replies, even when they arrive after the host's RESET. Each segment keeps its own replies; the final reply of a
row is that of the last segment that answered it (`temps`, `replied_s`, `owner`).

Marks: BenchEvent frames (injected faults, target lost, re-initialization, retransmission) are collected in
`marks`; a TARGET-LOST mark and the REINIT mark after it make a `gap` (rows restart..lost were answered again by
the new segment).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dbc.codec import decode_any
from dbc.contract import (
    CURRENT_MESSAGE,
    CURRENT_SIGNALS,
    DRIVE_SIGNALS,
    FIRMWARE_TIMING_MESSAGE,
    REPLY_COMPLETE,
    REPLY_SIGNALS,
    RESET_SIGNALS,
    STATE_SIZE,
    BenchEvent,
    Command,
    FaultKind,
    FrameError,
    TargetState,
    join_temperatures,
    nearest_row,
    place_temperatures,
    rx_error_counts,
    target_info,
)
from host.canlog import LogError, read_log


@dataclass
class Segment:
    """Rows start_row.. as one target process state ran them from `initial`, and the replies it sent."""

    start_row: int
    initial: np.ndarray | None              # [yoke, winding, tooth, magnet] of a RESET
    recovery: bool = False                  # started by a re-initialization (REINIT)
    state: np.ndarray | None = None         # float32 state vector of a RESTORE (then `initial` is None)
    reply_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    reply_temps: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    reply_s: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass
class Mark:
    """A BenchEvent of the log."""

    event: str                  # fault, target-lost, reinit, retransmit
    row: int
    fault: str | None           # the injected kind (FAULT marks), e.g. "drop"
    frame_id: int | None
    t: float


@dataclass
class BusRecord:
    path: Path
    frames: int = 0
    invalid: dict[str, int] = field(default_factory=dict)
    initial: np.ndarray | None = None            # [yoke, winding, tooth, magnet] of the session's first RESET
    drive: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))   # (rows, 4), or 6 with the d/q currents
    sent_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    temps: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    replied_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    owner: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # segment of the final reply
    timing: dict[str, np.ndarray] = field(default_factory=dict)   # row, measured_us, overruns, cycles, ...
    status_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    states: list[str] = field(default_factory=list)
    faults_seen: int = 0
    model_id: int | None = None
    rx_errors: dict[str, int] = field(default_factory=dict)
    target_info: dict[str, object] = field(default_factory=dict)
    frame_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frame_dlc: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    frame_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    frame_data: np.ndarray = field(default_factory=lambda: np.zeros((0, 8), dtype=np.uint8))
    sessions: int = 0
    segments: list[Segment] = field(default_factory=list)
    marks: list[Mark] = field(default_factory=list)

    @property
    def rows(self) -> int:
        return len(self.drive)

    @property
    def answered(self) -> np.ndarray:
        return np.isfinite(self.temps).all(axis=1)

    @property
    def gaps(self) -> list[dict]:
        """Each TARGET-LOST mark with the REINIT after it: {lost_row, restart_row, rows, lost_s, reinit_s}."""
        out = []
        lost: Mark | None = None
        for mark in self.marks:
            if mark.event == "target-lost":
                lost = mark
            elif mark.event == "reinit" and lost is not None:
                out.append({"lost_row": lost.row, "restart_row": mark.row, "rows": [mark.row, lost.row],
                            "lost_s": lost.t, "reinit_s": mark.t})
                lost = None
        if lost is not None:  # lost and never re-initialized
            out.append({"lost_row": lost.row, "restart_row": None, "rows": [lost.row, self.rows - 1],
                        "lost_s": lost.t, "reinit_s": None})
        return out


@dataclass
class _Reply:
    """What came back for one row so far: temperatures in the state order, the reply bits, the last frame's time."""

    temps: list[float] = field(default_factory=lambda: [math.nan] * STATE_SIZE)
    got: int = 0
    t: float = math.nan

    @property
    def complete(self) -> bool:
        return self.got == REPLY_COMPLETE


class _SegmentBuilder:
    def __init__(self, start_row: int, initial, recovery: bool, state=None):
        self.start_row = start_row
        self.initial = initial
        self.state = state
        self.recovery = recovery
        self.host_row = start_row - 1          # the last row sent in this segment
        self.replies: dict[int, _Reply] = {}
        self.pair_s: dict[int, float] = {}     # row -> send time of the pair that was answered

    @property
    def reference_row(self) -> int:
        """The row a Step of this segment is read near: the last row sent (or its first row)."""
        return max(self.host_row, self.start_row)

    def build(self) -> Segment:
        rows = sorted(r for r, reply in self.replies.items() if reply.complete)
        temps = np.array([self.replies[r].temps for r in rows], dtype=float).reshape(-1, STATE_SIZE)
        return Segment(self.start_row, self.initial, self.recovery, self.state,
                       reply_rows=np.array(rows, dtype=np.int64), reply_temps=temps,
                       reply_s=np.array([self.replies[r].t for r in rows], dtype=float))


_TIMING_SIGNALS = {"Timing1": ("row_t1", (("measured_us", "StepTimeMeasured"), ("overruns", "Overruns"))),
                   "Timing2": ("row_t2", (("cycles", "EstCycles"), ("exec_us", "EstExecTime"))),
                   "Timing3": ("row_t3", (("cpu_load", "CpuLoad"),)),
                   # the firmware engine's measured Cortex-M4F cycles (absent with the Python engine)
                   FIRMWARE_TIMING_MESSAGE: ("row_t4", (("m4_cycles", "M4Cycles"), ("m4_exec_us", "M4ExecTime")))}


class _LogDecoder:
    """Reads a log frame by frame; one handler per message of the contract (see the module docstring)."""

    def __init__(self, path: Path) -> None:
        self.record = BusRecord(path)
        self.invalid: dict[str, int] = {}
        self.drive: dict[int, list[float]] = {}
        self.segments: list[_SegmentBuilder] = []
        self.marks: list[Mark] = []
        self.base_step = 0                 # Step of the fresh session's START: row 0
        self.pending_inputs: tuple[dict, float] | None = None   # a DriveInputs waiting for its DriveTemps
        self.pending_pair: tuple[int, int, dict] | None = None   # (Step, row, DriveTemps) of the last pair: its
        # DriveCurrents comes next
        self.currents: dict[int, list[float]] = {}         # row -> [i_d, i_q] of its DriveCurrents
        self.reset_frames: dict[str, dict] = {}
        self.restore_frames: dict[int, dict] = {}
        self.pending_initial: np.ndarray | None = None
        self.pending_state: np.ndarray | None = None
        self.reinit_announced = False
        self.transitions = 0               # the target's transitions into RUNNING
        self.epoch_base = 0                # transitions before the fresh session
        self.last_state: int | None = None
        self.timing: dict[str, list] = self._empty_timing()
        self.status_s: list[float] = []
        self.frame_s: list[float] = []
        self.frame_dlc: list[int] = []
        self.frame_ids: list[int] = []
        self.frame_bytes = bytearray()
        self.handlers = {"DriveInputs": self.drive_inputs, "DriveTemps": self.drive_temps,
                         CURRENT_MESSAGE: self.drive_currents,
                         **dict.fromkeys(REPLY_SIGNALS, self.temperatures),
                         **dict.fromkeys(_TIMING_SIGNALS, self.timing_frame),
                         **dict.fromkeys(RESET_SIGNALS, self.reset_temps),
                         "RestoreState": self.restore_state, "Control": self.control,
                         "BenchEvent": self.bench_event, "Status": self.status, "RxErrors": self.rx_errors,
                         "TargetInfo": self.target_info}

    @staticmethod
    def _empty_timing() -> dict[str, list]:
        return {key: [] for row_key, signals in _TIMING_SIGNALS.values() for key in (row_key, *(k for k, _ in signals))}

    def _row(self, segment: _SegmentBuilder, step) -> int:
        return nearest_row(int(step) - self.base_step, segment.reference_row)

    def target_segment(self) -> _SegmentBuilder | None:
        """The segment the target was running when it sent a frame (its k-th transition into RUNNING)."""
        index = self.transitions - self.epoch_base - 1
        return self.segments[index] if 0 <= index < len(self.segments) else None

    # ------------------------------------------------------------------ frames
    def feed(self, msg) -> None:
        self.record.frames += 1
        self.frame_s.append(msg.timestamp)
        self.frame_dlc.append(msg.dlc)
        self.frame_ids.append(msg.arbitration_id)
        self.frame_bytes += bytes(msg.data[:8]).ljust(8, b"\0")
        try:
            frame = decode_any(msg)
        except FrameError as exc:
            self.invalid[exc.kind] = self.invalid.get(exc.kind, 0) + 1
            return
        handler = self.handlers.get(frame.name)
        if handler is not None:
            handler(frame.name, frame.signals, msg.timestamp)

    def drive_inputs(self, name: str, s: dict, t: float) -> None:
        self.pending_inputs = (s, t)
        self.pending_pair = None

    def drive_temps(self, name: str, s: dict, t: float) -> None:
        pending, self.pending_inputs = self.pending_inputs, None
        if pending is None and self.pending_pair is not None and self.pending_pair[2] != s:
            self.pending_pair = None   # a DriveTemps between a pair and its currents (not a copy of the pair's)
        if pending is None or pending[0]["Step"] != s["Step"] or not self.segments:
            return
        inputs, inputs_t = pending
        segment = self.segments[-1]
        row = self._row(segment, s["Step"])
        if row < 0:
            return
        self.drive[row] = [inputs["MotorTorque"], inputs["MotorSpeed"], s["CoolantTemp"], s["AmbientTemp"]]
        self.currents.pop(row, None)        # a row sent again: its currents come again after this pair
        self.pending_pair = (int(s["Step"]), row, s)
        segment.host_row = row
        reply = segment.replies.get(row)
        if reply is None or not reply.complete:
            segment.pair_s[row] = inputs_t

    def drive_currents(self, name: str, s: dict, t: float) -> None:
        """The d/q currents of the pair right before them (same Step): the row's last two values, as the target
        completes a row. A DriveCurrents of another Step ends the pair without currents (the target drops the row);
        copies of a frame (the target refuses them for their alive counter, which the decoder does not judge)
        carry the same values and change nothing."""
        pair = self.pending_pair
        if pair is not None and pair[0] == int(s["Step"]):
            self.currents[pair[1]] = [s["CurrentD"], s["CurrentQ"]]
        else:
            self.pending_pair = None

    def temperatures(self, name: str, s: dict, t: float) -> None:
        segment = self.target_segment()
        if segment is None:
            return
        reply = segment.replies.setdefault(self._row(segment, s["Step"]), _Reply())
        reply.got |= place_temperatures(name, s, reply.temps)
        reply.t = t if math.isnan(reply.t) else max(reply.t, t)

    def timing_frame(self, name: str, s: dict, t: float) -> None:
        segment = self.target_segment()
        if segment is None:
            return
        row_key, signals = _TIMING_SIGNALS[name]
        self.timing[row_key].append(self._row(segment, s["Step"]))
        for key, signal in signals:
            self.timing[key].append(s[signal])

    def reset_temps(self, name: str, s: dict, t: float) -> None:
        self.reset_frames[name] = s

    def restore_state(self, name: str, s: dict, t: float) -> None:
        self.restore_frames[int(s["StateIndex"])] = s

    def control(self, name: str, s: dict, t: float) -> None:
        command = int(s["Command"])
        if command == Command.RESET:
            frames = self.reset_frames
            if len(frames) == len(RESET_SIGNALS) and all(f["Step"] == s["Step"] for f in frames.values()):
                self.pending_initial = np.array(join_temperatures(frames, RESET_SIGNALS), dtype=float)
                self.pending_state = None
        elif command == Command.RESTORE:
            elements = [self.restore_frames[i]["StateValue"] for i in range(STATE_SIZE)
                        if i in self.restore_frames and self.restore_frames[i]["Step"] == s["Step"]]
            if len(elements) == STATE_SIZE:
                self.pending_state, self.pending_initial = np.array(elements, dtype=np.float32), None
            self.restore_frames = {}
        elif command == Command.START:
            self.start(int(s["Step"]))

    def start(self, step: int) -> None:
        """A START: a new segment after a REINIT mark, else a fresh session (the last session of a log wins)."""
        self.record.sessions += 1
        if self.reinit_announced and self.segments:
            start = self._row(self.segments[-1], step)
            self.segments.append(_SegmentBuilder(start, self.pending_initial, True, self.pending_state))
        else:
            self.base_step = step
            self.record.initial = self.pending_initial
            self.segments = [_SegmentBuilder(0, self.pending_initial, False)]
            self.drive = {}
            self.currents = {}
            self.marks = []
            self.timing = self._empty_timing()
            # the session's first transition into RUNNING starts segment 0 (one already RUNNING: its own)
            self.epoch_base = self.transitions - (1 if self.last_state == TargetState.RUNNING else 0)
        self.reinit_announced = False

    def bench_event(self, name: str, s: dict, t: float) -> None:
        event = BenchEvent(int(s["Event"]))
        kind = FaultKind(int(s["FaultKind"]))
        reference = self.segments[-1].reference_row if self.segments else 0
        self.marks.append(Mark(event.name.lower().replace("_", "-"),
                               nearest_row(int(s["Step"]) - self.base_step, reference),
                               None if kind == FaultKind.NONE else kind.name.lower(), int(s["FrameId"]) or None, t))
        if event == BenchEvent.REINIT:
            self.reinit_announced = True

    def status(self, name: str, s: dict, t: float) -> None:
        self.status_s.append(t)
        state = int(s["State"])
        if state == TargetState.RUNNING and self.last_state != TargetState.RUNNING:
            self.transitions += 1
        self.last_state = state
        self.record.states.append(TargetState(state).name)
        self.record.faults_seen |= int(s["FaultBits"])
        self.record.model_id = int(s["ModelId"])

    def rx_errors(self, name: str, s: dict, t: float) -> None:
        self.record.rx_errors = rx_error_counts(s)

    def target_info(self, name: str, s: dict, t: float) -> None:
        self.record.target_info = target_info(s)

    # ------------------------------------------------------------------ the record
    def finish(self) -> BusRecord:
        record = self.record
        path = record.path
        if record.frames == 0:
            raise LogError(f"log {path} holds no frames")
        if record.sessions == 0:
            raise LogError(f"log {path} holds no session (no Control START); is it a log of this bench?")
        rows = max(self.drive) + 1 if self.drive else 0
        record.invalid = self.invalid
        width = len(DRIVE_SIGNALS) + (len(CURRENT_SIGNALS) if self.currents else 0)
        record.drive = np.full((rows, width), np.nan)
        for row, values in self.drive.items():
            record.drive[row, :len(values)] = values
            if width > len(values) and row in self.currents:
                record.drive[row, len(values):] = self.currents[row]
        record.segments = [segment.build() for segment in self.segments]
        self._final_replies(rows)
        record.timing = {k: np.array(v, dtype=float) for k, v in self.timing.items()}
        record.status_s = np.array(self.status_s, dtype=float)
        record.frame_s = np.array(self.frame_s, dtype=float)
        record.frame_dlc = np.array(self.frame_dlc, dtype=np.int64)
        record.frame_ids = np.array(self.frame_ids, dtype=np.int64)
        record.frame_data = np.frombuffer(bytes(self.frame_bytes), dtype=np.uint8).reshape(-1, 8)
        record.marks = self.marks
        return record

    def _final_replies(self, rows: int) -> None:
        """Each row's final reply: that of the last segment that answered it, and when its pair was sent."""
        record = self.record
        record.temps = np.full((rows, STATE_SIZE), np.nan)
        record.replied_s = np.full(rows, np.nan)
        record.sent_s = np.full(rows, np.nan)
        record.owner = np.full(rows, -1, dtype=np.int64)
        for index, (builder, segment) in enumerate(zip(self.segments, record.segments, strict=True)):
            keep = segment.reply_rows < rows
            replied = segment.reply_rows[keep]
            record.temps[replied] = segment.reply_temps[keep]
            record.replied_s[replied] = segment.reply_s[keep]
            record.owner[replied] = index
            for row in replied.tolist():
                record.sent_s[row] = builder.pair_s.get(row, math.nan)
        unanswered = np.isnan(record.sent_s)
        if unanswered.any():  # rows never answered: when they were (last) sent
            for builder in self.segments:
                for row, t in builder.pair_s.items():
                    if row < rows and unanswered[row]:
                        record.sent_s[row] = t


def decode_log(path: str | Path) -> BusRecord:
    """Read and decode a log; LogError for a file that cannot be read or holds no session."""
    decoder = _LogDecoder(Path(path))
    for msg in read_log(path):
        decoder.feed(msg)
    return decoder.finish()
