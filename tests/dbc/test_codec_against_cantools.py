"""The one codec (`dbc.codec`, fast by construction) against cantools: the same bytes as cantools' encoder with
its AUTOSAR E2E profile-2 CRC, the same values and types as cantools' decoder, and a one-sentence FrameError of
the right kind for every frame the contract refuses."""

from __future__ import annotations

import random

import can
import pytest
from cantools.autosar.end_to_end import apply_profile2_crc, compute_profile2_crc

from dbc import FrameCodec, FrameError, FrameValidator, decode_any, load_database, profile2_crc, signal_ranges
from dbc.database import contract, e2e_data_id, role_name

MESSAGES = [m for m in load_database().messages]


def dbc_names(message, signals: dict) -> dict:
    """The codec's signal names (roles: Step) as the DBC spells them (Control_Step): unique across messages."""
    layout = contract().by_name[message.name]
    return {layout.signal(name).dbc_name: value for name, value in signals.items()}


def cantools_encode(message, signals: dict, counter: int) -> bytes:
    """What cantools makes of the frame (signals named as the codec names them): its strict encoder, then its
    profile-2 CRC."""
    data = {**dbc_names(message, signals), f"{message.name}_CRC": 0, f"{message.name}_Counter": counter}
    payload = message.encode(data, scaling=True, padding=False, strict=True)
    return bytes(apply_profile2_crc(payload, e2e_data_id(message.frame_id)))


def cantools_decode(message, payload: bytes) -> dict:
    """cantools' decoded values, by the codec's names."""
    decoded = message.decode(payload, decode_choices=False, scaling=True)
    return {role_name(message.name, k): v for k, v in decoded.items()
            if k not in (f"{message.name}_CRC", f"{message.name}_Counter")}


def test_crc_table_matches_cantools():
    rng = random.Random(1)
    for _ in range(2000):
        payload = bytes(rng.randrange(256) for _ in range(8))
        data_id = rng.randrange(256)
        assert profile2_crc(payload, data_id) == compute_profile2_crc(payload, data_id)


def _random_signals(rng, message):
    out = {}
    for name, (low, high) in signal_ranges(message.name).items():
        scale = contract().by_name[message.name].signal(name).scale
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
def test_encode_and_validate_agree_with_cantools(message):
    rng = random.Random(message.frame_id)
    sender = message.senders[0]
    receiver = "TARGET" if sender == "HOST" else "HOST"
    codec, validator = FrameCodec(sender), FrameValidator(receiver)
    for i in range(300):
        signals = _random_signals(rng, message)
        frame = codec.encode(message.name, signals, timestamp=5.0)
        assert bytes(frame.data) == cantools_encode(message, signals, i % 16)
        assert (frame.arbitration_id, frame.dlc, frame.is_extended_id) == (message.frame_id, 8, False)
        decoded = validator.validate(frame)
        reference = cantools_decode(message, bytes(frame.data))
        assert decoded.signals == reference and decoded.counter == i % 16
        assert [type(v) for v in decoded.signals.values()] == [type(v) for v in reference.values()]
        assert decode_any(frame) == decoded


def _kind(fn, *args) -> str:
    with pytest.raises(FrameError) as info:
        fn(*args)
    assert info.value.message and "\n" not in info.value.message
    return info.value.kind


def test_rejections_in_contract_order():
    codec = FrameCodec("HOST")
    good = codec.encode("DriveInputs", {"Step": 1, "MotorTorque": 10.0, "MotorSpeed": 100.0})
    bad_crc = bytearray(good.data)
    bad_crc[3] ^= 0x40
    word = int.from_bytes(bytes(good.data), "little") & ~(0xFFFF << 44) | (0x7FFF << 44)  # 16383.5 rpm ...
    bad_range = bytearray(word.to_bytes(8, "little"))
    bad_range[0] = compute_profile2_crc(bytes(bad_range), 0x10)  # ... with a valid CRC
    cases = [
        (can.Message(arbitration_id=0x7FF, data=bytes(8), is_extended_id=False), "unknown_id"),
        (can.Message(arbitration_id=0x110, data=bytes(good.data[:7]), is_extended_id=False, dlc=7), "wrong_length"),
        (can.Message(arbitration_id=0x110, data=bytes(bad_crc), is_extended_id=False), "crc"),
        (can.Message(arbitration_id=0x110, data=bytes(bad_range), is_extended_id=False), "out_of_range"),
        (can.Message(arbitration_id=0x110, data=bytes(good.data), is_extended_id=True), "unknown_id"),
        (can.Message(arbitration_id=0x220, data=bytes(8), is_extended_id=False), "unknown_id"),  # the target's own
    ]
    for frame, kind in cases:
        assert _kind(FrameValidator("TARGET").validate, frame) == kind
    validator = FrameValidator("TARGET")
    codec.encode("DriveInputs", {"Step": 2, "MotorTorque": 10.0, "MotorSpeed": 100.0})  # lost on the way
    third = codec.encode("DriveInputs", {"Step": 3, "MotorTorque": 10.0, "MotorSpeed": 100.0})
    validator.validate(good)
    assert _kind(validator.validate, third) == "counter"


