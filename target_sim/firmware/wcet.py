"""A static bound of the worst-case execution time of a firmware function, from the ELF alone.

    bound = wcet(image, "node_on_frame", loop_facts(sources))   # cycles on every path, with the loop bounds
    bound.cycles, bound.loops, bound.calls

The control-flow graph of each function is rebuilt from the disassembly (capstone, recursive descent from the
function's symbol): conditional branches and compare-and-branch have two successors, TBB/TBH jump tables are read
from the bytes after the instruction (the table ends where the first target begins, as the compiler lays them
out), BL/BLX to a symbol is a call (the callee's bound is added: the call graph must be acyclic, the firmware has
no recursion), a branch out of the function is a tail call, BX LR / POP {..., PC} / LDR PC return. An indirect
jump or call that is not a jump table cannot be bounded: `WcetError` names it.

Each instruction costs what the emulator counts for it (`target_sim.firmware.cycles`, the same table and
`instruction_cost`): its cycles with a conditional branch not taken, plus `taken_extra` on the edge where the
branch is taken. The bound is the longest path from the entry to a return by implicit path enumeration
(`target_sim.firmware.ipet`, Li and Malik's integer program, solved by scipy's MILP): a count per block and per
edge, flow conserved at every block, and each loop's header at most N times per entry into the loop. A callee
costs its own bound at each call (its worst case, whatever the caller's context).

Loop bounds are never guessed. A counted loop (`target_sim.firmware.counted_loops`: an induction register set to
a constant before the loop, stepped by a constant once per iteration, compared with a constant in the latch) gets
its exact trip count from the machine code, however clang rotated or unrolled it. Every other loop needs a bound
stated in the C, `/* wcet-loop: N */` on its line (`loop_facts` reads them; N may name a #define or `lost_rows`),
found through the image's DWARF line table (the timing image carries one: `-gline-tables-only`, the same code);
a loop with neither is an error naming its function, address and C line. A stated bound N is the most times the
C loop's body runs per entry: the machine loop's header runs N times, or N + 1 when it tests before the body.
Conditional instructions inside an IT block count as executed, as in the emulator, so the bound covers the
emulator's count of every path (the tests check the measured maximum never exceeds it).

A mode of the firmware may fix globals (`value_facts`: `/* wcet-value(MODE): name = N */` in the C, e.g. no XCP
master since power-on keeps `xcp_connected` 0): with `values`, a block whose own instructions load such a global
and test it (`target_sim.firmware.known_values`) has its other way out infeasible, an IPET fact (count 0); the
bound's `decided` lists those branches.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field

from capstone import arm_const

from target_sim.errors import TargetError
from target_sim.firmware.counted_loops import trip_count
from target_sim.firmware.cycles import InstructionCost, instruction_cost, new_disassembler
from target_sim.firmware.elf import ElfImage, Symbol
from target_sim.firmware.ipet import Edge, Fact, FlowGraph, IpetError, LoopFact, longest_path
from target_sim.firmware.known_values import Read, ValueFactError, decided_branch, memory_reader

RETURN_MNEMONICS = frozenset({"bx", "pop", "ldm", "ldr", "mov"})   # ... when they write the PC


class WcetError(TargetError):
    """The function cannot be bounded (an indirect jump, a loop without a stated bound, recursion); one sentence."""


@dataclass(frozen=True)
class LoopBound:
    """The most times a loop's back edges are taken per entry into it, and why (from the C)."""

    iterations: int
    reason: str


@dataclass(frozen=True)
class Loop:
    function: str
    header: int
    order: int                     # place of the header among the function's loops, by address
    bound: LoopBound
    header_runs: int               # the most times its header runs per entry (the IPET's loop fact)


@dataclass(frozen=True)
class Decided:
    """A conditional branch the mode's known values decide (`known_values`): its other way out never runs."""

    function: str
    address: int
    taken: bool


@dataclass
class Bound:
    """The WCET bound of a function: cycles, and what it rests on (its loops, its callees' bounds)."""

    function: str
    cycles: int
    loops: list[Loop] = field(default_factory=list)
    calls: dict[str, int] = field(default_factory=dict)
    block_counts: dict[int, int] = field(default_factory=dict)     # the worst case's runs of each block (IPET)
    decided: list[Decided] = field(default_factory=list)            # branches the mode's values decide

    def as_dict(self) -> dict:
        return {"function": self.function, "cycles": self.cycles, "calls": dict(self.calls),
                "decided": [{"function": branch.function, "branch": f"{branch.address:#010x}",
                             "taken": branch.taken} for branch in self.decided],
                "loops": [{"function": loop.function, "header": f"{loop.header:#010x}", "order": loop.order,
                           "bound": loop.bound.iterations, "reason": loop.bound.reason,
                           "header_runs": loop.header_runs} for loop in self.loops]}


