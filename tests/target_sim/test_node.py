"""The target node in-process: protocol, frame validation, sequence handling, replies (no bus, or `virtual`).

The conformance suite of the two engines: every test that takes `make` runs against the Python reference node
and against the firmware node (bench/firmware/node.c in the emulated Cortex-M4F), with the same frames and the
same expectations, the way python-can runs one back-to-back test over its interfaces; loss-map models and a model
with an electrical loss model (a data row of DriveInputs, DriveTemps and DriveCurrents, six values accumulated)."""

from __future__ import annotations

import threading
import time

import can
import numpy as np
import pytest
from cantools.autosar.end_to_end import compute_profile2_crc

from dbc import Command, FaultBit, FrameCodec, TargetState, decode_any
from dbc.contract import CHECKPOINT_EVERY_STEPS
from target_sim.artifact import load_artifact
from target_sim.engines import ENGINES, make_node
from target_sim.model import run_offline
from target_sim.node import TargetNode, serve

from helpers import electrical_artifact_text

INITIAL = [40.0, 45.0, 41.0, 50.0]  # yoke, winding, tooth, magnet


class Host:
    """A minimal host side: encodes what a host sends, decodes what the node answers."""

    def __init__(self, node: TargetNode):
        self.node = node
        self.codec = FrameCodec("HOST")

    def send(self, *frames: can.Message) -> list:
        out = []
        for frame in frames:
            out += [decode_any(reply) for reply in self.node.handle(frame)]
        return out

    def frame(self, name, **signals):
        return self.codec.encode(name, signals)

    def reset(self, temps=INITIAL, step=0):
        yoke, winding, tooth, magnet = temps
        return self.send(self.frame("ResetTemps1", Step=step, WindingTempInit=winding, MagnetTempInit=magnet),
                         self.frame("ResetTemps2", Step=step, YokeTempInit=yoke, ToothTempInit=tooth),
                         self.frame("Control", Command=int(Command.RESET), Step=step))

    def start(self, step=0):
        return self.send(self.frame("Control", Command=int(Command.START), Step=step))

    def row_frames(self, step, values):
        torque, speed, coolant, ambient = values
        return (self.frame("DriveInputs", Step=step, MotorTorque=torque, MotorSpeed=speed),
                self.frame("DriveTemps", Step=step, CoolantTemp=coolant, AmbientTemp=ambient))

    def row(self, step, values):
        return self.send(*self.row_frames(step, values))


class CurrentsHost(Host):
    """A host whose rows carry the d/q currents (DBC 1.4.0): DriveInputs, DriveTemps, DriveCurrents."""

    def row_frames(self, step, values):
        return (*super().row_frames(step, values[:4]),
                self.frame("DriveCurrents", Step=step, CurrentD=values[4], CurrentQ=values[5]))


def drive_rows(n: int, seed: int = 2) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([np.round(rng.uniform(-300, 500, n), 1), np.round(rng.uniform(0, 8000, n), 1) // 0.5 * 0.5,
                            np.round(40 + rng.normal(0, 1, n), 1), np.round(25 + rng.normal(0, 0.5, n), 1)])


def drive_rows_with_currents(n: int, seed: int = 2) -> np.ndarray:
    """`drive_rows` and d/q currents (0.1 A): i_d in -400..0 A, i_q in -300..450 A."""
    rng = np.random.default_rng(seed + 100)
    currents = np.round(np.column_stack([rng.uniform(-400, 0, n), rng.uniform(-300, 450, n)]), 1)
    return np.column_stack([drive_rows(n, seed), currents])


def temps_of(replies) -> dict[str, dict]:
    return {f.name: f.signals for f in replies if f.name.startswith("Temperatures")}


ISR_RATE_HZ = 10_000     # the conformance suite again with the current loop's interrupt preempting the node
TARGETS = [*ENGINES, pytest.param("firmware+isr", marks=pytest.mark.slow)]


