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

import can
import numpy as np

from bench.analysis.logdecode import BusRecord
from dbc.codec import decode_any
from dbc.contract import REPLY_SIGNALS, STATE_SIZE, nearest_row, place_temperatures
from dbc.database import target_frame_ids
from dbc.mutations import foreign_ids, reply_ids
from dbc.xcp import res_id
from target_sim.artifact import ModelArtifact
from target_sim.node import TargetNode


def twin_estimates(artifact: ModelArtifact, record: BusRecord, xcp_elf: str | os.PathLike | None = None
                   ) -> np.ndarray:
    """(rows, 4) yoke, winding, tooth, magnet the twin answered after each row (its last answer; NaN: none); its XCP
    cells at the addresses of the firmware ELF `xcp_elf`, the target's layout (None: the Python slave's pages)."""
    node = TargetNode(artifact, clock_ns=lambda: 0, xcp_elf=xcp_elf)
    out = np.full((record.rows, STATE_SIZE), np.nan)
    # its own frames (and its XCP replies), its reply faults' foreign ids; a master's XCP commands it replays
    not_received = target_frame_ids() | {res_id()} | foreign_ids(REPLY_SIGNALS)
    replies = reply_ids()
    latest = 0
    for fid, dlc, data in zip(record.frame_ids.tolist(), record.frame_dlc.tolist(), record.frame_data, strict=True):
        if fid in not_received:
            continue
        msg = can.Message(arbitration_id=fid, is_extended_id=False, dlc=dlc, data=bytes(data[:dlc]), check=False)
        for reply in node.handle(msg):
            if reply.arbitration_id not in replies:
                continue
            frame = decode_any(reply)
            row = nearest_row(int(frame.signals["Step"]), latest)
            latest = max(latest, row)
            if 0 <= row < record.rows:
                place_temperatures(frame.name, frame.signals, out[row])
    return out