@dataclass(frozen=True)
class _Node:
    """A basic block: its instructions' cycles (branch not taken) and its successors with the edge's extra cost."""

    start: int
    cycles: int
    calls: tuple[str, ...]
    successors: tuple[tuple[int, int], ...]      # (address, extra cycles on that edge)
    returns: int | None                          # extra cycles when it returns (None: it does not)
    addresses: tuple[int, ...] = ()              # its instructions' addresses, in order


class _Image:
    """The instructions of an ELF image: one capstone pass over each code range of the mapping symbols ($t), which
    keeps the conditions of IT blocks (an instruction decoded alone loses them) and never decodes data."""

    def __init__(self, image: ElfImage):
        self.image = image
        self.functions = {symbol.address: name for name, symbol in image.symbols.items()
                          if symbol.kind == "STT_FUNC"}
        disassembler = new_disassembler()
        self._decoded: dict[int, tuple[InstructionCost, object]] = {}
        for start, end in image.thumb_ranges:
            offset, code = 0, self.read(start, end - start) if end > start else b""
            while offset < len(code):
                last = offset
                for insn in disassembler.disasm(code[offset:], start + offset):
                    self._decoded[insn.address] = (instruction_cost(insn), insn)
                    offset = insn.address + insn.size - start
                if offset == last:
                    offset += 2

    def read(self, address: int, size: int) -> bytes:
        for segment in self.image.segments:
            if segment.vaddr <= address and address + size <= segment.vaddr + len(segment.data):
                offset = address - segment.vaddr
                return segment.data[offset:offset + size]
        raise WcetError(f"{self.image.name} has no code at {address:#010x}")

    def instruction(self, address: int) -> tuple[InstructionCost, object]:
        known = self._decoded.get(address)
        if known is None:
            raise WcetError(f"{self.image.name} has no instruction at {address:#010x} (a jump into data?)")
        return known


def _target(insn) -> int | None:
    """The immediate branch target of a branch instruction, else None."""
    for op in insn.operands:
        if op.type == arm_const.ARM_OP_IMM:
            return op.imm
    return None


def _table_targets(code: _Image, insn, halfwords: bool) -> list[int]:
    """Targets of a TBB/TBH jump table: entries after the instruction until the lowest target seen (a table of odd
    length is padded to a halfword: that entry points into the table and is dropped)."""
    base = insn.address + 4
    step = 2 if halfwords else 1
    targets: list[int] = []
    at = base
    while not targets or at < min(targets):
        raw = code.read(at, step)
        targets.append(base + 2 * int.from_bytes(raw, "little"))
        at += step
        if len(targets) > 4096:
            raise WcetError(f"the jump table at {insn.address:#010x} has no end")
    return [target for target in targets if target >= at]     # a padding entry points into the table itself


def _function_graph(code: _Image, name: str, symbol: Symbol) -> dict[int, _Node]:
    """The basic blocks of one function by recursive descent from its entry."""
    start, end = symbol.address, symbol.address + symbol.size
    successors: dict[int, list[tuple[int, int]]] = {}
    leaders = {start}
    order: list[int] = []
    seen: set[int] = set()
    work = [start]
    while work:
        address = work.pop()
        if address in seen:
            continue
        seen.add(address)
        order.append(address)
        cost, insn = code.instruction(address)
        following = address + cost.size
        outs: list[tuple[int, int]] = []
        mnemonic = cost.mnemonic
        if mnemonic in ("tbb", "tbh"):
            for target in _table_targets(code, insn, mnemonic == "tbh"):
                outs.append((target, 0))
                leaders.add(target)
        elif mnemonic in ("bl", "blx"):
            target = _target(insn)
            if target is None or target not in code.functions:
                raise WcetError(f"{name} makes an indirect call at {address:#010x} ({cost.text}): its callee "
                                "cannot be bounded statically")
            outs.append((following, 0))
        elif cost.writes_pc:
            target = _target(insn) if mnemonic in ("b", "cbz", "cbnz") else None
            if mnemonic in ("b", "cbz", "cbnz") and target is None:
                raise WcetError(f"{name} jumps indirectly at {address:#010x} ({cost.text})")
            if target is not None:
                extra = cost.taken_extra
                inside = start <= target < end
                outs.append((target if inside else -target, extra))     # out of the function: a tail call
                if inside:
                    leaders.add(target)
            elif mnemonic not in RETURN_MNEMONICS:
                raise WcetError(f"{name} jumps indirectly at {address:#010x} ({cost.text})")
            else:
                outs.append((-1, cost.taken_extra))        # a return
            if cost.conditional_branch:
                outs.append((following, 0))
            leaders.add(following)
        else:
            outs.append((following, 0))
        successors[address] = outs
        for target, _ in outs:
            if target >= 0 and target not in seen:
                work.append(target)
    return _blocks(code, name, sorted(seen), leaders, successors)