@pytest.fixture(params=TARGETS)
def make(request, artifacts, firmware_elf):
    """make(name of `artifacts` or an artifact path, journal=None) -> a node of the engine under test (the
    firmware one also beside the motor-control interrupt at ISR_RATE_HZ: the same frames, the same answers)."""
    engine, _, isr = request.param.partition("+")

    def new(which, journal=None):
        path = artifacts[which] if which in artifacts else which
        firmware = firmware_elf(path, isr=bool(isr)) if engine == "firmware" else None
        return make_node(load_artifact(path), engine=engine, firmware=firmware, journal=journal,
                         isr_rate_hz=ISR_RATE_HZ if isr else 0.0)

    return new


@pytest.fixture(scope="module")
def electrical(tmp_path_factory):
    """The packaged Hammerstein model with an electrical loss model (`helpers.electrical_artifact_text`)."""
    path = tmp_path_factory.mktemp("electrical") / "electrical.json"
    path.write_text(electrical_artifact_text(), encoding="utf-8")
    return path


@pytest.fixture
def lti(artifacts):
    return load_artifact(artifacts["lti"])


@pytest.fixture
def running(make):
    node = make("lti")
    host = Host(node)
    host.reset()
    host.start()
    assert node.state == TargetState.RUNNING
    return node, host


def test_startup_announces_model_and_idle(make, lti):
    node = make("lti")
    frames = [decode_any(f) for f in node.startup_frames()]
    assert [f.name for f in frames] == ["TargetInfo", "Status", "RxErrors"]
    info, status = frames[0].signals, frames[1].signals
    assert info["ModelKind"] == 0 and info["Realization"] == 2 and info["ModelDt"] == pytest.approx(0.5)
    assert info["FlashBytes"] == node.memory.flash_bytes and info["RamBytes"] == node.memory.ram_bytes
    assert status["State"] == TargetState.IDLE and status["ModelId"] == lti.model_id and status["FaultBits"] == 0


def test_session_replies_equal_the_offline_float32_reference(make, lti):
    node = make("lti")
    host = Host(node)
    replies = host.reset()
    assert [f.name for f in replies] == ["TargetInfo", "Status"] and replies[1].signals["State"] == TargetState.READY
    assert host.start()[0].signals["State"] == TargetState.RUNNING
    drive = drive_rows(50)
    sent = []  # the drive values as the target decoded them
    answers = []
    for step, values in enumerate(drive):
        frames = host.row_frames(step, values)
        d1, d2 = decode_any(frames[0]).signals, decode_any(frames[1]).signals
        sent.append([d1["MotorTorque"], d1["MotorSpeed"], d2["CoolantTemp"], d2["AmbientTemp"]])
        out = host.send(*frames)
        names = [f.name for f in out]
        assert names[:2] == ["Temperatures1", "Temperatures2"]  # temperatures first, then the timing frames
        assert all(f.signals["Step"] == step for f in out)
        answers.append(out)
    rows, expected = run_offline(lti, np.array(sent), INITIAL)
    np.testing.assert_array_equal(rows, [2, 4, 7, 9, 12, 14, 17, 19, 22, 24, 27, 29, 32, 34, 37, 39, 42, 44, 47, 49])
    for i, row in enumerate(rows):
        t = temps_of(answers[row])
        got = [t["Temperatures2"]["YokeTemp"], t["Temperatures1"]["WindingTemp"], t["Temperatures2"]["ToothTemp"],
               t["Temperatures1"]["MagnetTemp"]]
        assert np.max(np.abs(np.array(got) - expected[i])) <= 0.005 + 1e-9
        checkpoint = ["StateCheckpoint"] * 4 if (i + 1) % CHECKPOINT_EVERY_STEPS == 0 else []
        timing4 = ["Timing4"] if node.engine == "firmware" else []     # the firmware's measured M4 cycles
        timing5 = ["Timing5"] if getattr(node, "isr_rate_hz", 0) else []  # response time beside the interrupt
        assert [f.name for f in answers[row]] == ["Temperatures1", "Temperatures2", "Timing1", "Timing2", "Timing3",
                                                  *timing4, *timing5, *checkpoint]
    # rows before the first model step carry the reset temperatures
    first = temps_of(answers[0])
    assert first["Temperatures1"]["WindingTemp"] == pytest.approx(45.0)
    assert first["Temperatures2"]["YokeTemp"] == pytest.approx(40.0)
    assert node.model_steps == len(rows) and node.rows_used == 50
    timing2 = [f for f in answers[2] if f.name == "Timing2"][0].signals     # the C28x estimate, both engines
    assert timing2["EstCycles"] == node.cost.cycles
    assert timing2["EstExecTime"] == pytest.approx(round(node.cost.exec_time_us, 1))


