"""The Python node's XCP slave in-process: the commands' replies and refusals, DAQ limits, and the address space
against the firmware engine and the generated A2L (every address the A2L names reads, by UPLOAD, the value the
engine holds; every cell that mirrors a C symbol holds the same bytes as the firmware's RAM at that address)."""

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
from target_sim.xcp.daq import MAX_DAQ_LISTS, MAX_ODT_ENTRIES, MAX_ODTS, ODT_PAYLOAD

from helpers import ROOT, session_drive, session_frames, session_start

PACKAGED = ROOT / "bench" / "data" / "default_model.json"
PACKAGED_ELF = ROOT / "bench" / "data" / "firmware" / "default_model.elf"
OK = b"\xff"


def err(code: Err) -> bytes:
    return bytes((0xFE, code))


def set_mta(address: int) -> bytes:
    return bytes((0xF6, 0, 0, 0)) + struct.pack("<I", address)


def short_upload(address: int, size: int = 4) -> bytes:
    return bytes((0xF4, size, 0, 0)) + struct.pack("<I", address)


def download(value: float) -> bytes:
    return bytes((0xF0, 4)) + struct.pack("<f", value)


@pytest.fixture
def node():
    node = TargetNode(load_artifact(PACKAGED), clock_ns=lambda: 0)
    assert node.xcp.command(bytes((0xFF, 0)))[:2] == bytes((0xFF, 0x05))
    return node


def test_only_connect_is_answered_while_disconnected():
    node = TargetNode(load_artifact(PACKAGED))
    assert node.xcp.command(bytes((0xFD,))) is None and node.xcp.ignored == 1
    reply = node.handle(can.Message(arbitration_id=cmd_id(), is_extended_id=False, data=bytes((0xFF, 0))))
    assert [(m.arbitration_id, bytes(m.data)) for m in reply] == [(res_id(), bytes.fromhex("ff05800808000101"))]
    assert node.frames_received == 0 and node.errors["unknown_id"] == 0     # not a frame of the contract


def test_refusals_change_nothing(node):
    slave, cells = node.xcp, node.xcp.memory.by_name
    alpha = cells["cal_alpha_cu"]
    before = node.model.alpha_cu
    assert slave.command(bytes((0x12,))) == err(Err.CMD_UNKNOWN)
    assert slave.command(bytes((0xF6, 0))) == err(Err.CMD_SYNTAX)
    assert slave.command(short_upload(0x1000)) == err(Err.ACCESS_DENIED)            # not mapped
    assert slave.command(set_mta(cells["x_state_0"].address)) == OK
    assert slave.command(download(1.0)) == err(Err.ACCESS_DENIED)                    # read-only
    for value in (0.5, -1e-3, float("nan"), float("inf")):
        assert slave.command(set_mta(alpha.address)) == OK
        assert slave.command(download(value)) == err(Err.OUT_OF_RANGE)
    assert slave.command(set_mta(alpha.address + 2)) == OK
    assert slave.command(bytes((0xF0, 2, 0, 0))) == err(Err.OUT_OF_RANGE)            # half a float
    assert node.model.alpha_cu == before
    assert slave.command(set_mta(alpha.address)) == OK and slave.command(download(0.005)) == OK
    assert node.model.alpha_cu == np.float32(0.005) and slave.calibrations == [("cal_alpha_cu", np.float32(0.005))]
    assert slave.errors == {"CMD_UNKNOWN": 1, "CMD_SYNTAX": 1, "ACCESS_DENIED": 2, "OUT_OF_RANGE": 5}


def test_get_id_and_checksum(node):
    slave = node.xcp
    reply = slave.command(bytes((0xFA, 0)))
    length = struct.unpack_from("<I", reply, 4)[0]
    text = b"".join(slave.command(bytes((0xF5, min(7, length - i))))[1:] for i in range(0, length, 7))
    assert text.decode() == f"pmsm-thermal-bench model {node.artifact.model_id:08x}"
    start = slave.memory.by_name["x_state_0"].address
    assert slave.command(set_mta(start)) == OK
    reply = slave.command(bytes((0xF3, 0, 0, 0)) + struct.pack("<I", 32))
    assert reply[1] == 0x09 and struct.unpack_from("<I", reply, 4)[0] == zlib.crc32(slave.memory.read(start, 32))


