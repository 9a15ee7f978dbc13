"""FrameCodec / FrameValidator / decode_any: round trips, E2E protection and every rejection kind."""

import hashlib
import math
import subprocess
import sys

import can
import numpy as np
import pytest
from cantools.autosar import end_to_end
from hypothesis import given, settings
from hypothesis import strategies as st

import dbc
from dbc import (
    Command,
    FrameCodec,
    FrameError,
    FrameValidator,
    TargetState,
    apply_crc,
    decode_any,
    frame_id,
    load_database,
)
from dbc.database import role_name

DB = load_database()
NAMES = [m.name for m in DB.messages]


def sender_of(name):
    return DB.get_message_by_name(name).senders[0]


def receiver_of(name):
    return "TARGET" if sender_of(name) == "HOST" else "HOST"


def app_signals(name):
    message = DB.get_message_by_name(name)
    return [s for s in message.signals if s.name not in (f"{name}_CRC", f"{name}_Counter")]


def key(name, s):
    """The name the codec gives cantools' signal `s` of message `name` (Control_Step -> Step)."""
    return role_name(name, s.name)


def at(name, which):
    return {key(name, s): getattr(s, which) for s in app_signals(name)}


def mid(name):
    return {key(name, s): round((s.minimum + s.maximum) / 2) for s in app_signals(name)}


def assert_round_trip(name, values, decoded):
    assert decoded.name == name and decoded.frame_id == frame_id(name)
    assert set(decoded.signals) == set(values)
    for s in app_signals(name):
        half = abs(s.scale) / 2
        k = key(name, s)
        error = abs(decoded.signals[k] - values[k])
        assert error <= half * (1 + 1e-9) + 1e-9, (k, values[k], decoded.signals[k])