def _blocks(code: _Image, name: str, addresses: list[int], leaders: set[int],
            successors: dict[int, list[tuple[int, int]]]) -> dict[int, _Node]:
    nodes: dict[int, _Node] = {}
    index = 0
    while index < len(addresses):
        first = addresses[index]
        cycles, calls, members = 0, [], []
        while True:
            address = addresses[index]
            members.append(address)
            cost, insn = code.instruction(address)
            cycles += cost.cycles
            if cost.mnemonic in ("bl", "blx"):
                calls.append(code.functions[_target(insn)])
            outs = successors[address]
            index += 1
            following = address + cost.size
            ends = (len(outs) != 1 or outs[0][0] != following or index == len(addresses)
                    or addresses[index] != following or following in leaders)
            if ends:
                break
        block_outs, returns = [], None
        for target, extra in outs:
            if target == -1:
                returns = extra
            elif target < 0:              # a tail call: the callee's bound, then its return is ours
                calls.append(code.functions.get(-target) or f"{-target:#x}")
                returns = extra
            else:
                block_outs.append((target, extra))
        nodes[first] = _Node(first, cycles, tuple(calls), tuple(block_outs), returns, tuple(members))
    return nodes


def _loops(nodes: Mapping[int, _Node], entry: int) -> dict[int, set[int]]:
    """Natural loops: header -> its body (the blocks that reach a back edge's source without the header)."""
    back: dict[int, list[int]] = {}
    state: dict[int, int] = {}           # 1 on the DFS stack, 2 done
    stack = [(entry, iter(nodes[entry].successors))]
    state[entry] = 1
    while stack:
        node, successors = stack[-1]
        advanced = False
        for target, _ in successors:
            if state.get(target) == 1:
                back.setdefault(target, []).append(node)
            elif target not in state:
                state[target] = 1
                stack.append((target, iter(nodes[target].successors)))
                advanced = True
                break
        if not advanced:
            state[node] = 2
            stack.pop()
    predecessors: dict[int, list[int]] = {}
    for node in nodes.values():
        for target, _ in node.successors:
            predecessors.setdefault(target, []).append(node.start)
    loops: dict[int, set[int]] = {}
    for header, sources in back.items():
        body = {header}
        work = [source for source in sources if source != header]
        body.update(work)
        while work:
            for previous in predecessors.get(work.pop(), ()):
                if previous not in body:
                    body.add(previous)
                    work.append(previous)
        loops[header] = body
    return loops


