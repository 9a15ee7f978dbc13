"""The firmware node's XCP slave (bench/firmware/xcp.c in the emulated Cortex-M4F) against the Python node's
(target_sim.xcp), its cells laid out by the same ELF: one command sequence (the session commands, uploads, the
checksum, calibrations and their refusals, the DAQ configuration and its refusals) and a DAQ run over model steps
and heartbeats give the same reply bytes from both, and the calibration moves both models alike."""

from __future__ import annotations

import struct
import zlib

import can
import numpy as np
import pytest

from dbc import FrameCodec
from dbc.database import host_frame_ids
from dbc.xcp import cmd_id, res_id
from host.replay import encode_row
from target_sim.artifact import load_artifact
from target_sim.node import TargetNode
from target_sim.xcp.codes import Err
from target_sim.xcp.daq import DAQ_QUEUE, MAX_DAQ_LISTS, MAX_ODT_ENTRIES, MAX_ODTS, ODT_PAYLOAD

from helpers import ROOT, built_observer, session_drive, session_start, steady_form

PACKAGED = ROOT / "bench" / "data" / "default_model.json"
PACKAGED_ELF = ROOT / "bench" / "data" / "firmware" / "default_model.elf"


def u32(value: int) -> bytes:
    return struct.pack("<I", value)


def f32(value: float) -> bytes:
    return struct.pack("<f", value)


@pytest.fixture(scope="module")
def engines():
    """A fresh pair per use: (Python node with the ELF's layout, firmware node) of the packaged model."""
    from target_sim.firmware.node_engine import FirmwareNode

    artifact = load_artifact(PACKAGED)

    def make():
        return TargetNode(artifact, clock_ns=lambda: 0, xcp_elf=PACKAGED_ELF), FirmwareNode(artifact, PACKAGED_ELF)
    return make


def xcp_of(frames) -> list[bytes]:
    return [bytes(m.data) for m in frames if m.arbitration_id == res_id()]


def command(node, cto: bytes) -> list[bytes]:
    return xcp_of(node.handle(can.Message(arbitration_id=cmd_id(), is_extended_id=False, data=cto)))


def both(pair, cto: bytes) -> list[bytes]:
    """`cto` into both engines: their replies, which must be the same bytes."""
    python, firmware = (command(node, cto) for node in pair)
    assert firmware == python, f"{cto.hex()}: firmware {[r.hex() for r in firmware]}, " \
                               f"python {[r.hex() for r in python]}"
    return python


