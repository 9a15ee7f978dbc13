"""Issue 39: a tiny reply deadline with faults flooded the udp bus. The lockstep replay retransmits an unanswered row
every RETRY_FACTOR reply timeouts; at a 10 µs deadline that was every 40 µs, so each row went out ~25 times over
before a target answering in milliseconds got a word in (`bench run --reply-timeout 0.00001 --faults ...`: 4 932
RETRANSMIT marks and 40 933 frames for 200 rows, counter rejections of the target's frames). The deadline is still
judged as given; a retransmission waits at least RETRY_MIN_S."""

from __future__ import annotations

import threading
import time

import can
import numpy as np

from dbc import FrameCodec, TargetState
from host.faults import FaultyBus, parse_faults
from host.faults.lockstep import RETRY_MIN_S, FaultLockstep
from host.faults.plan import FaultPlan
from host.session import HostSession

ANSWER_AFTER_S = 0.2       # the stand-in target answers the row this long after the retransmissions start


def _stand_in_target(bus: can.BusABC, started: float, stop: threading.Event) -> None:
    """Heartbeats (RUNNING) every 50 ms; row 0's replies once ANSWER_AFTER_S has passed."""
    codec, answered = FrameCodec("TARGET"), False
    status = {"State": int(TargetState.RUNNING), "FaultBits": 0, "ModelId": 1, "DbcVersionMajor": 1,
              "DbcVersionMinor": 8}
    while not stop.is_set():
        bus.send(codec.encode("Status", status))
        if not answered and time.perf_counter() - started >= ANSWER_AFTER_S:
            bus.send(codec.encode("Temperatures1", {"Step": 0, "WindingTemp": 45.0, "MagnetTemp": 50.0}))
            bus.send(codec.encode("Temperatures2", {"Step": 0, "YokeTemp": 40.0, "ToothTemp": 41.0}))
            answered = True
        stop.wait(0.05)


def test_a_tiny_deadline_retransmits_no_sooner_than_the_floor():
    host_bus = can.Bus(interface="virtual", channel="retransmission", receive_own_messages=False)
    target_bus = can.Bus(interface="virtual", channel="retransmission", receive_own_messages=False)
    reply_timeout_s = 1e-5
    plan = FaultPlan(parse_faults(["drop=0.01"]), 4)
    faulty = FaultyBus(host_bus, plan, delay_s=1.5 * reply_timeout_s)
    session = HostSession(faulty)
    lockstep = FaultLockstep(session, np.tile([100.0, 2000.0, 40.0, 25.0], (4, 1)), [40.0, 45.0, 41.0, 50.0],
                             faulty=faulty, plan=plan, control=None, reply_timeout_s=reply_timeout_s,
                             connect_timeout_s=5.0, abort_after=100)
    session.last_sent_row = 0
    stop = threading.Event()
    started = time.perf_counter()
    target = threading.Thread(target=_stand_in_target, args=(target_bus, started, stop), daemon=True)
    target.start()
    try:
        outcome = lockstep._retry(0, 0)
        elapsed = time.perf_counter() - started
    finally:
        stop.set()
        target.join(5)
        host_bus.shutdown()
        target_bus.shutdown()
    assert outcome == "answered"
    rounds = int(lockstep.fault_run.sends[0]) // 2          # each round sends the row twice
    assert rounds <= elapsed / RETRY_MIN_S + 1, (rounds, elapsed)
