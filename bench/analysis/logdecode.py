"""Decode a bus log (any format the host writes) into arrays: what was sent, what came back, and when.

Rows: a fresh session begins at a Control START not announced by a BenchEvent REINIT (everything before it is
forgotten: the last session of a log wins); its START Step is data row 0, and a drive frame's Step maps to the
row nearest to the last row sent (mod 65536), so a row sent again (a retransmission) is the same row. A data row
is a DriveInputs followed by the DriveTemps of the same Step, and in a log whose host sent the d/q currents (DBC
1.4.0) the DriveCurrents of that Step right after them: such a log's drive matrix has six columns (torque, speed,
coolant, ambient, i_d, i_q; NaN where a row's DriveCurrents never came intact), else four. A row's measurements
(DBC 1.6.0, a model with an observer) are the VALID values of the Measurements frame (and, DBC 1.7.0, the
DriveVoltages frame) of its Step that came right before its pair, as the target pairs them (`measurements`, one
column per `dbc.contract.MEASUREMENT_CHANNELS`, NaN: none); the observer's per-step frames (each node's
1-sigma, the innovations) are collected like the timing frames (`observer`). The initial temperatures
are those of the
ResetTemps frames the session's RESET used. Frames that fail the DBC checks (unknown id, length, CRC, range)
are counted and skipped; the drive values of a row come from its frames that pass them.

Segments: a Control START announced by a BenchEvent REINIT (the host re-initialized a lost target) starts a new
segment of the same session at its Step's row, from the state vector of its RESTORE (an echoed StateCheckpoint,
float32 bit for bit, with the observer's echoed ObserverCheckpoint when its RestoreObserver frames came) or from
the temperatures of its RESET. Replies belong to the
segment the target was running when it sent them: the target's k-th transition into RUNNING (Status frames)
starts segment k; so the late replies of a target that was frozen are told apart from the new segment's
replies, even when they arrive after the host's RESET. Each segment keeps its own replies; the final reply of a
row is that of the last segment that answered it (`temps`, `replied_s`, `owner`).

Marks: BenchEvent frames (injected faults, target lost, re-initialization, retransmission) are collected in
`marks`; a TARGET-LOST mark and the REINIT mark after it make a `gap` (rows restart..lost were answered again by
the new segment).

The host's checks: every frame the target sends goes through the host's own `dbc.FrameValidator("HOST")` in log
order (id, length, CRC, range, and the alive counter per id, forgotten at each TARGET-LOST mark as the host does),
so a frame the host rejected is never used, whatever it carries; its kind is counted in `invalid` and its message
in `rejected`. XCP frames (the two ids of `dbc/xcp.toml`, a calibration master's traffic) count in the bus load
and are otherwise left alone, as the host leaves them; a log with an XCP DOWNLOAD (a calibration during the run,
`xcp_downloads`) is judged against the target's twin, which replays the commands in their place. Frames that
pass those checks and still do not belong to this session are *foreign*, counted by
reason in `foreign` and never used: a Status of another model id than the session's first, a reply or timing
frame for a row the host had not sent in its segment, and a second reply for a row that carries other
temperatures than the first. So is a reply frame that repeats the alive counter of the one before it for the same
row with other temperatures (rejected by the counter check, but one of the two is not the target's: a replayed
frame that took the genuine one's counter). Such a row is *contested*: neither reply is reported. A reply frame
the counter check rejected (a replayed frame: its alive counter is out of sequence) that names a row its segment
answered, with other temperatures than that answer, makes the row *replayed* (`BusRecord.replayed`): the host used
the frame in sequence, but the row had two answers. Contested and replayed rows are flagged as not the target's
own answer; `bench.analysis.rowfilter` keeps them out of every figure. The host's own frames (DriveInputs,
DriveTemps, ...) are checked for id, length, CRC and range; its measurement frames (Measurements, DriveVoltages)
also for their alive counter, as the target checks them (`dbc.FrameValidator("TARGET")`, forgotten at each STOP and
TARGET-LOST mark, as a stopped or restarted target forgets it): one the target refuses (a replayed or lost frame) is
counted (`invalid`, and by message in `rejected_host`) and its readings are not the row's, as they were not the
target's.

Checkpoints: the target's StateCheckpoint and ObserverCheckpoint frames are kept as the host's checks accept them,
by the row their Step names, read as a reply's is (nearest the last row sent: two checkpoints of a long log 65536
steps apart are two checkpoints). Like a reply, a checkpoint frame that repeats the alive counter of the one
before it and is not a copy of it (rejected by the counter check), or a second accepted frame of an element with
another value in the same run of the target, makes the
checkpoints of both frames *contested* (counted foreign): one of them is not the target's (a forged or replayed
frame). A RESTORE is compared with them: its RestoreState state vector must be a checkpoint the target sent, not
contested, and its RestoreObserver elements that checkpoint's ObserverCheckpoint, bit for bit; a segment restored
otherwise starts from a state the target never had (`Segment.checkpoint`: "forged" or "contested"), and
`bench.analysis.rowfilter` keeps its rows out of every figure.

Complete: a run's log ends with the host's Control STOP; one without it after the last session's START (a killed
run, a partial file) is `complete = False`, and so is a .blf whose header was never finalized by its writer.

Memory: frames and rows are kept in columns (numpy arrays that grow by doubling, `array` for per-frame fields), not
as objects per frame or per row: about 20 bytes a frame and 270 a row in the record.
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dbc.codec import FrameValidator, decode_any
from dbc.contract import (
    CHANNEL_NAMES,
    CHECKPOINT_STEP_LOW_MODULO,
    CURRENT_MESSAGE,
    CURRENT_SIGNALS,
    DRIVE_SIGNALS,
    FIRMWARE_TIMING_MESSAGE,
    FLAG_MESSAGE,
    FLAGGED_SIGNALS,
    INNOVATION_MESSAGE,
    MEASUREMENT_MESSAGES,
    OBSERVER_CHECKPOINT_MESSAGE,
    REJECTED_SIGNALS,
    REPLY_BIT,
    REPLY_COMPLETE,
    REPLY_SIGNALS,
    RESET_SIGNALS,
    RESPONSE_TIMING_MESSAGE,
    RESTORE_OBSERVER_MESSAGE,
    STATE_SIZE,
    BenchEvent,
    Command,
    FaultKind,
    FrameError,
    TargetState,
    channel_values,
    join_temperatures,
    nearest_row,
    rx_error_counts,
    step_of,
    target_info,
)
from dbc.database import contract, frame_id, target_frame_ids
from dbc.xcp import cmd_id, xcp_ids
from host.canlog import LogError, read_log
from target_sim.xcp.codes import Cmd

# why a frame that passed the host's checks is not used (BusRecord.foreign)
FOREIGN_MODEL = "Status of another model id"
FOREIGN_ROW = "reply or timing for a row not sent"
FOREIGN_CONTESTED = "second reply with other temperatures"
FOREIGN_CHECKPOINT = "checkpoint frame contested"
CHECKPOINT_MESSAGES = ("StateCheckpoint", OBSERVER_CHECKPOINT_MESSAGE)
# why a segment's restore is not the target's own checkpoint (Segment.checkpoint)
RESTORE_FORGED = "forged"          # the echoed state (or filter) is no checkpoint the target sent
RESTORE_CONTESTED = "contested"    # it is one, but a frame of it was contested


@dataclass
class Segment:
    """Rows start_row.. as one target process state ran them from `initial`, and the replies it sent."""

    start_row: int
    initial: np.ndarray | None              # [yoke, winding, tooth, magnet] of a RESET
    recovery: bool = False                  # started by a re-initialization (REINIT)
    state: np.ndarray | None = None         # float32 state vector of a RESTORE (then `initial` is None)
    observer_checkpoint: dict | None = None  # a RESTORE's RestoreObserver elements {Index: value} (DBC 1.7.0)
    checkpoint: str | None = None           # a RESTORE not from the target's own checkpoint: forged, contested
    reply_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    reply_temps: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    reply_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    contested_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


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
    invalid: dict[str, int] = field(default_factory=dict)      # frames that failed the checks, by kind
    rejected: dict[str, int] = field(default_factory=dict)     # the target's frames the host's checks reject
    rejected_host: dict[str, int] = field(default_factory=dict)  # the host's measurement frames the target refuses
    foreign: dict[str, int] = field(default_factory=dict)      # frames that passed them but are not of this session
    initial: np.ndarray | None = None            # [yoke, winding, tooth, magnet] of the session's first RESET
    drive: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))   # (rows, 4), or 6 with the d/q currents
    # (rows, one per measurement channel, `dbc.contract.MEASUREMENT_CHANNELS`): the VALID values of the measurement
    # frames (Measurements, DriveVoltages) that came before each row's pair (NaN: none), and how many such frames
    # passed the checks (0: the host sent none)
    measurements: np.ndarray = field(default_factory=lambda: np.zeros((0, len(CHANNEL_NAMES))))
    measurement_frames: int = 0
    xcp_downloads: int = 0        # XCP DOWNLOAD commands in the log: calibrations the twin replays
    sent_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    temps: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    replied_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    owner: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # segment of the final reply
    contested: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # rows whose replies disagree
    replayed: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))   # a rejected reply disagrees
    timing: dict[str, np.ndarray] = field(default_factory=dict)   # row, measured_us, overruns, cycles, ...
    # per model step of an observer (Uncertainty1/2, Innovations): row_u1, winding_sigma, ..., sensor_flagged, ...,
    # row_inn, sensor_used, ..., sensor_rejected (DBC 1.8.0)
    observer: dict[str, np.ndarray] = field(default_factory=dict)
    status_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    final_state: str | None = None
    faults_seen: int = 0
    model_id: int | None = None
    target_dbc: tuple[int, int] | None = None   # (major, minor) of the DBC the target was built against (Status)
    rx_errors: dict[str, int] = field(default_factory=dict)
    target_info: dict[str, object] = field(default_factory=dict)
    frame_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frame_dlc: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.uint8))
    frame_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.uint32))
    frame_data: np.ndarray = field(default_factory=lambda: np.zeros((0, 8), dtype=np.uint8))
    sessions: int = 0
    stopped: bool = False         # the host's Control STOP came after the last START
    unclosed: bool = False        # a .blf whose writer never finalized its header (the process was killed)
    segments: list[Segment] = field(default_factory=list)
    marks: list[Mark] = field(default_factory=list)

    @property
    def rows(self) -> int:
        return len(self.drive)

    @property
    def answered(self) -> np.ndarray:
        return np.isfinite(self.temps).all(axis=1)

    @property
    def complete(self) -> bool:
        """The log holds a whole run: its host sent STOP, and its writer closed the file."""
        return self.stopped and not self.unclosed

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


class _Grow:
    """A numpy array that grows along its first axis by doubling; new entries hold `fill`."""

    def __init__(self, shape: tuple[int, ...] = (), dtype=np.float64, fill=np.nan, capacity: int = 1024):
        self.fill = fill
        self.data = np.full((capacity, *shape), fill, dtype=dtype)

    def ensure(self, index: int) -> np.ndarray:
        """The array, long enough to hold `index`."""
        if index >= len(self.data):
            grown = np.full((max(2 * len(self.data), index + 1), *self.data.shape[1:]), self.fill,
                            dtype=self.data.dtype)
            grown[: len(self.data)] = self.data
            self.data = grown
        return self.data


class _SegmentBuilder:
    """One segment's replies, by row - start_row, in columns."""

    def __init__(self, start_row: int, initial, recovery: bool, state=None, observer_checkpoint=None,
                 checkpoint: str | None = None):
        self.start_row = start_row
        self.initial = initial
        self.state = state
        self.observer_checkpoint = observer_checkpoint
        self.checkpoint = checkpoint
        self.recovery = recovery
        self.host_row = start_row - 1          # the last row sent in this segment
        self.temps = _Grow((STATE_SIZE,))
        self.got = _Grow((), np.uint8, 0)
        self.t = _Grow()
        self.pair_s = _Grow()                  # send time of the pair that was answered (else the last one sent)
        self.contested = _Grow((), bool, False)
        self.size = 0                          # entries in use

    @property
    def reference_row(self) -> int:
        """The row a Step of this segment is read near: the last row sent (or its first row)."""
        return max(self.host_row, self.start_row)

    def index(self, row: int) -> int:
        i = row - self.start_row
        for column in (self.temps, self.got, self.t, self.pair_s, self.contested):
            column.ensure(i)
        self.size = max(self.size, i + 1)
        return i

    def build(self) -> Segment:
        n = self.size
        got, contested = self.got.data[:n], self.contested.data[:n]
        complete = np.flatnonzero((got == REPLY_COMPLETE) & ~contested)
        return Segment(self.start_row, self.initial, self.recovery, self.state, self.observer_checkpoint,
                       checkpoint=self.checkpoint, reply_rows=(complete + self.start_row).astype(np.int64),
                       reply_temps=self.temps.data[complete].astype(float),
                       reply_s=self.t.data[complete].copy(),
                       contested_rows=(np.flatnonzero(contested) + self.start_row).astype(np.int64))