def test_the_firmware_answers_every_command_and_refusal_as_the_python_slave(engines):
    pair = engines()
    python, firmware = pair
    cells = python.xcp.memory.by_name
    x0, y0, e0 = (cells[name].address for name in ("x_state_0", "y_est_0", "estimate_0"))
    alpha = cells["cal_alpha_cu"].address
    assert alpha == firmware.fw.symbols["fw_cal_alpha_cu"].address      # the C's own variable, not a page
    assert both(pair, bytes((0xFD,))) == [] and both(pair, b"") == [bytes((0xFE, Err.CMD_SYNTAX))]
    assert both(pair, bytes((0xFF, 0))) == [bytes.fromhex("ff05800808000101")]
    for cto in (bytes((0xFD,)), bytes((0xFC,)), bytes((0xFB,)), bytes((0x12,)), bytes((0xF6, 0)), bytes((0xFA,))):
        both(pair, cto)
    # GET_ID: both texts uploaded from the MTA, a type that does not exist
    for kind in (0, 1):
        length = struct.unpack_from("<I", both(pair, bytes((0xFA, kind)))[0], 4)[0]
        text = b"".join(both(pair, bytes((0xF5, min(7, length - i))))[0][1:] for i in range(0, length, 7))
        assert text.decode().endswith(f"{python.artifact.model_id:08x}")
    both(pair, bytes((0xFA, 5)))
    # uploads: each cell, runs across cells, partial floats, unmapped and too long
    for address in (x0, x0 + 1, y0 - 2, e0, e0 + 12, alpha, alpha - 3, 0x1000, 0x20000000 - 1, 0xFFFFFFFE):
        for size in (0, 1, 4, 7, 8):
            both(pair, bytes((0xF4, size, 0, 0)) + u32(address))
    both(pair, bytes((0xF6, 0, 0, 0)) + u32(x0))
    for _ in range(6):
        both(pair, bytes((0xF5, 7)))
    # BUILD_CHECKSUM: the state, the text, a run into unmapped bytes, sizes out of range
    for start, size in ((x0, 32), (x0, 48), (x0 + 3, 5), (x0, 4096), (x0, 0), (x0, 0x10001),
                        (python.xcp.id_address, 20)):
        both(pair, bytes((0xF6, 0, 0, 0)) + u32(start))
        reply = both(pair, bytes((0xF3, 0, 0, 0)) + u32(size))[0]
        if reply[0] == 0xFF:
            assert struct.unpack_from("<I", reply, 4)[0] == zlib.crc32(python.xcp.memory.read(start, size))
    # DOWNLOAD: read-only, out of the limits, not a float's start, too short, too long, then one accepted
    for mta, cto in ((x0, bytes((0xF0, 4)) + f32(1.0)), (alpha, bytes((0xF0, 4)) + f32(0.5)),
                     (alpha, bytes((0xF0, 4)) + f32(-1e-3)), (alpha, bytes((0xF0, 4)) + f32(float("nan"))),
                     (alpha, bytes((0xF0, 4)) + f32(float("inf"))), (alpha + 2, bytes((0xF0, 2, 0, 0))),
                     (alpha, bytes((0xF0, 4, 0))), (alpha, bytes((0xF0, 7)) + bytes(6)), (alpha, bytes((0xF0, 0))),
                     (alpha, bytes((0xF0, 3, 1, 2, 3))), (0x1000, bytes((0xF0, 4)) + f32(0.0)),
                     (alpha, bytes((0xF0, 4)) + f32(-0.0)), (alpha, bytes((0xF0, 4)) + f32(0.01)),
                     (alpha, bytes((0xF0, 4)) + f32(0.005))):
        both(pair, bytes((0xF6, 0, 0, 0)) + u32(mta))
        both(pair, cto)
    assert both(pair, bytes((0xF4, 4, 0, 0)) + u32(alpha)) == [b"\xff" + f32(0.005)]
    assert python.model.alpha_cu == np.float32(0.005)
    assert python.xcp.calibrations == [("cal_alpha_cu", -0.0), ("cal_alpha_cu", np.float32(0.01)),
                                       ("cal_alpha_cu", np.float32(0.005))]
    stats = firmware.stats()["xcp"]
    assert stats["calibrations"] == 3 and stats["errors"] == sum(python.xcp.errors.values()) > 20