def test_daq_configuration_rules(node):
    slave = node.xcp
    assert slave.command(bytes((0xD5, 0, 1, 0))) == err(Err.SEQUENCE)                # ALLOC_DAQ before FREE_DAQ
    assert slave.command(bytes((0xD6,))) == OK
    assert slave.command(bytes((0xD5, 0, 1, 0))) == OK
    assert slave.command(bytes((0xD4, 0, 0, 0, 2))) == OK
    assert slave.command(bytes((0xD3, 0, 0, 0, 0, ODT_PAYLOAD + 1))) == err(Err.OUT_OF_RANGE)   # > 7 per ODT
    assert slave.command(bytes((0xD3, 0, 0, 0, 0, 2))) == OK
    assert slave.command(bytes((0xD3, 0, 0, 0, 1, 1))) == OK
    y0 = slave.memory.by_name["y_est_0"].address
    assert slave.command(bytes((0xE2, 0, 0, 0, 0, 0))) == OK
    assert slave.command(bytes((0xE1, 0xFF, 4, 0)) + struct.pack("<I", y0)) == OK
    assert slave.command(bytes((0xE1, 0xFF, 4, 0)) + struct.pack("<I", y0 + 4)) == err(Err.DAQ_CONFIG)  # 8 > 7 bytes
    assert slave.command(bytes((0xDE, 1, 0, 0))) == err(Err.DAQ_CONFIG)              # an entry never written
    assert slave.command(bytes((0xE1, 0xFF, 3, 0)) + struct.pack("<I", y0 + 4)) == OK
    assert slave.command(bytes((0xE2, 0, 0, 0, 1, 0))) == OK
    assert slave.command(bytes((0xE1, 0xFF, 4, 0)) + struct.pack("<I", 0x1000)) == err(Err.ACCESS_DENIED)
    assert slave.command(bytes((0xE1, 0xFF, 4, 0)) + struct.pack("<I", y0 + 12)) == OK
    assert slave.command(bytes((0xE0, 0x10, 0, 0, 0, 0, 1, 0))) == err(Err.MODE_NOT_VALID)   # time stamps
    assert slave.command(bytes((0xE0, 0, 0, 0, 0, 0, 2, 0))) == OK                  # every 2nd model step
    assert slave.command(bytes((0xDE, 1, 0, 0))) == bytes((0xFF, 0))
    codec = FrameCodec("HOST")
    for frame in session_start(codec):
        node.handle(frame)
    daq, outputs = [], []
    for row, values in enumerate(session_drive(40, 1)):
        steps = node.model_steps
        for frame in encode_row(codec, row, values):
            daq += [bytes(m.data) for m in node.handle(frame) if m.arbitration_id == res_id()]
        if node.model_steps > steps:
            outputs.append(node.model.y.copy())
    sampled = outputs[::2]                       # prescaler 2: the 1st, 3rd, ... model step
    assert len(outputs) >= 4
    assert daq == [p for y in sampled for p in (bytes((0,)) + y[:2].tobytes()[:7], bytes((1,)) + y[3:].tobytes())]


def test_the_daq_tables_have_the_c_nodes_ram_budget(node):
    """The limits the firmware's fixed tables set (bench/firmware/xcp.c), refused alike by both slaves:
    MAX_DAQ_LISTS lists, MAX_ODTS ODTs, MAX_ODT_ENTRIES entries in all (ERR_MEMORY_OVERFLOW)."""
    slave = node.xcp
    assert slave.command(bytes((0xD6,))) == OK
    assert slave.command(bytes((0xD5, 0, MAX_DAQ_LISTS + 1, 0))) == err(Err.MEMORY_OVERFLOW)
    assert slave.command(bytes((0xD5, 0, 2, 0))) == OK
    assert slave.command(bytes((0xD4, 0, 0, 0, MAX_ODTS))) == OK
    assert slave.command(bytes((0xD4, 0, 1, 0, 1))) == err(Err.MEMORY_OVERFLOW)
    full = MAX_ODT_ENTRIES // ODT_PAYLOAD
    for odt in range(full):
        assert slave.command(bytes((0xD3, 0, 0, 0, odt, ODT_PAYLOAD))) == OK
    left = MAX_ODT_ENTRIES - full * ODT_PAYLOAD
    assert slave.command(bytes((0xD3, 0, 0, 0, full, left + 1))) == err(Err.MEMORY_OVERFLOW)
    assert slave.command(bytes((0xD3, 0, 0, 0, full, left))) == OK


def drive_both(rows: int):
    """The packaged model's Python node (its XCP cells at the packaged ELF's addresses) and its firmware node, fed
    the same session."""
    from target_sim.firmware.node_engine import FirmwareNode

    artifact = load_artifact(PACKAGED)
    python = TargetNode(artifact, clock_ns=lambda: 0, xcp_elf=PACKAGED_ELF)
    firmware = FirmwareNode(artifact, PACKAGED_ELF)
    for frame in session_frames(artifact, session_drive(rows, 2), stop=False):
        if frame.arbitration_id in host_frame_ids():
            python.handle(frame)
            firmware.handle(frame)
    return python, firmware


