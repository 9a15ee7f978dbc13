"""The host's side of StateCheckpoint: only complete, valid checkpoints are kept, and the newest one before the
lost row is the one a re-initialization echoes back."""

from __future__ import annotations

import can
import numpy as np
import pytest

from dbc import FrameCodec
from host.session import HostSession


@pytest.fixture
def s():
    bus = can.Bus(interface="virtual", channel="checkpoints", receive_own_messages=False)
    session = HostSession(bus)
    session.last_sent_row = 1000
    yield session
    bus.shutdown()


def checkpoint(codec: FrameCodec, step: int, state) -> list[can.Message]:
    return [codec.encode("StateCheckpoint", {"Step": step, "StateIndex": i, "StateValue": float(v)})
            for i, v in enumerate(state)]


def test_four_valid_elements_make_a_checkpoint_bit_for_bit(s):
    codec = FrameCodec("TARGET")
    state = np.float32([-1311.3942, -735.39984, 3.3e-5, 1e6])
    for msg in checkpoint(codec, 499, state):
        s.accept(msg)
    assert list(s.checkpoints) == [499]
    assert np.array_equal(np.float32(s.checkpoints[499]), state)  # the float32 bits, unchanged
    assert s.last_checkpoint(500) == (499, s.checkpoints[499]) and s.last_checkpoint(499) is None


def test_a_corrupted_or_missing_element_makes_no_checkpoint(s):
    codec = FrameCodec("TARGET")
    frames = checkpoint(codec, 99, [1.0, 2.0, 3.0, 4.0])
    bad = bytearray(frames[2].data)
    bad[5] ^= 0x10                                    # a flipped bit: the CRC refuses the element
    frames[2] = can.Message(arbitration_id=frames[2].arbitration_id, data=bytes(bad), is_extended_id=False)
    for msg in frames:
        s.accept(msg)
    assert s.checkpoints == {} and s.invalid["crc"] == 1
    # the corrupted element, and the next one for its counter jump: each refused frame is on record
    assert [(r["kind"], r["data"]) for r in s.rejections] == [("crc", bytes(bad).hex()),
                                                              ("counter", bytes(frames[3].data).hex())]
    # later checkpoints complete (after one counter jump the validator resynchronizes) and the newest before a
    # row wins; elements that never completed are forgotten
    for step in (149, 199, 249, 299, 349, 399):
        for msg in checkpoint(codec, step, [float(step)] * 4):
            s.accept(msg)
    assert 99 not in s.checkpoints and {199, 249, 299, 349, 399} <= set(s.checkpoints)
    assert s.last_checkpoint(300) == (299, [299.0] * 4)
    assert len(s._checkpoint_parts) <= 4