def _bad_frames(host: Host, step: int):
    """One frame of each rejection kind, each a DriveInputs/DriveTemps the model must never see."""
    good = host.frame("DriveInputs", Step=step, MotorTorque=100.0, MotorSpeed=1000.0)
    crc = bytearray(good.data)
    crc[4] ^= 0x01
    word = int.from_bytes(bytes(good.data), "little") & ~(0xFFFF << 44) | (0x7FFF << 44)  # 16383.5 rpm
    out_of_range = bytearray(word.to_bytes(8, "little"))
    out_of_range[0] = compute_profile2_crc(bytes(out_of_range), 0x10)
    skipped = host.frame("DriveTemps", Step=step, CoolantTemp=40.0, AmbientTemp=25.0)
    del skipped  # never sent: the next DriveTemps has a counter one too far
    counter_jump = host.frame("DriveTemps", Step=step, CoolantTemp=40.0, AmbientTemp=25.0)
    return {
        "unknown_id": can.Message(arbitration_id=0x7FF, data=bytes(8), is_extended_id=False),
        "wrong_length": can.Message(arbitration_id=0x110, data=bytes(good.data[:6]), dlc=6, is_extended_id=False),
        "crc": can.Message(arbitration_id=0x110, data=bytes(crc), is_extended_id=False),
        "out_of_range": can.Message(arbitration_id=0x110, data=bytes(out_of_range), is_extended_id=False),
        "counter": counter_jump,
    }


def test_every_rejection_kind_is_counted_and_never_reaches_the_model(running):
    node, host = running
    drive = drive_rows(6)
    for step in range(3):
        host.row(step, drive[step])
    state = (node.rows_used, node.model_steps, node.estimate.copy())
    bad = _bad_frames(host, 3)
    for kind, frame in bad.items():
        before = dict(node.errors)
        assert node.handle(frame) == []
        assert node.errors[kind] == before[kind] + 1, kind
        assert sum(node.errors.values()) == sum(before.values()) + 1, kind
    assert (node.rows_used, node.model_steps) == state[:2]
    np.testing.assert_array_equal(node.estimate, state[2])
    assert node.faults & FaultBit.RX_ERROR
    rx = decode_any(node.rx_error_frames()[0]).signals
    assert (rx["UnknownId"], rx["WrongLength"], rx["CrcError"], rx["OutOfRange"], rx["CounterError"]) == (1,) * 5
    assert node.state == TargetState.RUNNING


def test_sequence_errors_are_counted_and_not_fed(running):
    node, host = running
    drive = drive_rows(10)
    host.row(0, drive[0])
    used = node.rows_used
    # DriveTemps without its DriveInputs
    temps = host.frame("DriveTemps", Step=1, CoolantTemp=40.0, AmbientTemp=25.0)
    assert host.send(temps) == [] and node.errors["sequence"] == 1
    # a pair with different Steps
    inputs = host.frame("DriveInputs", Step=1, MotorTorque=10.0, MotorSpeed=100.0)
    temps = host.frame("DriveTemps", Step=2, CoolantTemp=40.0, AmbientTemp=25.0)
    assert host.send(inputs, temps) == [] and node.errors["sequence"] == 2
    # the expected row is still accepted
    first = temps_of(host.row(1, drive[1]))
    assert first["Temperatures1"]["Step"] == 1
    used, steps = node.rows_used, node.model_steps
    # the last row again (a host retransmitting it) is answered again, stepping nothing
    again = host.row(1, drive[1])
    assert [f.name for f in again] == ["Temperatures1", "Temperatures2"] and temps_of(again) == first
    assert (node.rows_used, node.model_steps, node.repeats, node.errors["sequence"]) == (used, steps, 1, 2)
    # an older row is not answered
    assert host.row(0, drive[0]) == [] and node.errors["sequence"] == 3
    assert node.rows_used == used
    assert node.faults & FaultBit.SEQUENCE