class _Analysis:
    def __init__(self, image: ElfImage, facts: Mapping[tuple[str, int], LoopBound], read: Read | None = None):
        self.code = _Image(image)
        self.image = image
        self.facts = facts
        self.read = read
        self.results: dict[str, Bound] = {}
        self.active: list[str] = []

    def function(self, name: str) -> Bound:
        done = self.results.get(name)
        if done is not None:
            return done
        if name in self.active:
            raise WcetError(f"{name} is recursive ({' -> '.join([*self.active, name])}): no static bound")
        symbol = self.image.symbols.get(name)
        if symbol is None or symbol.kind != "STT_FUNC":
            raise WcetError(f"{self.image.name} has no function {name!r}")
        self.active.append(name)
        try:
            nodes = _function_graph(self.code, name, symbol)
            bound = Bound(name, 0)
            costs = {start: node.cycles + sum(self._callee(callee, bound) for callee in node.calls)
                     for start, node in nodes.items()}
            bound.cycles = self._longest(name, nodes, costs, symbol.address, bound)
        finally:
            self.active.pop()
        self.results[name] = bound
        return bound

    def _callee(self, callee: str, bound: Bound) -> int:
        inner = self.function(callee)
        bound.calls[callee] = inner.cycles
        bound.loops.extend(loop for loop in inner.loops if loop not in bound.loops)
        bound.decided.extend(branch for branch in inner.decided if branch not in bound.decided)
        return inner.cycles

    def _instructions(self, nodes: Mapping[int, _Node]):
        """block -> its capstone instructions, in order."""
        return lambda block: [self.code.instruction(address)[1] for address in nodes[block].addresses]

    def _lines(self, nodes: Mapping[int, _Node], header: int, body: set[int]) -> list[tuple[str, int]]:
        """The C lines of a loop, most telling first: its back edges' branches, the rest of its latches, its
        header."""
        latches = [block for block in body if any(target == header for target, _ in nodes[block].successors)]
        ordered = [nodes[block].addresses[-1] for block in latches]
        ordered += [address for block in latches for address in nodes[block].addresses[:-1]]
        ordered += list(nodes[header].addresses)
        lines = [self.image.line_of(address) for address in ordered]
        return list(dict.fromkeys(line for line in lines if line is not None))

    def _stated(self, nodes: Mapping[int, _Node], header: int, body: set[int]) -> LoopBound | None:
        """The stated bound of the C loop this machine loop comes from (the first of its lines with one)."""
        for line in self._lines(nodes, header, body):
            if line in self.facts:
                return self.facts[line]
        return None

    def _longest(self, name: str, nodes: dict[int, _Node], costs: dict[int, int], entry: int, bound: Bound) -> int:
        """The IPET maximum (`target_sim.firmware.ipet`) over the function's blocks, each loop's header bounded by
        its stated bound per entry into the loop."""
        loops = _loops(nodes, entry)
        headers = sorted(loops)
        worst: dict[tuple[int, int | None], int] = {}      # parallel edges (a jump table's repeats): the dearest
        for start, node in nodes.items():
            ways = [*node.successors, *([(None, node.returns)] if node.returns is not None else [])]
            for target, extra in ways:
                worst[(start, target)] = max(extra, worst.get((start, target), extra))
        edges = [Edge(start, target, extra) for (start, target), extra in worst.items()]
        predecessors: dict[int, list[int]] = {}
        for start, node in nodes.items():
            for target, _ in node.successors:
                predecessors.setdefault(target, []).append(start)
        facts = []
        for order, header in enumerate(headers):
            body = loops[header]
            entries = tuple(sorted({start for start in predecessors.get(header, []) if start not in body}))
            counted = trip_count(self._instructions(nodes), nodes, header, body, predecessors)
            limit = self._stated(nodes, header, body)
            if counted is not None:      # the machine code's own count: exact, and it needs no stated bound
                runs = counted
                limit = LoopBound(counted, "counted loop: its induction variable, step and limit in the code")
            elif limit is None:
                where = self._lines(nodes, header, body)
                raise WcetError(f"{name} has a loop at {header:#010x} (loop {order} of the function"
                                f"{', C ' + where[0][0] + ':' + str(where[0][1]) if where else ''}) whose count the "
                                "code does not show and without a stated bound (a /* wcet-loop: N */ on its C "
                                "line; the image needs its line table)")
            else:
                runs = limit.iterations + (1 if _tests_at_top(nodes, header, body) else 0)
            facts.append(LoopFact(header, entries, runs))
            bound.loops.append(Loop(name, header, order, limit, runs))
        try:
            solution = longest_path(FlowGraph(entry, costs, edges), facts, self._infeasible(name, nodes, worst, bound))
        except IpetError as exc:
            raise WcetError(f"{name}: {exc}") from None
        bound.block_counts = {start: runs for start, runs in solution.block_counts.items() if runs}
        return solution.cycles

    def _infeasible(self, name: str, nodes: Mapping[int, _Node], edges: Mapping[tuple[int, int | None], int],
                    bound: Bound) -> list[Fact]:
        """The way out of each block whose conditional branch the mode's known values decide: count 0."""
        if self.read is None:
            return []
        instructions = self._instructions(nodes)
        facts = []
        for start, node in nodes.items():
            cost, insn = self.code.instruction(node.addresses[-1])
            if not cost.conditional_branch:
                continue
            taken = decided_branch(instructions(start), self.read)
            if taken is None:
                continue
            target = _target(insn) if cost.mnemonic in ("b", "cbz", "cbnz") else None
            taken_way = target if target in nodes else None          # out of the function: a return, a tail call
            following = node.addresses[-1] + cost.size
            never = following if taken else taken_way
            if taken_way == following or (start, never) not in edges:
                continue
            facts.append(Fact(edges={(start, never): 1.0}, upper=0))
            bound.decided.append(Decided(name, node.addresses[-1], taken))
        return facts


def _tests_at_top(nodes: Mapping[int, _Node], header: int, body: set[int]) -> bool:
    """The loop's header has a way out and is not its own latch: it tests before the body, so it runs once more
    than the body (a one-block loop tests at its bottom)."""
    node = nodes[header]
    leaves = node.returns is not None or any(target not in body for target, _ in node.successors)
    return leaves and not any(target == header for target, _ in node.successors)


