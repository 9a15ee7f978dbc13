"""The target's twin: its own node code, offline, fed the frames the host put on the bus, in the logged order.

In a real-time run with faults the target leaves out the rows it never got or refused, forms its interval means
from the rest, and so departs from the clean run; which rows it used depends on its validator (alive counters,
CRC, sequence). The twin (`target_sim.node.TargetNode`, no bus, a fixed clock) receives exactly what the target
received — every logged frame but the target's own (and the target's reply faults on foreign ids, which its fault
layer filters) — and answers as the target must have, so "CAN = twin within the 0.01 °C quantization" checks the
target's arithmetic and its handling of every faulty frame at once.
"""

from __future__ import annotations

import can
import numpy as np

from bench.analysis.logdecode import BusRecord, nearest_row
from dbc import TARGET_FRAME_IDS, frame_id
from target_sim.artifact import ModelArtifact
from target_sim.fastframes import fast_decode_any
from target_sim.faults import REPLY_IDS, UNKNOWN_ID_FLIP
from target_sim.node import TargetNode

_NOT_RECEIVED = TARGET_FRAME_IDS | {fid ^ UNKNOWN_ID_FLIP for fid in REPLY_IDS}
_TEMPERATURES1, _TEMPERATURES2 = frame_id("Temperatures1"), frame_id("Temperatures2")


def twin_estimates(artifact: ModelArtifact, record: BusRecord) -> np.ndarray:
    """(rows, 4) yoke, winding, tooth, magnet the twin answered after each row (its last answer; NaN: none)."""
    node = TargetNode(artifact, clock_ns=lambda: 0)
    out = np.full((record.rows, 4), np.nan)
    latest = 0
    for fid, dlc, data in zip(record.frame_ids.tolist(), record.frame_dlc.tolist(), record.frame_data, strict=True):
        if fid in _NOT_RECEIVED:
            continue
        msg = can.Message(arbitration_id=fid, is_extended_id=False, dlc=dlc, data=bytes(data[:dlc]), check=False)
        for reply in node.handle(msg):
            if reply.arbitration_id not in (_TEMPERATURES1, _TEMPERATURES2):
                continue
            signals = fast_decode_any(reply).signals
            row = nearest_row(int(signals["Step"]), latest)
            latest = max(latest, row)
            if not 0 <= row < record.rows:
                continue
            if reply.arbitration_id == _TEMPERATURES1:
                out[row, 1], out[row, 3] = signals["WindingTemp"], signals["MagnetTemp"]
            else:
                out[row, 0], out[row, 2] = signals["YokeTemp"], signals["ToothTemp"]
    return out