def test_a_gap_is_one_sequence_error_and_the_model_keeps_time(running):
    node, host = running
    drive = drive_rows(20)
    for step in range(3):
        host.row(step, drive[step])
    steps_before = node.model_steps       # 1 step after row 2
    out = host.row(8, drive[8])           # rows 3..7 lost: intervals ending at rows 4 and 7 still step
    assert node.errors["sequence"] == 1
    assert temps_of(out)["Temperatures1"]["Step"] == 8
    assert node.model_steps == steps_before + 2
    assert sum(1 for f in out if f.name == "Timing1") == 2
    assert temps_of(host.row(9, drive[9])) and node.errors["sequence"] == 1   # row 9 is the next one


def test_drive_frames_outside_running_and_start_outside_ready(make, lti):
    node = make("lti")
    host = Host(node)
    assert host.row(0, drive_rows(1)[0]) == []
    assert node.errors["sequence"] == 1 and node.rows_used == 0
    assert host.start() == [] and node.state == TargetState.IDLE and node.errors["sequence"] == 2


def test_incomplete_reset_is_refused(make, lti):
    node = make("lti")
    host = Host(node)
    replies = host.send(host.frame("ResetTemps1", Step=5, WindingTempInit=45.0, MagnetTempInit=50.0),
                        host.frame("Control", Command=int(Command.RESET), Step=5))
    assert node.state == TargetState.IDLE and node.faults & FaultBit.RESET_INCOMPLETE
    assert replies == []  # state unchanged: no extra Status
    # ResetTemps of another Step do not complete it either
    host.send(host.frame("ResetTemps1", Step=1, WindingTempInit=45.0, MagnetTempInit=50.0),
              host.frame("ResetTemps2", Step=1, YokeTempInit=40.0, ToothTempInit=41.0),
              host.frame("Control", Command=int(Command.RESET), Step=2))
    assert node.state == TargetState.IDLE
    host.reset(step=3)
    assert node.state == TargetState.READY and node.faults == 0  # a good RESET clears the latched faults


def test_stop_ends_the_session_and_a_new_host_starts_clean(running):
    node, host = running
    host.row(0, drive_rows(1)[0])
    out = host.send(host.frame("Control", Command=int(Command.STOP), Step=0))
    assert out[0].signals["State"] == TargetState.STOPPED
    fresh = Host(node)  # new host: its alive counters restart at 0
    assert fresh.reset()[-1].signals["State"] == TargetState.READY
    assert fresh.start()[0].signals["State"] == TargetState.RUNNING
    assert temps_of(fresh.row(0, drive_rows(1)[0]))["Temperatures1"]["Step"] == 0
    assert node.errors["counter"] == 0


def test_a_diverging_float32_model_is_clamped_and_flagged(make):
    node = make("original")
    host = Host(node)
    host.reset()
    host.start()
    drive = np.tile([500.0, 6000.0, 40.0, 25.0], (3000, 1))
    last = None
    for step, values in enumerate(drive):
        out = host.row(step, values)
        last = temps_of(out) or last
    assert node.faults & FaultBit.SATURATED
    values = [last["Temperatures1"]["WindingTemp"], last["Temperatures1"]["MagnetTemp"],
              last["Temperatures2"]["YokeTemp"], last["Temperatures2"]["ToothTemp"]]
    assert all(-50.0 <= v <= 600.0 for v in values)
    assert any(v in (-50.0, 600.0) for v in values)


