"""Cycles of Cortex-M4F code, counted from the basic blocks the emulated core actually executed.

Each basic block the core enters costs the sum of its instructions' cycles, taken from the tables below; a block
ending in a branch costs the branch "not taken", plus `PIPELINE_REFILL` when the next block the core enters is not
the fall-through address (the branch was taken). The costs of a block are computed once, from a capstone
disassembly, and cached by (address, size); the emulator's block hook only looks them up and adds.

Source: ARM Cortex-M4 Processor Technical Reference Manual (ARM DDI 0439), Table 3-1 (processor instructions)
and Table 7-1 (FPU instructions). Cycles per instruction (`CYCLES`, by capstone's mnemonic without condition,
width or type suffix):

| instructions                                                      | cycles                            |
|-------------------------------------------------------------------|-----------------------------------|
| MOV/MOVW/MOVT/MVN, ADD/ADC/SUB/SBC/RSB, logic, shifts, compares   | 1                                 |
| MUL, MLA, MLS, SMULL/UMULL/SMLAL/UMLAL, DSP multiplies, SIMD, SAT | 1 (single-cycle MAC; M3: MLA 2)   |
| SDIV/UDIV                                                         | 12 (2-12, early exit: worst case) |
| extend, bit field, REV/RBIT, CLZ, SEL, IT, NOP, DMB/DSB           | 1                                 |
| LDR/LDRB/LDRH/LDRSB/LDRSH/LDREX, STR/STRB/STRH/STREX              | 2                                 |
| LDRD/STRD                                                         | 3 (1 + N, N = 2 words)            |
| LDM/STM/PUSH/POP                                                  | 1 + N (N words)                   |
| MRS/MSR/CPS                                                       | 2 (1 or 2: the worst case)        |
| B/BL/BX/BLX, CBZ/CBNZ                                             | 1, + P when taken                 |
| POP/LDM with PC                                                   | 1 + N + P                         |
| LDR PC                                                            | 2 + P                             |
| MOV/ADD to PC                                                     | 1 + P                             |
| TBB/TBH                                                           | 2 + P                             |
| ISB                                                               | 1 + P                             |
| VADD/VSUB/VMUL/VNMUL/VNEG/VABS/VCMP(E)/VCVT/VMOV/VMRS/VMSR        | 1                                 |
| VMOV two core registers <-> two singles or one double             | 2                                 |
| VMLA/VMLS/VNMLA/VNMLS/VFMA/VFMS/VFNMA/VFNMS                       | 3                                 |
| VDIV, VSQRT (.F32: an electrical loss model's current)            | 14                                |
| VLDR/VSTR                                                         | 2 (3 for a double)                |
| VLDM/VSTM/VPUSH/VPOP                                              | 1 + N (N words)                   |

Assumptions, stated because each one moves the count:
- zero-wait-state memory for code and data (no flash wait states, no accelerator or cache effects);
- P (pipeline refill after a taken branch, 1-3 in the TRM) is `PIPELINE_REFILL` = 2;
- loads and stores are never pipelined with their neighbours (the TRM lets a load or store that follows a load
  finish in 1 cycle), and no load-use, address-dependency or FPU-result stalls are modelled, so sequences of
  loads and stores count up to 1 cycle per instruction more than the core can do;
- a conditional branch not taken, or a conditional PC write (BXEQ LR, POPNE {..., PC}) that fails, costs 1;
- conditional instructions inside an IT block that are not the block's last are counted as executed (their
  condition is not visible to a block hook); most are 1-cycle ALU operations either way;
- IT counts 1 (the core may fold it into the preceding 16-bit instruction for 0);
- VDIV/VSQRT count their full 14 cycles (the core lets later integer instructions overlap them);
- a call's count covers the function's own instructions up to and including its return, not the caller's BL;
- a mnemonic missing from the table counts `DEFAULT_CYCLES` and is listed in `CycleModel.unknown`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import capstone
from capstone import arm_const

PIPELINE_REFILL = 2          # P of the TRM: cycles to refill the pipeline after a taken branch
CONDITIONAL_FAILED = 1       # a conditional branch not taken, or a conditional PC write whose condition fails
DEFAULT_CYCLES = 1           # a mnemonic not in CYCLES

_ALU = ("mov", "movs", "movw", "movt", "mvn", "add", "addw", "adc", "sub", "subs", "subw", "sbc", "rsb", "neg",
        "and", "orr", "orn", "eor", "bic", "lsl", "lsr", "asr", "ror", "rrx", "cmp", "cmn", "tst", "teq", "adr")
_MULTIPLY = ("mul", "mla", "mls", "smull", "umull", "smlal", "umlal", "umaal",
             "smulbb", "smulbt", "smultb", "smultt", "smulwb", "smulwt", "smlabb", "smlabt", "smlatb", "smlatt",
             "smlawb", "smlawt", "smlad", "smladx", "smlald", "smlaldx", "smlsd", "smlsdx", "smlsld", "smlsldx",
             "smlalbb", "smlalbt", "smlaltb", "smlaltt", "smmul", "smmulr", "smmla", "smmlar", "smmls", "smmlsr",
             "smuad", "smuadx", "smusd", "smusdx", "usad8", "usada8")
_SIMD_SATURATE = ("ssat", "usat", "ssat16", "usat16", "qadd", "qsub", "qdadd", "qdsub", "qadd8", "qadd16", "qsub8",
                  "qsub16", "qasx", "qsax", "sadd8", "sadd16", "ssub8", "ssub16", "sasx", "ssax", "shadd8",
                  "shadd16", "shsub8", "shsub16", "shasx", "shsax", "uadd8", "uadd16", "usub8", "usub16", "uasx",
                  "usax", "uhadd8", "uhadd16", "uhsub8", "uhsub16", "uhasx", "uhsax", "uqadd8", "uqadd16",
                  "uqsub8", "uqsub16", "uqasx", "uqsax", "sel", "pkhbt", "pkhtb")
_BITS = ("sxtb", "sxth", "uxtb", "uxth", "sxtab", "sxtah", "uxtab", "uxtah", "sxtb16", "uxtb16", "sxtab16",
         "uxtab16", "bfc", "bfi", "sbfx", "ubfx", "rev", "rev16", "revsh", "rbit", "clz")
_MISC = ("it", "nop", "yield", "dmb", "dsb", "clrex", "pld", "pli", "sev", "wfi", "wfe", "udf", "bkpt", "svc")
_LOADS_STORES = ("ldr", "ldrb", "ldrh", "ldrsb", "ldrsh", "ldrt", "ldrbt", "ldrht", "ldrsbt", "ldrsht", "ldrex",
                 "ldrexb", "ldrexh", "str", "strb", "strh", "strt", "strbt", "strht", "strex", "strexb", "strexh")
_FPU_1 = ("vadd", "vsub", "vmul", "vnmul", "vneg", "vabs", "vcmp", "vcmpe", "vcvt", "vcvtr", "vcvtb", "vcvtt",
          "vmov", "vmrs", "vmsr")
_FPU_MAC = ("vmla", "vmls", "vnmla", "vnmls", "vfma", "vfms", "vfnma", "vfnms")

CYCLES: dict[str, int] = {
    **dict.fromkeys(_ALU, 1),
    **dict.fromkeys(_MULTIPLY, 1),
    "sdiv": 12, "udiv": 12,
    **dict.fromkeys(_SIMD_SATURATE, 1),
    **dict.fromkeys(_BITS, 1),
    **dict.fromkeys(_MISC, 1),
    "isb": 1 + PIPELINE_REFILL,
    "mrs": 2, "msr": 2, "cps": 2,
    **dict.fromkeys(_LOADS_STORES, 2),
    "ldrd": 3, "strd": 3,
    "ldm": 1, "stm": 1, "push": 1, "pop": 1,         # + N words (MULTIPLE)
    "b": 1, "bl": 1, "bx": 1, "blx": 1, "cbz": 1, "cbnz": 1,   # + P when taken
    "tbb": 2, "tbh": 2,                               # + P (always taken)
    **dict.fromkeys(_FPU_1, 1),
    **dict.fromkeys(_FPU_MAC, 3),
    "vdiv": 14,
    "vsqrt": 14,        # VSQRT.F32, TRM Table 7-1: 14 cycles (the electrical loss model's sqrt(i_d^2 + i_q^2))
    "vldr": 2, "vstr": 2,                             # + 1 for a double register
    "vldm": 1, "vstm": 1, "vpush": 1, "vpop": 1,      # + N words (MULTIPLE)
}

# Rules on top of CYCLES, as data:
MULTIPLE = frozenset({"ldm", "stm", "push", "pop", "vldm", "vstm", "vpush", "vpop"})   # + N (32-bit words moved)
MULTIPLE_WITH_BASE = frozenset({"ldm", "stm", "vldm", "vstm"})                        # first operand: the base
BRANCHES = frozenset({"b", "bl", "bx", "blx", "cbz", "cbnz", "tbb", "tbh"})              # write the PC
COMPARE_AND_BRANCH = frozenset({"cbz", "cbnz"})                                          # conditional, no cc
DOUBLE_TRANSFER = frozenset({"vldr", "vstr"})                                            # + 1 for a D register
TWO_CORE_REGISTER_VMOV = 2                                                               # VMOV r, r <-> s, s / d

# capstone names -> the table's mnemonics
ALIASES: dict[str, str] = {
    "fmstat": "vmrs", "fconsts": "vmov", "fconstd": "vmov", "trap": "udf",
    "ldmia": "ldm", "ldmdb": "ldm", "ldmib": "ldm", "ldmda": "ldm",
    "stmia": "stm", "stmdb": "stm", "stmib": "stm", "stmda": "stm",
    "vldmia": "vldm", "vldmdb": "vldm", "vstmia": "vstm", "vstmdb": "vstm",
}


@dataclass(frozen=True, slots=True)
class InstructionCost:
    """One decoded instruction and what it costs."""

    address: int
    size: int
    mnemonic: str          # the table's mnemonic (no condition, width or type suffix)
    text: str              # as disassembled, e.g. "vadd.f32 s0, s1, s2"
    cycles: int            # executed, or for a conditional branch/PC write: not taken
    taken_extra: int       # added when this conditional branch is taken (0 otherwise)
    conditional_branch: bool
    writes_pc: bool
    known: bool            # the mnemonic is in CYCLES


def mnemonic_of(insn: capstone.CsInsn) -> str:
    """The table's mnemonic of a capstone instruction."""
    name = insn.insn_name()
    if name == "hint":     # capstone names NOP, WFI, YIELD, ... all "hint"
        name = insn.mnemonic.split(".")[0]
    return ALIASES.get(name, name)


