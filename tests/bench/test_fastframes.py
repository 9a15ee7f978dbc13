"""The fast codec twins give the same frames, values, types and errors as dbc's FrameCodec/FrameValidator."""

from __future__ import annotations

import random

import can
import pytest
from cantools.autosar.end_to_end import compute_profile2_crc

from dbc import FrameCodec, FrameError, FrameValidator, load_database, signal_ranges
from target_sim.fastframes import FastFrameCodec, FastFrameValidator, fast_decode_any, profile2_crc

MESSAGES = [m for m in load_database().messages]


def test_crc_table_matches_cantools():
    rng = random.Random(1)
    for _ in range(2000):
        payload = bytes(rng.randrange(256) for _ in range(8))
        data_id = rng.randrange(256)
        assert profile2_crc(payload, data_id) == compute_profile2_crc(payload, data_id)


def _random_signals(rng, message):
    out = {}
    for name, (low, high) in signal_ranges(message.name).items():
        scale = message.get_signal_by_name(name).scale
        pick = rng.random()
        if pick < 0.1:
            value = low
        elif pick < 0.2:
            value = high
        elif scale == 1:
            value = rng.randint(int(low), int(high))
        else:
            value = rng.uniform(low, high)
        out[name] = value
    return out


@pytest.mark.parametrize("message", MESSAGES, ids=lambda m: m.name)
def test_encode_and_validate_agree_with_the_reference(message):
    rng = random.Random(message.frame_id)
    sender = message.senders[0]
    receiver = "TARGET" if sender == "HOST" else "HOST"
    ref_codec, fast_codec = FrameCodec(sender), FastFrameCodec(sender)
    ref_val, fast_val = FrameValidator(receiver), FastFrameValidator(receiver)
    for _ in range(300):
        signals = _random_signals(rng, message)
        ref = ref_codec.encode(message.name, signals, timestamp=5.0)
        fast = fast_codec.encode(message.name, signals, timestamp=5.0)
        assert bytes(fast.data) == bytes(ref.data)
        assert (fast.arbitration_id, fast.dlc, fast.is_extended_id) == (ref.arbitration_id, 8, False)
        a, b = ref_val.validate(ref), fast_val.validate(fast)
        assert a == b
        assert [type(v) for v in a.signals.values()] == [type(v) for v in b.signals.values()]
        assert fast_decode_any(fast) == a


def _kind_and_message(fn, *args):
    with pytest.raises(FrameError) as info:
        fn(*args)
    return info.value.kind, info.value.message


def test_rejections_are_the_references_own():
    codec = FrameCodec("HOST")
    good = codec.encode("DriveInputs", {"Step": 1, "MotorTorque": 10.0, "MotorSpeed": 100.0})
    bad_crc = bytearray(good.data)
    bad_crc[3] ^= 0x40
    word = int.from_bytes(bytes(good.data), "little") & ~(0xFFFF << 44) | (0x7FFF << 44)  # 16383.5 rpm ...
    bad_range = bytearray(word.to_bytes(8, "little"))
    bad_range[0] = compute_profile2_crc(bytes(bad_range), 0x10)  # ... with a valid CRC
    frames = [
        can.Message(arbitration_id=0x7FF, data=bytes(8), is_extended_id=False),
        can.Message(arbitration_id=0x110, data=bytes(good.data[:7]), is_extended_id=False, dlc=7),
        can.Message(arbitration_id=0x110, data=bytes(bad_crc), is_extended_id=False),
        can.Message(arbitration_id=0x110, data=bytes(bad_range), is_extended_id=False),
        can.Message(arbitration_id=0x110, data=bytes(good.data), is_extended_id=True),
        can.Message(arbitration_id=0x220, data=bytes(8), is_extended_id=False),  # a target frame at the target
    ]
    for frame in frames:
        assert (_kind_and_message(FastFrameValidator("TARGET").validate, frame)
                == _kind_and_message(FrameValidator("TARGET").validate, frame))
    ref, fast = FrameValidator("TARGET"), FastFrameValidator("TARGET")
    second = codec.encode("DriveInputs", {"Step": 2, "MotorTorque": 10.0, "MotorSpeed": 100.0})
    third = codec.encode("DriveInputs", {"Step": 3, "MotorTorque": 10.0, "MotorSpeed": 100.0})
    for validator in (ref, fast):
        validator.validate(good)
    assert _kind_and_message(fast.validate, third) == _kind_and_message(ref.validate, third)  # counter jump
    del second


def test_unusual_encodes_fall_back_to_the_reference():
    fast = FastFrameCodec("HOST")
    frame = fast.encode("Control", {"Command": "START", "Step": 0})   # enum by name
    assert FrameValidator("TARGET").validate(frame).signals["Command"] == 2
    with pytest.raises(FrameError) as info:
        fast.encode("DriveInputs", {"Step": 0, "MotorTorque": 2500.0, "MotorSpeed": 0.0})
    assert info.value.kind == "out_of_range"
    with pytest.raises(FrameError):
        fast.encode("DriveInputs", {"Step": 0, "MotorTorque": float("nan"), "MotorSpeed": 0.0})
    with pytest.raises(ValueError):
        fast.encode("DriveInputs", {"Step": 0, "MotorTorque": 1.0})
    with pytest.raises(FrameError):
        fast.encode("Temperatures1", {"Step": 0, "WindingTemp": 1.0, "MagnetTemp": 1.0})  # the target's message
    # a refused frame does not use up a counter value
    ok = fast.encode("DriveInputs", {"Step": 0, "MotorTorque": 1.0, "MotorSpeed": 0.0})
    assert ok.data[1] & 0x0F == 0
