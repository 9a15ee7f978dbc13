"""Where each cell lives: the address the C node's RAM has it at, read from the firmware ELF's symbol table, or a
page of the slave's own.

A cell that mirrors a C symbol (`CellSpec.symbol`, element `index`) takes its address from the ELF: the element's
own symbol where the compiler split the array into scalars (clang names them `x_state.0`, `x_state.1`, ...), else
the array's symbol plus 4·index (its size must hold the element). Every other cell (without an ELF, a symbol the ELF
lacks, or a cell the C has no variable for yet) is placed, in catalogue order, in one of two pages at the top of the
Cortex-M4F's RAM (0x20000000, 64 KiB, bench/firmware/firmware.ld) that the C node leaves free:

    MEASUREMENT_PAGE  0x2000E000   read-only cells
    CALIBRATION_PAGE  0x2000F000   calibratable cells (the C node's calibration RAM, once it has one)
    IDENTIFICATION    0x0803F000   the GET_ID text (the last 4 KiB of flash), the A2L's EPK address; an ELF
                                   whose node has the XCP slave gives its text's own address (xcp_identification)

The layout is a function of the cells and the ELF only, so the A2L generated with an ELF (`bench firmware a2l`) and a
node started with the same ELF (`python -m target_sim --xcp-elf ELF`) agree address for address.
"""

from __future__ import annotations

import os
from collections.abc import Iterable

from target_sim.xcp.memory import Cell
from target_sim.xcp.variables import CellSpec

MEASUREMENT_PAGE = 0x2000E000
CALIBRATION_PAGE = 0x2000F000
PAGE_SIZE = 0x1000
IDENTIFICATION = 0x0803F000
IDENTIFICATION_SYMBOL = "xcp_identification"     # the C node's GET_ID text (bench/firmware/xcp.c), where it has one


def elf_symbols(path: str | os.PathLike, model_id: int | None = None) -> dict[str, tuple[int, int]]:
    """{name: (address, size)} of a checked firmware ELF's symbols (`target_sim.firmware.elf.read_elf`); with
    `model_id`, FirmwareError (one sentence) for the firmware of another model (its `fw_model_id`)."""
    from target_sim.firmware.elf import FirmwareError, read_elf
    from target_sim.firmware.engine import MODEL_ID_SYMBOL

    image = read_elf(path)
    symbol = image.symbols.get(MODEL_ID_SYMBOL)
    if model_id is not None and symbol is not None:
        for segment in image.segments:
            offset = symbol.address - segment.vaddr
            if 0 <= offset <= len(segment.data) - 4:
                found = int.from_bytes(segment.data[offset: offset + 4], "little")
                if found != model_id:
                    raise FirmwareError(f"{image.name} is the firmware of model {found:08x}, not of model "
                                        f"{model_id:08x}; its addresses would not fit: give that model's ELF")
    return {name: (s.address, s.size) for name, s in image.symbols.items()}


def identification_address(symbols: dict[str, tuple[int, int]] | None) -> int:
    """Where the GET_ID text lives: the C node's `xcp_identification` when the ELF has it, else IDENTIFICATION."""
    found = symbols.get(IDENTIFICATION_SYMBOL) if symbols else None
    return found[0] if found is not None else IDENTIFICATION


def symbol_address(symbols: dict[str, tuple[int, int]], symbol: str, index: int) -> int | None:
    """The address of element `index` of the float array `symbol`, or None when the ELF does not hold it."""
    piece = symbols.get(f"{symbol}.{index}")
    if piece is not None and piece[1] == 4:
        return piece[0]
    whole = symbols.get(symbol)
    if whole is not None and whole[1] >= 4 * (index + 1):
        return whole[0] + 4 * index
    return None


def place(specs: Iterable[CellSpec], page: int, symbols: dict[str, tuple[int, int]] | None = None) -> list[Cell]:
    """Cells with addresses: from `symbols` where the ELF has the spec's element, else the next word of `page`."""
    cells, at = [], page
    for spec in specs:
        address = symbol_address(symbols, spec.symbol, spec.index) if symbols and spec.symbol else None
        symbol = f"{spec.symbol}[{spec.index}]" if address is not None else None
        if address is None:
            if at + 4 > page + PAGE_SIZE:
                raise ValueError(f"page 0x{page:08X} is full at {spec.name}")
            address, at = at, at + 4
        cells.append(Cell(spec.name, address, spec.read, spec.write, spec.limits, spec.unit, spec.comment, symbol))
    return cells