def test_an_internal_error_is_a_fault_not_a_crash(running, monkeypatch):
    node, host = running
    drive = drive_rows(3)

    def broken(*args):
        raise RuntimeError("boom")

    if isinstance(node, TargetNode):
        monkeypatch.setattr(node, "model_step", broken)   # the step the node calls (compiled or numpy)
    else:
        node.fw.max_instructions = 1500     # a row with a model step runs ~2,000: the core "does not return"
    host.row(0, drive[0])
    host.row(1, drive[1])
    out = host.row(2, drive[2])  # completes a model step
    assert node.state == TargetState.FAULT and node.faults & FaultBit.INTERNAL
    assert out[0].name == "Status" and out[0].signals["State"] == TargetState.FAULT


def serve_and_listen(node, frames, seconds: float, on_error=None) -> list:
    """`serve` the node on a fresh virtual bus in a thread, send `frames` as a host, and decode what the node sends
    within `seconds`."""
    channel = f"node-test-{time.monotonic_ns()}"
    target_bus = can.Bus(interface="virtual", channel=channel)
    host_bus = can.Bus(interface="virtual", channel=channel)
    stop = threading.Event()
    thread = threading.Thread(target=serve, args=(node, target_bus, stop.is_set), kwargs={"on_error": on_error},
                              daemon=True)
    thread.start()
    try:
        for frame in frames:
            host_bus.send(frame)
        seen = []
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            msg = host_bus.recv(0.05)
            if msg is not None:
                seen.append(decode_any(msg))
    finally:
        stop.set()
        thread.join(2)
        target_bus.shutdown()
        host_bus.shutdown()
    return seen


def test_serve_on_a_virtual_bus_heartbeats_and_answers(make, lti):
    node = make("lti")
    codec = FrameCodec("HOST")
    yoke, winding, tooth, magnet = INITIAL
    seen = serve_and_listen(node, (
        codec.encode("ResetTemps1", {"Step": 0, "WindingTempInit": winding, "MagnetTempInit": magnet}),
        codec.encode("ResetTemps2", {"Step": 0, "YokeTempInit": yoke, "ToothTempInit": tooth}),
        codec.encode("Control", {"Command": int(Command.RESET), "Step": 0}),
        codec.encode("Control", {"Command": int(Command.START), "Step": 0}),
        codec.encode("DriveInputs", {"Step": 0, "MotorTorque": 50.0, "MotorSpeed": 500.0}),
        codec.encode("DriveTemps", {"Step": 0, "CoolantTemp": 40.0, "AmbientTemp": 25.0})), 0.55)
    names = [f.name for f in seen]
    assert "Temperatures1" in names and "Temperatures2" in names
    cyclic = [f for f in seen if f.name == "Status"]
    assert 5 <= len(cyclic) <= 9            # 100 ms heartbeat (plus the state-change Status frames)
    assert names.count("RxErrors") >= 4
    assert node.errors == dict.fromkeys(node.errors, 0)


def test_random_frames_never_crash_the_node(make, lti):
    """Valid frames in random order and values, mixed with garbage: counted, answered or refused, never fatal."""
    import random

    from dbc import apply_crc, host_frame_ids, signal_ranges

    rng = random.Random(7)
    node = make("lti")
    host = Host(node)
    codec = host.codec
    names = ["ResetTemps1", "ResetTemps2", "RestoreState", "Control", "DriveInputs", "DriveTemps", "DriveInputs",
             "DriveTemps"]
    good = drive_rows(5)
    answered = 0
    for i in range(6000 if isinstance(node, TargetNode) else 2000):
        if i % 500 == 0:  # now and then a proper session start and a few good rows
            host.reset()
            host.start()
            for step, values in enumerate(good):
                answered += sum(f.name == "Temperatures1" for f in host.row(step, values))
        if rng.random() < 0.6:
            name = rng.choice(names)
            signals = {}
            for signal, (low, high) in signal_ranges(name).items():
                signals[signal] = rng.randint(0, 5) if signal == "Step" else (
                    rng.randint(int(low), int(high)) if name == "Control" else rng.uniform(low, high))
            frame = codec.encode(name, signals)
        else:
            fid = rng.choice(sorted(host_frame_ids()) + [0x7FF, 0x221])
            data = bytes(rng.randrange(256) for _ in range(8))
            frame = can.Message(arbitration_id=fid, data=apply_crc(fid, data) if fid in host_frame_ids() else data,
                                is_extended_id=False)
        for reply in node.handle(frame):
            # everything the node sends is a valid frame of the contract
            answered += decode_any(reply).name == "Temperatures1"
    assert not node.faults & FaultBit.INTERNAL
    assert sum(node.errors.values()) > 300 and node.errors["out_of_range"] > 0 and node.errors["sequence"] > 0
    assert answered > 0  # the proper sessions' rows that got past the counters the random frames left


