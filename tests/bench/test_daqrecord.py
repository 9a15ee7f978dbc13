"""A DAQ recording into an MF4 (bench/daqrecord.py): the DAQ list as `configure_daq` sets it up in the Python
node's real slave, its packets heard by `DaqRecorder`, written by asammdf and read back by asammdf equal to the
packets' floats and to the node's temperature replies; a lost packet is a NaN and counted. The same through pyxcp
and a target process: tests/integration/test_xcp_pyxcp.py."""

from __future__ import annotations

import struct
from types import SimpleNamespace

import can
import numpy as np
import pytest

from bench.daqrecord import DaqRecorder, configure_daq, daq_channels, write_daq_mf4
from bench.errors import BenchError
from bench.model.default import default_artifact_path
from dbc import FrameCodec
from dbc.codec import decode_any
from host.canlog import mf4_available
from host.replay import encode_row
from target_sim.artifact import load_artifact
from target_sim.node import TargetNode

from helpers import session_drive, session_start

U16, U32 = struct.Struct("<H"), struct.Struct("<I")
CHANNELS = ("y_est_0", "y_est_1", "y_est_2", "y_est_3", "estimate_1")
ROWS = 40


class InProcessMaster:
    """The pyxcp Master calls `configure_daq` makes, as the XCP command packets pyxcp sends, into a node's slave."""

    def __init__(self, node: TargetNode):
        self.node = node

    def _cto(self, *parts: bytes) -> bytes:
        reply = self.node.xcp.command(b"".join(parts))
        assert reply is not None and reply[0] == 0xFF, reply
        return reply

    def freeDaq(self):  # noqa: N802 - pyxcp's names
        self._cto(bytes((0xD6,)))

    def allocDaq(self, count):  # noqa: N802
        self._cto(bytes((0xD5, 0)), U16.pack(count))

    def allocOdt(self, daq_list, count):  # noqa: N802
        self._cto(bytes((0xD4, 0)), U16.pack(daq_list), bytes((count,)))

    def allocOdtEntry(self, daq_list, odt, count):  # noqa: N802
        self._cto(bytes((0xD3, 0)), U16.pack(daq_list), bytes((odt, count)))

    def setDaqPtr(self, daq_list, odt, entry):  # noqa: N802
        self._cto(bytes((0xE2, 0)), U16.pack(daq_list), bytes((odt, entry)))

    def writeDaq(self, bit_offset, size, extension, address):  # noqa: N802
        self._cto(bytes((0xE1, bit_offset, size, extension)), U32.pack(address))

    def setDaqListMode(self, mode, daq_list, event, prescaler, priority):  # noqa: N802
        self._cto(bytes((0xE0, mode)), U16.pack(daq_list), U16.pack(event), bytes((prescaler, priority)))

    def startStopDaqList(self, mode, daq_list):  # noqa: N802
        return SimpleNamespace(firstPid=self._cto(bytes((0xDE, mode)), U16.pack(daq_list))[1])

    def startStopSynch(self, mode):  # noqa: N802
        self._cto(bytes((0xDD, mode)))


def recorded_session(node: TargetNode, channels, drop=()) -> tuple[DaqRecorder, list[dict]]:
    """A lockstep session through `node` with the DAQ list on: the recorder (every DAQ packet, stamped 0.1 s per
    row, except the packet numbers in `drop`) and the temperature replies of the rows that ran a model step."""
    node.xcp.command(bytes((0xFF, 0)))
    master = InProcessMaster(node)
    recorder = DaqRecorder(configure_daq(master, channels), len(channels))
    master.startStopSynch(0x01)
    codec = FrameCodec("HOST")
    for frame in session_start(codec):
        node.handle(frame)
    replies, heard = [], 0
    for row, values in enumerate(session_drive(ROWS, 5)):
        out = [reply for frame in encode_row(codec, row, values) for reply in node.handle(frame)]
        daq = [m for m in out if m.arbitration_id == recorder.arbitration_id]
        if daq:
            replies.append({name: signals for m in out if m.arbitration_id != recorder.arbitration_id
                            for name, signals in [(decode_any(m).name, decode_any(m).signals)]})
        for packet in daq:
            packet.timestamp = 1_700_000_000.0 + 0.1 * row
            if heard not in drop:
                recorder.on_message_received(packet)
            heard += 1
    return recorder, replies


@pytest.fixture
def node_and_channels():
    artifact = load_artifact(default_artifact_path())
    return TargetNode(artifact), daq_channels(artifact, CHANNELS)


@pytest.mark.skipif(not mf4_available(), reason="asammdf is not installed")
def test_a_daq_recording_reads_back_from_the_mf4_as_recorded(node_and_channels, tmp_path):
    from asammdf import MDF

    node, channels = node_and_channels
    recorder, replies = recorded_session(node, channels)
    samples = recorder.samples()
    assert samples.lost == 0 and samples.values.shape == (node.model_steps, len(CHANNELS)) and node.model_steps > 5
    # each value is the node's reply within the frames' 0.01 °C
    winding = [r["Temperatures1"]["WindingTemp"] for r in replies]
    assert np.allclose(samples.values[:, 1], winding, atol=0.005 + 1e-9)
    assert np.array_equal(samples.values[:, 1], samples.values[:, 4])     # y_est_1 is the estimate after a step
    path = write_daq_mf4(tmp_path / "daq.mf4", channels, samples)
    assert [p.name for p in tmp_path.iterdir()] == ["daq.mf4"]
    mdf = MDF(str(path))
    try:
        assert mdf.header.start_time.timestamp() == pytest.approx(samples.times[0], abs=1e-6)
        for i, channel in enumerate(channels):
            signal = mdf.get(channel.name)
            assert signal.samples.dtype == np.float32 and np.array_equal(signal.samples, samples.values[:, i])
            assert signal.unit == "degC" and signal.timestamps == pytest.approx(samples.times - samples.times[0])
    finally:
        mdf.close()


def test_a_lost_packet_is_a_nan_in_its_sample_and_counted(node_and_channels):
    node, channels = node_and_channels
    complete, _ = recorded_session(TargetNode(load_artifact(default_artifact_path())), channels)
    # packet 5 s + o is sample s's ODT o: sample 0's first, sample 1's third and sample 2's second go missing
    recorder, _ = recorded_session(node, channels, drop=(0, 7, 11))
    lossy, full = recorder.samples(), complete.samples()
    assert lossy.lost == 3 and lossy.values.shape == full.values.shape
    assert np.argwhere(np.isnan(lossy.values)).tolist() == [[0, 0], [1, 2], [2, 1]]
    kept = ~np.isnan(lossy.values)
    assert np.array_equal(lossy.values[kept], full.values[kept])


def test_an_unknown_measurement_is_refused_naming_the_known_ones():
    with pytest.raises(BenchError, match=r"no measurement obs_sigma_1; its measurements are x_state_0, "):
        daq_channels(load_artifact(default_artifact_path()), ["y_est_0", "obs_sigma_1"])


def test_only_the_lists_packets_are_kept():
    recorder = DaqRecorder(first_pid=2, count=2)
    for pid in (0xFF, 0xFE, 1, 2, 3, 4):
        recorder.on_message_received(can.Message(arbitration_id=recorder.arbitration_id, is_extended_id=False,
                                                 data=bytes((pid,)) + struct.pack("<f", pid)))
    recorder.on_message_received(can.Message(arbitration_id=0x123, data=bytes((2, 0, 0, 0, 0))))
    assert [data[0] for _, data in recorder.packets] == [2, 3]
