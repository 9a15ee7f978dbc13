"""Issue 39: checkpoint and measurement frames get the checks every other frame gets (E2E CRC, alive counter,
forged and replayed frames detected and counted, never a silent difference).

* A replayed Measurements frame (an old frame of the host's sent again by another node): the target's counter
  check refuses it and the genuine frame after it, and so does the log analysis (`bench.analysis.logdecode`):
  both counted, the rows without those readings predict only on both sides (CAN = the float32 reference), and the
  run's problems say so.
* Forged ObserverCheckpoint frames (valid CRC, the target's own next alive counter, other values) ahead of the
  genuine ones: the host's checks reject the genuine frames for repeating the counter, so the checkpoint is
  *contested*: the host (`host.session.HostSession`) never restores from it, and a restore from it (a host that
  did) or from a state the target never sent is found by the log analysis, its rows left out of every figure and
  named in the problems.
"""

from __future__ import annotations

import struct

import can
import numpy as np
import pytest

from bench.analysis.canmetrics import compute
from bench.analysis.logdecode import decode_log
from bench.analysis.report import render_markdown
from bench.analysis.verdict import problems
from dbc import BenchEvent, Command, FaultKind, FrameCodec, decode_any
from dbc.codec import apply_crc
from dbc.contract import step_of
from dbc.database import frame_id
from host.replay import encode_row
from host.session import HostSession
from target_sim.artifact import load_artifact
from target_sim.node import TargetNode

from helpers import SESSION_INITIAL, session_drive, write_frames

ROWS = 160
RESTART_AT = 120          # the target is lost after this row and restored from its first checkpoint


@pytest.fixture(scope="module")
def observer(observer_artifact):
    return load_artifact(observer_artifact)


def _measured(artifact, values: np.ndarray) -> np.ndarray:
    """A winding sensor column that reads the model's own winding + 0.5 K (its updates do something)."""
    from target_sim.model import run_offline

    rows, outputs = run_offline(artifact, values, SESSION_INITIAL)
    winding = np.interp(np.arange(len(values)), rows, outputs[:, 1]) + 0.5
    return np.column_stack([winding, np.full(len(values), np.nan)])


