"""The firmware node (bench/firmware/node.c and the model, in the emulated Cortex-M4F) against the Python reference
node: the same frames in, the same bytes out (timing and TargetInfo aside), plus Timing4 (the cycles the firmware
measured with DWT_CYCCNT) and the ELF's flash and RAM in TargetInfo; an ELF of another model or core is refused in
one sentence; an emulator fault is an INTERNAL fault, not a crash. (The shared behaviour is tested on both engines
by test_node.py.) A model with an electrical loss model, whose rows carry DriveCurrents, is held to the same
bytes."""

from __future__ import annotations

import os
import sys
from collections import Counter

import can
import numpy as np
import pytest

from dbc import Command, FaultBit, TargetState, decode_any
from dbc.contract import FIRMWARE_TIMING_MESSAGE, M4_CLOCK_HZ
from target_sim.artifact import load_artifact
from target_sim.engines import make_node
from target_sim.firmware import FirmwareError, FirmwareEstimator, memory_from_elf
from target_sim.firmware.elf import read_elf
from target_sim.firmware.emulator import Firmware
from target_sim.firmware.node_engine import FirmwareNode
from target_sim.node import TargetNode

from .test_node import (
    INITIAL,
    CurrentsHost,
    Host,
    checkpoints_of,
    drive_rows,
    drive_rows_with_currents,
    serve_and_listen,
)
from helpers import electrical_artifact_text, patched_elf

UDF = b"\xfe\xde"     # Thumb UDF #0xFE: an undefined instruction


def nodes(artifacts, firmware_elf, name: str) -> tuple[TargetNode, FirmwareNode]:
    """(python engine, firmware engine) nodes of one artifact."""
    artifact = load_artifact(artifacts[name])
    return TargetNode(artifact), FirmwareNode(artifact, firmware_elf(name))


TIMING_IDS = {0x222, 0x223, 0x224, 0x225}


def comparable(frames, info_ids) -> list[tuple[int, bytes]]:
    """(id, data) of every frame but the timing frames (measured times differ) and TargetInfo (ELF vs estimate)."""
    return [(f.arbitration_id, bytes(f.data)) for f in frames
            if f.arbitration_id not in TIMING_IDS and f.arbitration_id not in info_ids]


def session(node, drive: np.ndarray, lost: set[int] = frozenset()) -> list[can.Message]:
    """RESET, START, every row but the `lost` ones (and row 30 sent twice): every frame the node sent."""
    host = Host(node)
    out = node.startup_frames()          # as serve() sends them: the firmware's node_init already queued them
    out += [f for frame in (*host_frames_reset(host), host.frame("Control", Command=int(Command.START), Step=0))
            for f in node.handle(frame)]
    for step, values in enumerate(drive):
        frames = host.row_frames(step, values)
        if step in lost:
            continue
        for frame in frames:
            out += node.handle(frame)
        if step == 30:   # a retransmission: answered again, no step
            for frame in host.row_frames(step, values):
                out += node.handle(frame)
    return out


def host_frames_reset(host: Host):
    yoke, winding, tooth, magnet = INITIAL
    return (host.frame("ResetTemps1", Step=0, WindingTempInit=winding, MagnetTempInit=magnet),
            host.frame("ResetTemps2", Step=0, YokeTempInit=yoke, ToothTempInit=tooth),
            host.frame("Control", Command=int(Command.RESET), Step=0))


