"""Implicit path enumeration (target_sim.firmware.ipet) on small control-flow graphs whose longest path is known by
hand, and against an enumeration of every path; counted loops read from Thumb-2 code
(target_sim.firmware.counted_loops)."""

from __future__ import annotations

import itertools

import pytest

from target_sim.firmware.ipet import Edge, Fact, FlowGraph, IpetError, LoopFact, longest_path


def test_the_diamond_answer_by_hand():
    graph = FlowGraph(0, {0: 1, 1: 5, 2: 6, 3: 1}, [Edge(0, 1, 2), Edge(0, 2), Edge(1, 3), Edge(2, 3, 3),
                                                       Edge(3, None, 0)])
    # via 1: 1 + 2 + 5 + 0 + 1 = 9; via 2: 1 + 0 + 6 + 3 + 1 = 11
    solution = longest_path(graph)
    assert solution.cycles == 11 and solution.block_counts[2] == 1 and solution.edge_counts[(0, 1)] == 0


def test_a_loop_runs_its_header_the_stated_times_per_entry():
    # 0 -> 1 (header: body and test) -> 1 (back edge, +2) or -> 2 -> out; header at most 3 times per entry
    graph = FlowGraph(0, {0: 1, 1: 4, 2: 1}, [Edge(0, 1), Edge(1, 1, 2), Edge(1, 2), Edge(2, None)])
    solution = longest_path(graph, [LoopFact(1, (0,), 3)])
    assert solution.cycles == 1 + 3 * 4 + 2 * 2 + 1
    assert solution.block_counts[1] == 3 and solution.edge_counts[(1, 1)] == 2


def test_a_loop_at_the_entry_is_entered_by_the_call():
    graph = FlowGraph(1, {1: 4, 2: 1}, [Edge(1, 1, 2), Edge(1, 2), Edge(2, None)])
    assert longest_path(graph, [LoopFact(1, (), 3)]).cycles == 3 * 4 + 2 * 2 + 1


def test_nested_loops_multiply_and_a_fact_removes_an_infeasible_path():
    # outer header 1 (twice per entry), inner header 2 (three times per entry of the inner loop), then out by 3;
    # inside the inner body a choice: 4 (cost 10) or 5 (cost 1), both back to 2's latch 6
    blocks = {0: 0, 1: 1, 2: 1, 4: 10, 5: 1, 6: 1, 3: 1}
    edges = [Edge(0, 1), Edge(1, 2), Edge(2, 4), Edge(2, 5), Edge(4, 6), Edge(5, 6), Edge(6, 2), Edge(6, 1),
             Edge(1, 3), Edge(3, None)]
    inner = LoopFact(2, (1,), 3)
    outer = LoopFact(1, (0,), 3)             # tests at its top: 2 bodies, 3 runs of the header
    free = longest_path(FlowGraph(0, blocks, edges), [inner, outer])
    assert free.block_counts[1] == 3 and free.block_counts[2] == 6 and free.block_counts[4] == 6
    assert free.cycles == 3 * 1 + 6 * (1 + 10 + 1) + 1
    # an infeasible path: block 4 (say, an error branch) runs at most once in all
    once = longest_path(FlowGraph(0, blocks, edges), [inner, outer], [Fact(blocks={4: 1.0}, upper=1)])
    assert once.block_counts[4] == 1 and once.cycles == free.cycles - 5 * 9


def test_the_ipet_equals_the_longest_of_every_path_of_a_small_dag():
    # a 3-stage chain of diamonds with edge costs: 8 paths, each summed by hand below
    costs = {0: 2, 1: 3, 2: 7, 3: 1, 4: 4, 5: 2, 6: 6, 7: 1}
    edges = [Edge(0, 1, 2), Edge(0, 2), Edge(1, 3), Edge(2, 3, 2), Edge(3, 4), Edge(3, 5, 2), Edge(4, 6, 2),
             Edge(5, 6), Edge(6, 7), Edge(6, None), Edge(7, None, 1)]
    extra = {(e.source, e.target): e.cycles for e in edges}
    best = 0
    for a, b, c in itertools.product((1, 2), (4, 5), (None, 7)):
        path = [0, a, 3, b, 6] + ([7] if c else [])
        total = sum(costs[n] for n in path) + sum(extra[(x, y)] for x, y in zip(path, path[1:], strict=False))
        total += extra[(path[-1], None)]
        best = max(best, total)
    assert longest_path(FlowGraph(0, costs, edges)).cycles == best


def test_a_loop_without_a_bound_or_a_graph_without_a_return_is_refused():
    graph = FlowGraph(0, {0: 1, 1: 1, 2: 1}, [Edge(0, 1), Edge(1, 1), Edge(1, 2), Edge(2, None)])
    with pytest.raises(IpetError, match="unbounded"):
        longest_path(graph)
    with pytest.raises(IpetError, match="no way out"):
        longest_path(FlowGraph(0, {0: 1}, [Edge(0, 0)]), [LoopFact(0, (), 1)])
    with pytest.raises(IpetError, match="given twice"):
        longest_path(FlowGraph(0, {0: 1}, [Edge(0, None), Edge(0, None)]))


CONDITIONS = {"eq": 0, "ne": 1, "hs": 2, "lo": 3, "ge": 10, "lt": 11, "gt": 12, "le": 13}


def _loop_code(init: int, step: int, limit: int, condition: str) -> bytes:
    """Thumb-16 at 0x1000: movs r4, #init; (0x1002) adds r4, #step; cmp r4, #limit; b<condition> 0x1002."""
    words = [0x2400 | init, 0x3400 | step, 0x2C00 | limit, 0xD000 | (CONDITIONS[condition] << 8) | 0xFC]
    return b"".join(word.to_bytes(2, "little") for word in words)


@pytest.mark.parametrize(("init", "step", "limit", "condition", "trips"), [
    (0, 1, 4, "ne", 4), (0, 8, 16, "ne", 2), (0, 2, 4, "ne", 2), (0, 1, 4, "lo", 4), (1, 1, 8, "lt", 7),
    (0, 3, 10, "lt", 4)])
def test_a_counted_loop_gives_its_trip_count(init, step, limit, condition, trips):
    from types import SimpleNamespace

    from target_sim.firmware.counted_loops import trip_count
    from target_sim.firmware.cycles import new_disassembler

    instructions = list(new_disassembler().disasm(_loop_code(init, step, limit, condition), 0x1000))
    assert [insn.mnemonic for insn in instructions][-1] == f"b{condition}"
    blocks = {0x1000: instructions[:1], 0x1002: instructions[1:]}
    nodes = {0x1000: SimpleNamespace(successors=((0x1002, 0),), calls=(), returns=None),
             0x1002: SimpleNamespace(successors=((0x1002, 2), (0x1008, 0)), calls=(), returns=None)}
    assert trip_count(blocks.__getitem__, nodes, 0x1002, {0x1002}, {0x1002: [0x1000, 0x1002]}) == trips
    # the same loop entered with an unknown count (the register not set to a constant) is not counted
    blocks[0x1000] = []
    assert trip_count(blocks.__getitem__, nodes, 0x1002, {0x1002}, {0x1002: [0x1000, 0x1002]}) is None
