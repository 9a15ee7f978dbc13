"""The CAN link layer both nodes stand on: the contract (``thermal_bench.dbc`` and the facts code needs by name),
one codec/validator, the frame faults both sides inject, and the bus transport.

Importing this package reads no file: the DBC is loaded on first use (`dbc.database.contract`).

    contract    facts defined once: enums, Step and counter arithmetic, reply and temperature layout, timeouts
    database    the DBC loaded lazily: ids, senders, layouts, ranges, cycle times, version
    codec       FrameCodec / FrameValidator / decode_any: E2E profile-2 CRC8 and alive counters, fast by design
    mutations   what each frame fault kind does to a frame (host and target fault layers)
    transport   BusConfig, python-can bus options, own-frame filter, channel-in-use listening
    files       NAME_MAX and the atomic write, which every layer writes its files with (it imports nothing)
"""

from dbc.codec import DecodedFrame, FrameCodec, FrameValidator, apply_crc, decode_any, profile2_crc
from dbc.contract import (
    DBC_PATH,
    FRAME_ERROR_KINDS,
    NODES,
    BenchEvent,
    Command,
    FaultBit,
    FaultKind,
    FrameError,
    FrameErrorKind,
    ModelKind,
    Realization,
    TargetState,
    model_id_from_sha256,
)
from dbc.database import (
    DbcError,
    dbc_version,
    dbc_version_info,
    frame_id,
    frame_ids,
    host_frame_ids,
    load_database,
    signal_ranges,
    target_frame_ids,
)

__all__ = [
    "DBC_PATH",
    "FRAME_ERROR_KINDS",
    "NODES",
    "BenchEvent",
    "Command",
    "DbcError",
    "DecodedFrame",
    "FaultBit",
    "FaultKind",
    "FrameCodec",
    "FrameError",
    "FrameErrorKind",
    "FrameValidator",
    "ModelKind",
    "Realization",
    "TargetState",
    "apply_crc",
    "dbc_version",
    "dbc_version_info",
    "decode_any",
    "frame_id",
    "frame_ids",
    "host_frame_ids",
    "load_database",
    "model_id_from_sha256",
    "profile2_crc",
    "signal_ranges",
    "target_frame_ids",
]