@pytest.mark.parametrize("name", ["lti", "pv", "hammerstein", "modal"])
def test_the_firmware_engine_answers_bit_for_bit_as_the_python_engine(artifacts, firmware_elf, name):
    python, firmware = nodes(artifacts, firmware_elf, name)
    drive = drive_rows(130, seed=4)
    lost = {50, 51, 52, 53, 54, 55, 56, 90}     # rows lost on the bus: intervals ending among them, held inputs
    expected = session(python, drive, lost)
    got = session(firmware, drive, lost)
    timing4 = [decode_any(f) for f in got if f.arbitration_id == 0x225]
    # every frame the python engine sends, byte for byte: Status, temperatures, checkpoints (alive counters and
    # CRCs included); the timing frames carry measured times, TargetInfo the ELF's flash and RAM
    info = {f.arbitration_id for f in expected if decode_any(f).name == "TargetInfo"}
    assert comparable(got, info) == comparable(expected, info)
    assert [f.arbitration_id for f in got if f.arbitration_id != 0x225] == [f.arbitration_id for f in expected]
    assert python.model_steps == firmware.model_steps == len(timing4) > 40
    assert checkpoints_of(decode_any(f) for f in got)
    assert np.array_equal(python.model.x.view(np.uint32), firmware.x.view(np.uint32))
    assert python.errors["sequence"] == firmware.errors["sequence"] == 2 and firmware.repeats == 1
    # Timing4: the cycles the firmware measured around fw_step (DWT_CYCCNT), and their time at 90 MHz
    cycles = [f.signals["M4Cycles"] for f in timing4]
    assert all(200 < c < 5000 for c in cycles) and Counter(cycles) == firmware.m4_cycles
    assert all(f.signals["M4ExecTime"] == pytest.approx(round(f.signals["M4Cycles"] * 1e6 / M4_CLOCK_HZ, 1))
               for f in timing4)
    names = [decode_any(f).name for f in got if decode_any(f).name.startswith("Timing")]
    assert names[:4] == ["Timing1", "Timing2", "Timing3", FIRMWARE_TIMING_MESSAGE]
    stats = firmware.stats()
    assert stats["engine"] == "firmware" and stats["m4_cycles"]["max"] == max(cycles)
    assert python.stats()["engine"] == "python" and python.stats()["m4_cycles"] is None


class ReferenceCore(Firmware):
    """Every call through `Firmware.call`, its blocks counted by the Python hook and DWT_CYCCNT read by the Python
    callback: none of the firmware engine's per-frame fast paths (`Firmware.caller` with the output and the stack
    guard in one read, the native block hook and DWT read, the PC read skipped)."""

    def call(self, *args, **kwargs):
        return super().call(*args, **kwargs)

    def _on_block(self, *args) -> None:
        super()._on_block(*args)

    def _on_dwt_read(self, *args) -> int:
        return super()._on_dwt_read(*args)


@pytest.mark.parametrize("name", ["lti", "hammerstein"])
def test_the_fast_paths_change_no_frame_and_no_cycle_figure(artifacts, firmware_elf, name):
    """The same frames in (a DAQ list on the model step, rows with a gap and a repeat, heartbeats): the same frames
    out (ids, data, order), journal records, per-frame cycle statistics, counters and DWT count with the engine's
    per-frame fast paths as through the plain calls."""
    from bench.firmware.daqload import full_daq_commands
    from dbc.xcp import cmd_id

    artifact = load_artifact(artifacts[name])
    image = read_elf(firmware_elf(name))
    journals: tuple[list, list] = ([], [])
    fast = FirmwareNode(artifact, image, journal=journals[0].append, clock_s=lambda: 0.0)
    plain = FirmwareNode(artifact, image, journal=journals[1].append, clock_s=lambda: 0.0, core=ReferenceCore)
    assert set(fast._callers) == {"node_on_frame", "node_on_xcp", "node_on_tick"} and fast.fw._dwt is not None
    assert not plain._callers and plain.fw._native is None and plain.fw._dwt is None
    xcp = [can.Message(arbitration_id=cmd_id(), is_extended_id=False, data=cto) for cto in full_daq_commands(image)]
    drive = drive_rows(60, seed=7)
    outputs = []
    for node in (fast, plain):
        out = [f for frame in xcp for f in node.handle(frame)]
        out += session(node, drive, lost={20, 21, 40})
        out += node.heartbeat_frames()
        outputs.append([(f.arbitration_id, f.dlc, bytes(f.data)) for f in out])
    assert outputs[0] == outputs[1] and journals[0] == journals[1] and journals[0]
    assert sum(1 for fid, _, _ in outputs[0] if fid == 0x225) == fast.model_steps > 20     # Timing4: steps ran
    stats = fast.stats(), plain.stats()
    assert stats[0] == stats[1] and stats[0]["xcp"]["daq_sample_cycles"]["max"]
    assert fast.frame_cycles == plain.frame_cycles and fast.reply_cycles == plain.reply_cycles
    assert fast.xcp_cycles == plain.xcp_cycles and fast.xcp_sample_cycles == plain.xcp_sample_cycles
    assert fast.fw.total_cycles == plain.fw.total_cycles and fast.fw.cyccnt() == plain.fw.cyccnt()


