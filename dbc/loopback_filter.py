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

`drop_own_frames` is only for a node that must never hear these ids from anyone (the target: its own ids are the
target's; another target on the channel is refused before it serves, `target_sim.node.target_on_channel`). A host
must still hear another host's frames (`dbc.transport.SenderGuard`): it sends from a socket of its own instead
(`UnechoedSender`), whose datagrams its bus's socket drops by their source port.
"""

from __future__ import annotations

import ctypes
import os
import socket
import sys
from collections.abc import Iterable

import can
from can.interfaces.udp_multicast import UdpMulticastBus
from can.interfaces.udp_multicast.utils import pack_message

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
    return _attach(bus, own_frames_program(own_ids))


def own_port_program(port: int) -> list[tuple[int, int, int, int]]:
    """The filter: DROP a datagram whose UDP source port is `port`, else ACCEPT."""
    p = _Program()
    p.load(0, 2)                                  # the UDP header's source port
    p.jump(_JEQ, port, "drop", 0)
    p.ret(ACCEPT)
    p.label("drop")
    p.ret(DROP)
    return p.resolve()


def _attach(bus: can.BusABC, program: list[tuple[int, int, int, int]]) -> bool:
    instructions = (_SockFilter * len(program))(*program)
    fprog = _SockFprog(len(program), ctypes.cast(instructions, ctypes.POINTER(_SockFilter)))
    try:
        with socket.socket(fileno=os.dup(bus.fileno())) as sock:   # the same socket; closing the copy keeps it
            sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, bytes(fprog))
    except (OSError, ValueError):
        return False
    return True


class UnechoedSender:
    """Sends a udp_multicast bus's frames from a socket of its own, whose copies the bus's socket drops in the kernel.

    For a node that must tell its own frames from another node's of the same ids (a host's `SenderGuard`): the
    bus's own socket sends from the group's port, as every python-can node does, so nothing tells its frames from
    another node's there; this socket sends from a port of its own (bound to port 0: one the kernel has free), and
    the bus's socket drops the datagrams from that port (a classic BPF filter on the UDP source port). What goes out
    is python-can's own encoding (`can.interfaces.udp_multicast.utils.pack_message`) to the same group and port,
    so every other node hears the same datagrams. `attach` returns None where this cannot be set up (not Linux,
    not udp_multicast, a socket that refuses it): the node then sends through the bus and drops its copies itself.
    """

    def __init__(self, sock: socket.socket, destination: tuple[str, int]) -> None:
        self.sock = sock
        self.destination = destination

    @classmethod
    def attach(cls, bus: can.BusABC, group: str, port: int, hop_limit: int = 1) -> UnechoedSender | None:
        if not sys.platform.startswith("linux") or not isinstance(bus, UdpMulticastBus):
            return None
        try:
            family = socket.getaddrinfo(group, port, type=socket.SOCK_DGRAM)[0][0]
            sock = socket.socket(family, socket.SOCK_DGRAM)
        except OSError:
            return None
        try:
            hops = hop_limit.to_bytes(4, sys.byteorder)       # python-can's setting: struct "@I"
            if family == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS, hops)
            else:
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, hops)
            sock.bind(("", 0))
            if _attach(bus, own_port_program(sock.getsockname()[1])):
                return cls(sock, (group, port))
        except OSError:
            pass
        sock.close()
        return None

    def send(self, msg: can.Message) -> None:
        data = pack_message(msg)
        try:
            sent = self.sock.sendto(data, self.destination)
        except OSError as error:
            raise can.CanOperationError("failed to send via socket") from error
        if sent < len(data):
            raise can.CanOperationError("the frame's datagram went out incomplete")

    def close(self) -> None:
        self.sock.close()
