"""Faster twins of `dbc.FrameCodec` and `dbc.FrameValidator` for the nodes' hot paths (same frames, same results).

A lockstep round trip must stay well under 0.4 ms, and cantools' general encoder and crccheck's CRC cost about
30 µs per frame. These subclasses precompute each message's bit layout from the same DBC, compute the E2E
profile-2 CRC8H2F with a table, and keep cantools' own conversion objects for scaling, so a frame comes out
byte-identical (encode) and a decoded frame has identical values and types (validate). Anything off the common
path — an enum given by name, a value out of range, a wrong signal set, and every frame that fails a check — is
handed to the parent class, so errors, their kinds and their messages are exactly the parent's. The tests
compare both paths over every message.
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Mapping

import can

from dbc import DecodedFrame, FrameCodec, FrameValidator, decode_any, load_database
from dbc.codec import COUNTER_MODULO, FRAME_LENGTH, SignalValue

_POLY = 0x2F


def _crc8h2f_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ _POLY) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_TABLE = _crc8h2f_table()


def profile2_crc(payload: bytes, data_id: int) -> int:
    """AUTOSAR CRC8H2F (init 0xFF, xor-out 0xFF) over payload[1:] and the data id, as cantools computes it."""
    crc = 0xFF
    table = _TABLE
    for byte in payload[1:]:
        crc = table[crc ^ byte]
    return table[crc ^ data_id] ^ 0xFF


_FLOAT_FORMATS = {32: ("<f", "<I"), 64: ("<d", "<Q")}


class _Layout:
    """One message: its application signals as (name, start, length, signed, mask, conversion, low, high, inline,
    offset, scale, is_float); an IEEE float signal (SIG_VALTYPE_) carries the bits of a float32 or float64."""

    def __init__(self, message, data_id: int, sender: str):
        self.name = message.name
        self.frame_id = message.frame_id
        self.data_id = data_id
        self.sender = sender
        crc_name, counter_name = f"{message.name}_CRC", f"{message.name}_Counter"
        self.signals = []
        for s in message.signals:
            if s.name in (crc_name, counter_name):
                continue
            if s.byte_order != "little_endian" or (s.conversion.is_float and s.length not in (32, 64)):
                raise ValueError(f"fast path supports Intel integer and IEEE float signals only "
                                 f"({message.name}.{s.name})")
            tolerance = abs(s.conversion.scale) * 1e-6
            low = -math.inf if s.minimum is None else float(s.minimum) - tolerance
            high = math.inf if s.maximum is None else float(s.maximum) + tolerance
            # cantools' scaled -> raw is round((value - offset) / scale) for these conversions; others are called
            inline = type(s.conversion).__name__ in ("IdentityConversion", "LinearConversion",
                                                     "NamedSignalConversion")
            self.signals.append((s.name, s.start, s.length, s.is_signed, (1 << s.length) - 1, s.conversion,
                                 low, high, inline, s.conversion.offset, s.conversion.scale,
                                 _FLOAT_FORMATS[s.length] if s.conversion.is_float else None))
        self.names = frozenset(entry[0] for entry in self.signals)


def _layouts() -> dict[int, _Layout]:
    out = {}
    for message in load_database().messages:
        data_id = int(message.dbc.attributes["E2EDataID"].value)
        out[message.frame_id] = _Layout(message, data_id, message.senders[0])
    return out


_LAYOUTS = _layouts()
_BY_NAME = {layout.name: layout for layout in _LAYOUTS.values()}


class FastFrameCodec(FrameCodec):
    """`FrameCodec` with a precomputed encoder; falls back to the parent for anything unusual."""

    def encode(self, name: str, signals: Mapping[str, SignalValue | str], *,
               timestamp: float | None = None) -> can.Message:
        layout = _BY_NAME.get(name)
        if layout is None or layout.sender != self.sender or len(signals) != len(layout.names):
            return super().encode(name, signals, timestamp=timestamp)
        word = 0
        for sig_name, start, length, signed, mask, conversion, low, high, inline, offset, scale, ieee in layout.signals:
            value = signals.get(sig_name)
            if value is None or isinstance(value, str):
                return super().encode(name, signals, timestamp=timestamp)
            number = float(value)
            if not low <= number <= high:  # also refuses NaN
                return super().encode(name, signals, timestamp=timestamp)
            if ieee is not None:  # the bits of the IEEE value, as cantools packs a SIG_VALTYPE_ signal
                word |= struct.unpack(ieee[1], struct.pack(ieee[0], number))[0] << start
                continue
            if inline:
                raw = round(((value if isinstance(value, int) else number) - offset) / scale)
            else:
                raw = conversion.numeric_scaled_to_raw(value if isinstance(value, int) else number)
            if signed:
                if not -(1 << (length - 1)) <= raw < (1 << (length - 1)):
                    return super().encode(name, signals, timestamp=timestamp)
                raw &= mask
            elif not 0 <= raw <= mask:
                return super().encode(name, signals, timestamp=timestamp)
            word |= raw << start
        fid = layout.frame_id
        counter = self._next_counter.get(fid, 0)
        word |= counter << 8
        payload = bytearray(word.to_bytes(FRAME_LENGTH, "little"))
        payload[0] = profile2_crc(payload, layout.data_id)
        self._next_counter[fid] = (counter + 1) % COUNTER_MODULO
        return can.Message(timestamp=time.time() if timestamp is None else timestamp, arbitration_id=fid,
                           is_extended_id=False, dlc=FRAME_LENGTH, data=payload, check=False)


def _fast_decode(msg: can.Message, accepted: frozenset[int] | None) -> tuple[_Layout, dict, int] | None:
    """(layout, signals, counter) of a frame that passes every stateless check, else None."""
    fid = msg.arbitration_id
    layout = _LAYOUTS.get(fid)
    if (layout is None or msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame or msg.is_fd
            or (accepted is not None and fid not in accepted) or msg.dlc != FRAME_LENGTH
            or len(msg.data) != FRAME_LENGTH):
        return None
    payload = bytes(msg.data)
    if payload[0] != profile2_crc(payload, layout.data_id):
        return None
    word = int.from_bytes(payload, "little")
    values: dict[str, SignalValue] = {}
    for sig_name, start, length, signed, mask, conversion, low, high, *_, ieee in layout.signals:
        raw = (word >> start) & mask
        if ieee is not None:
            value = struct.unpack(ieee[0], struct.pack(ieee[1], raw))[0]
        else:
            if signed and raw >> (length - 1):
                raw -= 1 << length
            value = conversion.raw_to_scaled(raw, False)
        if not low <= value <= high:
            return None
        values[sig_name] = value
    return layout, values, payload[1] & 0x0F


def fast_decode_any(msg: can.Message) -> DecodedFrame:
    """`dbc.decode_any` (stateless: id, length, CRC, ranges), faster for frames that pass."""
    decoded = _fast_decode(msg, None)
    if decoded is None:
        return decode_any(msg)
    layout, values, counter = decoded
    return DecodedFrame(layout.name, layout.frame_id, values, counter, msg.timestamp)


class FastFrameValidator(FrameValidator):
    """`FrameValidator` with a precomputed decoder for frames that pass; the parent judges every other frame."""

    def validate(self, msg: can.Message) -> DecodedFrame:
        decoded = _fast_decode(msg, self._accepted)
        if decoded is None:
            return super().validate(msg)
        layout, values, counter = decoded
        fid = layout.frame_id
        last = self._last_counter.get(fid)
        if last is not None and counter != (last + 1) % COUNTER_MODULO:
            return super().validate(msg)
        self._last_counter[fid] = counter
        return DecodedFrame(layout.name, fid, values, counter, msg.timestamp)
