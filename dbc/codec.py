"""Encode and validate the frames of the bench's CAN contract, ``thermal_bench.dbc``: one codec for both nodes.

The host encodes drive and control frames with a :class:`FrameCodec` and checks the replies with a
:class:`FrameValidator`; the target does the reverse. Every frame carries an AUTOSAR E2E profile-2 header: byte 0
is a CRC8H2F (polynomial 0x2F) over bytes 1..7 followed by one data-id byte, and the low nibble of byte 1 is an
alive counter that the sender increments by one (mod 16) per message. The data id of a message is its
``E2EDataID`` attribute in the DBC (frame id AND 0xFF, unique per message), a simplification of profile 2's list
of 16 data ids.

Fast by construction: a lockstep round trip must stay well under 0.4 ms, and cantools' general encoder and
crccheck's CRC cost about 30 µs per frame. So each message's bit layout is precomputed from the DBC
(`dbc.database`), the CRC comes from a table, and cantools' own conversion objects do the scaling, so a frame is
byte-identical to what cantools encodes and a decoded frame has cantools' values and types (the tests compare
both over every message).
"""

from __future__ import annotations

import numbers
import struct
import time
from collections.abc import Mapping
from dataclasses import dataclass

import can

from dbc.contract import COUNTER_MODULO, DBC_PATH, FRAME_LENGTH, NODES, FrameError
from dbc.database import MessageLayout, SignalLayout, contract, layout_named

SignalValue = int | float

_POLY = 0x2F


def crc8h2f_table() -> tuple[int, ...]:
    """The CRC8H2F look-up table (polynomial 0x2F), also written into the firmware node (bench.firmware.nodegen)."""
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ _POLY) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_TABLE = crc8h2f_table()


def profile2_crc(payload: bytes, data_id: int) -> int:
    """AUTOSAR CRC8H2F (init 0xFF, xor-out 0xFF) over payload[1:] and the data id, as cantools computes it."""
    crc = 0xFF
    table = _TABLE
    for byte in payload[1:]:
        crc = table[crc ^ byte]
    return table[crc ^ data_id] ^ 0xFF


def apply_crc(frame_id: int, payload: bytes) -> bytes:
    """``payload`` (8 bytes) with byte 0 replaced by its E2E profile-2 CRC for message ``frame_id``."""
    layout = contract().by_id.get(frame_id)
    if layout is None:
        raise FrameError("unknown_id", f"frame 0x{frame_id:X} is not in {DBC_PATH.name}.")
    data = bytearray(payload)
    data[0] = profile2_crc(data, layout.data_id)
    return bytes(data)


@dataclass(slots=True)
class DecodedFrame:
    """A frame that passed validation; ``signals`` holds scaled values without the CRC and counter signals.

    Not frozen: one is made per received frame, and a frozen dataclass's construction costs four times as much."""

    name: str
    frame_id: int
    signals: dict[str, SignalValue]
    counter: int
    timestamp: float


def _check_node(node: str) -> str:
    if node not in NODES:
        raise ValueError(f"node {node!r} is not one of {', '.join(NODES)} in {DBC_PATH.name}.")
    return node


def _format_value(value: float, unit: str) -> str:
    return f"{value:.10g} {unit}".rstrip()


def _format_range(s: SignalLayout) -> str:
    return f"{s.minimum:.10g} to {s.maximum:.10g} {s.unit}".rstrip()


# ---------------------------------------------------------------------------------------------- encoding
def _raw_value(layout: MessageLayout, s: SignalLayout, value: SignalValue | str) -> int:
    """The bits signal `s` carries for `value` (FrameError("out_of_range") for what the DBC does not allow)."""
    if isinstance(value, str):
        if value not in s.choices:
            raise FrameError("out_of_range", f"signal {s.dbc_name} of message {layout.name} has no value named "
                             f"{value!r}" + (f"; use one of {', '.join(s.choices)}." if s.choices
                                             else "; give a number."))
        value = s.choices[value]
    # numpy scalars (np.float32 is no float) become Python numbers, as cantools takes them
    number: SignalValue = int(value) if isinstance(value, numbers.Integral) else float(value)
    if not s.low <= number <= s.high:  # also refuses NaN
        raise FrameError("out_of_range", f"signal {s.dbc_name} of message {layout.name} cannot carry "
                         f"{_format_value(float(number), s.unit)}, its range is {_format_range(s)}.")
    if s.ieee is not None:  # the bits of the IEEE value, as cantools packs a SIG_VALTYPE_ signal
        return struct.unpack(s.ieee[1], struct.pack(s.ieee[0], number))[0]
    raw = round((number - s.offset) / s.scale) if s.inline else s.conversion.numeric_scaled_to_raw(number)
    if s.signed:
        if not -(1 << (s.length - 1)) <= raw < (1 << (s.length - 1)):
            raise FrameError("out_of_range", f"message {layout.name} cannot be encoded: {s.dbc_name} raw value {raw} "
                             f"does not fit {s.length} signed bits.")
        return raw & s.mask
    if not 0 <= raw <= s.mask:
        raise FrameError("out_of_range", f"message {layout.name} cannot be encoded: {s.dbc_name} raw value {raw} does "
                         f"not fit {s.length} bits.")
    return raw


