"""Drop a node's own udp_multicast frames in the kernel, before they wake it and cost it a python-can `recv`.

udp_multicast hands every frame back to the socket that sent it (multicast loopback, which is also how the other
processes of this machine hear it), and a node reads and discards each such copy in Python (`OwnFrameFilter`):
in lockstep the target sends about 3.3 frames a row and read back as many, about a fifth of its time a row. A
classic BPF socket filter (Linux `SO_ATTACH_FILTER`, on the socket python-can's public `BusABC.fileno()` names)
drops them instead: a datagram that is python-can's udp_multicast encoding of a standard, non-error frame with
one of the given ids. Its encoding (`can.interfaces.udp_multicast`: a msgpack map whose first keys are
"timestamp" (a float64), "arbitration_id", "is_extended_id", "is_remote_frame", "is_error_frame") is checked
byte for byte, key names too; a datagram of any other layout is let through, so `OwnFrameFilter` still decides
everything that reaches Python and a python-can that encodes otherwise only loses the speed, never a frame.

Only for a node that must never hear these ids from anyone (the target: its own ids are the target's; another
target on the channel is refused before it serves, `target_sim.node.target_on_channel`). A host does not use it:
its `SenderGuard` must see its own copies to tell another host's frames from them.
"""

from __future__ import annotations

import ctypes
import os
import socket
import sys
from collections.abc import Iterable

import can
from can.interfaces.udp_multicast import UdpMulticastBus

SO_ATTACH_FILTER = 26      # Linux <asm-generic/socket.h>; the socket module does not name it
UDP_HEADER = 8             # a UDP socket's filter sees the datagram from its UDP header on

# classic BPF opcodes (linux/filter.h)
_LD_W, _LD_H, _LD_B = 0x20, 0x28, 0x30          # BPF_LD | BPF_ABS | size
_JEQ, _JGE = 0x15, 0x35                          # BPF_JMP | BPF_J* | BPF_K
_LD_LEN = 0x80                                   # BPF_LD | BPF_W | BPF_LEN
_RET = 0x06                                      # BPF_RET | BPF_K
ACCEPT, DROP = 0xFFFF_FFFF, 0

MSGPACK_FALSE, MSGPACK_FLOAT64, MSGPACK_UINT8, MSGPACK_UINT16 = 0xC2, 0xCB, 0xCC, 0xCD
MAP_OF_11 = 0x8B           # pack_message's map has eleven entries


def _key(name: str) -> bytes:
    """A msgpack fixstr key."""
    return bytes([0xA0 | len(name)]) + name.encode()


class _Program:
    """A classic BPF program built forward, with labels for its jumps (cBPF jumps only forward, up to 255)."""

    def __init__(self) -> None:
        self.code: list[list] = []     # [opcode, jt, jf, k]; jt/jf may be a label until `resolve`
        self.labels: dict[str, int] = {}

    def load_length(self) -> None:
        self.code.append([_LD_LEN, 0, 0, 0])

    def load(self, offset: int, size: int) -> None:
        self.code.append([{4: _LD_W, 2: _LD_H, 1: _LD_B}[size], 0, 0, offset])

    def jump(self, op: int, k: int, true, false) -> None:
        self.code.append([op, true, false, k])

    def ret(self, value: int) -> None:
        self.code.append([_RET, 0, 0, value])

    def label(self, name: str) -> None:
        self.labels[name] = len(self.code)

    def expect(self, offset: int, data: bytes, otherwise: str) -> None:
        """Go on when the payload holds `data` at `offset`, else jump to `otherwise`."""
        at = 0
        while at < len(data):
            size = 4 if len(data) - at >= 4 else 2 if len(data) - at >= 2 else 1
            self.load(UDP_HEADER + offset + at, size)
            self.jump(_JEQ, int.from_bytes(data[at:at + size], "big"), 0, otherwise)
            at += size

    def resolve(self) -> list[tuple[int, int, int, int]]:
        out = []
        for index, (op, jt, jf, k) in enumerate(self.code):
            jt, jf = (self.labels[j] - index - 1 if isinstance(j, str) else j for j in (jt, jf))
            if not (0 <= jt <= 255 and 0 <= jf <= 255):
                raise ValueError("a BPF jump too far")
            out.append((op, jt, jf, k))
        return out


