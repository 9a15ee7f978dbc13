"""udp_multicast without reading one's own copies (`dbc.loopback_filter`) and the leaner receive (`dbc.udp_bus`):
the kernel drops exactly the frames it should, everything else arrives as python-can's own bus delivers it."""

import sys
import time

import can
import pytest

from dbc.loopback_filter import MAX_IDS, drop_own_frames, own_frames_program
from dbc.transport import BusConfig, SenderGuard
from dbc.udp_bus import LeanUdpMulticastBus

from helpers import private_udp_bus

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="socket filters are Linux's")


def _drain(bus, quiet_s: float = 0.1) -> list[can.Message]:
    got = []
    while (msg := bus.recv(quiet_s)) is not None:
        got.append(msg)
    return got


def _frames() -> list[can.Message]:
    """Standard ids of every msgpack integer width (fixint, uint8, uint16), an extended one with an own id's number
    and an error frame with one."""
    frames = [can.Message(arbitration_id=i, data=bytes([i & 0xFF] * 8), is_extended_id=False)
              for i in (0x7F, 0x7E, 0xFF, 0xFE, 0x220, 0x221, 0x7FF)]
    frames.append(can.Message(arbitration_id=0x220, data=bytes(8), is_extended_id=True))
    frames.append(can.Message(arbitration_id=0x220, is_error_frame=True, is_extended_id=False))
    return frames


def test_the_kernel_drops_the_standard_frames_of_the_own_ids_and_nothing_else():
    config = private_udp_bus()
    node, other = config.open(), config.open()
    try:
        assert drop_own_frames(node, {0x7F, 0xFF, 0x220, 0x7FF})
        for frame in _frames():
            node.send(frame)              # its own copies: dropped when the id is its own
            other.send(frame)             # and another sender's frames of those ids: dropped too (the target's rule)
        got = [(m.arbitration_id, m.is_extended_id, m.is_error_frame) for m in _drain(node)]
        kept = [(0x7E, False, False), (0xFE, False, False), (0x221, False, False), (0x220, True, False),
                (0x220, False, True)]
        assert sorted(got) == sorted(kept * 2)
        assert len(_drain(other)) == 2 * len(_frames())      # the other socket has no filter: it hears all
    finally:
        node.shutdown()
        other.shutdown()


def test_own_ids_are_standard_ids_within_the_programs_reach():
    for ids in (set(), {0x800}, {-1}, set(range(MAX_IDS + 1))):
        with pytest.raises(ValueError, match="standard"):
            own_frames_program(ids)


def test_other_buses_are_left_as_they_were():
    bus = BusConfig("virtual", channel=f"filter-{time.monotonic_ns()}").open()
    try:
        assert not drop_own_frames(bus, {0x220})
        guard = SenderGuard(bus, BusConfig("virtual"), {0x100})
        assert guard.unechoed is None
    finally:
        bus.shutdown()


def test_the_lean_receive_gives_what_python_cans_bus_gives():
    config = private_udp_bus()
    lean = config.open()
    plain = config.open(lean=False)      # python-can's own bus, as the sitting's ping-pong opens it
    sender = can.Bus(interface="udp_multicast", channel=config.channel, **config.kwargs)
    try:
        assert isinstance(lean, LeanUdpMulticastBus)
        assert type(plain) is not LeanUdpMulticastBus and isinstance(plain, can.BusABC)
        assert lean.recv(0.0) is None and lean.recv(0.05) is None     # nothing there: None, polled or waited for
        before = time.time()
        frames = _frames() + [can.Message(arbitration_id=0x123, data=bytes(range(12)), is_fd=True, dlc=12)]
        for frame in frames:
            sender.send(frame)
        got, expected = _drain(lean), _drain(plain)
        fields = ("arbitration_id", "is_extended_id", "is_error_frame", "is_fd", "dlc", "data", "is_remote_frame")
        assert [[getattr(m, f) for f in fields] for m in got] == [[getattr(m, f) for f in fields] for m in expected]
        assert len(got) == len(frames)
        assert all(before - 1.0 < m.timestamp < time.time() + 1.0 for m in got)   # the kernel's receive time
    finally:
        for bus in (lean, plain, sender):
            bus.shutdown()