def _check_signal_set(layout: MessageLayout, signals: Mapping[str, object]) -> None:
    expected, given = layout.signal_names, set(signals)
    if given != expected:
        missing, unknown = sorted(expected - given), sorted(given - expected)
        raise ValueError(
            f"message {layout.name} needs exactly the signals {sorted(expected)}"
            + (f"; missing {missing}" if missing else "")
            + (f"; unknown {unknown}" if unknown else "")
            + "."
        )


class FrameCodec:
    """Encodes the messages one node sends, filling in alive counter and CRC (one instance per sending node)."""

    def __init__(self, sender: str) -> None:
        self.sender = _check_node(sender)
        self._next_counter: dict[int, int] = {}
        self._layouts: dict[str, MessageLayout] = {}    # the messages encoded so far (this node sends them)

    def reset_counters(self) -> None:
        """Restart every alive counter at 0 (receivers accept the first frame after their own reset only)."""
        self._next_counter.clear()

    def encode(self, name: str, signals: Mapping[str, SignalValue | str], *,
               timestamp: float | None = None) -> can.Message:
        """A classic 11-bit, DLC-8 frame of message ``name`` with the given application signals.

        ``signals`` holds every signal of the message except ``<name>_CRC`` and ``<name>_Counter``, in physical
        units; enum signals also take their value-table names. Values outside the DBC range raise
        FrameError("out_of_range") instead of wrapping, and a refused frame does not use up a counter value.
        """
        layout = self._layouts.get(name)
        if layout is None:
            layout = contract().by_name.get(name) or layout_named(name)
            if layout.sender != self.sender:
                raise FrameError("unknown_id", f"message {name} is sent by {layout.sender}, not by {self.sender}.")
            self._layouts[name] = layout
        if len(signals) != len(layout.packed):
            _check_signal_set(layout, signals)
        word = 0
        # the common case inline (a number in range); anything else through _raw_value, which also words the error
        for sig_name, start, length, signed, mask, conversion, low, high, inline, offset, scale, ieee in layout.packed:
            value = signals.get(sig_name)
            kind = type(value)
            if (kind is not float and kind is not int) or ieee is not None or not low <= value <= high:  # type: ignore
                if value is None:
                    _check_signal_set(layout, signals)
                word |= _raw_value(layout, layout.signal(sig_name), value) << start  # type: ignore[arg-type]
                continue
            raw = round((value - offset) / scale) if inline else conversion.numeric_scaled_to_raw(value)
            if signed:
                if not -(1 << (length - 1)) <= raw < (1 << (length - 1)):
                    raw = _raw_value(layout, layout.signal(sig_name), value)   # raises, in words
                word |= (raw & mask) << start
            elif 0 <= raw <= mask:
                word |= raw << start
            else:
                word |= _raw_value(layout, layout.signal(sig_name), value) << start  # raises, in words
        fid = layout.frame_id
        counter = self._next_counter.get(fid, 0)
        payload = bytearray((word | counter << 8).to_bytes(FRAME_LENGTH, "little"))
        payload[0] = profile2_crc(payload, layout.data_id)
        self._next_counter[fid] = (counter + 1) % COUNTER_MODULO
        return can.Message(timestamp=time.time() if timestamp is None else timestamp, arbitration_id=fid,
                           is_extended_id=False, dlc=FRAME_LENGTH, data=payload, check=False)