def test_what_the_codec_refuses():
    codec = FrameCodec("HOST")
    frame = codec.encode("Control", {"Command": "START", "Step": 0})   # enum by name
    assert FrameValidator("TARGET").validate(frame).signals["Command"] == 2
    assert _kind(codec.encode, "DriveInputs", {"Step": 0, "MotorTorque": 2500.0, "MotorSpeed": 0.0}) == "out_of_range"
    assert _kind(codec.encode, "DriveInputs", {"Step": 0, "MotorTorque": float("nan"), "MotorSpeed": 0.0}) \
        == "out_of_range"
    assert _kind(codec.encode, "Control", {"Command": "LAUNCH", "Step": 0}) == "out_of_range"
    with pytest.raises(ValueError, match="missing"):
        codec.encode("DriveInputs", {"Step": 0, "MotorTorque": 1.0})
    with pytest.raises(ValueError, match="unknown"):
        codec.encode("DriveInputs", {"Step": 0, "MotorTorque": 1.0, "Speed": 0.0})
    assert _kind(codec.encode, "Temperatures1", {"Step": 0, "WindingTemp": 1.0, "MagnetTemp": 1.0}) == "unknown_id"
    assert _kind(codec.encode, "NoSuchMessage", {}) == "unknown_id"
    # a refused frame does not use up a counter value
    ok = codec.encode("DriveInputs", {"Step": 0, "MotorTorque": 1.0, "MotorSpeed": 0.0})
    assert ok.data[1] & 0x0F == 0


def test_drive_currents_round_trip_through_cantools_and_the_codec():
    """DriveCurrents (DBC 1.4.0): the codec's bytes are cantools', both decode them to the same currents, and the
    validator refuses a bad CRC and a current beyond ±3000 A."""
    message = load_database().get_message_by_name("DriveCurrents")
    codec, validator = FrameCodec("HOST"), FrameValidator("TARGET")
    for counter, (i_d, i_q) in enumerate([(-123.4, 456.7), (-3000.0, 3000.0), (0.0, -0.1), (2999.9, -2999.9)]):
        signals = {"Step": 40000 + counter, "CurrentD": i_d, "CurrentQ": i_q}
        frame = codec.encode("DriveCurrents", signals)
        assert frame.arbitration_id == 0x112 and bytes(frame.data) == cantools_encode(message, signals, counter)
        assert cantools_decode(message, bytes(frame.data)) == pytest.approx(signals)
        decoded = validator.validate(frame)
        assert decoded.name == "DriveCurrents" and decoded.signals == pytest.approx(signals)
        assert decoded.counter == counter
    raw = int.from_bytes(bytes(frame.data), "little")
    assert (raw >> 28) & 0xFFFF == (29999 & 0xFFFF) and (raw >> 44) & 0xFFFF == (-29999 & 0xFFFF)
    assert _kind(codec.encode, "DriveCurrents", {"Step": 0, "CurrentD": 3000.1, "CurrentQ": 0.0}) == "out_of_range"
    corrupt = bytearray(codec.encode("DriveCurrents", {"Step": 1, "CurrentD": 1.0, "CurrentQ": 2.0}).data)
    corrupt[3] ^= 0x10
    bad = can.Message(arbitration_id=0x112, is_extended_id=False, data=bytes(corrupt))
    assert _kind(validator.validate, bad) == "crc"
    beyond = (int.from_bytes(bytes(corrupt), "little") & ~(0xFFFF << 44)) | ((30001 & 0xFFFF) << 44)
    beyond_frame = can.Message(arbitration_id=0x112, is_extended_id=False,
                               data=bytes(apply_profile2_crc(bytearray(beyond.to_bytes(8, "little")), 0x12)))
    assert _kind(decode_any, beyond_frame) == "out_of_range"