def test_cells_that_mirror_c_symbols_hold_the_firmware_ram_bytes():
    python, firmware = drive_both(60)
    assert python.model_steps == firmware.model_steps > 0
    python.xcp.command(bytes((0xFF, 0)))
    mirrored = [c for c in python.xcp.memory.cells if c.symbol is not None]
    assert {c.name for c in mirrored} == {f"{s}_{i}" for s in ("x_state", "y_est", "estimate") for i in range(4)} \
        | {"cal_alpha_cu"}
    for cell in mirrored:
        reply = python.xcp.command(short_upload(cell.address))
        assert reply[1:] == firmware.fw.read_bytes(cell.address, 4), cell.name


def test_the_a2l_loads_in_a_third_party_parser_and_every_address_reads_the_engine(tmp_path):
    pya2l = pytest.importorskip("pya2l")
    from pya2l import model

    from bench.firmware.a2l import a2l_text

    python, _ = drive_both(60)
    python.xcp.command(bytes((0xFF, 0)))
    path = tmp_path / "target.a2l"
    path.write_text(a2l_text(python.artifact, PACKAGED_ELF), encoding="latin-1")
    session = pya2l.import_a2l(str(path), in_memory=True, remove_existing=True, progress_bar=False,
                               loglevel="ERROR")
    measurements = {m.name: m.ecu_address.address for m in session.query(model.Measurement).all()}
    characteristics = {c.name: (c.address, c.lowerLimit, c.upperLimit)
                       for c in session.query(model.Characteristic).all()}
    engine = {**{f"x_state_{i}": v for i, v in enumerate(python.model.x)},
              **{f"y_est_{i}": v for i, v in enumerate(python.model.y)},
              **{f"estimate_{i}": v for i, v in enumerate(python.estimate)}}
    assert set(measurements) == set(engine)
    for name, address in measurements.items():
        assert python.xcp.command(short_upload(address))[1:] == np.float32(engine[name]).tobytes(), name
    assert characteristics == {"cal_alpha_cu": (python.xcp.memory.by_name["cal_alpha_cu"].address, 0.0, 0.01)}
    address = characteristics["cal_alpha_cu"][0]
    assert python.xcp.command(short_upload(address))[1:] == np.float32(python.model.alpha_cu).tobytes()


def test_a_daq_list_on_the_time_event_goes_out_with_each_heartbeat(node):
    slave = node.xcp
    x0 = slave.memory.by_name["x_state_0"].address
    for cto in (bytes((0xD6,)), bytes((0xD5, 0, 1, 0)), bytes((0xD4, 0, 0, 0, 1)), bytes((0xD3, 0, 0, 0, 0, 1)),
                bytes((0xE2, 0, 0, 0, 0, 0)), bytes((0xE1, 0xFF, 4, 0)) + struct.pack("<I", x0),
                bytes((0xE0, 0, 0, 0, 1, 0, 1, 0)), bytes((0xDE, 2, 0, 0)), bytes((0xDD, 1))):
        assert slave.command(cto)[0] == 0xFF, cto.hex()
    assert slave.command(bytes((0xFD,)))[1] & 0x40             # GET_STATUS: DAQ running
    beats = [node.heartbeat_frames() for _ in range(3)]
    assert [[bytes(m.data) for m in beat if m.arbitration_id == res_id()] for beat in beats] == \
        [[bytes((0,)) + np.float32(node.model.x[0]).tobytes()]] * 3
    assert slave.command(bytes((0xFE,))) == OK                   # DISCONNECT stops the lists
    assert all(m.arbitration_id != res_id() for m in node.heartbeat_frames())


def test_a_log_with_xcp_traffic_decodes_as_the_same_session(tmp_path):
    """XCP frames in a bus log (a master's commands, the slave's replies and DAQ) are bus load for `bench analyze`,
    never invalid or foreign frames, and change nothing it decodes."""
    from bench.analysis.logdecode import decode_log

    from helpers import write_frames

    artifact = load_artifact(PACKAGED)
    frames = session_frames(artifact, session_drive(60, 3))
    xcp = [can.Message(arbitration_id=cmd_id(), is_extended_id=False, data=bytes((0xFF, 0))),
           can.Message(arbitration_id=res_id(), is_extended_id=False, data=bytes.fromhex("ff05800808000101")),
           can.Message(arbitration_id=res_id(), is_extended_id=False, data=bytes((0, 1, 2, 3, 4)))]
    mixed = [f for i, frame in enumerate(frames) for f in ([frame, *xcp] if i % 20 == 5 else [frame])]
    for i, frame in enumerate(mixed):
        frame.timestamp = i * 1e-3
    clean = decode_log(write_frames(tmp_path / "clean.blf", frames))
    record = decode_log(write_frames(tmp_path / "xcp.blf", mixed))
    assert record.frames == clean.frames + len(mixed) - len(frames)
    assert (record.invalid, record.rejected, record.foreign) == (clean.invalid, clean.rejected, clean.foreign) == \
        ({}, {}, {})
    assert np.array_equal(record.drive, clean.drive)


