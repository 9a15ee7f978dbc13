"""XCP on CAN (ASAM MCD-1 XCP 1.x) in the Python target node: measurement and calibration by an XCP master (pyxcp,
CANape, INCA) while the model runs, described by an A2L file (`bench firmware a2l`).

    codes      the protocol's numbers (command codes, error codes, reply bits)
    memory     the address space: float32 cells bound to the engine, UPLOAD/DOWNLOAD rules
    variables  the catalogue: which measurements and calibratable parameters the node shows, their limits
    layout     where each cell lives: the C node's address from the firmware ELF, else the slave's pages
    daq        dynamic DAQ lists sampled on the model step's event
    commands   the command processor (CTO in, RES/ERR out)

`node_slave(node, elf)` builds the slave of a `target_sim.node.TargetNode`; its two CAN ids are `dbc.xcp`'s.
"""

from __future__ import annotations

import os

from target_sim.xcp.commands import XcpSlave
from target_sim.xcp.layout import CALIBRATION_PAGE, MEASUREMENT_PAGE, elf_symbols, identification_address, place
from target_sim.xcp.memory import AddressSpace, Cell
from target_sim.xcp.variables import node_cells


def identification(model_id: int) -> tuple[str, str]:
    """(GET_ID ASCII text, A2L name without extension) of a model: the A2L's EPK is the text."""
    return f"pmsm-thermal-bench model {model_id:08x}", f"thermal_bench_{model_id:08x}"


def node_layout(node, elf: str | os.PathLike | None = None) -> tuple[list[Cell], list[Cell], int]:
    """(measurements, calibrations, address of the GET_ID text) of `node` (`target_sim.xcp.layout`)."""
    symbols = elf_symbols(elf, node.artifact.model_id) if elf is not None else None
    measurements, calibrations = node_cells(node)
    return (place(measurements, MEASUREMENT_PAGE, symbols), place(calibrations, CALIBRATION_PAGE, symbols),
            identification_address(symbols))


def node_cells_placed(node, elf: str | os.PathLike | None = None) -> tuple[list[Cell], list[Cell]]:
    """(measurements, calibrations) of `node` with their addresses (`target_sim.xcp.layout`)."""
    measurements, calibrations, _ = node_layout(node, elf)
    return measurements, calibrations


def node_slave(node, elf: str | os.PathLike | None = None) -> XcpSlave:
    """The XCP slave of a Python target node, its cells placed by the firmware ELF `elf` (None: the slave's pages)."""
    measurements, calibrations, text_address = node_layout(node, elf)
    text, a2l_name = identification(node.artifact.model_id)
    memory = AddressSpace(measurements + calibrations, (text_address, (text + a2l_name).encode("ascii")))
    return XcpSlave(memory, identification=text, a2l_name=a2l_name, identification_address=text_address)


__all__ = ["XcpSlave", "AddressSpace", "Cell", "node_slave", "node_cells_placed", "node_layout", "identification"]