def test_the_journal_names_every_rejected_frame_and_sequence_error(make):
    records: list[dict] = []
    node = make("lti", journal=records.append)
    host = Host(node)
    host.reset()
    host.start()
    di, dt = host.row_frames(0, (10.0, 1000.0, 40.0, 25.0))
    bad = bytearray(di.data)
    bad[5] ^= 0x10
    host.send(can.Message(arbitration_id=di.arbitration_id, is_extended_id=False, dlc=8, data=bytes(bad)))
    host.send(dt)  # its DriveInputs was refused: a sequence error
    assert [(r["kind"], r["id"], r["dlc"], r["data"]) for r in records] == [
        ("crc", di.arbitration_id, 8, bytes(bad).hex()), ("sequence", dt.arbitration_id, 8, bytes(dt.data).hex())]
    assert "without its DriveInputs" in records[1]["detail"]
    assert sum(node.errors.values()) == len(records) == 2


def state_of(node) -> np.ndarray:
    """The model state vector x of either engine."""
    return node.model.x if isinstance(node, TargetNode) else node.x


def checkpoints_of(frames) -> dict[int, list[float]]:
    """{Step: state vector} of the complete StateCheckpoints among decoded frames."""
    parts: dict[int, dict[int, float]] = {}
    for f in frames:
        if f.name == "StateCheckpoint":
            parts.setdefault(f.signals["Step"], {})[f.signals["StateIndex"]] = f.signals["StateValue"]
    return {step: [p[i] for i in range(4)] for step, p in parts.items() if len(p) == 4}


@pytest.mark.parametrize("kind", ["hammerstein", "pv-lptn"])
def test_a_target_restored_from_its_checkpoint_continues_bit_for_bit(make, kind):
    from bench.model.default import default_artifact_path

    path = default_artifact_path() if kind == "hammerstein" else default_artifact_path().with_name(
        "default_model-pv-lptn.json")
    drive = drive_rows(160)
    # the uninterrupted run
    node = make(path)
    host = Host(node)
    host.reset()
    host.start()
    clean = [host.row(step, drive[step]) for step in range(160)]
    checkpoints = checkpoints_of([f for out in clean for f in out])
    assert len(checkpoints) == node.model_steps // CHECKPOINT_EVERY_STEPS >= 2
    c = max(step for step in checkpoints if step < 120)
    state = checkpoints[c]
    # a fresh target (a restart) restored from that checkpoint answers rows c+1.. exactly as the clean run did
    fresh = make(path)
    other = Host(fresh)
    frames = [other.frame("RestoreState", Step=c + 1, StateIndex=i, StateValue=v) for i, v in enumerate(state)]
    out = other.send(*frames, other.frame("Control", Command=int(Command.RESTORE), Step=c + 1))
    assert fresh.state == TargetState.READY and [f.name for f in out] == ["TargetInfo", "Status"]
    other.start(c + 1)
    for step in range(c + 1, 160):
        again = other.row(step, drive[step])
        assert temps_of(again) == temps_of(clean[step]), step
    assert np.array_equal(state_of(fresh).view(np.uint32), state_of(node).view(np.uint32))