def configure_daq(pair) -> None:
    """A DAQ configuration with every kind of refusal on the way: list 0 (two ODTs: y_est and the estimate's
    winding, every 2nd model step), list 1 (x_state_0 and 3 bytes of the GET_ID text, on the heartbeat)."""
    python = pair[0]
    cells = python.xcp.memory.by_name
    x0, y0, e1 = (cells[name].address for name in ("x_state_0", "y_est_0", "estimate_1"))
    text = python.xcp.id_address
    sequence = [
        bytes((0xD5, 0, 1, 0)), bytes((0xD4, 0, 0, 0, 1)), bytes((0xD3, 0, 0, 0, 0, 1)),   # before FREE_DAQ
        bytes((0xE2, 0, 0, 0, 0, 0)), bytes((0xE1, 0xFF, 4, 0)) + u32(x0), bytes((0xDD, 1)),
        bytes((0xDA,)), bytes((0xD9,)), bytes((0xD6,)),
        bytes((0xD5, 0)), bytes((0xD5, 0, MAX_DAQ_LISTS + 1, 0)), bytes((0xD5, 0, 2, 0)), bytes((0xD5, 0, 2, 0)),
        bytes((0xD3, 0, 0, 0, 0, 1)), bytes((0xD4, 0, 2, 0, 1)), bytes((0xD4, 0, 0, 0, MAX_ODTS + 1)),
        bytes((0xD4, 0, 0, 0, 2)), bytes((0xD4, 0, 0, 0, 2)), bytes((0xD4, 0, 1, 0, 1)),
        bytes((0xD3, 0, 0, 0, 2, 1)), bytes((0xD3, 0, 0, 0, 0, ODT_PAYLOAD + 1)),
        bytes((0xD3, 0, 0, 0, 0, MAX_ODT_ENTRIES)), bytes((0xD3, 0, 0, 0, 0, 2)), bytes((0xD3, 0, 0, 0, 1, 1)),
        bytes((0xD3, 0, 1, 0, 0, 3)), bytes((0xD4, 0, 1, 0, 1)),
        bytes((0xE1, 0xFF, 4, 0)) + u32(y0),                                                # no pointer yet
        bytes((0xE2, 0, 0, 0, 0, 2)), bytes((0xE2, 0, 5, 0, 0, 0)), bytes((0xE2, 0, 0, 0, 0, 0)),
        bytes((0xE1, 0, 4, 0)) + u32(y0), bytes((0xE1, 0xFF, 4, 0)) + u32(y0),
        bytes((0xE1, 0xFF, 4, 0)) + u32(y0 + 4), bytes((0xE1, 0xFF, 0, 0)) + u32(y0 + 4),
        bytes((0xDE, 1, 0, 0)), bytes((0xE1, 0xFF, 3, 0)) + u32(y0 + 4), bytes((0xE1, 0xFF, 1, 0)) + u32(y0),
        bytes((0xE2, 0, 0, 0, 1, 0)), bytes((0xE1, 0xFF, 4, 0)) + u32(0x1000),
        bytes((0xE1, 0xFF, 4, 0)) + u32(e1),
        bytes((0xE2, 0, 1, 0, 0, 2)), bytes((0xE1, 0xFF, 2, 0)) + u32(text + 5),               # entry 2 first
        bytes((0xE2, 0, 1, 0, 0, 0)), bytes((0xE1, 0xFF, 4, 0)) + u32(x0),
        bytes((0xDE, 1, 1, 0)), bytes((0xDE, 2, 1, 0)), bytes((0xDD, 1)),                      # entry 1 missing
        bytes((0xE2, 0, 1, 0, 0, 1)), bytes((0xE1, 0xFF, 2, 0)) + u32(x0), bytes((0xE1, 0xFF, 0, 0)) + u32(x0),
        bytes((0xE2, 0, 1, 0, 0, 1)), bytes((0xE1, 0xFF, 1, 0)) + u32(0x1000),
        bytes((0xE1, 0xFF, 1, 0)) + u32(x0 + 4),
        bytes((0xE0, 0x10, 0, 0, 0, 0, 1, 0)), bytes((0xE0, 0x02, 0, 0, 0, 0, 1, 0)),
        bytes((0xE0, 0, 0, 0, 2, 0, 1, 0)), bytes((0xE0, 0, 0, 0, 0, 0, 0, 0)), bytes((0xE0, 0, 9, 0, 0, 0, 1, 0)),
        bytes((0xE0, 0, 0, 0, 0, 0, 2, 0)), bytes((0xE0, 0, 1, 0, 1, 0, 1, 0)),
        bytes((0xDE, 3, 0, 0)), bytes((0xDE, 1, 7, 0)), bytes((0xDE, 2, 1, 0)), bytes((0xDD, 4)),
        bytes((0xDE, 1, 0, 0)), bytes((0xE2, 0, 0, 0, 0, 0)), bytes((0xFD,)), bytes((0xDD, 1)), bytes((0xFD,)),
    ]
    for cto in sequence:
        both(pair, cto)