def session_with_currents(node, drive: np.ndarray) -> list[can.Message]:
    """RESET, START, every row with a DriveCurrents after its pair (DBC 1.4.0); row 20's DriveCurrents with a wrong
    CRC, row 40's with a current out of range, row 60 lost on the bus (all three frames): every frame sent."""
    from cantools.autosar.end_to_end import compute_profile2_crc

    host = Host(node)
    out = node.startup_frames()
    out += [f for frame in (*host_frames_reset(host), host.frame("Control", Command=int(Command.START), Step=0))
            for f in node.handle(frame)]
    rng = np.random.default_rng(9)
    for step, values in enumerate(drive):
        frames = list(host.row_frames(step, values))
        frames.append(host.frame("DriveCurrents", Step=step, CurrentD=float(np.round(rng.uniform(-3000, 0), 1)),
                                 CurrentQ=float(np.round(rng.uniform(-3000, 3000), 1))))
        data = bytearray(frames[2].data)
        if step == 20:
            data[7] ^= 0x40
        elif step == 40:
            word = int.from_bytes(bytes(data), "little") & ~(0xFFFF << 44) | ((-30001 & 0xFFFF) << 44)
            data = bytearray(word.to_bytes(8, "little"))
            data[0] = compute_profile2_crc(bytes(data), 0x12)
        frames[2] = can.Message(arbitration_id=0x112, is_extended_id=False, data=bytes(data))
        if step != 60:
            for frame in frames:
                out += node.handle(frame)
    return out


@pytest.mark.parametrize("name", ["lti", "hammerstein"])
def test_the_engines_answer_alike_with_drive_currents_in_the_stream(artifacts, firmware_elf, name):
    """A loss-map model on both engines, with DriveCurrents frames (valid, a bad CRC, out of range) between the rows:
    every frame byte for byte, the same rejection counts, the same model state."""
    python, firmware = nodes(artifacts, firmware_elf, name)
    drive = drive_rows(80, seed=6)
    expected = session_with_currents(python, drive)
    got = session_with_currents(firmware, drive)
    info = {f.arbitration_id for f in expected if decode_any(f).name == "TargetInfo"}
    assert comparable(got, info) == comparable(expected, info)
    assert [f.arbitration_id for f in got if f.arbitration_id != 0x225] == [f.arbitration_id for f in expected]
    # the bad CRC and the out-of-range current; the valid DriveCurrents after each shows the counter jump, as do
    # the three frames of row 61 after row 60 (lost: rows 60, 61 never used; one sequence error)
    assert python.errors == firmware.errors
    assert (python.errors["crc"], python.errors["out_of_range"], python.errors["counter"],
            python.errors["sequence"]) == (1, 1, 2 + 3, 1)
    assert python.rows_used == firmware.rows_used == 78 and python.model_steps == firmware.model_steps == 32
    assert np.array_equal(python.model.x.view(np.uint32), firmware.x.view(np.uint32))


def electrical_session(node, drive: np.ndarray) -> list[can.Message]:
    """RESET, START, then every row as DriveInputs, DriveTemps, DriveCurrents, with what a bus does to them: rows
    50-56 and 90 lost (all three frames), row 30 retransmitted whole, row 70's DriveCurrents refused for its CRC
    (row 71's then shows the counter jump), row 110's frames out of order (DriveCurrents first), row 120's
    DriveCurrents of another Step, at row 150 a restore from the latest checkpoint (a restarted target's), then the
    rows after it. Every frame the node sent."""
    host = CurrentsHost(node)
    out = node.startup_frames()
    out += [f for frame in (*host_frames_reset(host), host.frame("Control", Command=int(Command.START), Step=0))
            for f in node.handle(frame)]
    checkpoint = None
    for step, values in enumerate(drive):
        frames = list(host.row_frames(step, values))
        if step in (50, 51, 52, 53, 54, 55, 56, 90):
            continue
        if step == 70:
            data = bytearray(frames[2].data)
            data[6] ^= 0x20
            frames[2] = can.Message(arbitration_id=frames[2].arbitration_id, is_extended_id=False, data=bytes(data))
        elif step == 110:
            frames = [frames[2], frames[0], frames[1]]
        elif step == 120:
            frames[2] = host.frame("DriveCurrents", Step=121, CurrentD=-1.0, CurrentQ=2.0)
        elif step == 150:
            c, state = checkpoint
            restore = [host.frame("RestoreState", Step=c + 1, StateIndex=i, StateValue=v) for i, v in enumerate(state)]
            restore += [host.frame("Control", Command=int(Command.RESTORE), Step=c + 1),
                        host.frame("Control", Command=int(Command.START), Step=c + 1)]
            for frame in restore:
                out += node.handle(frame)
        for frame in frames:
            replies = node.handle(frame)
            out += replies
            found = checkpoints_of(decode_any(f) for f in replies)
            if found:
                checkpoint = max(found.items())
        if step == 30:
            for frame in host.row_frames(step, values):
                out += node.handle(frame)
    return out


