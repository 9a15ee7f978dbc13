"""DriveCurrents (DBC 1.4.0) at the target: a model with an electrical loss model uses a row only with DriveInputs,
DriveTemps and DriveCurrents of its Step and equals the offline float32 reference on the six values; a model with
loss maps accepts valid DriveCurrents and ignores them (both engines); a bad DriveCurrents is counted like any bad
frame (both engines)."""

from __future__ import annotations

import can
import numpy as np
import pytest
from cantools.autosar.end_to_end import compute_profile2_crc

from dbc import FaultBit, TargetState, decode_any
from dbc.contract import CURRENT_SIGNALS, DRIVE_SIGNALS
from target_sim.artifact import load_artifact
from target_sim.engines import ENGINES, make_node
from target_sim.model import run_offline
from target_sim.node import TargetNode

from .test_node import INITIAL, Host, drive_rows, temps_of
from helpers import electrical_artifact_text

CURRENTS_ID = 0x112


@pytest.fixture(params=ENGINES)
def make(request, artifacts, firmware_elf):
    """make(name of `artifacts`) -> a node of the engine under test (as test_node.py's conformance suite)."""

    def new(which):
        firmware = firmware_elf(which) if request.param == "firmware" else None
        return make_node(load_artifact(artifacts[which]), engine=request.param, firmware=firmware)

    return new


@pytest.fixture(scope="module")
def electrical(tmp_path_factory):
    path = tmp_path_factory.mktemp("electrical") / "electrical.json"
    path.write_text(electrical_artifact_text(), encoding="utf-8")
    return path


class CurrentsHost(Host):
    """A host whose rows carry the d/q currents: DriveInputs, DriveTemps, DriveCurrents."""

    def row_frames(self, step, values):
        return (*super().row_frames(step, values[:4]),
                self.frame("DriveCurrents", Step=step, CurrentD=values[4], CurrentQ=values[5]))