class Session:
    """A lockstep session with a Python target in-process, every frame as the host logs it, and the host's own
    checks of the target's frames (a `HostSession` fed each one, as it would receive them)."""

    def __init__(self, artifact, values, measured):
        self.artifact, self.values, self.measured = artifact, values, measured
        self.node, self.codec = TargetNode(artifact, clock_ns=lambda: 0), FrameCodec("HOST")
        self.host = HostSession(can.Bus(interface="virtual", channel="checks", receive_own_messages=False))
        self.frames: list[can.Message] = list(self.node.startup_frames())
        self.forge_checkpoint = self.duplicate_checkpoint = False
        self.forged: set[int] = set()      # id() of the forged frames

    def send(self, messages) -> None:
        for message in messages:
            self.frames.append(message)
            for reply in self.node.handle(message):
                if self.duplicate_checkpoint and reply.arbitration_id == frame_id("ObserverCheckpoint"):
                    self._receive(reply)                  # a copy of the genuine frame: harmless
                if self.forge_checkpoint and reply.arbitration_id == frame_id("ObserverCheckpoint"):
                    fake = forged(reply)              # the forger's frame comes first, with the same counter
                    self.forged.add(id(fake))
                    self._receive(fake)
                self._receive(reply)

    def _receive(self, frame: can.Message) -> None:
        self.frames.append(frame)
        self.host.accept(frame)

    def start(self, initial=SESSION_INITIAL) -> None:
        yoke, winding, tooth, magnet = initial
        self.send([self.codec.encode("ResetTemps1", {"Step": 0, "WindingTempInit": winding,
                                                     "MagnetTempInit": magnet}),
                   self.codec.encode("ResetTemps2", {"Step": 0, "YokeTempInit": yoke, "ToothTempInit": tooth}),
                   self.codec.encode("Control", {"Command": int(Command.RESET), "Step": 0}),
                   self.codec.encode("Control", {"Command": int(Command.START), "Step": 0})])

    def row(self, row: int) -> list[can.Message]:
        self.host.last_sent_row = row
        frames = encode_row(self.codec, row, self.values[row].tolist(), self.measured[row].tolist())
        self.send(frames)
        if row % 25 == 0:
            for frame in self.node.heartbeat_frames():
                self._receive(frame)
        return frames

    def mark(self, event: BenchEvent, row: int) -> None:
        self.frames.append(self.codec.encode("BenchEvent", {"Step": step_of(row), "Event": int(event),
                                                            "FaultKind": int(FaultKind.NONE), "FrameId": 0}))

    def restart_and_restore(self, row: int, state, observer: dict[int, float]) -> None:
        """The target lost after `row`: a fresh target process, restored to `state` and `observer` at the row after
        the checkpoint's interval, as the host's recovery does (TARGET-LOST, REINIT, RestoreState, RestoreObserver,
        RESTORE, START)."""
        self.mark(BenchEvent.TARGET_LOST, row + 1)
        self.host.validator.reset_counters()           # as the host's recovery does
        self.node = TargetNode(self.artifact, clock_ns=lambda: 0)
        for frame in self.node.startup_frames():
            self._receive(frame)
        start = self.restore_row
        self.mark(BenchEvent.REINIT, start)
        step = step_of(start)
        self.send([*(self.codec.encode("RestoreState", {"Step": step, "StateIndex": i, "StateValue": v})
                     for i, v in enumerate(state)),
                   *(self.codec.encode("RestoreObserver", {"Index": i, "StepLow": step % 4096, "Value": v})
                     for i, v in sorted(observer.items())),
                   self.codec.encode("Control", {"Command": int(Command.RESTORE), "Step": step}),
                   self.codec.encode("Control", {"Command": int(Command.START), "Step": step})])

    def stop(self) -> None:
        self.send([self.codec.encode("Control", {"Command": int(Command.STOP), "Step": 0})])
        for frame in self.node.heartbeat_frames():
            self._receive(frame)
        self.host.bus.shutdown()

    def first_checkpoint(self) -> tuple[int, list[float], dict[int, float], dict[int, float]]:
        """(its row, the state the target sent, the filter elements it sent, the filter elements the host's checks
        accepted) of the first checkpoint in the log."""
        state, sent, accepted, step = {}, {}, {}, None
        for frame in self.frames:
            if frame.arbitration_id == frame_id("StateCheckpoint"):
                s = decode_any(frame).signals
                step = int(s["Step"]) if step is None else step
                if int(s["Step"]) == step:
                    state[int(s["StateIndex"])] = s["StateValue"]
            elif frame.arbitration_id == frame_id("ObserverCheckpoint") and step is not None:
                s = decode_any(frame).signals
                if int(s["StepLow"]) == step % 4096 and id(frame) not in self.forged:
                    sent.setdefault(int(s["Index"]), s["Value"])
        accepted = dict(self.host.observer_checkpoints.get(step, {}))
        return step, [state[i] for i in range(4)], sent, accepted

    @property
    def restore_row(self) -> int:
        step = self.first_checkpoint()[0]
        return step + 1 if (step + 1) % 5 == 0 else step + 5 - (step + 1) % 5    # the first row of an interval


def forged(genuine: can.Message) -> can.Message:
    """The genuine ObserverCheckpoint frame with another value (+100) and a valid CRC, its alive counter kept."""
    data = bytearray(genuine.data)
    value = struct.unpack("<f", bytes(data[4:8]))[0]
    data[4:8] = struct.pack("<f", value + 100.0)
    return can.Message(arbitration_id=genuine.arbitration_id, is_extended_id=False, dlc=8,
                       data=apply_crc(genuine.arbitration_id, bytes(data)))


def _run(artifact, *, replay_at: int | None = None, forge: bool = False, restore: str | None = None,
         duplicate: bool = False):
    values = session_drive(ROWS, 3)
    measured = _measured(artifact, values)
    session = Session(artifact, values, measured)
    session.start()
    kept: dict[int, list[can.Message]] = {}
    for row in range(ROWS if restore is None else RESTART_AT + 1):
        if replay_at is not None and row == replay_at + 6:
            session.send([kept[replay_at][0]])        # row replay_at's Measurements frame, sent again
        session.forge_checkpoint, session.duplicate_checkpoint = forge, duplicate
        kept[row] = session.row(row)
    if restore is not None:
        step, state, sent, accepted = session.first_checkpoint()
        if restore == "forged-state":
            state = [state[0] + 10.0, *state[1:]]
        session.restart_and_restore(RESTART_AT, state, accepted if restore == "accepted" else sent)
        for row in range(session.restore_row, ROWS):
            kept[row] = session.row(row)
    session.stop()
    return session


