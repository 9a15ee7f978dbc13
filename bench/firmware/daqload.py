"""The heaviest DAQ an XCP master can start on the firmware node, and a drive's frames under it: the measured side
of node_on_frame's WCET bound with a master (`bench.firmware.timing.XCP_MODES`' "master_daq").

    figures = daq_run(artifact, image, frames)      # frames: bench.firmware.timing._frames
    figures["node_on_frame_max"], figures["daq_packets"], figures["model_steps"]

The master (CONNECT, then the XCP commands of `full_daq_commands`) allocates the DAQ tables' whole budget of lists,
one ODT each, every ODT a full packet (a float32 cell and three bytes of the next: ODT_PAYLOAD bytes), every list on
the model step's event with prescaler 1, and starts them: each model step samples and sends every packet, the most
work the DAQ path does per frame. Every command must be answered positively (else the run would measure less than
it claims): `BenchError` otherwise.
"""

from __future__ import annotations

import struct

import can

from bench.errors import BenchError
from dbc.xcp import cmd_id, res_id
from target_sim.artifact import ModelArtifact
from target_sim.firmware.elf import ElfImage
from target_sim.firmware.node_engine import FirmwareNode
from target_sim.xcp.codes import Cmd
from target_sim.xcp.daq import EVENT_MODEL_STEP, MAX_DAQ_LISTS, MAX_ODTS, ODT_PAYLOAD

SAMPLED = "y_est"            # the model's outputs (float32[4]): cells the slave maps, as a calibration tool reads them
POSITIVE = 0xFF              # XCP's RES packet identifier
START = 1                    # START_STOP_DAQ_LIST mode: start


def full_daq_commands(image: ElfImage) -> list[bytes]:
    """The CTOs of a master that starts the DAQ tables' whole budget (see the module docstring)."""
    address = image.symbols[SAMPLED].address
    lists = min(MAX_DAQ_LISTS, MAX_ODTS)                     # one ODT each
    commands = [bytes((Cmd.CONNECT, 0)), bytes((Cmd.FREE_DAQ,)), bytes((Cmd.ALLOC_DAQ, 0)) + struct.pack("<H", lists)]
    commands += [bytes((Cmd.ALLOC_ODT, 0)) + struct.pack("<HB", daq, 1) for daq in range(lists)]
    commands += [bytes((Cmd.ALLOC_ODT_ENTRY, 0)) + struct.pack("<HBB", daq, 0, 2) for daq in range(lists)]
    for daq in range(lists):
        commands += [bytes((Cmd.SET_DAQ_PTR, 0)) + struct.pack("<HBB", daq, 0, 0),
                     bytes((Cmd.WRITE_DAQ, 0xFF, 4, 0)) + struct.pack("<I", address),
                     bytes((Cmd.WRITE_DAQ, 0xFF, ODT_PAYLOAD - 4, 0)) + struct.pack("<I", address + 4),
                     bytes((Cmd.SET_DAQ_LIST_MODE, 0)) + struct.pack("<HHBB", daq, EVENT_MODEL_STEP, 1, 0),
                     bytes((Cmd.START_STOP_DAQ_LIST, START)) + struct.pack("<H", daq)]
    return commands


def daq_run(artifact: ModelArtifact, image: ElfImage, frames: list[list]) -> dict:
    """The drive's `frames` (groups of can.Message) through the firmware node after `full_daq_commands`: the most
    cycles of node_on_frame, the DAQ packets sent and the model steps run."""
    node = FirmwareNode(artifact, image)
    for cto in full_daq_commands(image):
        replies = [bytes(m.data) for m in node.handle(can.Message(arbitration_id=cmd_id(), is_extended_id=False,
                                                                   data=cto)) if m.arbitration_id == res_id()]
        if len(replies) != 1 or replies[0][0] != POSITIVE:
            raise BenchError(f"the firmware's XCP slave refused {cto.hex()} (replies {[r.hex() for r in replies]}): "
                             "the DAQ run cannot set up its lists")
    most = packets = 0
    for group in frames:
        for frame in group:
            replies = node.handle(frame)
            most = max(most, node.fw.last.cycles)
            packets += sum(1 for m in replies if m.arbitration_id == res_id())
    return {"node_on_frame_max": most, "daq_packets": packets, "model_steps": node.model_steps}