def drive_with_currents(n: int, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    currents = np.round(np.column_stack([rng.uniform(-400, 0, n), rng.uniform(-300, 450, n)]), 1)
    return np.column_stack([drive_rows(n, seed), currents])


def decoded_values(frames) -> list[float]:
    """The row's values as the target decodes them (DRIVE_SIGNALS, then CURRENT_SIGNALS)."""
    signals = {f.name: f.signals for f in map(decode_any, frames)}
    return [signals[message][signal] for message, signal in (*DRIVE_SIGNALS, *CURRENT_SIGNALS)]


def started(node) -> CurrentsHost:
    host = CurrentsHost(node)
    host.reset()
    host.start()
    assert node.state == TargetState.RUNNING
    return host


def reply_temperatures(frames) -> list[float]:
    t = temps_of(frames)
    return [t["Temperatures2"]["YokeTemp"], t["Temperatures1"]["WindingTemp"], t["Temperatures2"]["ToothTemp"],
            t["Temperatures1"]["MagnetTemp"]]


def test_an_electrical_model_steps_on_complete_rows_and_equals_the_offline_reference(electrical):
    artifact = load_artifact(electrical)
    assert artifact.loss_model == "electrical" and len(artifact.drive_signals) == 6
    node = TargetNode(artifact)
    host = started(node)
    drive = drive_with_currents(60)
    sent, answers = [], []
    for step, values in enumerate(drive):
        inputs, temps, currents = host.row_frames(step, values)
        sent.append(decoded_values((inputs, temps, currents)))
        assert host.send(inputs, temps) == []          # the pair alone is no row for an electrical model
        assert node.rows_used == step
        out = host.send(currents)
        assert [f.name for f in out][:2] == ["Temperatures1", "Temperatures2"]
        assert all(f.signals["Step"] == step for f in out)
        answers.append(out)
    assert sum(node.errors.values()) == 0 and node.rows_used == 60
    rows, expected = run_offline(artifact, np.array(sent), INITIAL)
    assert len(rows) == node.model_steps == 24
    for i, row in enumerate(rows):
        assert np.max(np.abs(np.array(reply_temperatures(answers[row])) - expected[i])) <= 0.005 + 1e-9
    np.testing.assert_array_equal(node.estimate, expected[-1])      # the very float32 values, bit for bit
    # the currents matter: the same rows with other currents give another estimate
    _, other = run_offline(artifact, np.array(sent) * [1, 1, 1, 1, 0.5, 0.5], INITIAL)
    assert np.max(np.abs(other[-1] - expected[-1])) > 0.05


def test_an_electrical_row_needs_its_three_frames_in_order_and_of_one_step(electrical):
    node = TargetNode(load_artifact(electrical))
    host = started(node)
    journal: list[dict] = []
    node.journal = journal.append

    def frame(name, step):   # one frame of row `step`, encoded only when sent (the alive counters stay in step)
        signals = {"DriveInputs": {"MotorTorque": 100.0, "MotorSpeed": 2000.0},
                   "DriveTemps": {"CoolantTemp": 40.0, "AmbientTemp": 25.0},
                   "DriveCurrents": {"CurrentD": -50.0, "CurrentQ": 120.0}}[name]
        return host.frame(name, Step=step, **signals)

    assert host.send(frame("DriveInputs", 0), frame("DriveTemps", 0)) == []
    assert host.send(frame("DriveInputs", 1)) == [] and node.errors["sequence"] == 1   # row 0 had no currents
    assert journal[-1]["detail"] == "DriveInputs of step 0 had no DriveCurrents"
    assert host.send(frame("DriveCurrents", 1)) == [] and node.errors["sequence"] == 2  # currents without temps
    assert journal[-1]["detail"] == "DriveCurrents of step 1 without its DriveTemps"
    assert host.send(frame("DriveInputs", 2), frame("DriveTemps", 2), frame("DriveCurrents", 3)) == []
    assert node.errors["sequence"] == 3
    assert journal[-1]["detail"] == "DriveInputs step 2 paired with DriveCurrents step 3"
    assert host.send(frame("DriveTemps", 3)) == [] and node.errors["sequence"] == 4
    assert journal[-1]["detail"] == "DriveTemps of step 3 without its DriveInputs"
    assert node.rows_used == 0 and node.model_steps == 0
    out = host.send(frame("DriveInputs", 4), frame("DriveTemps", 4), frame("DriveCurrents", 4))
    assert temps_of(out)["Temperatures1"]["Step"] == 4 and node.rows_used == 1   # rows 0..3 lost, row 4 used
    assert node.errors["sequence"] == 5 and journal[-1]["detail"] == "steps 0..3 never arrived"
    assert node.faults & FaultBit.SEQUENCE and sum(node.errors.values()) == 5


def test_a_bad_drive_currents_loses_its_row_like_any_bad_drive_frame(electrical):
    """A DriveCurrents with a wrong CRC is refused (RxErrors CrcError): its row (and the next, whose DriveCurrents
    shows the alive-counter jump) is left out of its interval's mean exactly as rows that never arrived."""
    artifact = load_artifact(electrical)
    node, reference = TargetNode(artifact), TargetNode(artifact)
    host, ref_host = started(node), started(reference)
    drive = drive_with_currents(14, seed=8)
    for step, values in enumerate(drive):
        frames = host.row_frames(step, values)
        ref_frames = ref_host.row_frames(step, values)
        if step == 6:
            bad = bytearray(frames[2].data)
            bad[5] ^= 0x04
            assert host.send(frames[0], frames[1], can.Message(arbitration_id=CURRENTS_ID, data=bytes(bad),
                                                               is_extended_id=False)) == []
            continue                                     # the reference never gets row 6 at all
        out, ref_out = host.send(*frames), ref_host.send(*ref_frames)
        if step == 7:   # the next DriveCurrents shows the alive-counter jump (so do all three frames at the
            assert out == ref_out == []   # reference): row 7 is lost too, as after any lost frame
            continue
        assert reply_temperatures(out) == reply_temperatures(ref_out), step
    # sequence errors: rows 6 and 7 never completed (their DriveInputs and DriveTemps came), rows 6..7 lost
    assert (node.errors["crc"], node.errors["counter"], node.errors["sequence"]) == (1, 1, 3)
    assert (reference.errors["crc"], reference.errors["counter"], reference.errors["sequence"]) == (0, 3, 1)
    np.testing.assert_array_equal(node.estimate, reference.estimate)
    assert node.model_steps == reference.model_steps == 5 and node.rows_used == reference.rows_used == 12


def _drive_currents_frames(host: Host, step: int):
    """A valid DriveCurrents, and two bad ones: a wrong CRC, a current beyond 3000 A (valid CRC)."""
    good = host.frame("DriveCurrents", Step=step, CurrentD=-100.0, CurrentQ=250.0)
    crc = bytearray(good.data)
    crc[6] ^= 0x01
    word = int.from_bytes(bytes(good.data), "little") & ~(0xFFFF << 28) | (30001 << 28)     # 3000.1 A
    out_of_range = bytearray(word.to_bytes(8, "little"))
    out_of_range[0] = compute_profile2_crc(bytes(out_of_range), 0x12)
    return good, can.Message(arbitration_id=CURRENTS_ID, data=bytes(crc), is_extended_id=False), \
        can.Message(arbitration_id=CURRENTS_ID, data=bytes(out_of_range), is_extended_id=False)


def test_a_loss_map_model_accepts_valid_drive_currents_and_ignores_them(make):
    """Both engines: the same replies, byte for byte, with and without a DriveCurrents after every pair, and no
    error counted for them."""
    plain, with_currents = make("lti"), make("lti")
    hosts = (Host(plain), CurrentsHost(with_currents))
    for host in hosts:
        host.reset()
        host.start()
    drive = drive_with_currents(30, seed=5)
    for step, values in enumerate(drive):
        expected = [(f.arbitration_id, bytes(f.data)) for frame in hosts[0].row_frames(step, values[:4])
                    for f in plain.handle(frame) if f.arbitration_id in (0x220, 0x221)]
        frames = hosts[1].row_frames(step, values)
        assert len(frames) == 3 and frames[2].arbitration_id == CURRENTS_ID
        got = [(f.arbitration_id, bytes(f.data)) for frame in frames for f in with_currents.handle(frame)
               if f.arbitration_id in (0x220, 0x221)]
        assert got == expected and len(got) == 2, step
    assert sum(with_currents.errors.values()) == 0 and not with_currents.faults & FaultBit.RX_ERROR
    assert with_currents.rows_used == plain.rows_used == 30
    assert with_currents.model_steps == plain.model_steps == 12
    np.testing.assert_array_equal(with_currents.estimate, plain.estimate)


def test_a_bad_drive_currents_is_counted_in_rx_errors(make):
    """Both engines, a loss-map model: a DriveCurrents with a wrong CRC or a current out of range is refused and
    counted (RxErrors CrcError, OutOfRange); a valid one after them is accepted; the model sees none of them."""
    node = make("lti")
    host = CurrentsHost(node)
    host.reset()
    host.start()
    drive = drive_with_currents(4)
    host.row(0, drive[0])
    state = (node.rows_used, node.model_steps)
    good, crc, out_of_range = _drive_currents_frames(host, 1)
    assert node.handle(crc) == [] and node.errors["crc"] == 1
    assert node.handle(out_of_range) == [] and node.errors["out_of_range"] == 1
    assert node.handle(good) == [] and sum(node.errors.values()) == 2
    assert (node.rows_used, node.model_steps) == state and node.faults & FaultBit.RX_ERROR
    rx = decode_any(node.rx_error_frames()[0]).signals
    assert (rx["CrcError"], rx["OutOfRange"], rx["CounterError"], rx["SequenceError"]) == (1, 1, 0, 0)
    assert temps_of(host.row(1, drive[1]))["Temperatures1"]["Step"] == 1       # the session goes on
