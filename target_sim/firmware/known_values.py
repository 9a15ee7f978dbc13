"""Branches a block decides from globals whose value a mode fixes: the infeasible paths of that mode.

A mode of the firmware fixes some of its globals for as long as it lasts: without an XCP master since power-on,
`xcp_connected` stays 0 (only a CONNECT command sets it). The WCET analysis (`target_sim.firmware.wcet`) asks, of
each block that ends in a conditional branch, whether the block's own instructions decide that branch from those
values alone, and if so the other way out is infeasible (an IPET fact: its count 0).

The evaluation is deliberately small, so that it decides only what the code plainly says: MOV/MOVW an immediate
and MOVT build an address, LDR/LDRB/LDRH with an immediate offset read a known global there, CMP of known values
sets the flags, and CBZ/CBNZ or the last instruction's condition (a B<cc>, or a BX<cc>/POP<cc> in an IT block)
tests them. Every other instruction makes what it writes unknown (a call: every register and the flags), a
conditional instruction before the last as well, so a value never survives a guess.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

from capstone import CsInsn, arm_const

from target_sim.errors import TargetError
from target_sim.firmware.elf import ElfImage

Read = Callable[[int, int], int | None]      # (address, bytes) -> the value there when the mode fixes it
_MASK = 0xFFFF_FFFF
_LOADS = {"ldr": 4, "ldrh": 2, "ldrb": 1}
_CALLS = frozenset({"bl", "blx"})


class ValueFactError(TargetError):
    """A value fact names a global the image does not have, or one too small for the value; one sentence."""


def memory_reader(image: ElfImage, values: Mapping[str, int]) -> Read:
    """What a load reads under `values` (global name -> its value throughout the mode, little-endian over the
    symbol's bytes): the bytes of a load that lies wholly inside such a global, else None (unknown)."""
    spans = []
    for name, value in values.items():
        symbol = image.symbols.get(name)
        if symbol is None or symbol.kind != "STT_OBJECT" or symbol.size <= 0:
            raise ValueFactError(f"{image.name} has no global {name!r} for a value fact")
        if value < 0 or value >= 1 << (8 * symbol.size):
            raise ValueFactError(f"the value fact {name} = {value} does not fit its {symbol.size} bytes")
        spans.append((symbol.address, symbol.address + symbol.size, value.to_bytes(symbol.size, "little")))

    def read(address: int, size: int) -> int | None:
        for start, end, raw in spans:
            if start <= address and address + size <= end:
                return int.from_bytes(raw[address - start:address - start + size], "little")
        return None

    return read


def _flags_of_compare(a: int, b: int) -> dict[str, bool]:
    result = (a - b) & _MASK
    return {"n": bool(result >> 31), "z": result == 0, "c": a >= b,
            "v": bool(((a ^ b) & (a ^ result)) >> 31)}


_CONDITIONS: dict[int, Callable[[dict[str, bool]], bool]] = {
    arm_const.ARM_CC_EQ: lambda f: f["z"], arm_const.ARM_CC_NE: lambda f: not f["z"],
    arm_const.ARM_CC_HS: lambda f: f["c"], arm_const.ARM_CC_LO: lambda f: not f["c"],
    arm_const.ARM_CC_MI: lambda f: f["n"], arm_const.ARM_CC_PL: lambda f: not f["n"],
    arm_const.ARM_CC_VS: lambda f: f["v"], arm_const.ARM_CC_VC: lambda f: not f["v"],
    arm_const.ARM_CC_HI: lambda f: f["c"] and not f["z"], arm_const.ARM_CC_LS: lambda f: not f["c"] or f["z"],
    arm_const.ARM_CC_GE: lambda f: f["n"] == f["v"], arm_const.ARM_CC_LT: lambda f: f["n"] != f["v"],
    arm_const.ARM_CC_GT: lambda f: not f["z"] and f["n"] == f["v"],
    arm_const.ARM_CC_LE: lambda f: f["z"] or f["n"] != f["v"],
}


def _written(insn: CsInsn) -> list[int]:
    try:
        return list(insn.regs_access()[1])
    except Exception:           # no access detail: the implicit writes only
        return list(insn.regs_write)


def _operand(insn: CsInsn, op, registers: dict[int, int]) -> int | None:
    if op.type == arm_const.ARM_OP_IMM:
        return op.imm & _MASK
    if op.type == arm_const.ARM_OP_REG and op.shift.type == 0:
        return registers.get(op.reg)
    return None


def _step(insn: CsInsn, registers: dict[int, int], flags: dict[str, bool] | None, read: Read
          ) -> dict[str, bool] | None:
    """Apply one instruction (not the block's last) to the known registers; the flags after it."""
    name, ops = insn.insn_name(), insn.operands
    written = _written(insn)
    unconditional = insn.cc in (arm_const.ARM_CC_AL, arm_const.ARM_CC_INVALID)
    value: int | None = None
    target = ops[0].reg if ops and ops[0].type == arm_const.ARM_OP_REG else None
    if name in _CALLS:
        registers.clear()
        return None
    if not unconditional or insn.update_flags and name != "cmp":
        for reg in written:
            registers.pop(reg, None)
        return None if arm_const.ARM_REG_CPSR in written or insn.update_flags else flags
    if name == "cmp" and len(ops) == 2:
        a, b = _operand(insn, ops[0], registers), _operand(insn, ops[1], registers)
        return None if a is None or b is None else _flags_of_compare(a, b)
    if name == "mov" and len(ops) == 2 and ops[1].type == arm_const.ARM_OP_IMM:
        value = ops[1].imm & _MASK
    elif name == "movt" and target is not None and target in registers:
        value = (registers[target] & 0xFFFF) | (ops[1].imm & 0xFFFF) << 16
    elif name in _LOADS and len(ops) == 2 and ops[1].type == arm_const.ARM_OP_MEM and written == [target]:
        mem = ops[1].mem
        base = registers.get(mem.base)
        if base is not None and mem.index == 0:
            value = read((base + mem.disp) & _MASK, _LOADS[name])
    for reg in written:
        registers.pop(reg, None)
    if value is not None and target is not None and written == [target]:
        registers[target] = value
    return None if arm_const.ARM_REG_CPSR in written else flags


def decided_branch(instructions: Sequence[CsInsn], read: Read) -> bool | None:
    """Whether the last of `instructions` (a block's conditional branch or conditional PC write) is taken, as the
    block's own instructions decide it from the values `read` knows: True, False, or None (not decided)."""
    registers: dict[int, int] = {}
    flags: dict[str, bool] | None = None
    *body, last = instructions
    for insn in body:
        flags = _step(insn, registers, flags, read)
    name = last.insn_name()
    if name in ("cbz", "cbnz"):
        tested = registers.get(last.operands[0].reg)
        return None if tested is None else (tested == 0) == (name == "cbz")
    condition = _CONDITIONS.get(last.cc)
    return None if condition is None or flags is None else condition(flags)