def test_the_a2l_checks_the_dwarf_types_where_the_image_has_them(tmp_path):
    """An object compiled with -g for the Cortex-M4F: DWARF types float arrays as float and anything else not."""
    import subprocess
    import sys

    from bench.firmware.a2l import dwarf_float_arrays
    from bench.firmware.toolchain import TARGET_FLAGS

    source = tmp_path / "cells.c"
    source.write_text("float x_state[4];\nstatic float y_est[4];\nint estimate[4];\n"
                      "float *touch(void) { return y_est; }\n", encoding="utf-8")
    done = subprocess.run([sys.executable, "-m", "ziglang", "cc", *TARGET_FLAGS, "-O2", "-g", "-c", str(source), "-o",
                           str(tmp_path / "cells.o")], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert dwarf_float_arrays(tmp_path / "cells.o") == {"x_state": True, "y_est": True, "estimate": False}
    assert dwarf_float_arrays(PACKAGED_ELF) is None          # the packaged images have no DWARF


def test_an_elf_of_another_model_is_refused_in_one_sentence():
    from target_sim.firmware.elf import FirmwareError

    other = ROOT / "bench" / "data" / "firmware" / "default_model-lti-lptn.elf"
    with pytest.raises(FirmwareError, match=r"default_model-lti-lptn.elf is the firmware of model \w{8}, not of"):
        TargetNode(load_artifact(PACKAGED), xcp_elf=other)


def test_random_xcp_commands_never_touch_the_model_or_the_contract_counters():
    """Thousands of random XCP packets (any code but DOWNLOAD, any length, mid-session) get XCP replies or none, are
    counted, and leave every frame of the contract the node sends as in the session without them, bit for bit."""
    artifact = load_artifact(PACKAGED)
    frames = [f for f in session_frames(artifact, session_drive(80, 5)) if f.arbitration_id in host_frame_ids()]
    rng = np.random.default_rng(42)

    def run(noise: bool):
        node = TargetNode(artifact, clock_ns=lambda: 0)
        out = []
        if noise:
            node.handle(can.Message(arbitration_id=cmd_id(), is_extended_id=False, data=bytes((0xFF, 0))))
        for frame in frames:
            out += [(m.arbitration_id, bytes(m.data)) for m in node.handle(frame) if m.arbitration_id != res_id()]
            for _ in range(25 if noise else 0):
                data = rng.integers(0, 256, int(rng.integers(0, 9)), dtype=np.uint8).tobytes()
                if data[:1] in (b"\xf0", b"\xfe"):        # no DOWNLOAD (a calibration), no DISCONNECT
                    continue
                for reply in node.handle(can.Message(arbitration_id=cmd_id(), is_extended_id=False, data=data)):
                    assert reply.arbitration_id == res_id() and 1 <= reply.dlc <= 8
        return node, out

    clean_node, clean = run(False)
    noisy_node, noisy = run(True)
    assert noisy == clean
    assert noisy_node.errors == clean_node.errors and noisy_node.faults == clean_node.faults
    assert sum(noisy_node.xcp.errors.values()) > 100 and noisy_node.xcp.calibrations == []


def test_bench_firmware_a2l_writes_the_file_and_refuses_to_overwrite_its_input(tmp_path, capsys):
    import json

    from bench.cli import main

    out = tmp_path / "target.a2l"
    assert main(["firmware", "a2l", "--elf", str(PACKAGED_ELF), "--out", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert (report["measurements"], report["characteristics"]) == (12, 1)
    text = out.read_text(encoding="latin-1")
    from target_sim.xcp.layout import elf_symbols

    x_state = elf_symbols(PACKAGED_ELF)["x_state"][0]
    assert "CAN_ID_MASTER 0x6A0 CAN_ID_SLAVE 0x6A1" in text and f"ECU_ADDRESS 0x{x_state:08X}" in text
    copy = tmp_path / "model.json"
    copy.write_bytes(PACKAGED.read_bytes())
    assert main(["firmware", "a2l", "--model", str(copy), "--out", str(copy)]) != 0
    assert copy.read_bytes() == PACKAGED.read_bytes()
    assert "--out" in capsys.readouterr().err
