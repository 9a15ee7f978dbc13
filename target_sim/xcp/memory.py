"""The XCP slave's address space: float32 cells at addresses, and a read-only identification string.

A `Cell` is one float32 of the engine's state or calibration (one element of a C array), at the address the C node
has it (`target_sim.xcp.layout`). UPLOAD reads any run of mapped bytes (cells and the identification string, with
no gap between them); DOWNLOAD writes only whole calibratable cells, every value finite and within its limits, all
checked before any is written (a refused DOWNLOAD changes nothing). Both answer with an XCP error code when they
cannot: ERR_ACCESS_DENIED for a byte that is not mapped or not calibratable, ERR_OUT_OF_RANGE for a value outside
its cell's limits or a write that splits a float32."""

from __future__ import annotations

import bisect
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from target_sim.errors import TargetError
from target_sim.xcp.codes import Err

FLOAT = struct.Struct("<f")


class AccessRefused(TargetError):
    """An access the address space refuses; `code` is the XCP error code it answers with."""

    def __init__(self, code: Err, why: str):
        super().__init__(why)
        self.code = code


@dataclass(frozen=True)
class Cell:
    """One float32 at `address`: `read()` its value, `write(value)` sets it (None: read-only); `limits` are the
    calibration range of a writable cell (A2L LOWER_LIMIT/UPPER_LIMIT)."""

    name: str
    address: int
    read: Callable[[], float]
    write: Callable[[float], None] | None = None
    limits: tuple[float, float] = (float("-inf"), float("inf"))
    unit: str = ""
    comment: str = ""
    symbol: str | None = None      # the C node's symbol (element) this cell mirrors; None: a page of the slave's

    size = 4

    def bytes(self) -> bytes:
        return FLOAT.pack(self.read())


class AddressSpace:
    """Cells and a read-only byte string (the identification), by address; no two may overlap."""

    def __init__(self, cells: Sequence[Cell], text: tuple[int, bytes] | None = None):
        self.cells = sorted(cells, key=lambda c: c.address)
        self.by_name = {c.name: c for c in self.cells}
        self.text = text
        self._starts = [c.address for c in self.cells]
        spans = [(c.address, c.address + 4, c.name) for c in self.cells]
        if text is not None:
            spans.append((text[0], text[0] + len(text[1]), "identification"))
        spans.sort()
        for (_, end, name), (start, _, other) in zip(spans, spans[1:], strict=False):
            if start < end:
                raise ValueError(f"{other} at 0x{start:08X} overlaps {name}")

    def _cell_at(self, address: int) -> Cell | None:
        i = bisect.bisect_right(self._starts, address) - 1
        if i >= 0 and address < self._starts[i] + 4:
            return self.cells[i]
        return None

    def read(self, address: int, size: int) -> bytes:
        """`size` bytes from `address` (AccessRefused ACCESS_DENIED at the first unmapped byte)."""
        out = bytearray()
        at, end = address, address + size
        while at < end:
            cell = self._cell_at(at)
            if cell is not None:
                raw = cell.bytes()
                take = raw[at - cell.address: min(end, cell.address + 4) - cell.address]
            elif self.text is not None and self.text[0] <= at < self.text[0] + len(self.text[1]):
                base, data = self.text
                take = data[at - base: min(end, base + len(data)) - base]
            else:
                raise AccessRefused(Err.ACCESS_DENIED, f"0x{at:08X} is not mapped")
            out += take
            at += len(take)
        return bytes(out)

    def write(self, address: int, data: bytes) -> list[Cell]:
        """Write whole calibratable cells from `address`; every value checked first, then all written."""
        if len(data) % 4:
            raise AccessRefused(Err.OUT_OF_RANGE, f"{len(data)} bytes do not fill whole float32 cells")
        planned = []
        for offset in range(0, len(data), 4):
            at = address + offset
            cell = self._cell_at(at)
            if cell is None or cell.write is None:
                what = "not mapped" if cell is None else f"{cell.name}, which is not calibratable"
                raise AccessRefused(Err.ACCESS_DENIED, f"0x{at:08X} is {what}")
            if cell.address != at:
                raise AccessRefused(Err.OUT_OF_RANGE, f"0x{at:08X} is inside {cell.name}, not at its start")
            (value,) = FLOAT.unpack_from(data, offset)
            low, high = cell.limits
            if not low <= value <= high:     # NaN fails both comparisons
                raise AccessRefused(Err.OUT_OF_RANGE, f"{value!r} is outside {cell.name}'s limits [{low:g}, {high:g}]")
            planned.append((cell, value))
        for cell, value in planned:
            cell.write(value)
        return [cell for cell, _ in planned]

    def locate(self, address: int, size: int) -> list[tuple[Cell | None, int, int]]:
        """The pieces (cell, start within its 4 bytes, length) a DAQ entry reads; (None, offset in the
        identification, length) for its bytes; AccessRefused when a byte is not mapped. Resolved once per entry."""
        pieces: list[tuple[Cell | None, int, int]] = []
        at, end = address, address + size
        while at < end:
            cell = self._cell_at(at)
            if cell is None:
                self.read(at, 1)              # raises for an unmapped byte; the text is constant
                base, data = self.text        # type: ignore[misc]
                n = min(end, base + len(data)) - at
                pieces.append((None, at - base, n))
                at += n
                continue
            n = min(end, cell.address + 4) - at
            pieces.append((cell, at - cell.address, n))
            at += n
        return pieces