def test_a_daq_run_over_model_steps_and_heartbeats_gives_the_same_packets(engines):
    pair = engines()
    python, firmware = pair
    codec = FrameCodec("HOST")
    both(pair, bytes((0xFF, 0)))
    alpha = python.xcp.memory.by_name["cal_alpha_cu"].address
    both(pair, bytes((0xF6, 0, 0, 0)) + u32(alpha))
    both(pair, bytes((0xF0, 4)) + f32(0.006))                 # a calibration the steps below run with
    configure_daq(pair)
    for frame in session_start(codec):
        assert xcp_of(python.handle(frame)) == xcp_of(firmware.handle(frame)) == []
    packets = 0
    for row, values in enumerate(session_drive(50, 4)):
        for frame in encode_row(codec, row, values):
            replies = [xcp_of(node.handle(frame)) for node in pair]
            assert replies[1] == replies[0], row
            packets += len(replies[0])
        if row % 10 == 9:
            beats = [xcp_of(node.heartbeat_frames()) for node in pair]
            assert beats[1] == beats[0] and len(beats[0]) == 1
            both(pair, bytes((0xF4, 4, 0, 0)) + u32(python.xcp.memory.by_name["estimate_1"].address))
            both(pair, bytes((0xFD,)))
    assert python.model_steps == firmware.model_steps >= 8 and packets == 2 * ((python.model_steps + 1) // 2)
    assert np.array_equal(python.estimate, firmware.estimate)
    assert both(pair, bytes((0xFE,))) == [b"\xff"]                             # DISCONNECT stops the lists
    for frame in encode_row(codec, 50, session_drive(51, 4)[-1]):
        assert xcp_of(python.handle(frame)) == xcp_of(firmware.handle(frame)) == []
    stats = firmware.stats()["xcp"]
    assert stats["daq_packets"] == python.xcp.daq.packets and stats["daq_sample_cycles"]["max"] > 0


def test_the_calibrated_coefficient_moves_both_models_alike(engines):
    """alpha_cu at its upper limit: the firmware's step reads the downloaded value (its outputs leave the
    uncalibrated firmware's) and equals the calibrated Python model bit for bit."""
    calibrated, plain = engines(), engines()
    codec = FrameCodec("HOST")
    both(calibrated, bytes((0xFF, 0)))
    alpha = calibrated[0].xcp.memory.by_name["cal_alpha_cu"].address
    both(calibrated, bytes((0xF6, 0, 0, 0)) + u32(alpha))
    both(calibrated, bytes((0xF0, 4)) + f32(0.01))
    frames = session_start(codec) + [f for row, values in enumerate(session_drive(40, 6))
                                     for f in encode_row(codec, row, values)]
    for frame in frames:
        for node in (*calibrated, *plain):
            node.handle(frame)
    assert np.array_equal(calibrated[0].estimate, calibrated[1].estimate)
    assert not np.array_equal(calibrated[1].estimate, plain[1].estimate)
    assert np.array_equal(plain[0].estimate, plain[1].estimate)


def test_xcp_frames_are_not_frames_of_the_contract_to_the_firmware(engines):
    _, firmware = engines()
    frames = command(firmware, bytes((0xFF, 0)))
    assert frames == [bytes.fromhex("ff05800808000101")]
    counters = firmware.counters()
    assert counters["frames_received"] == 0 and counters["errors"]["unknown_id"] == 0


def observer_pair(path, firmware_elf):
    """(Python node with the ELF's layout, firmware node) of the observer artifact at `path`, its firmware built."""
    from target_sim.firmware.node_engine import FirmwareNode

    artifact = load_artifact(path)
    elf = firmware_elf(path)
    return (TargetNode(artifact, clock_ns=lambda: 0, xcp_elf=elf), FirmwareNode(artifact, elf))


def observer_session(artifact, rows: int) -> list[can.Message]:
    """The host's frames of a session of `rows` rows with a winding sensor 1.5 K warm of the open loop (within the
    gate: the filter updates), ABSENT every 7th row, not stopped."""
    from target_sim.model import run_offline

    from helpers import SESSION_INITIAL, session_frames

    drive = session_drive(rows, 8)
    steps, open_loop = run_offline(artifact, drive, SESSION_INITIAL)
    sensor = np.round(np.interp(np.arange(rows), steps, open_loop[:, 1]) + 1.5, 2)
    sensor[::7] = np.nan
    measured = np.column_stack([sensor, np.full(rows, np.nan)])
    return [f for f in session_frames(artifact, drive, stop=False, measurements=measured)
            if f.arbitration_id in host_frame_ids()]


def feed(pair, frames) -> int:
    """`frames` into both engines: their XCP frames (DAQ packets) must be the same bytes; how many there were."""
    packets = 0
    for frame in frames:
        replies = [xcp_of(node.handle(frame)) for node in pair]
        assert replies[1] == replies[0], frame
        packets += len(replies[0])
    return packets


def read_every_cell(pair) -> None:
    """Each cell of the catalogue, and runs of bytes across neighbours, read alike by both engines."""
    for cell in pair[0].xcp.memory.cells:
        assert both(pair, bytes((0xF4, 4, 0, 0)) + u32(cell.address))[0][0] == 0xFF, cell.name
        both(pair, bytes((0xF4, 7, 0, 0)) + u32(cell.address + 1))


# a value within each calibratable observer cell's limits, and one outside them (name prefix -> values)
CALIBRATIONS = {"cal_sensor0_offset": (1.5, 20.5), "cal_sensor0_lag": (0.95, 1.0), "cal_sensor0_r": (2.5, 0.0),
                "cal_q_": (0.02, -1.0)}


def calibrate_every_cell(pair) -> list[str]:
    """DOWNLOADs to every writable observer cell (refused out of its limits, accepted within), the same replies."""
    done = []
    for cell in pair[0].xcp.memory.cells:
        if cell.write is None or cell.name == "cal_alpha_cu":
            continue
        good, bad = next(v for prefix, v in CALIBRATIONS.items() if cell.name.startswith(prefix))
        both(pair, bytes((0xF6, 0, 0, 0)) + u32(cell.address))
        assert both(pair, bytes((0xF0, 4)) + f32(bad)) == [bytes((0xFE, Err.OUT_OF_RANGE))], cell.name
        assert both(pair, bytes((0xF0, 4)) + f32(good)) == [b"\xff"], cell.name
        done.append(cell.name)
    return done


def test_the_c_slave_serves_the_observers_cells_as_the_python_slave(observer_artifact, firmware_elf):
    """An observer model's firmware: every cell of the catalogue, the observer's too (1-sigma, innovations, sensor
    offset and R, Q), is a C variable at the address the A2L gives; before a session (P0's 1-sigma, no innovation),
    after steps, its calibrations and their refusals, and after steps with them, both engines answer the same
    bytes, and the calibrated filters give the same estimate."""
    pair = observer_pair(observer_artifact, firmware_elf)
    python, firmware = pair
    cells = python.xcp.memory.cells
    for cell in cells:
        symbol, _, index = cell.symbol.rstrip("]").partition("[")
        assert cell.address == firmware.fw.symbols[symbol].address + 4 * int(index or 0), cell.name
    assert {c.name for c in cells} >= {"obs_sigma_0", "obs_innov_0", "cal_sensor0_offset", "cal_sensor0_r",
                                       "cal_q_1"}
    both(pair, bytes((0xFF, 0)))
    read_every_cell(pair)
    frames = observer_session(python.artifact, 40)
    feed(pair, frames[:25])
    assert python.model_steps == firmware.model_steps > 0
    read_every_cell(pair)
    assert calibrate_every_cell(pair)
    feed(pair, frames[25:])
    read_every_cell(pair)
    sigma = python.xcp.memory.by_name["obs_sigma_0"].address
    both(pair, bytes((0xF6, 0, 0, 0)) + u32(sigma))
    assert both(pair, bytes((0xF3, 0, 0, 0)) + u32(16))[0][0] == 0xFF           # the 1-sigma array, checksummed
    assert np.array_equal(python.estimate, firmware.estimate)
    assert firmware.stats()["xcp"]["calibrations"] == len(python.xcp.calibrations) > 3
    assert np.isfinite(python.observer.filter.innovations[0])                 # the last step used its reading


def observer_daq(pair) -> int:
    """DAQ list 0 on the model step over the observer's cells (ODT 0: the winding's 1-sigma and 3 bytes of the
    first innovation; ODT 1: the sensor offset and 3 bytes of Q's winding element; ODT 2 where the filter has extra
    states: the first of them), started; its ODT count."""
    cells = pair[0].xcp.memory.by_name
    odts = [[("obs_sigma_1", 4), ("obs_innov_0", 3)], [("cal_sensor0_offset", 4), ("cal_q_1", 3)]]
    if "obs_extra_0" in cells:
        odts.append([("obs_extra_0", 4)])
    both(pair, bytes((0xD6,)))
    both(pair, bytes((0xD5, 0, 1, 0)))
    both(pair, bytes((0xD4, 0, 0, 0, len(odts))))
    for k, entries in enumerate(odts):
        both(pair, bytes((0xD3, 0, 0, 0, k, len(entries))))
    for k, entries in enumerate(odts):
        both(pair, bytes((0xE2, 0, 0, 0, k, 0)))
        for name, size in entries:
            assert both(pair, bytes((0xE1, 0xFF, size, 0)) + u32(cells[name].address)) == [b"\xff"], name
    both(pair, bytes((0xE0, 0, 0, 0, 0, 0, 1, 0)))
    assert both(pair, bytes((0xDE, 1, 0, 0))) == [bytes((0xFF, 0))]
    return len(odts)


@pytest.mark.slow
@pytest.mark.parametrize("which", ["lagged", "steady"])
def test_observer_cells_in_a_daq_run_with_calibrations_give_the_same_packets(which, request, firmware_elf):
    """The lagged winding sensor with the heat-bias state (UD form: the lag pole and Q in the prediction), and the
    same in the steady-state-gain form (Q read-only): a DAQ list over the observer's cells at every model step, the
    calibrations of every observer cell during the run (the lag pole, offset, R, Q), the same packets, replies
    and estimates from both engines; the calibration moved the estimate (against an uncalibrated Python node)."""
    path = request.getfixturevalue(f"{which}_observer_artifact")
    pair = observer_pair(path, firmware_elf)
    python, firmware = pair
    plain = TargetNode(python.artifact, clock_ns=lambda: 0)
    assert {"obs_extra_0", "obs_extra_1", "cal_sensor0_lag"} <= set(python.xcp.memory.by_name)
    both(pair, bytes((0xFF, 0)))
    read_every_cell(pair)
    odts = observer_daq(pair)
    frames = observer_session(python.artifact, 60)
    packets = feed(pair, frames[:30])
    calibrated = calibrate_every_cell(pair)
    assert "cal_sensor0_lag" in calibrated and any(n.startswith("cal_q_") for n in calibrated) == (which == "lagged")
    packets += feed(pair, frames[30:])
    for frame in frames:
        plain.handle(frame)
    read_every_cell(pair)
    assert packets == odts * python.model_steps and python.model_steps == firmware.model_steps
    assert np.array_equal(python.estimate, firmware.estimate)
    assert not np.array_equal(python.estimate, plain.estimate)
    assert firmware.stats()["xcp"]["daq_packets"] == python.xcp.daq.packets


@pytest.fixture(scope="module")
def lagged_observer_artifact(small_dataset, tmp_path_factory):
    """The packaged hammerstein model with a lagged winding sensor (tau 60 s) and the winding heat-bias state."""
    return built_observer(tmp_path_factory, small_dataset, "lagged", "--lag", "60", "--bias")


@pytest.fixture(scope="module")
def steady_observer_artifact(lagged_observer_artifact, tmp_path_factory):
    """The same observer in the steady-state-gain form."""
    return steady_form(lagged_observer_artifact, tmp_path_factory)


@pytest.mark.slow
def test_a_row_of_several_steps_queues_their_daq_packets_alike(engines):
    """Rows after lost rows run several model steps: each step's packets (4 ODTs) in order, while they fit the
    slave's queue of DAQ_QUEUE packets, the rest dropped and counted, the same bytes from both engines."""
    pair = engines()
    python, firmware = pair
    codec = FrameCodec("HOST")
    cells = python.xcp.memory.by_name
    names = ("y_est_0", "y_est_1", "estimate_2", "x_state_3")
    both(pair, bytes((0xFF, 0)))
    for cto in (bytes((0xD6,)), bytes((0xD5, 0, 1, 0)), bytes((0xD4, 0, 0, 0, len(names)))):
        both(pair, cto)
    for k, name in enumerate(names):
        both(pair, bytes((0xD3, 0, 0, 0, k, 1)))
        both(pair, bytes((0xE2, 0, 0, 0, k, 0)))
        assert both(pair, bytes((0xE1, 0xFF, 4, 0)) + u32(cells[name].address)) == [b"\xff"]
    both(pair, bytes((0xE0, 0, 0, 0, 0, 0, 1, 0)))
    both(pair, bytes((0xDE, 1, 0, 0)))
    for frame in session_start(codec):
        assert feed(pair, [frame]) == 0
    drive, row, counts = session_drive(80, 4), 0, []
    for gap in (0, 2, 0, 7, 0, 12, 0, 3):
        row += gap
        before = python.model_steps
        counts.append((feed(pair, encode_row(codec, row, drive[row])), python.model_steps - before))
        row += 1
    assert all(packets == min(len(names) * steps, DAQ_QUEUE) for packets, steps in counts), counts
    assert any(DAQ_QUEUE >= packets > len(names) for packets, _ in counts), counts     # several steps, all sent
    assert any(steps * len(names) > DAQ_QUEUE for _, steps in counts), counts         # more than the queue
    dropped = sum(len(names) * steps - packets for packets, steps in counts)
    assert python.xcp.stats()["daq_dropped"] == dropped > 0
    assert firmware.stats()["xcp"]["daq_packets"] == python.xcp.daq.packets


@pytest.fixture(scope="module")
def output_bias_observer_artifact(small_dataset, tmp_path_factory):
    """The packaged hammerstein model observing its winding with `bench observer`'s default bias (auto: the winding's
    output bias, added to the winding the target reports)."""
    path = built_observer(tmp_path_factory, small_dataset, "output-bias")
    assert load_artifact(path).content["observer"]["bias"] == "winding-output"
    return path


def winding_bits(value: float) -> int:
    """The bits Temperatures1's WindingTemp carries for `value` (as the codec encodes it)."""
    from dbc.database import layout_named

    s = layout_named("Temperatures1").signal("WindingTemp")
    return round((value - s.offset) / s.scale)


def reported_winding_by_daq(node, frames) -> list[tuple[int, float, float]]:
    """A DAQ list on the model step over the reported winding (`estimate_1`, ODT 0) and the model's (`y_est_1`,
    ODT 1), `frames` into `node`: per model step (the reply's WindingTemp bits, the two DAQ'd values)."""
    from dbc.database import frame_id, layout_named

    rows = []
    reply_id, s = frame_id("Temperatures1"), layout_named("Temperatures1").signal("WindingTemp")
    for frame in frames:
        out = node.handle(frame)
        replies = [int.from_bytes(bytes(m.data), "little") >> s.start & s.mask for m in out
                   if m.arbitration_id == reply_id]
        daq = {p[0]: struct.unpack_from("<f", p, 1)[0] for p in xcp_of(out)}
        if daq:
            assert len(replies) == 1 and sorted(daq) == [0, 1], (replies, daq)
            rows.append((replies[0], daq[0], daq[1]))
    return rows


def daq_the_reported_winding(node, addresses: dict[str, int]) -> None:
    """CONNECT, then DAQ list 0 on the model step: ODT 0 `estimate_1`, ODT 1 `y_est_1`, started."""
    for cto in (bytes((0xFF, 0)), bytes((0xD6,)), bytes((0xD5, 0, 1, 0)), bytes((0xD4, 0, 0, 0, 2))):
        assert command(node, cto)[0][0] == 0xFF
    for k, name in enumerate(("estimate_1", "y_est_1")):
        assert command(node, bytes((0xD3, 0, 0, 0, k, 1))) == [b"\xff"]
        assert command(node, bytes((0xE2, 0, 0, 0, k, 0))) == [b"\xff"]
        assert command(node, bytes((0xE1, 0xFF, 4, 0)) + u32(addresses[name])) == [b"\xff"], name
    assert command(node, bytes((0xE0, 0, 0, 0, 0, 0, 1, 0))) == [b"\xff"]
    assert command(node, bytes((0xDE, 1, 0, 0))) == [bytes((0xFF, 0))]


def check_reported_winding(rows, steps: int) -> None:
    """Every model step's DAQ'd reported winding is the CAN reply's WindingTemp bit for bit; the model's winding
    (y_est_1) is not, once the output bias has moved."""
    assert len(rows) == steps > 20
    assert all(bits == winding_bits(reported) for bits, reported, _ in rows)
    assert sum(bits != winding_bits(model) for bits, _, model in rows) > steps // 2


def test_a_daq_of_the_reported_winding_is_the_can_reply_with_an_output_bias(output_bias_observer_artifact):
    """With the winding's output bias, the cell `estimate_1` (y_w + bias, what Temperatures1 carries) DAQ'd at every
    model step equals the reply's WindingTemp bits; `y_est_1` (the model's winding y = C x) differs by the bias."""
    node = TargetNode(load_artifact(output_bias_observer_artifact), clock_ns=lambda: 0)
    daq_the_reported_winding(node, {c.name: c.address for c in node.xcp.memory.cells})
    rows = reported_winding_by_daq(node, observer_session(node.artifact, 60))
    check_reported_winding(rows, node.model_steps)
    assert node.observer.filter.extra[-1] != 0                         # the bias the reply carries


@pytest.mark.slow
def test_the_c_slave_daqs_the_reported_winding_as_the_can_reply(output_bias_observer_artifact, firmware_elf):
    """The same DAQ in the firmware node of the output-bias observer (its own C build): the DAQ'd reported winding is
    its CAN reply bit for bit, and both engines send the same packets."""
    pair = observer_pair(output_bias_observer_artifact, firmware_elf)
    addresses = {c.name: c.address for c in pair[0].xcp.memory.cells}
    frames = observer_session(pair[0].artifact, 60)
    runs = []
    for node in pair:
        daq_the_reported_winding(node, addresses)
        runs.append(reported_winding_by_daq(node, frames))
        check_reported_winding(runs[-1], node.model_steps)
    assert runs[1] == runs[0]