def _words(insn: capstone.CsInsn, registers: Iterable[int]) -> int:
    """32-bit words a register list moves (a D register is two)."""
    return sum(2 if insn.reg_name(reg).startswith("d") else 1 for reg in registers)


def instruction_cost(insn: capstone.CsInsn) -> InstructionCost:
    """Cost of one instruction (capstone, detail on) by the tables and rules of this module."""
    mnemonic = mnemonic_of(insn)
    known = mnemonic in CYCLES
    cycles = CYCLES.get(mnemonic, DEFAULT_CYCLES)
    registers = [op.reg for op in insn.operands if op.type == arm_const.ARM_OP_REG]
    if mnemonic in MULTIPLE:
        cycles += _words(insn, registers[1:] if mnemonic in MULTIPLE_WITH_BASE else registers)
    elif mnemonic in DOUBLE_TRANSFER and registers and insn.reg_name(registers[0]).startswith("d"):
        cycles += 1
    elif mnemonic == "vmov" and len(registers) >= 3:
        cycles = TWO_CORE_REGISTER_VMOV          # VMOV r, r <-> s, s or d: the only forms with 3-4 registers
    try:
        written = insn.regs_access()[1]
    except capstone.CsError:       # no access detail for this instruction: the implicit writes only
        written = insn.regs_write
    writes_pc = mnemonic in BRANCHES or arm_const.ARM_REG_PC in written
    conditional = writes_pc and (insn.cc not in (arm_const.ARM_CC_AL, arm_const.ARM_CC_INVALID)
                                 or mnemonic in COMPARE_AND_BRANCH)
    if writes_pc:
        taken = cycles + PIPELINE_REFILL
        if conditional:
            return InstructionCost(insn.address, insn.size, mnemonic, f"{insn.mnemonic} {insn.op_str}".strip(),
                                   CONDITIONAL_FAILED, taken - CONDITIONAL_FAILED, True, True, known)
        cycles = taken
    return InstructionCost(insn.address, insn.size, mnemonic, f"{insn.mnemonic} {insn.op_str}".strip(),
                           cycles, 0, False, writes_pc, known)