def test_a_replayed_measurements_frame_is_refused_and_counted_as_the_target_counts_it(observer, tmp_path):
    session = _run(observer, replay_at=40)
    assert session.node.errors["counter"] == 2               # the replay, and the genuine frame after it
    record = decode_log(write_frames(tmp_path / "replayed.blf", session.frames))
    assert record.rejected_host == {"Measurements": 2} and record.invalid == {"counter": 2}
    assert np.isnan(record.measurements[46, 0]) and np.isfinite(record.measurements[[45, 47], 0]).all()
    results, _ = compute(record, observer)
    assert results.agreement.can_agrees_with_float32, results.agreement.max_abs_can_minus_float32_C
    assert results.figure_rows.excluded == {}
    said = [p for p in problems(results) if "of the host's measurement frames" in p]
    assert len(said) == 1 and said[0].startswith("the target's checks refuse 2 of the host's measurement frames")
    text = render_markdown(results, problems(results), None, {})
    assert "| ... of them the host's measurement frames the target's checks refuse (their readings unused) | " \
        "Measurements 2 |" in text


def test_forged_checkpoint_frames_are_contested_and_never_restored_from(observer, tmp_path):
    session = _run(observer, forge=True)
    step = session.first_checkpoint()[0]
    assert step in session.host.contested_checkpoints
    assert session.host.last_checkpoint(ROWS) is None or session.host.last_checkpoint(ROWS)[0] != step
    assert session.host.invalid["counter"] >= 1
    record = decode_log(write_frames(tmp_path / "forged.blf", session.frames))
    assert record.foreign.get("checkpoint frame contested", 0) >= 1
    assert record.rejected.get("ObserverCheckpoint", 0) >= 1
    results, _ = compute(record, observer)
    assert any("checkpoint frame contested" in p for p in problems(results))


def test_a_duplicated_checkpoint_frame_contests_nothing(observer, tmp_path):
    """A copy of a genuine checkpoint frame (its counter repeated, its bytes the same) is rejected and counted, and
    contests nothing: the host still restores from it, the log analysis finds nothing foreign."""
    session = _run(observer, duplicate=True)
    assert session.host.contested_checkpoints == set() and session.host.invalid["counter"] > 0
    assert session.host.last_checkpoint(ROWS) is not None
    record = decode_log(write_frames(tmp_path / "duplicated.blf", session.frames))
    assert record.foreign == {} and record.rejected.get("ObserverCheckpoint", 0) > 0


@pytest.mark.parametrize("restore, why", [("accepted", "contested"), ("forged-state", "forged"), ("sent", None)])
def test_a_restore_from_a_checkpoint_the_target_did_not_send_is_found(observer, tmp_path, restore, why):
    """A host that restored from the forged elements it accepted (contested), or from a state the target never
    sent (forged): the segment's rows are left out of every figure and the problem names the checkpoint; a restore
    from what the target sent is clean."""
    session = _run(observer, forge=restore == "accepted", restore=restore)
    record = decode_log(write_frames(tmp_path / f"{restore}.blf", session.frames))
    assert len(record.segments) == 2 and record.segments[1].checkpoint == why
    results, _ = compute(record, observer)
    restored = ROWS - session.restore_row
    named = [p for p in problems(results) if "was restored at row" in p]
    if why is None:
        assert named == [] and results.figure_rows.excluded == {} and record.foreign == {}
        assert problems(results) == []
        return
    assert results.figure_rows.excluded.get("restored_not_from_target") == restored
    assert len(named) == 1 and f"restored at row {session.restore_row}" in named[0]
    assert ("a state the target never sent" if why == "forged" else "contested") in named[0]
    assert results.integrity.restores_not_from_target == [[session.restore_row, why]]
    text = render_markdown(results, problems(results), None, {})
    assert f"| restores not from a checkpoint the target sent (start row, why) | {session.restore_row} {why} |" in text
