"""The trip count of a counted loop, read from its machine code: what clang made of `for (i = 0; i < N; i++)`.

A loop is counted when (all read from the instructions, nothing assumed):
- it has one latch (the one block that jumps back to the header), which tests: either back or out of the loop, so
  every iteration that goes on passes that test (the test at the bottom: clang's rotated loop, including one it
  unrolled, whose step is then 2, 4, ... per trip); other ways out (a `break`, a `return`) only end it sooner;
- the latch's conditional branch reads the flags of a `cmp rX, #imm` (or of `subs rX, rX, #imm` / `subs rX, #imm`)
  in the latch itself, with no flag-setting instruction between it and the branch;
- rX is written exactly once in the loop, by `add`/`adds`/`sub`/`subs` rX, (rX,) #imm, in the latch or the header
  (each iteration runs both exactly once), and no call in the loop can change it (rX is r4-r11, callee-saved);
- on every way into the loop rX was last set by `mov`/`movs`/`movw` rX, #imm, within the entering block or the
  chain of single predecessors above it.
The trip count is then found by running the induction variable's arithmetic and the flags of the compare (32-bit,
ARM condition codes) until the branch leaves the loop: the header runs that many times per entry. A loop that
does not match returns None, and its bound must be stated (`target_sim.firmware.wcet.loop_bounds`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from capstone import arm_const

MAX_TRIPS = 1 << 16                      # a counted loop running longer than this is treated as not counted
CALLEE_SAVED = frozenset(f"r{n}" for n in range(4, 12)) | {"sb", "sl", "fp"}
_ARITHMETIC = {"add": 1, "adds": 1, "sub": -1, "subs": -1, "addw": 1, "subw": -1}
_MOVES = ("mov", "movs", "movw")
_MASK = 0xFFFFFFFF


def _condition_holds(cc: int, n: bool, z: bool, c: bool, v: bool) -> bool:
    table: dict[int, bool] = {
        arm_const.ARM_CC_EQ: z, arm_const.ARM_CC_NE: not z, arm_const.ARM_CC_HS: c, arm_const.ARM_CC_LO: not c,
        arm_const.ARM_CC_MI: n, arm_const.ARM_CC_PL: not n, arm_const.ARM_CC_VS: v, arm_const.ARM_CC_VC: not v,
        arm_const.ARM_CC_HI: c and not z, arm_const.ARM_CC_LS: not c or z, arm_const.ARM_CC_GE: n == v,
        arm_const.ARM_CC_LT: n != v, arm_const.ARM_CC_GT: not z and n == v, arm_const.ARM_CC_LE: z or n != v,
    }
    return table[cc]


def _subtract_flags(a: int, b: int) -> tuple[int, tuple[bool, bool, bool, bool]]:
    """a - b in 32 bits and its N, Z, C, V (as CMP / SUBS set them)."""
    result = (a - b) & _MASK
    negative = bool(result >> 31)
    overflow = bool(((a ^ b) & (a ^ result)) >> 31)
    return result, (negative, result == 0, (a & _MASK) >= (b & _MASK), overflow)


def _operands(insn) -> tuple[list[str], list[int]]:
    registers = [insn.reg_name(op.reg) for op in insn.operands if op.type == arm_const.ARM_OP_REG]
    immediates = [op.imm for op in insn.operands if op.type == arm_const.ARM_OP_IMM]
    return registers, immediates


def _writes(insn, register: str) -> bool:
    try:
        written = insn.regs_access()[1]
    except Exception:                    # noqa: BLE001 - capstone has no access detail: count it as a write
        return True
    return any(insn.reg_name(reg) == register for reg in written)


def _always(insn) -> bool:
    """The instruction runs unconditionally (not a conditional one of an IT block)."""
    return insn.cc in (arm_const.ARM_CC_AL, arm_const.ARM_CC_INVALID)


def _sets_flags(insn) -> bool:
    return insn.update_flags or insn.mnemonic.split(".")[0] in ("cmp", "cmn", "tst", "teq")


def trip_count(instructions: Callable[[int], list], nodes: Mapping, header: int, body: set[int],
               predecessors: Mapping[int, list[int]]) -> int | None:
    """The header's runs per entry of the loop (`body`, headed by `header`) when it is counted, else None.
    `instructions(block)` lists a block's capstone instructions; `nodes[block].successors` its (target, extra)
    pairs and `.calls` its callees."""
    latches = [block for block in body if any(target == header for target, _ in nodes[block].successors)]
    if len(latches) != 1:
        return None
    latch = latches[0]
    if not any(target not in body for target, _ in nodes[latch].successors):
        return None                     # the latch does not test: the count is decided elsewhere
    code = instructions(latch)
    branch = code[-1]
    if branch.cc in (arm_const.ARM_CC_AL, arm_const.ARM_CC_INVALID) or branch.mnemonic.split(".")[0] in ("cbz",
                                                                                                      "cbnz"):
        return None
    compare = next((insn for insn in reversed(code[:-1]) if _sets_flags(insn)), None)
    if compare is None:
        return None
    if not _always(compare):
        return None
    base = compare.mnemonic.split(".")[0]
    registers, immediates = _operands(compare)
    if base not in ("cmp", "subs") or len(immediates) != 1 or not registers or \
            (base == "subs" and len(set(registers)) != 1):
        return None
    register, limit = registers[0], immediates[0]
    update = _single_update(instructions, body, register, compare.address)
    if update is None or update[0] not in (latch, header):
        return None
    block, step, at = update
    if any(nodes[member].calls for member in body) and register not in CALLEE_SAVED:
        return None
    start = None
    for entry in sorted(predecessors.get(header, [])):
        if entry in body:
            continue
        value = _initial_value(instructions, predecessors, entry, register)
        if value is None or (start is not None and value != start):
            return None
        start = value
    if start is None:
        return None
    branch_target = next((op.imm for op in branch.operands if op.type == arm_const.ARM_OP_IMM), None)
    continue_when_taken = branch_target == header
    # the update runs before the compare unless both sit in the latch with the compare first
    update_first = block != latch or at < compare.address
    value = start & _MASK
    for trips in range(1, MAX_TRIPS + 1):
        if update_first:
            value = (value + step) & _MASK
        if base == "cmp":
            _, flags = _subtract_flags(value, limit)
        else:                                       # subs rX, #imm: the update is the compare
            value, flags = _subtract_flags(value, limit)
        if not update_first and base == "cmp":
            value = (value + step) & _MASK
        if _condition_holds(branch.cc, *flags) != continue_when_taken:
            return trips
    return None


def _single_update(instructions, body: set[int], register: str, compare: int) -> tuple[int, int, int] | None:
    """(block, signed step, address) of the one write of `register` in the loop, if it is an add/sub of an
    immediate to itself (a `subs` that is the compare itself: step 0 here, the compare does the update)."""
    found = None
    for block in body:
        for insn in instructions(block):
            if not _writes(insn, register):
                continue
            base = insn.mnemonic.split(".")[0]
            registers, immediates = _operands(insn)
            if found is not None or base not in _ARITHMETIC or len(immediates) != 1 or \
                    any(name != register for name in registers) or not _always(insn):
                return None             # a second write, another operation, or one an IT block may skip
            step = 0 if insn.address == compare else _ARITHMETIC[base] * immediates[0]
            found = (block, step, insn.address)
    return found


def _initial_value(instructions, predecessors, block: int, register: str, depth: int = 8) -> int | None:
    """The immediate `register` holds when control leaves `block`, from its last write there (or, when the block
    does not write it, in its single predecessor, up to `depth` blocks up)."""
    seen: set[int] = set()
    while depth > 0 and block not in seen:
        seen.add(block)
        for insn in reversed(instructions(block)):
            if _writes(insn, register):
                registers, immediates = _operands(insn)
                if insn.mnemonic.split(".")[0] in _MOVES and len(immediates) == 1 and registers == [register] \
                        and _always(insn):
                    return immediates[0] & _MASK
                return None
        above = predecessors.get(block, [])
        if len(above) != 1:
            return None
        block, depth = above[0], depth - 1
    return None
