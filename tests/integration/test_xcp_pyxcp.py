"""pyxcp as the XCP master of the Python target node (and of the firmware node's C slave) over the bench's own bus
(udp_multicast, pyxcp's public CAN config): connect, identify, read the temperatures by UPLOAD, record them by DAQ
at every model step, and calibrate the observer's sensor offset (the firmware's alpha_cu) during a run; the run's
replies equal an in-process node given the same frames and the same calibration at the same row, bit for bit, and
differ from the uncalibrated run."""

from __future__ import annotations

import struct
import time
from pathlib import Path

import can
import numpy as np
import pytest

from bench.daqrecord import configure_daq, daq_channels
from dbc import Command, FrameCodec
from dbc.codec import decode_any
from dbc.contract import REPLY_SIGNALS
from dbc.xcp import cmd_id, res_id
from host.canlog import mf4_available
from host.replay import encode_row
from target_sim.artifact import load_artifact
from target_sim.node import TargetNode

from helpers import ROOT, SESSION_INITIAL, private_udp_bus, session_drive, session_start, start_target, subprocess_env

pyxcp_config = pytest.importorskip("pyxcp.config")
pyxcp_master = pytest.importorskip("pyxcp.master")

ROWS = 160
CALIBRATE_AT = 60          # the row after which the master downloads the new sensor offset
OFFSET = 3.0               # K: the sensor reads this much warm
REPLY_TIMEOUT_S = 5.0


def master(config):
    """A pyxcp master on the bench's udp_multicast bus, configured through pyxcp's public config."""
    app = pyxcp_config.create_application_from_config({"Transport": {"CAN": {
        "interface": "udp_multicast", "channel": config.channel, "can_id_master": cmd_id(),
        "can_id_slave": res_id()}}})
    app.transport.layer = "CAN"
    app.transport.can.udp_multicast.port = config.kwargs["port"]
    app.general.disable_error_handling = True      # an ERR packet raises, not pyxcp's retry matrix
    return pyxcp_master.Master("can", config=app)