_TIMING_SIGNALS = {"Timing1": ("row_t1", (("measured_us", "StepTimeMeasured"), ("overruns", "Overruns"))),
                   "Timing2": ("row_t2", (("cycles", "EstCycles"), ("exec_us", "EstExecTime"))),
                   "Timing3": ("row_t3", (("cpu_load", "CpuLoad"),)),
                   # the firmware engine's measured Cortex-M4F cycles (absent with the Python engine)
                   FIRMWARE_TIMING_MESSAGE: ("row_t4", (("m4_cycles", "M4Cycles"), ("m4_exec_us", "M4ExecTime"))),
                   # the firmware's response time and its interrupt's load (only with the motor-control interrupt)
                   RESPONSE_TIMING_MESSAGE: ("row_t5", (("response_us", "ResponseTime"), ("isr_load", "IsrLoad")))}
# the observer's frames per model step (a target whose model has an observer), collected like the timing frames
_OBSERVER_SIGNALS = {"Uncertainty1": ("row_u1", (("winding_sigma", "WindingSigma"), ("magnet_sigma", "MagnetSigma"))),
                     "Uncertainty2": ("row_u2", (("yoke_sigma", "YokeSigma"), ("tooth_sigma", "ToothSigma"))),
                     INNOVATION_MESSAGE: ("row_inn", (("sensor_innovation", "SensorInnovation"),
                                                      ("sensor_used", "SensorUsed"),
                                                      ("flux_innovation", "FluxMagnetInnovation"),
                                                      ("flux_used", "FluxMagnetUsed")))}