def new_disassembler() -> capstone.Cs:
    """capstone for Cortex-M Thumb-2 code, with the operand detail the costs need."""
    disassembler = capstone.Cs(capstone.CS_ARCH_ARM, capstone.CS_MODE_THUMB | capstone.CS_MODE_MCLASS)
    disassembler.detail = True
    return disassembler


def sweep(disassembler: capstone.Cs, code: bytes, address: int) -> Iterable[InstructionCost]:
    """Costs of every instruction of a Thumb code range, in order (one pass keeps IT-block conditions right)."""
    offset = 0
    while offset < len(code):
        last = offset
        for insn in disassembler.disasm(code[offset:], address + offset):
            yield instruction_cost(insn)
            offset = insn.address + insn.size - address
        if offset == last:   # undecodable halfword (data in code): skip it and go on
            offset += 2


BlockCost = tuple[int, int, int, int]
"""(cycles with its final branch not taken, extra cycles when taken, fall-through address, instructions)."""


class CycleModel:
    """Costs of the basic blocks of one firmware image, computed once per block and cached."""

    def __init__(self, read: Callable[[int, int], bytes], thumb_ranges: Iterable[tuple[int, int]]):
        """`read(address, size)` reads code; `thumb_ranges` are the [start, end) ranges of Thumb code to sweep."""
        self._read = read
        self._disassembler = new_disassembler()
        self.instructions: dict[int, InstructionCost] = {}
        for start, end in thumb_ranges:
            if end > start:
                for cost in sweep(self._disassembler, read(start, end - start), start):
                    self.instructions.setdefault(cost.address, cost)
        self.blocks: dict[tuple[int, int], BlockCost] = {}
        self.unknown: set[str] = set()

    def block(self, address: int, size: int) -> BlockCost:
        """Cost of the block of `size` bytes at `address` (cached)."""
        cost = self.blocks.get((address, size))
        if cost is None:
            cost = self.blocks[(address, size)] = self._compute(address, size)
        return cost

    def instructions_of(self, address: int, size: int) -> list[InstructionCost]:
        """The decoded instructions of the block of `size` bytes at `address`, in order."""
        return self._decoded(address, size)

    def _decoded(self, address: int, size: int) -> list[InstructionCost]:
        end = address + size
        decoded: list[InstructionCost] = []
        at = address
        while at < end:
            cost = self.instructions.get(at)
            if cost is None:   # not met by the sweep (no mapping symbols, or code outside them): decode here
                return list(sweep(self._disassembler, self._read(address, size), address))
            decoded.append(cost)
            at += cost.size
        return decoded

    def _compute(self, address: int, size: int) -> BlockCost:
        decoded = self._decoded(address, size)
        self.unknown.update(cost.mnemonic for cost in decoded if not cost.known)
        cycles = sum(cost.cycles for cost in decoded)
        last = decoded[-1] if decoded else None
        extra = last.taken_extra if last is not None else 0
        return cycles, extra, address + size, len(decoded)