def flipped(msg, bit):
    data = bytearray(msg.data)
    data[bit // 8] ^= 1 << (bit % 8)
    return can.Message(arbitration_id=msg.arbitration_id, is_extended_id=False, dlc=8, data=bytes(data))


def kind_of(validator, msg):
    with pytest.raises(FrameError) as info:
        validator.validate(msg)
    assert str(info.value).endswith(".") and "\n" not in str(info.value)
    return info.value.kind


# ---------------------------------------------------------------- round trips


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("which", ["minimum", "maximum"])
def test_round_trip_at_range_limits(name, which):
    values = at(name, which)
    msg = FrameCodec(sender_of(name)).encode(name, values)
    assert (msg.arbitration_id, msg.is_extended_id, msg.dlc, len(msg.data)) == (frame_id(name), False, 8, 8)
    assert not msg.is_remote_frame and not msg.is_fd
    decoded = FrameValidator(receiver_of(name)).validate(msg)
    assert_round_trip(name, values, decoded)
    assert decoded.signals == values  # the limits are on the raw grid, so they come back exactly
    assert decoded.counter == 0 and decoded.timestamp == msg.timestamp


def signal_values(s):
    if s.choices:
        return st.sampled_from(sorted(int(raw) for raw in s.choices))
    floats = st.floats(min_value=s.minimum, max_value=s.maximum, allow_nan=False)
    if s.scale == 1 and s.offset == 0:
        return st.one_of(st.integers(int(s.minimum), int(s.maximum)), floats)
    return floats


@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_round_trip_random_values_within_half_resolution(name, data):
    values = {key(name, s): data.draw(signal_values(s), label=s.name) for s in app_signals(name)}
    decoded = FrameValidator(receiver_of(name)).validate(FrameCodec(sender_of(name)).encode(name, values))
    assert_round_trip(name, values, decoded)


def test_known_values_decode_exactly():
    host, target = FrameCodec("HOST"), FrameValidator("TARGET")
    frame = target.validate(host.encode("DriveInputs", {"Step": 65535, "MotorTorque": -1234.5, "MotorSpeed": 14999.5}))
    assert frame.signals == {"Step": 65535, "MotorTorque": -1234.5, "MotorSpeed": 14999.5}
    values = {"Step": 3, "WindingTemp": 123.456, "MagnetTemp": -49.99}
    frame = FrameValidator("HOST").validate(FrameCodec("TARGET").encode("Temperatures1", values))
    assert frame.signals["WindingTemp"] == pytest.approx(123.46, abs=1e-9)
    assert frame.signals["MagnetTemp"] == pytest.approx(-49.99, abs=1e-9)


def test_enum_names_numpy_scalars_and_intenums_are_accepted():
    host, target = FrameCodec("HOST"), FrameValidator("TARGET")
    assert target.validate(host.encode("Control", {"Step": np.uint16(9), "Command": "START"})).signals == {
        "Step": 9,
        "Command": 2,
    }
    assert target.validate(host.encode("Control", {"Step": np.int64(10), "Command": Command.STOP})).signals == {
        "Step": 10,
        "Command": 3,
    }
    values = {"Step": np.int32(1), "MotorTorque": np.float32(-12.3), "MotorSpeed": np.float64(100.5)}
    assert target.validate(host.encode("DriveInputs", values)).signals == {
        "Step": 1,
        "MotorTorque": pytest.approx(-12.3),
        "MotorSpeed": 100.5,
    }
    status = {"State": TargetState.FAULT, "FaultBits": dbc.FaultBit.NONFINITE | dbc.FaultBit.INTERNAL}
    status |= {"ModelId": dbc.model_id_from_sha256("ffee" * 16), "DbcVersionMajor": 1, "DbcVersionMinor": 0}
    frame = FrameValidator("HOST").validate(FrameCodec("TARGET").encode("Status", status))
    assert frame.signals["State"] == 5 and frame.signals["FaultBits"] == 0xA0
    assert frame.signals["ModelId"] == 0xFFEEFFEE


def test_model_id_is_the_first_eight_hex_digits_of_the_sha256():
    digest = hashlib.sha256(b"artifact").hexdigest()
    assert dbc.model_id_from_sha256(digest) == int(digest[:8], 16)
    assert dbc.model_id_from_sha256("0123456789abcdef" * 4) == 0x01234567


def test_alive_counter_increments_mod_16_per_message():
    host = FrameCodec("HOST")
    counters = [host.encode("DriveInputs", mid("DriveInputs")).data[1] & 0x0F for _ in range(20)]
    assert counters == [i % 16 for i in range(20)]
    assert host.encode("DriveTemps", mid("DriveTemps")).data[1] & 0x0F == 0  # own counter per message
    host.reset_counters()
    assert host.encode("DriveInputs", mid("DriveInputs")).data[1] & 0x0F == 0


def test_crc_is_autosar_profile2_with_the_frame_data_id():
    msg = FrameCodec("HOST").encode("DriveTemps", {"Step": 1, "CoolantTemp": 20, "AmbientTemp": 25})
    data_id = frame_id("DriveTemps") & 0xFF
    assert end_to_end.check_profile2_crc(bytes(msg.data), data_id) is True
    assert msg.data[0] == end_to_end.compute_profile2_crc(bytes(msg.data), data_id)
    assert end_to_end.check_profile2_crc(bytes(msg.data), data_id ^ 1) is False
    assert apply_crc(msg.arbitration_id, bytes([0]) + bytes(msg.data[1:])) == bytes(msg.data)


# ---------------------------------------------------------------- encoder refusals


@pytest.mark.parametrize("name", NAMES)
def test_out_of_range_values_are_refused_not_wrapped(name):
    codec = FrameCodec(sender_of(name))
    for s in app_signals(name):
        for bad in (s.maximum + s.scale, s.minimum - s.scale, math.nan, math.inf, -math.inf):
            values = mid(name) | {key(name, s): bad}
            with pytest.raises(FrameError) as info:
                codec.encode(name, values)
            assert info.value.kind == "out_of_range", (s.name, bad)
            assert s.name in str(info.value) and name in str(info.value)
    # a refused frame does not use up a counter value
    assert codec.encode(name, mid(name)).data[1] & 0x0F == 0


def test_encoder_refuses_wrong_names_and_other_nodes_messages():
    host = FrameCodec("HOST")
    with pytest.raises(FrameError, match="no message named 'Nope'") as info:
        host.encode("Nope", {})
    assert info.value.kind == "unknown_id"
    with pytest.raises(FrameError, match="sent by TARGET") as info:
        host.encode("Temperatures1", mid("Temperatures1"))
    assert info.value.kind == "unknown_id"
    with pytest.raises(FrameError, match="no value named 'JUMP'; use one of NOP, RESET, START, STOP"):
        host.encode("Control", {"Step": 0, "Command": "JUMP"})
    with pytest.raises(ValueError, match=r"missing \['MotorSpeed'\]"):
        host.encode("DriveInputs", {"Step": 0, "MotorTorque": 0})
    with pytest.raises(ValueError, match=r"unknown \['DriveInputs_Counter'\]"):
        host.encode("DriveInputs", mid("DriveInputs") | {"DriveInputs_Counter": 3})
    with pytest.raises(ValueError, match="not one of HOST, TARGET"):
        FrameCodec("ECU")
    with pytest.raises(ValueError):
        FrameError("bad_kind", "x")


# ---------------------------------------------------------------- validator rejections


def test_every_single_bit_flip_is_a_crc_error_and_changes_no_state():
    host, target = FrameCodec("HOST"), FrameValidator("TARGET")
    first = host.encode("DriveInputs", {"Step": 100, "MotorTorque": 250.5, "MotorSpeed": 3000})
    second = host.encode("DriveInputs", {"Step": 101, "MotorTorque": -250.5, "MotorSpeed": 3000.5})
    target.validate(first)
    for bit in range(64):
        assert kind_of(target, flipped(second, bit)) == "crc", bit
        assert kind_of(dbc.FrameValidator(), flipped(second, bit)) == "crc", bit
    assert target.validate(second).signals["Step"] == 101  # the rejected copies did not move the counter


@pytest.mark.parametrize("length", [0, 1, 7])
def test_short_frames_are_wrong_length(length):
    msg = FrameCodec("HOST").encode("DriveTemps", mid("DriveTemps"))
    short = can.Message(arbitration_id=msg.arbitration_id, is_extended_id=False, data=msg.data[:length])
    assert short.dlc == length
    assert kind_of(FrameValidator("TARGET"), short) == "wrong_length"
    # a DLC that disagrees with the data is refused too
    lying = can.Message(arbitration_id=msg.arbitration_id, is_extended_id=False, dlc=length, data=msg.data)
    assert kind_of(FrameValidator("TARGET"), lying) == "wrong_length"


def test_unknown_ids_extended_remote_error_fd_and_own_frames():
    msg = FrameCodec("HOST").encode("DriveInputs", mid("DriveInputs"))
    target = FrameValidator("TARGET")
    cases = {
        "unlisted": can.Message(arbitration_id=0x7FF, is_extended_id=False, data=msg.data),
        "unused": can.Message(arbitration_id=0x115, is_extended_id=False, data=msg.data),
        "extended": can.Message(arbitration_id=msg.arbitration_id, is_extended_id=True, data=msg.data),
        "remote": can.Message(arbitration_id=msg.arbitration_id, is_extended_id=False, is_remote_frame=True, dlc=8),
        "error": can.Message(arbitration_id=0, is_error_frame=True, data=msg.data),
        "fd": can.Message(arbitration_id=msg.arbitration_id, is_extended_id=False, is_fd=True, data=msg.data),
    }
    for label, frame in cases.items():
        assert kind_of(target, frame) == "unknown_id", label
    # a node does not accept the frames it sends itself (udp_multicast echoes them back)
    assert kind_of(FrameValidator("HOST"), msg) == "unknown_id"
    assert target.validate(msg).counter == 0


def test_counter_jump_and_duplicate_are_errors_and_resynchronize():
    host, target = FrameCodec("HOST"), FrameValidator("TARGET")
    frames = [host.encode("DriveInputs", mid("DriveInputs") | {"Step": i}) for i in range(40)]
    target.validate(frames[0])
    assert kind_of(target, frames[2]) == "counter"  # frame 1 lost
    assert target.validate(frames[3]).signals["Step"] == 3  # resynchronized: one lost frame, one error
    assert kind_of(target, frames[3]) == "counter"  # duplicate
    assert target.validate(frames[4]).signals["Step"] == 4
    assert kind_of(target, frames[4 + 16]) == "counter"  # same counter value 16 frames later: a repeat
    steps = [target.validate(frame).signals["Step"] for frame in frames[21:40]]  # wraps 15 -> 0 on the way
    assert steps == list(range(21, 40))


def test_counter_sequence_wraps_and_is_kept_per_message():
    host, target = FrameCodec("HOST"), FrameValidator("TARGET")
    counters = []
    for step in range(35):
        counters.append(target.validate(host.encode("DriveInputs", mid("DriveInputs") | {"Step": step})).counter)
        target.validate(host.encode("DriveTemps", mid("DriveTemps") | {"Step": step}))
    assert counters == [step % 16 for step in range(35)]


def test_first_frame_after_construction_or_reset_is_accepted_with_any_counter():
    host = FrameCodec("HOST")
    frames = [host.encode("DriveTemps", mid("DriveTemps")) for _ in range(8)]
    target = FrameValidator("TARGET")
    assert target.validate(frames[5]).counter == 5
    assert kind_of(target, frames[1]) == "counter"
    target.reset_counters()
    assert target.validate(frames[7]).counter == 7
    assert kind_of(target, frames[7]) == "counter"


def hand_built_drive_inputs(step, torque_raw, speed_raw, counter):
    """Payload built bit by bit from the DBC layout, independent of cantools, with a valid CRC."""
    bits = (counter & 0xF) << 8 | (step & 0xFFFF) << 12 | (torque_raw & 0xFFFF) << 28 | (speed_raw & 0xFFFF) << 44
    payload = bytearray(bits.to_bytes(8, "little"))
    payload[0] = end_to_end.compute_profile2_crc(bytes(payload), 0x110 & 0xFF)
    return can.Message(arbitration_id=0x110, is_extended_id=False, data=bytes(payload))


def test_hand_built_frame_decodes_as_the_layout_says():
    frame = decode_any(hand_built_drive_inputs(step=513, torque_raw=-20000, speed_raw=30000, counter=9))
    assert frame.signals == {"Step": 513, "MotorTorque": -2000.0, "MotorSpeed": 15000.0}
    assert frame.counter == 9


@pytest.mark.parametrize(
    ("torque_raw", "speed_raw"),
    [(20001, 0), (-20001, 0), (32767, 0), (-32768, 0), (0, 30001), (0, -2001), (0, -32768)],
)
def test_valid_crc_with_raw_value_outside_range_is_out_of_range(torque_raw, speed_raw):
    target = FrameValidator("TARGET")
    assert target.validate(hand_built_drive_inputs(1, 0, 0, counter=0)).counter == 0
    bad = hand_built_drive_inputs(2, torque_raw, speed_raw, counter=1)
    assert kind_of(target, bad) == "out_of_range"
    with pytest.raises(FrameError, match="outside its range"):
        decode_any(bad)
    # the rejected frame changed no state: the good frame with the same counter is next in order
    assert target.validate(hand_built_drive_inputs(2, 100, 100, counter=1)).signals["Step"] == 2


def test_out_of_range_enums_and_temperatures_with_valid_crc():
    def sealed(name, raw):
        message = DB.get_message_by_name(name)
        payload = message.encode(raw, scaling=False, strict=False)
        return can.Message(
            arbitration_id=message.frame_id, is_extended_id=False, data=apply_crc(message.frame_id, payload)
        )

    control = {"Control_CRC": 0, "Control_Counter": 0, "Control_Step": 0, "Command": 7}
    assert kind_of(FrameValidator("TARGET"), sealed("Control", control)) == "out_of_range"
    temps = {"Temperatures1_CRC": 0, "Temperatures1_Counter": 0, "Temperatures1_Step": 0, "WindingTemp": 65001,
             "MagnetTemp": 0}
    assert kind_of(FrameValidator("HOST"), sealed("Temperatures1", temps)) == "out_of_range"
    temps["WindingTemp"] = 65000  # exactly 600 degC
    assert FrameValidator("HOST").validate(sealed("Temperatures1", temps)).signals["WindingTemp"] == 600


def test_checks_run_in_contract_order():
    msg = FrameCodec("HOST").encode("DriveInputs", mid("DriveInputs"))
    short_bad_crc = can.Message(arbitration_id=msg.arbitration_id, is_extended_id=False, data=b"\x00" * 7)
    assert kind_of(FrameValidator("TARGET"), short_bad_crc) == "wrong_length"
    unknown_short = can.Message(arbitration_id=0x7FF, is_extended_id=False, data=b"\x00")
    assert kind_of(FrameValidator("TARGET"), unknown_short) == "unknown_id"
    bad_crc_and_range = hand_built_drive_inputs(1, 32767, 0, 0)
    bad_crc_and_range.data[0] ^= 0xFF
    assert kind_of(FrameValidator("TARGET"), bad_crc_and_range) == "crc"


def test_decode_any_has_no_counter_state():
    msg = FrameCodec("TARGET").encode("Timing3", {"Step": 7, "CpuLoad": 0.0123})
    first, again = decode_any(msg), decode_any(msg)
    assert first == again
    assert first.name == "Timing3" and first.signals == {"Step": 7, "CpuLoad": pytest.approx(0.0123)}
    with pytest.raises(FrameError) as info:
        decode_any(flipped(msg, 13))
    assert info.value.kind == "crc"


def test_frame_id_sets_partition_the_database():
    assert dbc.host_frame_ids().isdisjoint(dbc.target_frame_ids())
    assert dbc.host_frame_ids() | dbc.target_frame_ids() == {m.frame_id for m in DB.messages}
    assert dbc.frame_id("Status") == frame_id("Status") == 0x230
    assert set(dbc.FRAME_ERROR_KINDS) == {"unknown_id", "wrong_length", "crc", "counter", "out_of_range"}
    assert dbc.signal_ranges("DriveTemps") == {"Step": (0, 65535), "CoolantTemp": (-40, 150), "AmbientTemp": (-40, 150)}


def test_package_imports_nothing_beyond_numpy_python_can_and_cantools():
    code = (
        "import sys, dbc; "
        "print(sorted(m for m in ('scipy', 'control', 'matplotlib', 'bench', 'host', 'target_sim') "
        "if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert result.stdout.strip() == "[]"