@pytest.fixture(scope="module")
def electrical(tmp_path_factory):
    path = tmp_path_factory.mktemp("electrical") / "electrical.json"
    path.write_text(electrical_artifact_text(), encoding="utf-8")
    return path


def test_the_engines_answer_alike_for_an_electrical_model(electrical, firmware_elf):
    """An electrical loss model (rows of DriveInputs, DriveTemps, DriveCurrents; six values accumulated): every
    frame byte for byte through lost rows, a retransmission, a refused DriveCurrents, frames out of order or of
    another Step and a restore; the same rejection counts and the same model state, bit for bit."""
    artifact = load_artifact(electrical)
    python, firmware = TargetNode(artifact), FirmwareNode(artifact, firmware_elf(electrical))
    drive = drive_rows_with_currents(200, seed=12)
    expected = electrical_session(python, drive)
    got = electrical_session(firmware, drive)
    info = {f.arbitration_id for f in expected if decode_any(f).name == "TargetInfo"}
    assert comparable(got, info) == comparable(expected, info)
    assert [f.arbitration_id for f in got if f.arbitration_id != 0x225] == [f.arbitration_id for f in expected]
    assert python.errors == firmware.errors
    # counter jumps: the three frames after each gap (rows 50-56 and 90), row 71's DriveCurrents after the refused
    # one, row 120's after the DriveCurrents encoded and not sent
    assert (python.errors["crc"], python.errors["counter"]) == (1, 3 + 3 + 1 + 1)
    assert python.errors["sequence"] >= 6
    assert python.repeats == firmware.repeats == 1
    assert python.rows_used == firmware.rows_used and python.model_steps == firmware.model_steps > 15
    assert len(checkpoints_of(decode_any(f) for f in got)) >= 2
    assert np.array_equal(python.model.x.view(np.uint32), firmware.x.view(np.uint32))
    assert np.array_equal(python.estimate.view(np.uint32), firmware.estimate.view(np.uint32))
    timing4 = [decode_any(f).signals["M4Cycles"] for f in got if f.arbitration_id == 0x225]
    assert len(timing4) == sum(f.arbitration_id == 0x222 for f in got) and all(200 < c < 5000 for c in timing4)


def test_target_info_carries_the_elf_figures_with_the_firmware_engine(artifacts, firmware_elf):
    python, firmware = nodes(artifacts, firmware_elf, "hammerstein")
    measured = memory_from_elf(firmware_elf("hammerstein"))
    info = decode_any(firmware.startup_frames()[0]).signals
    assert (info["FlashBytes"], info["RamBytes"]) == (measured["flash_bytes"], measured["ram_bytes"])
    estimate = decode_any(python.startup_frames()[0]).signals
    assert (estimate["FlashBytes"], estimate["RamBytes"]) == (python.memory.flash_bytes, python.memory.ram_bytes)
    assert firmware.stats()["memory"] == "measured from the firmware ELF"


def test_a_checkpoint_of_the_python_engine_restores_into_the_firmware_engine(artifacts, firmware_elf):
    python, firmware = nodes(artifacts, firmware_elf, "hammerstein")
    drive = drive_rows(120, seed=9)
    host = Host(python)
    host.reset()
    host.start()
    clean = [host.row(step, drive[step]) for step in range(120)]
    checkpoints = checkpoints_of([f for out in clean for f in out])
    c = min(checkpoints)
    other = Host(firmware)
    frames = [other.frame("RestoreState", Step=c + 1, StateIndex=i, StateValue=v)
              for i, v in enumerate(checkpoints[c])]
    other.send(*frames, other.frame("Control", Command=int(Command.RESTORE), Step=c + 1))
    other.start(c + 1)
    for step in range(c + 1, 120):
        again = [f for f in other.row(step, drive[step]) if f.name != FIRMWARE_TIMING_MESSAGE]
        measured = [f for f in again if f.name == "Timing1"]     # a measured time: the engines' own
        assert [(f.name, f.signals) for f in again if f.name != "Timing1"] == \
            [(f.name, f.signals) for f in clean[step] if f.name != "Timing1"], step
        assert len(measured) == sum(f.name == "Timing1" for f in clean[step])