ID_AT = 1 + len(_key("timestamp")) + 9 + len(_key("arbitration_id"))   # the id's first byte in the payload
# the last byte the filter reads (a uint16 id): is_error_frame's value, and how long a payload must be to hold it
SHORTEST = ID_AT + 3 + len(_key("is_extended_id")) + 1 + len(_key("is_remote_frame")) + 1 \
    + len(_key("is_error_frame")) + 1
MAX_IDS = 48               # every id is one instruction per branch; cBPF jumps reach 255 instructions ahead


def own_frames_program(own_ids: Iterable[int]) -> list[tuple[int, int, int, int]]:
    """The filter: DROP python-can's encoding of a standard, non-error frame with an id in `own_ids`, else ACCEPT."""
    ids = sorted({int(i) for i in own_ids})
    if not ids or len(ids) > MAX_IDS or min(ids) < 0 or max(ids) > 0x7FF:
        raise ValueError(f"own ids must be 1 to {MAX_IDS} standard (11-bit) ids")
    p = _Program()
    p.load_length()                               # a load past the end would drop the datagram: check first
    p.jump(_JGE, UDP_HEADER + SHORTEST, 0, "accept")
    p.expect(0, bytes([MAP_OF_11]) + _key("timestamp") + bytes([MSGPACK_FLOAT64]), "accept")
    p.expect(1 + len(_key("timestamp")) + 9, _key("arbitration_id"), "accept")
    p.load(UDP_HEADER + ID_AT, 1)
    p.jump(_JGE, 0x80, 0, "fixint")              # a positive fixint (< 0x80) is the id itself
    p.jump(_JEQ, MSGPACK_UINT8, "uint8", 0)
    p.jump(_JEQ, MSGPACK_UINT16, "uint16", "accept")
    for name, value_at, size in (("fixint", ID_AT, 1), ("uint8", ID_AT + 1, 1), ("uint16", ID_AT + 1, 2)):
        p.label(name)
        after = value_at + size                   # the next key: is_extended_id, is_remote_frame, is_error_frame
        extended = after + len(_key("is_extended_id"))
        remote = extended + 1 + len(_key("is_remote_frame"))
        error = remote + 1 + len(_key("is_error_frame"))
        p.expect(after, _key("is_extended_id"), "accept")
        p.expect(extended, bytes([MSGPACK_FALSE]), "accept")
        p.expect(extended + 1, _key("is_remote_frame"), "accept")
        p.expect(remote + 1, _key("is_error_frame"), "accept")
        p.expect(error, bytes([MSGPACK_FALSE]), "accept")
        p.load(UDP_HEADER + value_at, size)
        for own in ids:
            p.jump(_JEQ, own, "drop", 0)
        p.ret(ACCEPT)
    p.label("drop")
    p.ret(DROP)
    p.label("accept")
    p.ret(ACCEPT)
    return p.resolve()


class _SockFilter(ctypes.Structure):
    _fields_ = [("code", ctypes.c_uint16), ("jt", ctypes.c_uint8), ("jf", ctypes.c_uint8), ("k", ctypes.c_uint32)]


class _SockFprog(ctypes.Structure):
    _fields_ = [("len", ctypes.c_uint16), ("filter", ctypes.POINTER(_SockFilter))]


def drop_own_frames(bus: can.BusABC, own_ids: Iterable[int]) -> bool:
    """Attach the filter to a udp_multicast bus's socket (Linux); whether it is attached. Anything else (another
    interface, another system, a socket that refuses it) is left as it was: the node filters in Python as before."""
    if not sys.platform.startswith("linux") or not isinstance(bus, UdpMulticastBus):
        return False
    program = own_frames_program(own_ids)
    instructions = (_SockFilter * len(program))(*program)
    fprog = _SockFprog(len(program), ctypes.cast(instructions, ctypes.POINTER(_SockFilter)))
    try:
        with socket.socket(fileno=os.dup(bus.fileno())) as sock:   # the same socket; closing the copy keeps it
            sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, bytes(fprog))
    except (OSError, ValueError):
        return False
    return True
