"""A host stopped in the middle of sending a row (SIGSTOP between two of its frames) logs the target's heartbeats
of the pause at the times they came, not all at once after the pause.

The log makes its times non-decreasing: a frame the host stamped after the pause and logged before it read the
heartbeats that waited in its socket moved those heartbeats to its own time, a silence of the pause's length in
the log (a heartbeat loss in the report, though the target never stopped; CI saw 2.003 s of a 2 s SIGSTOP). The
pause here is a wait inside the bus's send of the row's first frame, while the target's Status frames come, each
stamped when it came, as python-can's udp_multicast (SO_TIMESTAMPNS) and virtual buses stamp them."""

from __future__ import annotations

import time

import can
import pytest
from can.interfaces.virtual import VirtualBus

from dbc import FrameCodec
from dbc.database import frame_id
from host.canlog import FrameLog
from host.replay import encode_row
from host.session import HOST_PAUSE_S, HostSession

BEATS = 4                          # heartbeats while the host is stopped
BEAT_S = HOST_PAUSE_S / 2          # so the pause (BEATS * BEAT_S) is twice what the host takes for one
STATUS = {"State": 2, "FaultBits": 0, "ModelId": 1, "DbcVersionMajor": 1, "DbcVersionMinor": 0}


class StoppedInSendBus(VirtualBus):
    """A virtual bus whose host is stopped once, inside the send of `stop_in`, while `target` sends heartbeats."""

    def __init__(self, channel: str, target: can.BusABC, stop_in: int):
        super().__init__(channel=channel)
        self.target, self.stop_in, self.beats_sent = target, stop_in, []   # (before, after) each Status's send
        self.codec = FrameCodec("TARGET")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        super().send(msg, timeout)
        if msg.arbitration_id == self.stop_in and not self.beats_sent:
            for _ in range(BEATS):   # the host does nothing meanwhile: it is stopped
                time.sleep(BEAT_S)
                before = time.time()
                self.target.send(self.codec.encode("Status", STATUS))
                self.beats_sent.append((before, time.time()))


@pytest.mark.parametrize("stop_in", ["DriveInputs", "DriveTemps"])
def test_heartbeats_that_came_while_the_host_was_stopped_keep_their_times(tmp_path, stop_in):
    channel = f"paused-send-{stop_in}"
    target = can.Bus(interface="virtual", channel=channel)
    bus = StoppedInSendBus(channel, target, frame_id(stop_in))
    log = FrameLog(tmp_path / "x.log")
    try:
        session = HostSession(bus, log=log)
        session.send(encode_row(FrameCodec("HOST"), 0, [10.0, 1000.0, 40.0, 25.0]))
        session.flush_log()
        session.send(encode_row(FrameCodec("HOST"), 1, [10.0, 1000.0, 40.0, 25.0]))
        session.flush_log()
    finally:
        log.close()
        bus.shutdown()
        target.shutdown()
    logged = [m for m in can.LogReader(str(tmp_path / "x.log"))]
    beats = [m.timestamp for m in logged if m.arbitration_id == frame_id("Status")]
    assert len(beats) == BEATS
    # each one logged at the time it came (the bus stamped it in the target's send), not when the host read it
    # (the .log format keeps microseconds)
    for came, (before, after) in zip(beats, bus.beats_sent, strict=True):
        assert before - 1e-6 <= came <= after + 1e-6
    # the log's order is the bus's: the row's frames sent after the pause come after the heartbeats
    assert [m.timestamp for m in logged] == sorted(m.timestamp for m in logged)
    host_after = [m.timestamp for m in logged if m.arbitration_id != frame_id("Status") and m.timestamp > beats[0]]
    assert host_after and min(host_after) >= beats[-1]
