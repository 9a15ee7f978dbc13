"""Bus load: the exact bits on the wire of the log's frames (stuff bits included), at the data rate and per window.

Classic 11-bit data frames with 8 data bytes: SOF, ID, RTR, IDE, r0, DLC, data and the CAN CRC-15 are bit-stuffed
(after 5 equal bits a complementary one is inserted), then CRC delimiter, ACK slot and delimiter, EOF and the
3-bit interframe space.
"""

from __future__ import annotations

import numpy as np

from bench.analysis.logdecode import BusRecord
from bench.analysis.results import BusLoad
from dbc.database import frame_id
from dbc.transport import NOMINAL_BITRATE


def _crc15(bits: np.ndarray) -> np.ndarray:
    """CAN CRC-15 (polynomial 0x4599) of each row of a (frames, n) bit matrix."""
    crc = np.zeros(bits.shape[0], dtype=np.int64)
    for i in range(bits.shape[1]):
        feedback = bits[:, i].astype(np.int64) ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        crc ^= np.where(feedback == 1, 0x4599, 0)
    return crc


FRAME_BITS_CHUNK = 16384   # frames per block: the bit matrices of a block take about 1.6 MB, whatever the log's size


def frame_bits(ids: np.ndarray, data: np.ndarray) -> np.ndarray:
    """Exact bits on the wire of classic 11-bit data frames with 8 data bytes, stuff bits and 3-bit IFS included
    (computed in blocks of FRAME_BITS_CHUNK frames, one byte per bit)."""
    n = len(ids)
    out = np.zeros(n, dtype=np.int64)
    for start in range(0, n, FRAME_BITS_CHUNK):
        stop = start + FRAME_BITS_CHUNK
        out[start:stop] = _frame_bits(np.asarray(ids[start:stop], dtype=np.int64), data[start:stop])
    return out


def _frame_bits(ids: np.ndarray, data: np.ndarray) -> np.ndarray:
    n = len(ids)
    id_bits = ((ids[:, None] >> np.arange(10, -1, -1)) & 1).astype(np.uint8)
    dlc_bits = np.tile(np.array([1, 0, 0, 0], dtype=np.uint8), (n, 1))      # DLC = 8
    data_bits = np.unpackbits(data.astype(np.uint8), axis=1)  # MSB first per byte, bytes in order
    head = np.column_stack([np.zeros(n, dtype=np.uint8), id_bits, np.zeros((n, 3), dtype=np.uint8), dlc_bits,
                            data_bits])  # SOF, ID, RTR, IDE, r0, DLC, data
    crc = _crc15(head)
    crc_bits = ((crc[:, None] >> np.arange(14, -1, -1)) & 1).astype(np.uint8)
    stuffed = np.column_stack([head, crc_bits])              # the bit-stuffed region: SOF .. CRC
    # count stuff bits: after 5 equal bits a complementary one is inserted (and counts toward the next run)
    stuff = np.zeros(n, dtype=np.int64)
    last = stuffed[:, 0].astype(np.int64)
    run = np.ones(n, dtype=np.int64)
    for i in range(1, stuffed.shape[1]):
        bit = stuffed[:, i].astype(np.int64)
        same = bit == last
        run = np.where(same, run + 1, 1)
        last = bit
        insert = run == 5
        stuff += insert
        # the stuff bit is the complement of `last`: a new run of length 1 with the opposite value
        last = np.where(insert, 1 - last, last)
        run = np.where(insert, 1, run)
    fixed_tail = 1 + 2 + 7 + 3                                # CRC delimiter, ACK slot+delimiter, EOF, IFS
    return stuffed.shape[1] + stuff + fixed_tail


def bus_load(record: BusRecord, data: np.ndarray, sample_period_s: float, bitrate: int = NOMINAL_BITRATE,
             window_s: float = 1.0) -> BusLoad:
    """Bus load at `bitrate`: of the schedule at the data rate, and of this log over its own time."""
    bits = frame_bits(record.frame_ids, data) if len(data) else np.zeros(0, dtype=np.int64)
    mean = float(bits.mean()) if bits.size else None
    if not bits.size or record.rows == 0:
        return BusLoad(bitrate, mean, None, window_s, [], [])
    heartbeat_ids = {frame_id("Status"), frame_id("RxErrors")}
    is_heartbeat = np.isin(record.frame_ids, list(heartbeat_ids))
    per_row_bits = bits[~is_heartbeat].sum() / record.rows
    heartbeat_bits_per_s = float(bits[is_heartbeat].mean()) * len(heartbeat_ids) * 10 if is_heartbeat.any() else 0.0
    data_rate = float((per_row_bits / sample_period_s + heartbeat_bits_per_s) / bitrate * 100.0)
    t = record.frame_s - record.frame_s[0]
    edges = np.arange(0.0, max(t[-1], window_s) + window_s, window_s)
    sums, _ = np.histogram(t, bins=edges, weights=bits)
    return BusLoad(bitrate, mean, data_rate, window_s, edges[:-1].tolist(),
                   (sums / (bitrate * window_s) * 100.0).tolist(),
                   float(sums.max() / (bitrate * window_s) * 100.0))