# ---------------------------------------------------------------------------------------------- decoding
def _layout_of(msg: can.Message, accepted: frozenset[int] | None) -> MessageLayout:
    """The message a frame claims to be, if it is a frame of the contract this node receives."""
    fid = msg.arbitration_id
    if msg.is_error_frame:
        raise FrameError("unknown_id", "an error frame is not a frame of the contract.")
    if msg.is_remote_frame:
        raise FrameError("unknown_id", f"remote frame 0x{fid:X} is not a frame of the contract.")
    if msg.is_extended_id:
        raise FrameError("unknown_id", f"extended frame 0x{fid:08X} is not a frame of the contract.")
    if msg.is_fd:
        raise FrameError("unknown_id", f"CAN FD frame 0x{fid:03X} is not a frame of the classic-CAN contract.")
    layout = contract().by_id.get(fid)
    if layout is None:
        raise FrameError("unknown_id", f"frame 0x{fid:03X} is not in {DBC_PATH.name}.")
    if accepted is not None and fid not in accepted:
        raise FrameError("unknown_id", f"{layout.label} is sent by {layout.sender} and not received here.")
    return layout


def _check_frame(msg: can.Message, accepted: frozenset[int] | None) -> tuple[MessageLayout, dict, int]:
    """Stateless checks in contract order: id, length, CRC, ranges. Returns (layout, signals, counter)."""
    layout = _layout_of(msg, accepted)
    data = msg.data
    if msg.dlc != FRAME_LENGTH or len(data) != FRAME_LENGTH:
        raise FrameError("wrong_length", f"{layout.label} has {len(data)} data bytes (DLC {msg.dlc}) instead of 8.")
    payload = bytes(data)
    expected_crc = profile2_crc(payload, layout.data_id)
    if payload[0] != expected_crc:
        raise FrameError("crc", f"{layout.label} has CRC 0x{payload[0]:02X} instead of 0x{expected_crc:02X}.")
    word = int.from_bytes(payload, "little")
    values: dict[str, SignalValue] = {}
    for name, start, mask, sign, wrap, scale, offset, conversion, low, high, ieee in layout.unpacked:
        raw = (word >> start) & mask
        if ieee is not None:
            value = struct.unpack(ieee[0], struct.pack(ieee[1], raw))[0]
        else:
            if raw & sign:
                raw -= wrap
            # cantools' own arithmetic where its conversion is that (`dbc.database`), without a call per signal
            value = raw * scale + offset if scale is not None else conversion.raw_to_scaled(raw, False)
        if not low <= value <= high:
            s = layout.signal(name)
            raise FrameError("out_of_range", f"{layout.label} carries {s.dbc_name} = "
                             f"{_format_value(float(value), s.unit)}, outside its range {_format_range(s)}.")
        values[name] = value
    return layout, values, payload[1] & 0x0F


def decode_any(msg: can.Message) -> DecodedFrame:
    """Decode any frame of the contract without counter state (for logs): checks id, length, CRC and ranges."""
    layout, signals, counter = _check_frame(msg, None)
    return DecodedFrame(layout.name, layout.frame_id, signals, counter, msg.timestamp)


class FrameValidator:
    """Checks received frames against the contract (one stateful instance per receiving node).

    Checks run in this order: id (extended, remote, error and FD frames are unknown too), DLC, CRC, signal
    ranges, alive counter. A rejected frame changes no state, so it counts as lost; the only exception is a
    counter error, after which the expected counter resynchronizes to the received one, so that one lost frame
    costs one error and not one per following frame.
    """

    def __init__(self, receiver: str | None = None) -> None:
        """``receiver`` ("HOST"/"TARGET") accepts only frames the other node sends; None accepts all frames."""
        self.receiver = None if receiver is None else _check_node(receiver)
        self._accepted: frozenset[int] | None = (
            None if receiver is None else frozenset(fid for fid, m in contract().by_id.items() if m.sender != receiver)
        )
        self._last_counter: dict[int, int] = {}

    def last_counter(self, fid: int) -> int | None:
        """The alive counter the next frame of `fid` is checked against (the last one received), or None."""
        return self._last_counter.get(fid)

    def reset_counters(self) -> None:
        """Forget every message's last counter: the next frame of each message is accepted with any counter."""
        self._last_counter.clear()

    def validate(self, msg: can.Message) -> DecodedFrame:
        """The decoded frame, or FrameError(kind, one-sentence message) if it must be rejected."""
        layout, signals, counter = _check_frame(msg, self._accepted)
        fid = layout.frame_id
        last = self._last_counter.get(fid)
        self._last_counter[fid] = counter
        if last is not None and counter != (last + 1) % COUNTER_MODULO:
            if counter == last:
                detail = f"repeats alive counter {counter}"
            else:
                detail = f"has alive counter {counter} after {last}, {(counter - last - 1) % 16} frame(s) lost"
            raise FrameError("counter", f"{layout.label} {detail}.")
        return DecodedFrame(layout.name, fid, signals, counter, msg.timestamp)