# DBC 1.8.0: each slot's innovation gate, `<slot>_rejected` per step (Innovations) and `<slot>_flagged` (latched)
for _message, _gate in ((INNOVATION_MESSAGE, {f"{slot}_rejected": s for slot, s in REJECTED_SIGNALS.items()}),
                        (FLAG_MESSAGE, {f"{slot}_flagged": s for slot, s in FLAGGED_SIGNALS.items()})):
    _OBSERVER_SIGNALS[_message] = (_OBSERVER_SIGNALS[_message][0], (*_OBSERVER_SIGNALS[_message][1], *_gate.items()))
_STEP_SERIES = {**_TIMING_SIGNALS, **_OBSERVER_SIGNALS}
# BLF file header (python-can's FILE_HEADER_STRUCT): "LOGG", then at byte 16 the file size its writer records
# when it closes the file (until then: the header's own size, 144)
_BLF_SIZE_OFFSET = 16


class _LogDecoder:
    """Reads a log frame by frame; one handler per message of the contract (see the module docstring)."""

    def __init__(self, path: Path) -> None:
        self.record = BusRecord(path)
        self.invalid: dict[str, int] = {}
        self.rejected: dict[str, int] = {}
        self.foreign: dict[str, int] = {}
        self.xcp_ids, self.xcp_cmd_id = xcp_ids(), cmd_id()
        self.validator = FrameValidator("HOST")      # the host's checks of what the target sends
        self.target_checks = FrameValidator("TARGET")   # the target's checks of the host's measurement frames
        self.measurement_ids = {frame_id(name) for name in MEASUREMENT_MESSAGES}
        self.rejected_host: dict[str, int] = {}
        # the target's checkpoint frames as accepted: (message, target run, Step) -> {index: float32 bits}; contested
        # ones; the (message, key) of the last accepted frame per id
        self.checkpoints: dict[tuple[str, int, int], dict[int, int]] = {}
        self.contested_checkpoints: set[tuple[str, int, int]] = set()
        self.last_checkpoint_key: dict[int, tuple[str, int, int]] = {}
        self.last_checkpoint_data: dict[int, bytes] = {}
        self.pending_checkpoint: str | None = None
        self.last_state_checkpoint: int | None = None   # the row of the last StateCheckpoint frame accepted
        self.last_reply_row: dict[int, int] = {}    # per reply id, the row of the last reply frame used
        # reply frames the counter check rejected: (segment index, row, message, signals), judged at the end
        self.out_of_sequence: list[tuple[int, int, str, dict]] = []
        self.reply_ids = {name: frame_id(name) for name in REPLY_SIGNALS}
        self.target_ids = target_frame_ids()
        self.by_id = contract().by_id
        self.segments: list[_SegmentBuilder] = []
        self.marks: list[Mark] = []
        self.base_step = 0                 # Step of the fresh session's START: row 0
        self.pending_inputs: tuple[dict, float] | None = None   # a DriveInputs waiting for its DriveTemps
        self.pending_pair: tuple[int, int, dict] | None = None   # (Step, row, DriveTemps) of the last pair: its
        # DriveCurrents comes next
        # the last frame of each measurement message: message -> (Step, {channel: value})
        self.pending_measurement: dict[str, tuple[int, dict[str, float]]] = {}
        self.measurement_frames = 0
        self._new_rows()
        self.reset_frames: dict[str, dict] = {}
        self.restore_frames: dict[int, dict] = {}
        self.restore_observer_frames: dict[int, dict] = {}
        self.pending_observer: dict[int, float] | None = None
        self.pending_initial: np.ndarray | None = None
        self.pending_state: np.ndarray | None = None
        self.reinit_announced = False
        self.transitions = 0               # the target's transitions into RUNNING
        self.epoch_base = 0                # transitions before the fresh session
        self.last_state: int | None = None
        self.timing: dict[str, array] = self._empty_timing()
        self.status_s = array("d")
        self.frame_s = array("d")
        self.frame_dlc = array("B")
        self.frame_ids = array("I")
        self.frame_bytes = bytearray()
        self.handlers = {"DriveInputs": self.drive_inputs, "DriveTemps": self.drive_temps,
                         CURRENT_MESSAGE: self.drive_currents,
                         **dict.fromkeys(MEASUREMENT_MESSAGES, self.measurement),
                         RESTORE_OBSERVER_MESSAGE: self.restore_observer,
                         **dict.fromkeys(REPLY_SIGNALS, self.temperatures),
                         **dict.fromkeys(_STEP_SERIES, self.timing_frame),
                         **dict.fromkeys(RESET_SIGNALS, self.reset_temps),
                         "RestoreState": self.restore_state, "Control": self.control,
                         **dict.fromkeys(CHECKPOINT_MESSAGES, self.checkpoint),
                         "BenchEvent": self.bench_event, "Status": self.status, "RxErrors": self.rx_errors,
                         "TargetInfo": self.target_info}

    def _new_rows(self) -> None:
        """Forget the rows sent so far (a fresh session)."""
        self.drive = _Grow((len(DRIVE_SIGNALS),))
        self.currents = _Grow((len(CURRENT_SIGNALS),))      # row -> [i_d, i_q] of its DriveCurrents
        self.measured = _Grow((len(CHANNEL_NAMES),))    # row -> its measurement frames' VALID values
        self.rows = 0                                        # 1 + the last row with a pair

    @staticmethod
    def _empty_timing() -> dict[str, array]:
        return {key: array("d") for row_key, signals in _STEP_SERIES.values()
                for key in (row_key, *(k for k, _ in signals))}

    def _row(self, segment: _SegmentBuilder, step) -> int:
        return nearest_row(int(step) - self.base_step, segment.reference_row)

    def target_segment(self) -> _SegmentBuilder | None:
        """The segment the target was running when it sent a frame (its k-th transition into RUNNING)."""
        index = self.transitions - self.epoch_base - 1
        return self.segments[index] if 0 <= index < len(self.segments) else None

    def _count(self, counts: dict[str, int], key: str) -> None:
        counts[key] = counts.get(key, 0) + 1

    # ------------------------------------------------------------------ frames
    def feed(self, msg) -> None:
        self.record.frames += 1
        fid = msg.arbitration_id
        self.frame_s.append(msg.timestamp)
        self.frame_dlc.append(min(msg.dlc, 255))
        self.frame_ids.append(fid)
        self.frame_bytes += bytes(msg.data[:8]).ljust(8, b"\0")
        if fid in self.xcp_ids and not msg.is_extended_id:
            # a calibration master's XCP traffic (dbc/xcp.toml): bus load, not a frame of the contract; a DOWNLOAD
            # may calibrate the target, so the run is judged against its twin, which replays it
            if fid == self.xcp_cmd_id and msg.data[:1] == bytes((Cmd.DOWNLOAD,)):
                self.record.xcp_downloads += 1
            return
        from_target = fid in self.target_ids and not msg.is_extended_id
        previous = self.validator.last_counter(fid) if from_target else None
        measured = fid in self.measurement_ids and not msg.is_extended_id
        try:
            if from_target:
                frame = self.validator.validate(msg)     # what the host accepted of the target's frames
            elif measured:
                frame = self.target_checks.validate(msg)   # a measurement frame, as the target accepted it
            else:
                frame = decode_any(msg)                  # the host's own frames (and unknown ids)
        except FrameError as exc:
            self._count(self.invalid, exc.kind)
            if measured and exc.kind != "unknown_id":
                self._count(self.rejected_host, self.by_id[fid].name)
            if from_target:
                name = self.by_id[fid].name
                self._count(self.rejected, name)
                # id, length, CRC and ranges passed, and the frame repeats the counter of the one before it
                if exc.kind == "counter" and name in REPLY_SIGNALS:
                    signals = decode_any(msg).signals
                    if msg.data[1] & 0x0F == previous:
                        self._contest(name, signals, self.last_reply_row.get(fid))
                    self._keep_out_of_sequence(name, signals)
                elif exc.kind == "counter" and name in CHECKPOINT_MESSAGES and msg.data[1] & 0x0F == previous \
                        and bytes(msg.data) != self.last_checkpoint_data.get(fid):   # a copy of it is harmless
                    self._contest_checkpoint(fid, name, decode_any(msg).signals)
            return
        if frame.name in CHECKPOINT_MESSAGES:
            self.last_checkpoint_data[fid] = bytes(msg.data)
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
        drive = self.drive.ensure(row)
        drive[row] = (inputs["MotorTorque"], inputs["MotorSpeed"], s["CoolantTemp"], s["AmbientTemp"])
        self.currents.ensure(row)[row] = np.nan     # a row sent again: its currents come again after this pair
        # the Measurements of this Step sent before the pair, as the target pairs them (none: NaN, predict only)
        measured, self.pending_measurement = self.pending_measurement, {}
        values = self.measured.ensure(row)[row]
        values[:] = np.nan
        for at, channels in measured.values():
            if at == int(s["Step"]):
                for channel, value in channels.items():
                    values[CHANNEL_NAMES.index(channel)] = value
        self.rows = max(self.rows, row + 1)
        self.pending_pair = (int(s["Step"]), row, s)
        segment.host_row = row
        if row >= segment.start_row:
            i = segment.index(row)
            if segment.got.data[i] != REPLY_COMPLETE:
                segment.pair_s.data[i] = inputs_t

    def drive_currents(self, name: str, s: dict, t: float) -> None:
        """The d/q currents of the pair right before them (same Step): the row's last two values, as the target
        completes a row. A DriveCurrents of another Step ends the pair without currents (the target drops the row);
        copies of a frame (the target refuses them for their alive counter, which the decoder does not judge)
        carry the same values and change nothing."""
        pair = self.pending_pair
        if pair is not None and pair[0] == int(s["Step"]):
            self.currents.ensure(pair[1])[pair[1]] = (s["CurrentD"], s["CurrentQ"])
        else:
            self.pending_pair = None

    def measurement(self, name: str, s: dict, t: float) -> None:
        """A row's measurements, kept until the pair of their Step (the row they go with) comes."""
        self.measurement_frames += 1
        self.pending_measurement[name] = (int(s["Step"]), channel_values(name, s))

    def _reply_row(self, name: str, s: dict) -> tuple[_SegmentBuilder, int] | None:
        """The target's segment and the row a reply or timing frame names; None (counted foreign) when the host had
        not sent that row in the segment."""
        segment = self.target_segment()
        if segment is None:
            return None
        row = self._row(segment, s["Step"])
        if not segment.start_row <= row <= segment.host_row:
            self._count(self.foreign, FOREIGN_ROW)
            return None
        return segment, row

    def _contest(self, name: str, s: dict, only_row: int | None = None) -> bool:
        """Whether this reply frame carries other temperatures than the segment already has for its row (then the
        row is contested and the frame counted foreign); with `only_row`, only for that row."""
        segment = self.target_segment()
        if segment is None:
            return False
        row = self._row(segment, s["Step"])
        if only_row is not None and row != only_row:
            return False
        i = row - segment.start_row
        if not 0 <= i < segment.size or not segment.got.data[i] & REPLY_BIT[name]:
            return False
        temps = segment.temps.data[i]
        if all(temps[index] == s[signal] for signal, index in REPLY_SIGNALS[name]):
            return False
        segment.contested.data[i] = True
        self._count(self.foreign, FOREIGN_CONTESTED)
        return True

    def _keep_out_of_sequence(self, name: str, s: dict) -> None:
        """Remember a reply frame the counter check rejected, with the segment and row it names (a row its segment
        had sent), to compare with that row's answer once the log is read."""
        segment = self.target_segment()
        if segment is None:
            return
        row = self._row(segment, s["Step"])
        if segment.start_row <= row <= segment.host_row:
            self.out_of_sequence.append((self.segments.index(segment), row, name, s))

    def temperatures(self, name: str, s: dict, t: float) -> None:
        found = self._reply_row(name, s)
        if found is None or self._contest(name, s):
            return
        segment, row = found
        self.last_reply_row[self.reply_ids[name]] = row
        i = segment.index(row)
        temps = segment.temps.data[i]
        for signal, index in REPLY_SIGNALS[name]:
            temps[index] = s[signal]
        segment.got.data[i] |= REPLY_BIT[name]
        previous = segment.t.data[i]
        segment.t.data[i] = t if math.isnan(previous) else max(previous, t)

    def timing_frame(self, name: str, s: dict, t: float) -> None:
        found = self._reply_row(name, s)
        if found is None:
            return
        row_key, signals = _STEP_SERIES[name]
        self.timing[row_key].append(found[1])
        for key, signal in signals:
            self.timing[key].append(s[signal])

    def _checkpoint_row(self, step: int) -> int:
        """The row a checkpoint's Step names, read as a reply's (nearest the last row the host sent): the Step
        repeats every 65536 rows, the row does not."""
        segment = self.target_segment() or (self.segments[-1] if self.segments else None)
        return self._row(segment, step) if segment is not None else step - self.base_step

    def _checkpoint_element(self, name: str, s: dict) -> tuple[tuple[str, int, int], int, int]:
        """(its checkpoint's key, the element's index, its value's float32 bits) of a checkpoint frame: the
        target's run that sent it (its transitions into RUNNING: a restored target checkpoints the same rows again,
        from another state) and the row its Step names; an ObserverCheckpoint's StepLow names the StateCheckpoint
        sent right before it (another StepLow: a key no restore matches)."""
        if name == OBSERVER_CHECKPOINT_MESSAGE:
            low, index, value = int(s["StepLow"]), int(s["Index"]), s["Value"]
            last = self.last_state_checkpoint
            named = last is not None and step_of(last + self.base_step) % CHECKPOINT_STEP_LOW_MODULO == low
            key = last if named else -1 - low
        else:
            key, index, value = self._checkpoint_row(int(s["Step"])), int(s["StateIndex"]), s["StateValue"]
        return (name, self.transitions, key), index, int(np.float32(value).view(np.uint32))

    def checkpoint(self, name: str, s: dict, t: float) -> None:
        """A checkpoint element the host's checks accepted; a second one of the element with another value
        contests its checkpoint."""
        key, index, bits = self._checkpoint_element(name, s)
        elements = self.checkpoints.setdefault(key, {})
        if elements.get(index, bits) != bits:
            self.contested_checkpoints.add(key)
            self._count(self.foreign, FOREIGN_CHECKPOINT)
        elements[index] = bits
        self.last_checkpoint_key[frame_id(name)] = key
        if name != OBSERVER_CHECKPOINT_MESSAGE:
            self.last_state_checkpoint = key[2]

    def _contest_checkpoint(self, fid: int, name: str, s: dict) -> None:
        """A checkpoint frame that repeats the alive counter of the one before it: one of the two is not the
        target's, so neither checkpoint is believed."""
        key, _, _ = self._checkpoint_element(name, s)
        self.contested_checkpoints.add(key)
        if fid in self.last_checkpoint_key:
            self.contested_checkpoints.add(self.last_checkpoint_key[fid])
        self._count(self.foreign, FOREIGN_CHECKPOINT)

    def _restore_judged(self, state: np.ndarray, observer: dict[int, float]) -> str | None:
        """Why a RESTORE of `state` (float32) with the filter's `observer` elements is not the target's own
        checkpoint (RESTORE_FORGED, RESTORE_CONTESTED), None when it is."""
        bits = [int(v) for v in np.asarray(state, dtype=np.float32).view(np.uint32)]
        found = None
        for key, elements in self.checkpoints.items():
            if key[0] != "StateCheckpoint" or [elements.get(i) for i in range(STATE_SIZE)] != bits:
                continue
            filter_key = (OBSERVER_CHECKPOINT_MESSAGE, *key[1:])
            sent = self.checkpoints.get(filter_key, {})
            if any(sent.get(i) != int(np.float32(v).view(np.uint32)) for i, v in observer.items()):
                continue
            contested = {key, filter_key} & self.contested_checkpoints if observer else \
                {key} & self.contested_checkpoints
            if not contested:
                return None
            found = RESTORE_CONTESTED
        return found or RESTORE_FORGED

    def reset_temps(self, name: str, s: dict, t: float) -> None:
        self.reset_frames[name] = s

    def restore_state(self, name: str, s: dict, t: float) -> None:
        self.restore_frames[int(s["StateIndex"])] = s

    def restore_observer(self, name: str, s: dict, t: float) -> None:
        self.restore_observer_frames[int(s["Index"])] = s

    def control(self, name: str, s: dict, t: float) -> None:
        command = int(s["Command"])
        if command == Command.RESET:
            frames = self.reset_frames
            if len(frames) == len(RESET_SIGNALS) and all(f["Step"] == s["Step"] for f in frames.values()):
                self.pending_initial = np.array(join_temperatures(frames, RESET_SIGNALS), dtype=float)
                self.pending_state = self.pending_observer = None
        elif command == Command.RESTORE:
            elements = [self.restore_frames[i]["StateValue"] for i in range(STATE_SIZE)
                        if i in self.restore_frames and self.restore_frames[i]["Step"] == s["Step"]]
            if len(elements) == STATE_SIZE:
                self.pending_state, self.pending_initial = np.array(elements, dtype=np.float32), None
                low = int(s["Step"]) % CHECKPOINT_STEP_LOW_MODULO
                self.pending_observer = {i: f["Value"] for i, f in self.restore_observer_frames.items()
                                         if f["StepLow"] == low}
                self.pending_checkpoint = self._restore_judged(self.pending_state, self.pending_observer)
            self.restore_frames = {}
            self.restore_observer_frames = {}
        elif command == Command.START:
            self.start(int(s["Step"]))
        elif command == Command.STOP:
            self.record.stopped = True
            self.target_checks.reset_counters()   # the target forgets the counters it expects at STOP

    def start(self, step: int) -> None:
        """A START: a new segment after a REINIT mark, else a fresh session (the last session of a log wins)."""
        self.record.sessions += 1
        self.record.stopped = False
        if self.reinit_announced and self.segments:
            start = self._row(self.segments[-1], step)
            self.segments.append(_SegmentBuilder(start, self.pending_initial, True, self.pending_state,
                                                 self.pending_observer,
                                                 self.pending_checkpoint if self.pending_state is not None else None))
        else:
            self.base_step = step
            self.record.initial = self.pending_initial
            self.segments = [_SegmentBuilder(0, self.pending_initial, False)]
            self._new_rows()
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
        elif event == BenchEvent.TARGET_LOST:
            self.validator.reset_counters()      # so does the host: a restarted target starts its counters at 0
            self.target_checks.reset_counters()  # and a restarted target knows none of the host's

    def status(self, name: str, s: dict, t: float) -> None:
        model_id = int(s["ModelId"])
        if self.record.model_id is None:
            self.record.model_id = model_id      # the host checked the first heartbeat's model id
        elif model_id != self.record.model_id:
            self._count(self.foreign, FOREIGN_MODEL)
            return
        self.status_s.append(t)
        state = int(s["State"])
        if state == TargetState.RUNNING and self.last_state != TargetState.RUNNING:
            self.transitions += 1
        self.last_state = state
        self.record.final_state = TargetState(state).name
        self.record.faults_seen |= int(s["FaultBits"])
        self.record.target_dbc = (int(s["DbcVersionMajor"]), int(s["DbcVersionMinor"]))

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
        rows = self.rows
        record.invalid, record.rejected, record.foreign = self.invalid, self.rejected, self.foreign
        record.rejected_host = self.rejected_host
        drive = self.drive.ensure(rows)[:rows]
        currents = self.currents.ensure(rows)[:rows]
        with_currents = bool(np.isfinite(currents).any())
        record.drive = np.concatenate([drive, currents], axis=1) if with_currents else drive.copy()
        record.measurements = self.measured.ensure(rows)[:rows].copy()
        record.measurement_frames = self.measurement_frames
        self.drive = self.currents = self.measured = None
        record.segments = [segment.build() for segment in self.segments]
        self._final_replies(rows)
        # the columns become arrays over the same memory (no copy: the decoder is done with them)
        series = {k: np.frombuffer(v, dtype=np.float64) for k, v in self.timing.items()}
        observer_keys = {key for row_key, signals in _OBSERVER_SIGNALS.values()
                         for key in (row_key, *(k for k, _ in signals))}
        record.timing = {k: v for k, v in series.items() if k not in observer_keys}
        record.observer = {k: v for k, v in series.items() if k in observer_keys}
        record.status_s = np.frombuffer(self.status_s, dtype=np.float64)
        record.frame_s = np.frombuffer(self.frame_s, dtype=np.float64)
        record.frame_dlc = np.frombuffer(self.frame_dlc, dtype=np.uint8)
        record.frame_ids = np.frombuffer(self.frame_ids, dtype=np.uint32)
        record.frame_data = np.frombuffer(self.frame_bytes, dtype=np.uint8).reshape(-1, 8)
        record.marks = self.marks
        record.unclosed = _blf_unclosed(path)
        # the builders' columns go now (the handlers hold the decoder)
        self.segments, self.handlers, self.out_of_sequence = [], {}, []
        return record

    def _final_replies(self, rows: int) -> None:
        """Each row's final reply: that of the last segment that answered it, and when its pair was sent."""
        record = self.record
        record.temps = np.full((rows, STATE_SIZE), np.nan)
        record.replied_s = np.full(rows, np.nan)
        record.sent_s = np.full(rows, np.nan)
        record.owner = np.full(rows, -1, dtype=np.int64)
        record.contested = np.zeros(rows, dtype=bool)
        for index, (builder, segment) in enumerate(zip(self.segments, record.segments, strict=True)):
            keep = segment.reply_rows < rows
            replied = segment.reply_rows[keep]
            record.temps[replied] = segment.reply_temps[keep]
            record.replied_s[replied] = segment.reply_s[keep]
            record.owner[replied] = index
            record.sent_s[replied] = builder.pair_s.data[replied - builder.start_row]
            contested = segment.contested_rows[segment.contested_rows < rows]
            record.contested[contested] = True
        record.replayed = self._replayed_rows(rows)
        unanswered = np.isnan(record.sent_s)
        if unanswered.any():  # rows never answered: when they were (last) sent
            for builder in self.segments:
                n = min(builder.size, max(rows - builder.start_row, 0))
                at = np.arange(builder.start_row, builder.start_row + n)
                sent = builder.pair_s.data[:n]
                use = unanswered[at] & np.isfinite(sent)
                record.sent_s[at[use]] = sent[use]


    def _replayed_rows(self, rows: int) -> np.ndarray:
        """Rows whose final answer came from a segment that also saw, in a frame its counter check rejected, other
        temperatures for the row: two answers, one of them not the target's (a copy of the same frame, a dropped
        frame's successor or a retransmission carry the same values and flag nothing)."""
        replayed = np.zeros(rows, dtype=bool)
        owner = self.record.owner
        for index, row, name, s in self.out_of_sequence:
            if row >= rows or owner[row] != index:
                continue
            answer = self.record.temps[row]
            if any(answer[i] != s[signal] for signal, i in REPLY_SIGNALS[name]):
                replayed[row] = True
        return replayed


def _blf_unclosed(path: Path) -> bool:
    """A .blf whose header does not record the file's size: its writer never closed it (a killed process)."""
    if path.suffix.lower() != ".blf":
        return False
    try:
        with open(path, "rb") as fh:
            head = fh.read(_BLF_SIZE_OFFSET + 8)
        size = path.stat().st_size
    except OSError:
        return False
    if head[:4] != b"LOGG" or len(head) < _BLF_SIZE_OFFSET + 8:
        return False
    return int.from_bytes(head[_BLF_SIZE_OFFSET:], "little") < size


def decode_log(path: str | Path) -> BusRecord:
    """Read and decode a log; LogError for a file that cannot be read or holds no session."""
    decoder = _LogDecoder(Path(path))
    for msg in read_log(path):
        decoder.feed(msg)
    return decoder.finish()