def test_an_incomplete_restore_changes_nothing(make, lti):
    node = make("lti")
    host = Host(node)
    host.reset()
    x_before = state_of(node).copy()
    frames = [host.frame("RestoreState", Step=5, StateIndex=i, StateValue=1.0) for i in range(3)]
    frames.append(host.frame("RestoreState", Step=6, StateIndex=3, StateValue=1.0))  # another Step
    host.send(*frames, host.frame("Control", Command=int(Command.RESTORE), Step=5))
    assert node.state == TargetState.IDLE and node.faults & FaultBit.RESET_INCOMPLETE
    assert np.array_equal(state_of(node), x_before)


# ---------------------------------------------------------------- an electrical loss model (DriveCurrents)


def decoded_row(frames) -> list[float]:
    """The row's six values as the target decodes them (DriveInputs, DriveTemps, DriveCurrents)."""
    signals = {f.name: f.signals for f in map(decode_any, frames)}
    return [signals["DriveInputs"]["MotorTorque"], signals["DriveInputs"]["MotorSpeed"],
            signals["DriveTemps"]["CoolantTemp"], signals["DriveTemps"]["AmbientTemp"],
            signals["DriveCurrents"]["CurrentD"], signals["DriveCurrents"]["CurrentQ"]]


def test_an_electrical_model_steps_on_complete_rows_and_equals_the_offline_reference(make, electrical):
    """A row is DriveInputs, DriveTemps and DriveCurrents: the pair alone is answered by nothing, the currents
    complete it; the estimate is the offline float32 reference's on the six decoded values, bit for bit."""
    artifact = load_artifact(electrical)
    node = make(electrical)
    host = CurrentsHost(node)
    host.reset()
    host.start()
    drive = drive_rows_with_currents(60, seed=3)
    sent, answers = [], []
    for step, values in enumerate(drive):
        frames = host.row_frames(step, values)
        sent.append(decoded_row(frames))
        assert host.send(*frames[:2]) == [] and node.rows_used == step
        out = host.send(frames[2])
        assert [f.name for f in out][:2] == ["Temperatures1", "Temperatures2"]
        assert all(f.signals["Step"] == step for f in out)
        answers.append(out)
    assert sum(node.errors.values()) == 0 and node.rows_used == 60
    rows, expected = run_offline(artifact, np.array(sent), INITIAL)
    assert len(rows) == node.model_steps == 24
    assert np.array_equal(np.asarray(node.estimate, np.float32).view(np.uint32), expected[-1].view(np.uint32))
    for i, row in enumerate(rows):
        t = temps_of(answers[row])
        got = [t["Temperatures2"]["YokeTemp"], t["Temperatures1"]["WindingTemp"], t["Temperatures2"]["ToothTemp"],
               t["Temperatures1"]["MagnetTemp"]]
        assert np.max(np.abs(np.array(got) - expected[i])) <= 0.005 + 1e-9
    # a retransmitted row is answered again without a step; an older one not at all
    again = host.row(59, drive[59])
    assert [f.name for f in again] == ["Temperatures1", "Temperatures2"] and temps_of(again) == temps_of(answers[59])
    assert (node.repeats, node.model_steps) == (1, 24)
    assert host.row(50, drive[50]) == [] and node.errors["sequence"] == 1


