"""The target's twin: its own node code, offline, fed the frames the host put on the bus, in the logged order.

In a real-time run with faults the target leaves out the rows it never got or refused, forms its interval means
from the rest, and so departs from the clean run; which rows it used depends on its validator (alive counters,
CRC, sequence). The twin (`target_sim.node.TargetNode`, no bus, a fixed clock) receives exactly what the target
received — every logged frame but the target's own (and the target's reply faults on foreign ids, which its fault
layer filters) — and answers as the target must have, so "CAN = twin within the 0.01 °C quantization" checks the
target's arithmetic and its handling of every faulty frame at once. The logged XCP commands of a calibration master
reach it too, in their place, so a run calibrated over XCP is checked against the twin calibrated the same way.
A DOWNLOAD names its cell by address, so the twin's cells must sit where the target's did: at the firmware ELF's
addresses for a firmware target (its C slave serves its own RAM variables) or a Python target started with
`--xcp-elf`, else in the Python slave's pages; the one mapping from addresses to cells is `target_sim.xcp.layout`'s.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import can
import numpy as np

from bench.analysis.logdecode import BusRecord
from dbc.codec import decode_any
from dbc.contract import REPLY_SIGNALS, STATE_SIZE, nearest_row, place_temperatures
from dbc.database import target_frame_ids
from dbc.mutations import foreign_ids, reply_ids
from dbc.xcp import cmd_id, res_id
from target_sim.artifact import ModelArtifact
from target_sim.node import TargetNode
from target_sim.xcp.codes import PID_ERR, PID_RES, Cmd


@dataclass
class TwinRun:
    """What the twin answered: its temperatures per row, and how many of the log's XCP DOWNLOADs it answered
    otherwise than the target did (accepted a calibration the target refused, or refused one it accepted: its
    cells are not where the target's were, or the target's slave is not its reference's)."""

    estimates: np.ndarray
    downloads_unlike_target: int


def run_twin(artifact: ModelArtifact, record: BusRecord, xcp_elf: str | os.PathLike | None = None) -> TwinRun:
    """The twin fed the logged frames, its XCP cells at the addresses of the firmware ELF `xcp_elf`, the target's
    layout (None: the Python slave's pages)."""
    node = TargetNode(artifact, clock_ns=lambda: 0, xcp_elf=xcp_elf)
    out = np.full((record.rows, STATE_SIZE), np.nan)
    # its own frames (and its XCP replies), its reply faults' foreign ids; a master's XCP commands it replays
    not_received = target_frame_ids() | {res_id()} | foreign_ids(REPLY_SIGNALS)
    replies = reply_ids()
    command, response = cmd_id(), res_id()
    pending: int | None = None    # the twin's answer (PID) to the last DOWNLOAD until the target's answer is logged
    unlike = latest = 0
    for fid, dlc, data in zip(record.frame_ids.tolist(), record.frame_dlc.tolist(), record.frame_data, strict=True):
        if fid == response and pending is not None and dlc and data[0] in (PID_RES, PID_ERR):   # not a DAQ packet
            unlike += int(data[0]) != pending
            pending = None
        if fid in not_received:
            continue
        msg = can.Message(arbitration_id=fid, is_extended_id=False, dlc=dlc, data=bytes(data[:dlc]), check=False)
        answers = node.handle(msg)
        if fid == command:     # XCP has one command outstanding: a new one ends the wait for the last one's answer
            pending = None
            if dlc and data[0] == Cmd.DOWNLOAD:
                pending = next((r.data[0] for r in answers if r.arbitration_id == response and r.data[0] >= PID_ERR),
                               None)
        for reply in answers:
            if reply.arbitration_id not in replies:
                continue
            frame = decode_any(reply)
            row = nearest_row(int(frame.signals["Step"]), latest)
            latest = max(latest, row)
            if 0 <= row < record.rows:
                place_temperatures(frame.name, frame.signals, out[row])
    return TwinRun(out, unlike)


def twin_estimates(artifact: ModelArtifact, record: BusRecord, xcp_elf: str | os.PathLike | None = None
                   ) -> np.ndarray:
    """(rows, 4) yoke, winding, tooth, magnet the twin answered after each row (its last answer; NaN: none); its XCP
    cells laid out by `xcp_elf` (`run_twin`)."""
    return run_twin(artifact, record, xcp_elf).estimates
