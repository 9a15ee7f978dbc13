"""Frame faults: what each kind does to a frame of the contract, and the seeded draws that place them.

Both nodes inject with this code: the host's fault layer (`host.faults.FaultyBus`) alters its drive frames, the
target's (`target_sim.faults.ReplyFaults`) its temperature replies. What each kind does to a frame F with alive
counter c (`mutate`):

* drop: F is not sent. The next frame of the same id (its `witness`) carries c+1 after c-1: a counter jump.
* duplicate: F goes out twice, byte for byte; the second copy repeats counter c.
* corrupt: 1 to 3 distinct bits of the 8 bytes are flipped. CRC8H2F has Hamming distance 4 over these 64 bits,
  so the CRC catches every such corruption by construction (checked again for each frame).
* stale_counter: F carries counter c-1 (the previous frame's) with a valid CRC: a sender that did not count.
* wrong_length: F goes out with its first 0..7 bytes only (DLC 0..7).
* unknown_id: F goes out on an id no DBC message has (its id with bit 3 flipped).
* out_of_range: the 16-bit signal at bit 28 (MotorTorque, CoolantTemp, CurrentD, SensorTemp, WindingTemp, YokeTemp)
  carries
  its largest raw value (3276.7 Nm, 3276.7 degC, 3276.7 A, 605.35 degC: beyond the DBC range) with a valid CRC and
  counter.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache

import can

from dbc.codec import apply_crc, profile2_crc
from dbc.contract import CURRENT_SIGNALS, DRIVE_SIGNALS, MEASUREMENT_MESSAGES, REPLY_MESSAGES, row_messages
from dbc.database import contract, frame_id

FRAME_FAULT_KINDS: tuple[str, ...] = ("drop", "duplicate", "corrupt", "stale_counter", "wrong_length", "unknown_id",
                                      "out_of_range")
REPLY_PREFIX = "reply_"       # a frame fault the target injects into its replies: "reply_drop", ...
REPLY_FAULT_KINDS: tuple[str, ...] = tuple(REPLY_PREFIX + kind for kind in FRAME_FAULT_KINDS)
# the host's frames its fault layer may alter: those of a data row, in their order (DriveInputs, DriveTemps, and
# DriveCurrents, which goes out only when the drive data has the currents), then the measurement frames
# (Measurements, and DriveVoltages for an observer that computes the flux linkage; sent before the row's
# DriveInputs, only for a model with an observer)
FAULTED_HOST_MESSAGES = (*row_messages(len(DRIVE_SIGNALS) + len(CURRENT_SIGNALS)), *MEASUREMENT_MESSAGES)
UNKNOWN_ID_FLIP = 0x008
OUT_OF_RANGE_START = 28
_MASK = (1 << 64) - 1

Draw = Callable[[int], float]


def _mix(x: int) -> int:
    x = (x + 0x9E3779B97F4A7C15) & _MASK
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _MASK
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _MASK
    return x ^ (x >> 31)


def unit(seed: int, *keys: int) -> float:
    """A uniform number in [0, 1) determined by the seed and the keys (splitmix64 chain): the same faults on the
    same frames whatever the machine's speed."""
    h = _mix(seed & _MASK)
    for key in keys:
        h = _mix(h ^ (key & _MASK))
    return (h >> 11) / float(1 << 53)


def pick(u: float, rates: list[tuple[str, float]]) -> str | None:
    """The kind whose slice of [0, 1) holds u (slices of width rate, in order), or None past the last one."""
    edge = 0.0
    for kind, rate in rates:
        edge += rate
        if u < edge:
            return kind
    return None


@cache
def reply_ids() -> frozenset[int]:
    """The ids of the target's temperature replies (what its reply faults alter)."""
    return frozenset(frame_id(name) for name in REPLY_MESSAGES)


def foreign_ids(names) -> frozenset[int]:
    """The ids the unknown_id fault moves the frames of messages `names` to."""
    return frozenset(frame_id(name) ^ UNKNOWN_ID_FLIP for name in names)


@cache
def _out_of_range_raw() -> dict[int, int]:
    """Per frame id, the largest raw value of its 16-bit signal at bit 28, when that lies beyond the DBC range;
    checked for every faultable message (and that unknown_id never lands on a DBC id)."""
    out = {}
    for layout in contract().by_id.values():
        for s in layout.signals:
            if s.start != OUT_OF_RANGE_START or s.length != 16 or s.ieee is not None:
                continue
            raw = (1 << 15) - 1 if s.signed else (1 << 16) - 1
            if raw * s.scale + s.offset > s.maximum:
                out[layout.frame_id] = raw
    for name in (*FAULTED_HOST_MESSAGES, *REPLY_MESSAGES):
        fid = frame_id(name)
        assert fid ^ UNKNOWN_ID_FLIP not in contract().by_id, "an unknown-id fault must not land on a DBC id"
        assert fid in out, "every faultable frame has a signal that can be pushed out of range"
    return out


def copy_frame(msg: can.Message, *, arbitration_id: int | None = None, data: bytes | None = None) -> can.Message:
    data = bytes(msg.data) if data is None else data
    return can.Message(timestamp=msg.timestamp, arbitration_id=msg.arbitration_id if arbitration_id is None else
                       arbitration_id, is_extended_id=False, dlc=len(data), data=data, is_rx=False, check=False)


def mutate(kind: str, msg: can.Message, draw: Draw) -> list[can.Message]:
    """The frames that go on the bus instead of `msg` for a fault of `kind` (`draw(slot)`: further uniform
    numbers for bit positions and lengths): none for drop, the frame and its copy for duplicate, else one."""
    data = bytearray(msg.data)
    fid = msg.arbitration_id
    if kind == "drop":
        return []
    if kind == "duplicate":
        return [msg, copy_frame(msg)]
    if kind == "corrupt":
        flips = 1 + int(draw(0) * 3)
        bits: list[int] = []
        slot = 1
        while len(bits) < flips:
            bit = int(draw(slot) * 64)
            slot += 1
            if bit not in bits:
                bits.append(bit)
        for bit in bits:
            data[bit // 8] ^= 1 << (bit % 8)
        # CRC8H2F has Hamming distance 4 over 64 bits: 1..3 flipped bits always break the CRC
        assert data[0] != profile2_crc(bytes(data), contract().by_id[fid].data_id), "an undetectable corruption"
        return [copy_frame(msg, data=bytes(data))]
    if kind == "stale_counter":
        data[1] = (data[1] & 0xF0) | ((data[1] - 1) & 0x0F)
        return [copy_frame(msg, data=apply_crc(fid, bytes(data)))]
    if kind == "wrong_length":
        return [copy_frame(msg, data=bytes(data[:int(draw(0) * 8)]))]
    if kind == "unknown_id":
        return [copy_frame(msg, arbitration_id=fid ^ UNKNOWN_ID_FLIP)]
    if kind == "out_of_range":
        word = int.from_bytes(bytes(data), "little")
        word = (word & ~(0xFFFF << OUT_OF_RANGE_START)) | (_out_of_range_raw()[fid] << OUT_OF_RANGE_START)
        return [copy_frame(msg, data=apply_crc(fid, word.to_bytes(8, "little")))]
    raise ValueError(f"unknown frame fault kind {kind}")


def raw_step(msg: can.Message) -> int:
    """The Step a frame of the contract carries, read from its bytes whatever else is wrong with them."""
    s = contract().by_id[msg.arbitration_id].signal("Step")
    return (int.from_bytes(bytes(msg.data).ljust(8, b"\0"), "little") >> s.start) & s.mask
