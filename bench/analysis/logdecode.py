"""Decode a bus log (any format the host writes) into arrays: what was sent, what came back, and when.

Rows: a fresh session begins at a Control START not announced by a BenchEvent REINIT (everything before it is
forgotten: the last session of a log wins); its START Step is data row 0, and a drive frame's Step maps to the
row nearest to the last row sent (mod 65536), so a row sent again (a retransmission) is the same row. A data row
is a DriveInputs followed by the DriveTemps of the same Step. The initial temperatures are those of the
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

from dbc import BenchEvent, Command, FaultKind, FrameError, ModelKind, Realization, TargetState
from host.canlog import LogError, read_log
from target_sim.fastframes import fast_decode_any

STEP_MODULO = 1 << 16
RX_ERROR_NAMES = {"UnknownId": "unknown_id", "WrongLength": "wrong_length", "CrcError": "crc",
                  "CounterError": "counter", "OutOfRange": "out_of_range", "SequenceError": "sequence"}


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
    drive: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
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


class _SegmentBuilder:
    def __init__(self, start_row: int, initial, recovery: bool, state=None):
        self.start_row = start_row
        self.initial = initial
        self.state = state
        self.recovery = recovery
        self.host_row = start_row - 1          # the last row sent in this segment
        self.replies: dict[int, list] = {}     # row -> [yoke, winding, tooth, magnet, got bits, time]
        self.pair_s: dict[int, float] = {}     # row -> send time of the pair that was answered

    def row_of(self, rel_step: int) -> int:
        return nearest_row(rel_step, max(self.host_row, self.start_row))

    def build(self) -> Segment:
        rows = sorted(r for r, v in self.replies.items() if v[4] == 3)
        temps = np.array([self.replies[r][:4] for r in rows], dtype=float).reshape(-1, 4)
        return Segment(self.start_row, self.initial, self.recovery, self.state,
                       reply_rows=np.array(rows, dtype=np.int64), reply_temps=temps,
                       reply_s=np.array([self.replies[r][5] for r in rows], dtype=float))


def nearest_row(rel_step: int, reference: int) -> int:
    """The row congruent to `rel_step` mod 65536 nearest to `reference`."""
    delta = (rel_step - reference) % STEP_MODULO
    if delta >= STEP_MODULO // 2:
        delta -= STEP_MODULO
    return reference + delta


def decode_log(path: str | Path) -> BusRecord:
    """Read and decode a log; LogError for a file that cannot be read or holds no session."""
    record = BusRecord(Path(path))
    invalid: dict[str, int] = {}
    drive: dict[int, list[float]] = {}
    segments: list[_SegmentBuilder] = []
    marks: list[Mark] = []
    base_step = 0                 # Step of the fresh session's START: row 0
    pending_inputs: dict | None = None
    pending_inputs_time = 0.0
    reset_frames: dict[str, dict] = {}
    restore_frames: dict[int, dict] = {}
    pending_initial = None
    pending_state = None
    reinit_announced = False
    transitions = 0               # the target's transitions into RUNNING
    epoch_base = 0                # transitions before the fresh session
    last_state: int | None = None
    timing: dict[str, list] = {k: [] for k in ("row_t1", "measured_us", "overruns", "row_t2", "cycles", "exec_us",
                                               "row_t3", "cpu_load")}
    status_s: list[float] = []
    frame_s: list[float] = []
    frame_dlc: list[int] = []
    frame_ids: list[int] = []
    frame_bytes = bytearray()

    def target_segment() -> _SegmentBuilder | None:
        index = transitions - epoch_base - 1
        return segments[index] if 0 <= index < len(segments) else None

    for msg in read_log(path):
        record.frames += 1
        frame_s.append(msg.timestamp)
        frame_dlc.append(msg.dlc)
        frame_ids.append(msg.arbitration_id)
        frame_bytes += bytes(msg.data[:8]).ljust(8, b"\0")
        try:
            frame = fast_decode_any(msg)
        except FrameError as exc:
            invalid[exc.kind] = invalid.get(exc.kind, 0) + 1
            continue
        name, s = frame.name, frame.signals
        if name == "DriveInputs":
            pending_inputs = s
            pending_inputs_time = msg.timestamp
        elif name == "DriveTemps":
            if pending_inputs is None or pending_inputs["Step"] != s["Step"] or not segments:
                pending_inputs = None
                continue
            segment = segments[-1]
            row = segment.row_of(int(s["Step"]) - base_step)
            if row < 0:
                pending_inputs = None
                continue
            drive[row] = [pending_inputs["MotorTorque"], pending_inputs["MotorSpeed"], s["CoolantTemp"],
                          s["AmbientTemp"]]
            segment.host_row = row
            reply = segment.replies.get(row)
            if reply is None or reply[4] != 3:
                segment.pair_s[row] = pending_inputs_time
            pending_inputs = None
        elif name in ("Temperatures1", "Temperatures2"):
            segment = target_segment()
            if segment is None:
                continue
            row = segment.row_of(int(s["Step"]) - base_step)
            reply = segment.replies.setdefault(row, [math.nan] * 4 + [0, math.nan])
            if name == "Temperatures1":
                reply[1], reply[3] = s["WindingTemp"], s["MagnetTemp"]
                reply[4] |= 1
            else:
                reply[0], reply[2] = s["YokeTemp"], s["ToothTemp"]
                reply[4] |= 2
            reply[5] = msg.timestamp if math.isnan(reply[5]) else max(reply[5], msg.timestamp)
        elif name in ("Timing1", "Timing2", "Timing3"):
            segment = target_segment()
            if segment is None:
                continue
            row = segment.row_of(int(s["Step"]) - base_step)
            if name == "Timing1":
                timing["row_t1"].append(row)
                timing["measured_us"].append(s["StepTimeMeasured"])
                timing["overruns"].append(s["Overruns"])
            elif name == "Timing2":
                timing["row_t2"].append(row)
                timing["cycles"].append(s["EstCycles"])
                timing["exec_us"].append(s["EstExecTime"])
            else:
                timing["row_t3"].append(row)
                timing["cpu_load"].append(s["CpuLoad"])
        elif name in ("ResetTemps1", "ResetTemps2"):
            reset_frames[name] = s
        elif name == "RestoreState":
            restore_frames[int(s["StateIndex"])] = s
        elif name == "Control":
            command = int(s["Command"])
            if command == Command.RESET:
                r1, r2 = reset_frames.get("ResetTemps1"), reset_frames.get("ResetTemps2")
                if r1 is not None and r2 is not None and r1["Step"] == r2["Step"] == s["Step"]:
                    pending_initial = np.array([r2["YokeTempInit"], r1["WindingTempInit"], r2["ToothTempInit"],
                                                r1["MagnetTempInit"]], dtype=float)
                    pending_state = None
            elif command == Command.RESTORE:
                elements = [restore_frames[i]["StateValue"] for i in range(4)
                            if i in restore_frames and restore_frames[i]["Step"] == s["Step"]]
                if len(elements) == 4:
                    pending_state, pending_initial = np.array(elements, dtype=np.float32), None
                restore_frames = {}
            elif command == Command.START:
                record.sessions += 1
                if reinit_announced and segments:
                    last = segments[-1]
                    start = nearest_row(int(s["Step"]) - base_step, max(last.host_row, last.start_row))
                    segments.append(_SegmentBuilder(start, pending_initial, True, pending_state))
                else:
                    base_step = int(s["Step"])
                    record.initial = pending_initial
                    segments = [_SegmentBuilder(0, pending_initial, False)]
                    drive = {}
                    marks = []
                    timing = {k: [] for k in timing}
                    # the session's first transition into RUNNING starts segment 0 (one already RUNNING: its own)
                    epoch_base = transitions - (1 if last_state == TargetState.RUNNING else 0)
                reinit_announced = False
        elif name == "BenchEvent":
            event = BenchEvent(int(s["Event"]))
            kind = FaultKind(int(s["FaultKind"]))
            reference = max(segments[-1].host_row, segments[-1].start_row) if segments else 0
            marks.append(Mark(event.name.lower().replace("_", "-"), nearest_row(int(s["Step"]) - base_step, reference),
                              None if kind == FaultKind.NONE else kind.name.lower(),
                              int(s["FrameId"]) or None, msg.timestamp))
            if event == BenchEvent.REINIT:
                reinit_announced = True
        elif name == "Status":
            status_s.append(msg.timestamp)
            state = int(s["State"])
            if state == TargetState.RUNNING and last_state != TargetState.RUNNING:
                transitions += 1
            last_state = state
            record.states.append(TargetState(state).name)
            record.faults_seen |= int(s["FaultBits"])
            record.model_id = int(s["ModelId"])
        elif name == "RxErrors":
            record.rx_errors = {RX_ERROR_NAMES.get(k, k): int(v) for k, v in s.items()}
        elif name == "TargetInfo":
            record.target_info = {
                "model_kind": ModelKind(int(s["ModelKind"])).name.lower().replace("_", "-"),
                "realization": Realization(int(s["Realization"])).name.lower(),
                "dt_s": float(s["ModelDt"]), "flash_bytes": int(s["FlashBytes"]), "ram_bytes": int(s["RamBytes"])}
    if record.frames == 0:
        raise LogError(f"log {path} holds no frames")
    if record.sessions == 0:
        raise LogError(f"log {path} holds no session (no Control START); is it a log of this bench?")
    rows = max(drive) + 1 if drive else 0
    record.invalid = invalid
    record.drive = np.full((rows, 4), np.nan)
    for row, values in drive.items():
        record.drive[row] = values
    record.segments = [segment.build() for segment in segments]
    record.temps = np.full((rows, 4), np.nan)
    record.replied_s = np.full(rows, np.nan)
    record.sent_s = np.full(rows, np.nan)
    record.owner = np.full(rows, -1, dtype=np.int64)
    for index, (builder, segment) in enumerate(zip(segments, record.segments, strict=True)):
        keep = segment.reply_rows < rows
        replied = segment.reply_rows[keep]
        record.temps[replied] = segment.reply_temps[keep]
        record.replied_s[replied] = segment.reply_s[keep]
        record.owner[replied] = index
        for row in replied.tolist():
            record.sent_s[row] = builder.pair_s.get(row, math.nan)
    unanswered = np.isnan(record.sent_s)
    if unanswered.any():  # rows never answered: when they were (last) sent
        for builder in segments:
            for row, t in builder.pair_s.items():
                if row < rows and unanswered[row]:
                    record.sent_s[row] = t
    record.timing = {k: np.array(v, dtype=float) for k, v in timing.items()}
    record.status_s = np.array(status_s, dtype=float)
    record.frame_s = np.array(frame_s, dtype=float)
    record.frame_dlc = np.array(frame_dlc, dtype=np.int64)
    record.frame_ids = np.array(frame_ids, dtype=np.int64)
    record.frame_data = np.frombuffer(bytes(frame_bytes), dtype=np.uint8).reshape(-1, 8)
    record.marks = marks
    return record