def test_an_elf_of_another_model_or_core_is_refused_in_one_sentence(artifacts, firmware_elf):
    lti = load_artifact(artifacts["lti"])
    with pytest.raises(FirmwareError, match=r"is the firmware of model [0-9a-f]{8}, not of the artifact's model "
                                            f"{lti.model_id:08x}; build it from this artifact"):
        make_node(lti, engine="firmware", firmware=firmware_elf("hammerstein"))
    with pytest.raises(FirmwareError, match="is an ELF for .*x86|not for an ARM Cortex-M4F"):
        FirmwareEstimator(lti, os.path.realpath(sys.executable))     # an ELF, for this machine's core
    with pytest.raises(FirmwareError, match="is not an ELF file"):
        FirmwareEstimator(lti, artifacts["lti"])
    with pytest.raises(ValueError, match="needs the model's firmware ELF"):
        make_node(lti, engine="firmware")


def test_an_emulator_fault_is_an_internal_fault_and_a_reset_recovers(artifacts, firmware_elf):
    artifact = load_artifact(artifacts["lti"])
    node = FirmwareNode(artifact, firmware_elf("lti"))
    host = Host(node)
    host.reset()
    host.start()
    drive = drive_rows(10)
    node.fw.max_instructions = 1000              # a row with a model step runs ~1,500: it "does not return"
    host.row(0, drive[0])
    host.row(1, drive[1])
    out = host.row(2, drive[2])                  # completes a model step
    assert node.state == TargetState.FAULT and node.faults & FaultBit.INTERNAL
    assert out[0].name == "Status" and out[0].signals["State"] == TargetState.FAULT
    assert node.last_error.startswith("node_on_frame in ") and "did not return" in node.last_error
    assert decode_any(node.heartbeat_frames()[0]).signals["State"] == TargetState.FAULT   # the heartbeat goes on
    assert host.row(3, drive[3]) == [] and node.errors["sequence"] == 1                   # nothing answered
    node.fw.max_instructions = 1_000_000
    host.reset()
    host.start()
    assert node.state == TargetState.RUNNING and not node.faults & FaultBit.INTERNAL
    assert [f.name for f in host.row(0, drive[0])][:2] == ["Temperatures1", "Temperatures2"]


def test_a_broken_elf_faults_on_the_bus_and_the_heartbeat_goes_on(artifacts, firmware_elf):
    artifact = load_artifact(artifacts["lti"])
    node = FirmwareNode(artifact, patched_elf(firmware_elf("lti"), "fw_step", UDF))
    errors: list[str] = []
    host = Host(node)
    seen = serve_and_listen(node, (*host_frames_reset(host), host.frame("Control", Command=int(Command.START), Step=0),
                                   *[f for step in range(3) for f in host.row_frames(step, (50.0, 500.0, 40.0, 25.0))]),
                            0.6, on_error=errors.append)
    states = [f.signals["State"] for f in seen if f.name == "Status"]
    assert states.count(TargetState.FAULT) >= 4           # the heartbeat goes on, in FAULT
    assert node.faults & FaultBit.INTERNAL and "undefined instruction" in node.last_error
    assert len(errors) == 1 and errors[0].startswith("internal fault, state FAULT until a RESET: node_on_frame")


def test_a_long_gap_overflows_the_bounded_queue_without_losing_the_temperatures(artifacts, firmware_elf):
    """Rows lost for more model steps than the 40-frame transmit queue holds: the temperatures go first, the
    timing frames that do not fit are dropped and counted, the model still keeps time (as the Python node)."""
    python, firmware = nodes(artifacts, firmware_elf, "lti")
    drive = drive_rows(60, seed=5)
    hosts = Host(python), Host(firmware)
    for host in hosts:
        host.reset()
        host.start()
        host.row(0, drive[0])
    expected, got = (host.row(40, drive[40]) for host in hosts)    # rows 1..39 lost: 16 model steps
    assert [f.name for f in got[:2]] == ["Temperatures1", "Temperatures2"]
    assert [(f.name, f.signals) for f in got[:2]] == [(f.name, f.signals) for f in expected[:2]]
    assert len(got) == 40 and len(expected) == 2 + 3 * 16
    assert firmware.stats()["tx_dropped"] == 2 + 4 * 16 - 40
    assert python.model_steps == firmware.model_steps == 16
    assert np.array_equal(python.model.x.view(np.uint32), firmware.x.view(np.uint32))
