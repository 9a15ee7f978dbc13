"""Issue 39: a checkpoint is keyed by the row its 16-bit Step names, not by the Step itself. In a log longer than
65 536 rows two checkpoints share a Step; they are two checkpoints of the target, neither contested by the other,
in the host's checks (`host.session.HostSession`) and in the log analysis (`bench.analysis.logdecode`)."""

from __future__ import annotations

import can
import pytest

from bench.analysis.logdecode import decode_log
from dbc import FrameCodec, TargetState
from dbc.contract import STEP_MODULO, step_of
from host.replay import encode_row
from host.session import HostSession

from helpers import session_start, write_frames

FIRST = 99                      # a checkpoint's row; the second is one Step wrap later, at the same Step
SECOND = FIRST + STEP_MODULO
ROWS = SECOND + 30


def _state_checkpoint(codec: FrameCodec, row: int, state: list[float]) -> list[can.Message]:
    """The elements of `state` (fewer than four: a checkpoint whose last elements never came)."""
    return [codec.encode("StateCheckpoint", {"Step": step_of(row), "StateIndex": i, "StateValue": v})
            for i, v in enumerate(state)]


def _observer_checkpoint(codec: FrameCodec, row: int, values: list[float]) -> list[can.Message]:
    return [codec.encode("ObserverCheckpoint", {"StepLow": step_of(row) % 4096, "Index": i, "Value": v})
            for i, v in enumerate(values)]


def test_the_log_analysis_keeps_two_checkpoints_of_one_step_apart(tmp_path):
    """A synthetic log (the host's rows and the target's Status and checkpoints, encoded with the DBC): the
    checkpoints of rows 99 and 65 635 carry other states and filters, and nothing is contested."""
    host, target = FrameCodec("HOST"), FrameCodec("TARGET")
    running = {"State": int(TargetState.RUNNING), "FaultBits": 0, "ModelId": 1, "DbcVersionMajor": 1,
               "DbcVersionMinor": 8}
    frames = [*session_start(host), target.encode("Status", running)]
    for row in range(ROWS):
        frames += encode_row(host, row, [10.0, 1000.0, 40.0, 25.0])
        if row in (FIRST, SECOND):
            offset = float(row == SECOND)
            frames += _state_checkpoint(target, row, [50.0 + offset, 51.0, 52.0, 53.0])
            frames += _observer_checkpoint(target, row, [1.0 + offset, 2.0])
    record = decode_log(write_frames(tmp_path / "long.blf", frames))
    assert record.rows == ROWS and record.rejected == {}
    assert record.foreign == {}, "two checkpoints 65 536 rows apart contest each other"


@pytest.fixture
def session():
    bus = can.Bus(interface="virtual", channel="checkpoint-wrap", receive_own_messages=False)
    yield HostSession(bus)
    bus.shutdown()


def test_the_host_keeps_two_checkpoints_of_one_step_apart(session):
    """A checkpoint of row 99 that never completed (a lost element) does not contest the checkpoint of row
    65 635, one Step wrap later, nor keeps it from being restored from."""
    codec = FrameCodec("TARGET")
    session.last_sent_row = FIRST
    for msg in _state_checkpoint(codec, FIRST, [50.0, 51.0, 52.0]):    # its last element never came
        session.accept(msg)
    session.last_sent_row = SECOND
    for msg in _state_checkpoint(codec, SECOND, [60.0, 61.0, 62.0, 63.0]):
        session.accept(msg)
    assert session.contested_checkpoints == set()
    assert session.last_checkpoint(SECOND + 1) == (SECOND, [60.0, 61.0, 62.0, 63.0])