def test_an_electrical_row_needs_its_three_frames_in_order_and_of_one_step(make, electrical):
    """Every sequence rule of a three-frame row, with the journal's sentences: both engines alike."""
    records: list[dict] = []
    node = make(electrical, journal=records.append)
    host = CurrentsHost(node)
    host.reset()
    host.start()

    def frame(name, step):   # one frame of row `step`, encoded only when sent (the alive counters stay in step)
        signals = {"DriveInputs": {"MotorTorque": 100.0, "MotorSpeed": 2000.0},
                   "DriveTemps": {"CoolantTemp": 40.0, "AmbientTemp": 25.0},
                   "DriveCurrents": {"CurrentD": -50.0, "CurrentQ": 120.0}}[name]
        return host.frame(name, Step=step, **signals)

    def last(detail: str, errors: int) -> None:
        assert records[-1]["kind"] == "sequence" and records[-1]["detail"] == detail
        assert node.errors["sequence"] == errors == len(records)

    assert host.send(frame("DriveInputs", 0), frame("DriveTemps", 0)) == []
    assert host.send(frame("DriveInputs", 1)) == []
    last("DriveInputs of step 0 had no DriveCurrents", 1)
    assert host.send(frame("DriveCurrents", 1)) == []
    last("DriveCurrents of step 1 without its DriveTemps", 2)
    assert host.send(frame("DriveCurrents", 1)) == []
    last("DriveCurrents of step 1 without its DriveInputs", 3)
    assert host.send(frame("DriveInputs", 2), frame("DriveTemps", 2), frame("DriveCurrents", 3)) == []
    last("DriveInputs step 2 paired with DriveCurrents step 3", 4)
    assert host.send(frame("DriveInputs", 3), frame("DriveTemps", 4)) == []
    last("DriveInputs step 3 paired with DriveTemps step 4", 5)
    assert host.send(frame("DriveTemps", 3)) == []
    last("DriveTemps of step 3 without its DriveInputs", 6)
    assert host.send(frame("DriveInputs", 3), frame("DriveTemps", 3), frame("DriveTemps", 3)) == []
    last("DriveInputs of step 3 had no DriveCurrents", 7)
    assert node.rows_used == 0 and node.model_steps == 0
    out = host.send(frame("DriveInputs", 4), frame("DriveTemps", 4), frame("DriveCurrents", 4))
    assert temps_of(out)["Temperatures1"]["Step"] == 4 and node.rows_used == 1     # rows 0..3 lost, row 4 used
    last("steps 0..3 never arrived", 8)
    assert node.faults & FaultBit.SEQUENCE and sum(node.errors.values()) == 8
    # STOP forgets a row begun; a new session's row is whole again
    host.send(frame("DriveInputs", 5), frame("DriveTemps", 5))
    host.send(host.frame("Control", Command=int(Command.STOP), Step=0))
    fresh = CurrentsHost(node)
    fresh.reset()
    fresh.start()
    assert temps_of(fresh.row(0, (10.0, 1000.0, 40.0, 25.0, -10.0, 20.0)))["Temperatures1"]["Step"] == 0
    assert node.errors["sequence"] == 8


def test_an_electrical_model_keeps_time_over_lost_rows_and_a_bad_drive_currents(make, electrical):
    """Rows lost on the bus and a DriveCurrents refused for its CRC: the model steps on the rows that arrived (or
    holds the previous inputs), as the Python node's RowAccumulator, on both engines alike."""
    node = make(electrical)
    host = CurrentsHost(node)
    host.reset()
    host.start()
    drive = drive_rows_with_currents(30, seed=8)
    for step in range(3):
        host.row(step, drive[step])
    out = host.row(12, drive[12])     # rows 3..11 lost: the intervals ending at 4, 7, 9 step (held inputs), then 12
    assert temps_of(out)["Temperatures1"]["Step"] == 12 and node.model_steps == 1 + 3 + 1
    inputs, temps, currents = host.row_frames(13, drive[13])
    bad = bytearray(currents.data)
    bad[5] ^= 0x04
    assert host.send(inputs, temps, can.Message(arbitration_id=currents.arbitration_id, data=bytes(bad),
                                                is_extended_id=False)) == []
    assert (node.errors["crc"], node.rows_used) == (1, 4)
    out = host.row(14, drive[14])              # its DriveCurrents shows the counter jump: row 14 is lost too
    assert out == [] and node.errors["counter"] == 1
    out = host.row(15, drive[15])     # the interval of rows 13..14 had none: it steps on the held inputs
    assert temps_of(out)["Temperatures1"]["Step"] == 15 and node.model_steps == 6 and node.rows_used == 5
    # sequence: rows 3..11 lost; rows 13 and 14 never completed; rows 13..14 lost
    assert (node.errors["sequence"], node.errors["crc"], node.errors["counter"]) == (1 + 2 + 1, 1, 1)