class Host:
    """A lockstep host on its own bus: sends each row's frames and waits for its temperatures; keeps every DAQ packet
    it hears (XCP packets on the response id whose identifier is an ODT number)."""

    def __init__(self, bus: can.BusABC):
        self.bus, self.codec = bus, FrameCodec("HOST")
        self.daq: list[bytes] = []
        self.temps: dict[int, dict[str, dict]] = {}
        self.log: list[can.Message] = []      # every frame heard, in bus order (the host's own come back too)

    def send(self, frames) -> None:
        for frame in frames:
            self.bus.send(frame)

    def wait(self, step: int) -> None:
        deadline = time.monotonic() + REPLY_TIMEOUT_S
        while time.monotonic() < deadline:
            msg = self.bus.recv(0.05)
            if msg is None:
                continue
            self.log.append(msg)
            if msg.arbitration_id == res_id():
                if msg.data[0] < 0xFC:
                    self.daq.append(bytes(msg.data))
                continue
            name = message_name(msg)
            if name in REPLY_SIGNALS:
                signals = decode_any(msg).signals
                if int(signals["Step"]) == step:
                    self.temps.setdefault(step, {})[name] = signals
                    if len(self.temps[step]) == len(REPLY_SIGNALS):
                        return
        raise AssertionError(f"no temperatures for row {step} within {REPLY_TIMEOUT_S} s")

    def drain(self, seconds: float = 0.3) -> None:
        """Keep the DAQ packets still in flight."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            msg = self.bus.recv(0.05)
            if msg is not None:
                self.log.append(msg)
            if msg is not None and msg.arbitration_id == res_id() and msg.data[0] < 0xFC:
                self.daq.append(bytes(msg.data))


def message_name(msg: can.Message) -> str | None:
    try:
        return decode_any(msg).name
    except Exception:  # noqa: BLE001 - XCP frames, the host's own frames looping back
        return None


@pytest.fixture(scope="module")
def observer_artifact(tmp_path_factory, small_dataset) -> Path:
    """The conftest's observer (`--bias none`: the DAQ's y_est is the reply), ungated (`--gate none`): the
    calibration steps the sensor's reading by OFFSET K at once, which the default 3-sigma innovation gate rightly
    takes for a lying sensor (it rejects the readings and flags the sensor; the gate's own tests show that). Here
    the calibration itself is under test."""
    from bench.cli import main

    out = tmp_path_factory.mktemp("xcp-observer") / "observer.json"
    assert main(["observer", "--train", str(small_dataset), "--evaluations", "2", "--gate", "none", "--bias", "none",
                 "--out", str(out), "--quiet"]) == 0
    return out


@pytest.fixture(scope="module")
def bench(observer_artifact):
    """(bus config, host bus) with a Python target serving the observer model on a private udp_multicast bus."""
    config = private_udp_bus()
    with start_target("--model", observer_artifact, "--quiet", *config.to_argv(),
                      env=subprocess_env(can_settings=False)):
        bus = config.open()
        try:
            deadline = time.monotonic() + 60
            while message_name(bus.recv(0.5) or can.Message(arbitration_id=0x7FF)) != "Status":
                assert time.monotonic() < deadline, "the target sent no heartbeat within 60 s"
            yield config, bus
        finally:
            bus.shutdown()


@pytest.fixture(scope="module")
def rows(observer_artifact):
    """Drive rows and a winding sensor 1.5 K above the open loop's winding (slot `sensor`; no flux reading)."""
    from target_sim.model import run_offline

    artifact = load_artifact(observer_artifact)
    drive = session_drive(ROWS, 3)
    steps, open_loop = run_offline(artifact, drive, SESSION_INITIAL)
    sensor = np.round(np.interp(np.arange(ROWS), steps, open_loop[:, 1]) + 1.5, 2)
    return drive, np.column_stack([sensor, np.full(ROWS, np.nan)])


def reference_node(artifact_path, rows, calibrate: bool) -> tuple[TargetNode, dict[int, list[float]]]:
    """An in-process node fed the same host frames (and the same DOWNLOAD after row CALIBRATE_AT): its winding
    estimate per row."""
    node = TargetNode(load_artifact(artifact_path), clock_ns=lambda: 0)
    codec = FrameCodec("HOST")
    for frame in session_start(codec):
        node.handle(frame)
    offset = node.xcp.memory.by_name["cal_sensor0_offset"].address
    if calibrate:
        node.xcp.command(bytes((0xFF, 0)))
    out = {}
    drive, measured = rows
    for row in range(ROWS):
        replies = [r for frame in encode_row(codec, row, drive[row], measured[row].tolist())
                   for r in node.handle(frame)]
        out[row] = [decode_any(r).signals["WindingTemp"] for r in replies if message_name(r) == "Temperatures1"][0]
        if calibrate and row == CALIBRATE_AT:
            assert node.xcp.command(bytes((0xF6, 0, 0, 0)) + struct.pack("<I", offset)) == b"\xff"
            assert node.xcp.command(bytes((0xF0, 4)) + struct.pack("<f", OFFSET)) == b"\xff"
    return node, out


DAQ_CELLS = ("y_est_0", "y_est_1", "y_est_2", "y_est_3", "obs_sigma_1")


@pytest.mark.slow   # about 45 s on one worker: the default run keeps its 5-minute budget; .ci/run runs it
def test_pyxcp_measures_and_calibrates_a_running_target(bench, rows, observer_artifact, tmp_path):
    config, bus = bench
    host = Host(bus)
    reference, calibrated = reference_node(observer_artifact, rows, calibrate=True)
    _, uncalibrated = reference_node(observer_artifact, rows, calibrate=False)
    cells = reference.xcp.memory.by_name
    drive, measured = rows
    with master(config) as xcp:
        connected = xcp.connect()
        assert connected.maxCto == 8 and connected.maxDto == 8 and connected.resource.daq and connected.resource.calpag
        assert xcp.getStatus().sessionStatus.daqRunning is False
        assert xcp.getCommModeInfo().xcpDriverVersionNumber == 0x10
        model_id = load_artifact(observer_artifact).model_id
        assert xcp.identifier(0) == f"pmsm-thermal-bench model {model_id:08x}"
        # DAQ: the four temperatures and the winding's 1-sigma, one float per ODT, on the model step's event
        assert configure_daq(xcp, daq_channels(load_artifact(observer_artifact), DAQ_CELLS)) == 0
        xcp.startStopSynch(0x01)
        assert xcp.getStatus().sessionStatus.daqRunning is True

        host.send(session_start(host.codec))
        for row in range(ROWS):
            host.send(encode_row(host.codec, row, drive[row], measured[row].tolist()))
            host.wait(row)
            if row == CALIBRATE_AT:
                # UPLOAD the winding temperature the node holds: the reply's value within its 0.01 K resolution
                (winding,) = struct.unpack("<f", xcp.shortUpload(4, cells["estimate_1"].address))
                assert winding == pytest.approx(host.temps[row]["Temperatures1"]["WindingTemp"], abs=0.005)
                xcp.setMta(cells["cal_sensor0_offset"].address)
                xcp.download(struct.pack("<f", OFFSET))
                assert struct.unpack("<f", xcp.shortUpload(4, cells["cal_sensor0_offset"].address))[0] == OFFSET
        host.send([host.codec.encode("Control", {"Command": int(Command.STOP), "Step": 0})])
        xcp.startStopSynch(0x00)
        host.drain()
        # refused: a read-only cell, a value outside the limits, an unknown command
        xcp.setMta(cells["x_state_0"].address)
        with pytest.raises(Exception, match="ACCESS_DENIED"):
            xcp.download(struct.pack("<f", 1.0))
        xcp.setMta(cells["cal_sensor0_offset"].address)
        with pytest.raises(Exception, match="OUT_OF_RANGE"):
            xcp.download(struct.pack("<f", 100.0))
        xcp.disconnect()

    can_winding = {row: host.temps[row]["Temperatures1"]["WindingTemp"] for row in range(ROWS)}
    assert can_winding == calibrated                    # the calibrated run is its calibrated reference, bit for bit
    moved = max(abs(can_winding[r] - uncalibrated[r]) for r in range(ROWS))
    assert all(can_winding[r] == uncalibrated[r] for r in range(CALIBRATE_AT + 1))
    # a sensor said to read 3 K warm: the filter pulls the winding down (a measured 0.2 K in 100 rows)
    assert moved >= 0.1 and can_winding[ROWS - 1] < uncalibrated[ROWS - 1], f"moved {moved:.3f} K"

    # DAQ: every model step's packets, none lost, each value the step's reply within its resolution
    steps = reference.model_steps
    by_pid = {pid: [struct.unpack_from("<f", p, 1)[0] for p in host.daq if p[0] == pid] for pid in range(5)}
    assert [len(v) for v in by_pid.values()] == [steps] * 5
    step_rows = sorted({row for row in range(ROWS) if reference.accumulator.ends_interval(row)})
    assert len(step_rows) == steps
    for pid, role in ((0, "YokeTemp"), (1, "WindingTemp"), (2, "ToothTemp"), (3, "MagnetTemp")):
        message = "Temperatures1" if role in ("WindingTemp", "MagnetTemp") else "Temperatures2"
        replies = [host.temps[row][message][role] for row in step_rows]
        assert np.allclose(by_pid[pid], replies, atol=0.005 + 1e-9), role
    assert all(v > 0 for v in by_pid[4])               # the winding's 1-sigma

    # bench analyze: the log's calibration is replayed by the target's twin, so the run is clean against its
    # calibrated reference; the same log without its XCP frames is judged against the uncalibrated references
    from bench.analysis.canmetrics import compute
    from bench.analysis.logdecode import decode_log
    from bench.analysis.verdict import problems

    from helpers import write_frames

    artifact = load_artifact(observer_artifact)
    record = decode_log(write_frames(tmp_path / "calibrated.blf", host.log))
    assert record.xcp_downloads >= 1 and record.invalid == {}
    results, _ = compute(record, artifact)
    assert results.figure_rows.kept == ROWS and problems(results) == []
    stripped = [m for m in host.log if m.arbitration_id not in (cmd_id(), res_id())]
    uncalibrated_results, _ = compute(decode_log(write_frames(tmp_path / "stripped.blf", stripped)), artifact)
    assert uncalibrated_results.figure_rows.kept < ROWS and problems(uncalibrated_results)


MF4_CHANNELS = ("y_est_0", "y_est_1", "y_est_2", "y_est_3", "obs_sigma_1", "obs_extra_0")


@pytest.fixture(scope="module")
def lagged_artifact(tmp_path_factory, small_dataset) -> Path:
    """An observer whose winding sensor lags (τ 60 s): the filter carries the lag's state, `obs_extra_0` (no output
    bias, `--bias none`: the DAQ's y_est is the reply)."""
    from bench.cli import main

    out = tmp_path_factory.mktemp("xcp-lagged") / "lagged.json"
    assert main(["observer", "--train", str(small_dataset), "--evaluations", "2", "--lag", "60", "--bias", "none",
                 "--out", str(out), "--quiet"]) == 0
    return out


@pytest.mark.slow   # an observer fit and a target process: about 40 s on a loaded machine
@pytest.mark.skipif(not mf4_available(), reason="asammdf is not installed")
def test_a_pyxcp_daq_recording_into_an_mf4_reads_back_as_the_target_sent_it(lagged_artifact, rows, tmp_path):
    """docs/tutorials/xcp.md's recording: pyxcp sets up the DAQ list of the four temperatures, the winding's 1-σ and
    the sensor's lag state on the model step's event (`bench.daqrecord`), every step's packets are heard, and
    asammdf reads back from the MF4 exactly the floats the packets carried: the temperatures the CAN replies', the
    lag state the in-process node's after the same frames, bit for bit."""
    from asammdf import MDF

    from bench.daqrecord import DaqRecorder, write_daq_mf4

    artifact = load_artifact(lagged_artifact)
    channels = daq_channels(artifact, MF4_CHANNELS)
    config = private_udp_bus()
    drive, measured = rows
    with start_target("--model", lagged_artifact, "--quiet", *config.to_argv(),
                      env=subprocess_env(can_settings=False)):     # stopped when the block ends
        bus = config.open()
        try:
            deadline = time.monotonic() + 60
            while message_name(bus.recv(0.5) or can.Message(arbitration_id=0x7FF)) != "Status":
                assert time.monotonic() < deadline, "the target sent no heartbeat within 60 s"
            host = Host(bus)
            with master(config) as xcp:
                xcp.connect()
                recorder = DaqRecorder(configure_daq(xcp, channels), len(channels))
                xcp.startStopSynch(0x01)
                host.send(session_start(host.codec))
                for row in range(ROWS):
                    host.send(encode_row(host.codec, row, drive[row], measured[row].tolist()))
                    host.wait(row)
                xcp.startStopSynch(0x00)
                host.drain()
                xcp.disconnect()
        finally:
            bus.shutdown()
    for msg in host.log:
        recorder.on_message_received(msg)
    samples = recorder.samples()
    path = write_daq_mf4(tmp_path / "daq.mf4", channels, samples)

    # the in-process node after the same frames: its lag state and temperatures at each model step
    node = TargetNode(artifact, clock_ns=lambda: 0)
    codec = FrameCodec("HOST")
    for frame in session_start(codec):
        node.handle(frame)
    cells, expected = node.xcp.memory.by_name, []
    for row in range(ROWS):
        before = node.model_steps
        for frame in encode_row(codec, row, drive[row], measured[row].tolist()):
            node.handle(frame)
        if node.model_steps > before:
            expected.append([np.float32(cells[name].read()) for name in MF4_CHANNELS])
    assert samples.lost == 0 and samples.values.shape == (node.model_steps, len(MF4_CHANNELS))
    assert np.array_equal(samples.values, np.array(expected, dtype=np.float32))
    step_rows = [row for row in range(ROWS) if node.accumulator.ends_interval(row)]
    winding = [host.temps[row]["Temperatures1"]["WindingTemp"] for row in step_rows]
    assert np.allclose(samples.values[:, 1], winding, atol=0.005 + 1e-9)
    assert np.all(samples.values[:, 4] > 0) and np.ptp(samples.values[:, 5]) > 0    # a 1-sigma, a lag that moves
    mdf = MDF(str(path))
    try:
        for i, name in enumerate(MF4_CHANNELS):
            assert np.array_equal(mdf.get(name).samples, samples.values[:, i]), name
        assert mdf.get("obs_extra_0").unit == "degC"
    finally:
        mdf.close()


PACKAGED = ROOT / "bench" / "data" / "default_model.json"
PACKAGED_ELF = ROOT / "bench" / "data" / "firmware" / "default_model.elf"
FIRMWARE_ROWS = 80
FIRMWARE_CALIBRATE_AT = 30
ALPHA_CU = 0.005           # 1/K: the copper coefficient the master downloads (the model's is 0.0039)
FIRMWARE_DAQ = ("y_est_0", "y_est_1", "y_est_2", "y_est_3", "estimate_1")


@pytest.fixture(scope="module")
def firmware_bench():
    """(bus config, host bus) with a firmware target (the packaged model's ELF in the emulated Cortex-M4F, its XCP
    slave in C) on a private udp_multicast bus."""
    config = private_udp_bus()
    with start_target("--model", PACKAGED, "--engine", "firmware", "--firmware", PACKAGED_ELF, "--quiet",
                      *config.to_argv(), env=subprocess_env(can_settings=False)):    # stopped when the block ends
        bus = config.open()
        try:
            deadline = time.monotonic() + 60
            while message_name(bus.recv(0.5) or can.Message(arbitration_id=0x7FF)) != "Status":
                assert time.monotonic() < deadline, "the firmware target sent no heartbeat within 60 s"
            yield config, bus
        finally:
            bus.shutdown()


@pytest.mark.slow   # the emulated core: about 20 s on one worker; .ci/run runs it
def test_pyxcp_measures_and_calibrates_the_firmware_target(firmware_bench, tmp_path):
    """pyxcp against the C slave: identify, DAQ of the temperatures at every model step, a DOWNLOAD of alpha_cu
    after row 30; the firmware's replies equal, bit for bit, the Python node given the same frames and calibration
    (its cells at the same ELF's addresses), and every DAQ value is its step's CAN reply within 0.005 K; `bench
    analyze` of the host's log replays the calibration at the ELF's addresses: clean, every row kept."""
    config, bus = firmware_bench
    host = Host(bus)
    artifact = load_artifact(PACKAGED)
    reference = TargetNode(artifact, clock_ns=lambda: 0, xcp_elf=PACKAGED_ELF)
    cells = reference.xcp.memory.by_name
    drive = session_drive(FIRMWARE_ROWS, 7)
    with master(config) as xcp:
        connected = xcp.connect()
        assert connected.maxCto == 8 and connected.resource.daq and connected.resource.calpag
        assert xcp.identifier(0) == f"pmsm-thermal-bench model {artifact.model_id:08x}"
        assert configure_daq(xcp, daq_channels(artifact, FIRMWARE_DAQ, PACKAGED_ELF)) == 0
        xcp.startStopSynch(0x01)
        assert xcp.getStatus().sessionStatus.daqRunning is True

        for frame in session_start(host.codec):
            reference.handle(frame)
        host.send(session_start(host.codec))
        expected = {}
        for row in range(FIRMWARE_ROWS):
            frames = encode_row(host.codec, row, drive[row])
            replies = [r for frame in frames for r in reference.handle(frame)]
            expected[row] = [decode_any(r).signals["WindingTemp"] for r in replies
                             if message_name(r) == "Temperatures1"][0]
            host.send(frames)
            host.wait(row)
            if row == FIRMWARE_CALIBRATE_AT:
                (winding,) = struct.unpack("<f", xcp.shortUpload(4, cells["estimate_1"].address))
                assert winding == pytest.approx(host.temps[row]["Temperatures1"]["WindingTemp"], abs=0.005)
                xcp.setMta(cells["cal_alpha_cu"].address)
                xcp.download(struct.pack("<f", ALPHA_CU))
                assert reference.xcp.command(bytes((0xFF, 0)))[0] == 0xFF          # the same calibration
                address = struct.pack("<I", cells["cal_alpha_cu"].address)
                assert reference.xcp.command(bytes((0xF6, 0, 0, 0)) + address) == b"\xff"
                assert reference.xcp.command(bytes((0xF0, 4)) + struct.pack("<f", ALPHA_CU)) == b"\xff"
                assert struct.unpack("<f", xcp.shortUpload(4, cells["cal_alpha_cu"].address))[0] == \
                    np.float32(ALPHA_CU)
        host.send([host.codec.encode("Control", {"Command": int(Command.STOP), "Step": 0})])
        xcp.startStopSynch(0x00)
        host.drain()
        xcp.setMta(cells["x_state_0"].address)
        with pytest.raises(Exception, match="ACCESS_DENIED"):
            xcp.download(struct.pack("<f", 1.0))
        xcp.setMta(cells["cal_alpha_cu"].address)
        with pytest.raises(Exception, match="OUT_OF_RANGE"):
            xcp.download(struct.pack("<f", 0.5))
        xcp.disconnect()

    assert {row: host.temps[row]["Temperatures1"]["WindingTemp"] for row in range(FIRMWARE_ROWS)} == expected
    steps = reference.model_steps
    by_pid = {pid: [struct.unpack_from("<f", p, 1)[0] for p in host.daq if p[0] == pid]
              for pid in range(len(FIRMWARE_DAQ))}
    assert [len(v) for v in by_pid.values()] == [steps] * len(FIRMWARE_DAQ) and steps > 20
    step_rows = sorted({row for row in range(FIRMWARE_ROWS) if reference.accumulator.ends_interval(row)})
    for pid, role in ((0, "YokeTemp"), (1, "WindingTemp"), (2, "ToothTemp"), (3, "MagnetTemp")):
        message = "Temperatures1" if role in ("WindingTemp", "MagnetTemp") else "Temperatures2"
        replies = [host.temps[row][message][role] for row in step_rows]
        assert np.allclose(by_pid[pid], replies, atol=0.005 + 1e-9), role

    # bench analyze: a firmware log's twin takes the packaged model's shipped ELF, so the DOWNLOAD at the C's
    # fw_cal_alpha_cu is replayed (the refused ones refused alike): the calibrated run is clean (exit status 0)
    from bench.cli import main

    from helpers import write_frames

    log = write_frames(tmp_path / "firmware.blf", host.log)
    assert main(["analyze", str(log), "--no-report", "--quiet"]) == 0
