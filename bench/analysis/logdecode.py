"""Decode a bus log (any format the host writes) into arrays: what was sent, what came back, and when.

Rows: after the last Control START of the log, the n-th DriveInputs is data row n (its DriveTemps carries the
same Step); a Temperatures/Timing frame belongs to the most recent row with its Step (mod 65536), as the host
matches them live. The initial temperatures are those of the ResetTemps frames the last RESET used. Frames that
fail the DBC checks (unknown id, length, CRC, range) are counted and skipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dbc import Command, FrameError, ModelKind, Realization, TargetState
from host.canlog import LogError, read_log
from target_sim.fastframes import fast_decode_any

STEP_MODULO = 1 << 16
RX_ERROR_NAMES = {"UnknownId": "unknown_id", "WrongLength": "wrong_length", "CrcError": "crc",
                  "CounterError": "counter", "OutOfRange": "out_of_range", "SequenceError": "sequence"}


@dataclass
class BusRecord:
    path: Path
    frames: int = 0
    invalid: dict[str, int] = field(default_factory=dict)
    initial: np.ndarray | None = None            # [yoke, winding, tooth, magnet]
    drive: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    sent_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    temps: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    replied_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
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

    @property
    def rows(self) -> int:
        return len(self.drive)

    @property
    def answered(self) -> np.ndarray:
        return np.isfinite(self.temps).all(axis=1)


def decode_log(path: str | Path) -> BusRecord:
    """Read and decode a log; LogError for a file that cannot be read or holds no session."""
    record = BusRecord(Path(path))
    invalid: dict[str, int] = {}
    drive: list[list[float]] = []
    sent: list[float] = []
    temps: list[list[float]] = []
    replied: list[float] = []
    step_row: dict[int, int] = {}
    pending_inputs: dict | None = None
    reset_frames: dict[str, dict] = {}
    pending_initial = None
    timing: dict[str, list] = {k: [] for k in ("row_t1", "measured_us", "overruns", "row_t2", "cycles", "exec_us",
                                               "row_t3", "cpu_load")}
    status_s: list[float] = []
    frame_s: list[float] = []
    frame_dlc: list[int] = []
    frame_ids: list[int] = []
    frame_bytes = bytearray()
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
            if pending_inputs is None or pending_inputs["Step"] != s["Step"]:
                pending_inputs = None
                continue
            step_row[int(s["Step"])] = len(drive)
            drive.append([pending_inputs["MotorTorque"], pending_inputs["MotorSpeed"], s["CoolantTemp"],
                          s["AmbientTemp"]])
            sent.append(pending_inputs_time)
            temps.append([math.nan] * 4)
            replied.append(math.nan)
            pending_inputs = None
        elif name in ("Temperatures1", "Temperatures2"):
            row = step_row.get(int(s["Step"]))
            if row is None:
                continue
            if name == "Temperatures1":
                temps[row][1], temps[row][3] = s["WindingTemp"], s["MagnetTemp"]
            else:
                temps[row][0], temps[row][2] = s["YokeTemp"], s["ToothTemp"]
            replied[row] = msg.timestamp if math.isnan(replied[row]) else max(replied[row], msg.timestamp)
        elif name in ("Timing1", "Timing2", "Timing3"):
            row = step_row.get(int(s["Step"]))
            if row is None:
                continue
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
        elif name == "Control":
            command = int(s["Command"])
            if command == Command.RESET:
                r1, r2 = reset_frames.get("ResetTemps1"), reset_frames.get("ResetTemps2")
                if r1 is not None and r2 is not None and r1["Step"] == r2["Step"] == s["Step"]:
                    pending_initial = np.array([r2["YokeTempInit"], r1["WindingTempInit"], r2["ToothTempInit"],
                                                r1["MagnetTempInit"]], dtype=float)
            elif command == Command.START:
                record.sessions += 1
                record.initial = pending_initial
                drive, sent, temps, replied, step_row = [], [], [], [], {}
                timing = {k: [] for k in timing}
        elif name == "Status":
            status_s.append(msg.timestamp)
            record.states.append(TargetState(int(s["State"])).name)
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
    record.invalid = invalid
    record.drive = np.array(drive, dtype=float).reshape(-1, 4)
    record.sent_s = np.array(sent, dtype=float)
    record.temps = np.array(temps, dtype=float).reshape(-1, 4)
    record.replied_s = np.array(replied, dtype=float)
    record.timing = {k: np.array(v, dtype=float) for k, v in timing.items()}
    record.status_s = np.array(status_s, dtype=float)
    record.frame_s = np.array(frame_s, dtype=float)
    record.frame_dlc = np.array(frame_dlc, dtype=np.int64)
    record.frame_ids = np.array(frame_ids, dtype=np.int64)
    record.frame_data = np.frombuffer(bytes(frame_bytes), dtype=np.uint8).reshape(-1, 8)
    return record