def wcet(image: ElfImage, function: str, facts: Mapping[tuple[str, int], LoopBound] | None = None,
         values: Mapping[str, int] | None = None) -> Bound:
    """The WCET bound of `function` in cycles (callees included); `facts`: the stated bounds of the loops the code
    does not count itself, by (source file name, line) of their C loop (`loop_facts`; the image must carry its
    line table then); `values`: globals a mode fixes (`value_facts`), whose tests decide branches
    (`target_sim.firmware.known_values`: the other way out of such a block is infeasible)."""
    try:
        read = memory_reader(image, values) if values else None
    except ValueFactError as exc:
        raise WcetError(str(exc)) from None
    return _Analysis(image, facts or {}, read).function(function)


ANNOTATION = re.compile(r"/\*\s*wcet-loop:\s*([^*]+?)\s*\*/")
_DEFINE = re.compile(r"^\s*#\s*define\s+([A-Z_][A-Z0-9_]*)\s+\(?\s*(\d+)u?\s*\)?\s*(?:/\*.*)?$", re.MULTILINE)


def loop_facts(sources: Mapping[str, str], lost_rows: int = 0, daq: tuple[int, int] = (0, 0)
               ) -> dict[tuple[str, int], LoopBound]:
    """The stated loop bounds of a firmware's sources: each C loop whose line carries `/* wcet-loop: BOUND */`, the
    most times its body runs each time the loop is entered. BOUND is an integer, a name of an integer `#define`
    of the sources, `lost_rows` (the most rows one received data frame may skip: its Step that far ahead of the next
    expected row), `steps_per_row` (lost_rows + 1: the model steps one frame can run), or `max(A, B, ...)` of those
    (names a build does not define are left out; a loop none of whose names it defines is compiled out). The node
    steps the model once for each lost row that ends an interval, so no bound holds for every frame the bus can
    carry (a frame 32 767 rows ahead runs that many iterations): node_on_frame's bound is stated per number of
    lost rows, 0 for a drive whose rows arrive in order. Likewise the XCP slave's DAQ sampling: `daq_lists` and
    `daq_odts` (`daq`) are the DAQ lists and ODTs a master has configured, (0, 0) without an XCP master."""
    if lost_rows < 0 or min(daq) < 0:
        raise ValueError(f"lost_rows and the DAQ lists and ODTs must be 0 or more, not {lost_rows}, {daq}")
    values = {"lost_rows": lost_rows, "steps_per_row": lost_rows + 1, "daq_lists": daq[0], "daq_odts": daq[1]}
    for text in sources.values():
        for name, number in _DEFINE.findall(text):        # defined twice (#if branches): the larger, to be safe
            values[name] = max(int(number), values.get(name, 0))
    facts: dict[tuple[str, int], LoopBound] = {}
    for file_name, text in sources.items():
        for number, line in enumerate(text.splitlines(), start=1):
            found = ANNOTATION.search(line)
            if found is None:
                continue
            expression = found.group(1)
            names = [name.strip() for name in expression.removeprefix("max(").removesuffix(")").split(",")]
            known = [int(name) if name.isdigit() else values[name] for name in names if name.isdigit()
                     or name in values]
            if not known:        # code this build leaves out (#ifdef): no machine loop comes from it
                continue
            reason = f"{file_name}:{number}: {line.split('/*')[0].strip()} (at most {expression})"
            facts[(file_name, number)] = LoopBound(max(known), reason)
    return facts


VALUE_ANNOTATION = re.compile(r"/\*\s*wcet-value\((\w+)\):\s*([^*]+?)\s*\*/")
_ASSIGNMENT = re.compile(r"([A-Za-z_]\w*)\s*=\s*(\d+)")


def value_facts(sources: Mapping[str, str], mode: str) -> dict[str, int]:
    """The globals `mode` fixes, as the sources state them: `/* wcet-value(MODE): name = N, ... */` on the line
    that declares them (the C says why beside it), each `name` keeping the value N for as long as the mode lasts.
    A mode no annotation names fixes nothing ({})."""
    values: dict[str, int] = {}
    for file_name, text in sources.items():
        for number, line in enumerate(text.splitlines(), start=1):
            for found in VALUE_ANNOTATION.finditer(line):
                if found.group(1) != mode:
                    continue
                pairs = [part.strip() for part in found.group(2).split(",")]
                matched = [_ASSIGNMENT.fullmatch(pair) for pair in pairs]
                if not all(matched):
                    raise ValueError(f"{file_name}:{number}: a wcet-value fact is 'name = N, ...', not "
                                     f"{found.group(2)!r}")
                for assignment in matched:
                    values[assignment.group(1)] = int(assignment.group(2))
    return values
