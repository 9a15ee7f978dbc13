"""Implicit path enumeration (IPET): the longest path through a control-flow graph as an integer linear program.

    graph = FlowGraph(entry=0, blocks={0: 3, 1: 5, 2: 1}, edges=[Edge(0, 1), Edge(1, 1, 2), Edge(1, 2), Edge(2, None)])
    solution = longest_path(graph, [LoopFact(header=1, entries=(0,), iterations=4)])
    solution.cycles, solution.block_counts, solution.edge_counts

Li and Malik's formulation (Y.-T. S. Li and S. Malik, "Performance analysis of embedded software using implicit
path enumeration", DAC 1995; IEEE TCAD 16(12), 1997): every block b and every edge e get an execution count x_b,
x_e >= 0 (integers); the count of a block equals the flow into it and the flow out of it (structural constraints:
the entry has one virtual edge in, the exits one virtual edge out in all), and the time of a run is
sum(c_b x_b) + sum(c_e x_e). Loops are bounded by linear flow facts (the header's count at most N times the flow
that enters the loop), infeasible paths by further linear facts on the counts (`Fact`). The worst case is the
maximum of that sum, solved exactly here by `scipy.optimize.milp` (HiGHS branch and bound). Without a bound on a
cycle the program is unbounded: `IpetError` says so.

Edge costs carry what depends on the path (a taken branch's pipeline refill), block costs what does not.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import Bounds, LinearConstraint, milp
from scipy.sparse import lil_matrix

from target_sim.errors import TargetError


class IpetError(TargetError):
    """The integer program has no bounded solution (a cycle without a fact) or no solution at all; one sentence."""


@dataclass(frozen=True)
class Edge:
    """A control-flow edge; `target` None is a way out of the graph (a return); `cycles` added when it is taken."""

    source: int
    target: int | None
    cycles: int = 0


@dataclass(frozen=True)
class FlowGraph:
    """Blocks (id -> cycles each time it runs), the edges between them, and the entry block."""

    entry: int
    blocks: Mapping[int, int]
    edges: Sequence[Edge]


@dataclass(frozen=True)
class LoopFact:
    """The loop's header runs at most `iterations` times for each time control enters the loop from outside
    (`entries`: the blocks outside the loop with an edge to its header; the call itself when the header is the
    graph's entry)."""

    header: int
    entries: tuple[int, ...]
    iterations: int


@dataclass(frozen=True)
class Fact:
    """A linear fact on the counts: sum(coefficient x block count) + sum(coefficient x edge count) <= upper.
    `edges` are keyed by (source, target)."""

    blocks: Mapping[int, float] = field(default_factory=dict)
    edges: Mapping[tuple[int, int | None], float] = field(default_factory=dict)
    upper: float = 0.0


@dataclass(frozen=True)
class Solution:
    """The worst case: its cycles and how often each block and edge runs on it."""

    cycles: int
    block_counts: dict[int, int]
    edge_counts: dict[tuple[int, int | None], int]


def longest_path(graph: FlowGraph, loops: Iterable[LoopFact] = (), facts: Iterable[Fact] = ()) -> Solution:
    """The maximum of sum(c_b x_b) + sum(c_e x_e) over the integer flows of `graph` that meet `loops` and `facts`."""
    blocks = sorted(graph.blocks)
    block_index = {block: k for k, block in enumerate(blocks)}
    edges = list(graph.edges)
    edge_index: dict[tuple[int, int | None], int] = {}
    for k, edge in enumerate(edges):
        if edge.source not in block_index or (edge.target is not None and edge.target not in block_index):
            raise IpetError(f"edge {edge.source} -> {edge.target} names a block the graph does not have")
        if (edge.source, edge.target) in edge_index:
            raise IpetError(f"edge {edge.source} -> {edge.target} is given twice")
        edge_index[(edge.source, edge.target)] = len(blocks) + k
    if graph.entry not in block_index:
        raise IpetError(f"the entry {graph.entry} is no block of the graph")
    count = len(blocks) + len(edges)
    rows: list[tuple[dict[int, float], float, float]] = []
    inflows: dict[int, list[int]] = {block: [] for block in blocks}
    outflows: dict[int, list[int]] = {block: [] for block in blocks}
    for k, edge in enumerate(edges):
        outflows[edge.source].append(len(blocks) + k)
        if edge.target is not None:
            inflows[edge.target].append(len(blocks) + k)
    for block in blocks:                                   # x_b = flow in (+1 at the entry) = flow out
        inflow = {block_index[block]: 1.0, **{column: -1.0 for column in inflows[block]}}
        outflow = {block_index[block]: 1.0, **{column: -1.0 for column in outflows[block]}}
        entry = 1.0 if block == graph.entry else 0.0
        rows.append((inflow, entry, entry))
        rows.append((outflow, 0.0, 0.0))
    exits = {len(blocks) + k: 1.0 for k, edge in enumerate(edges) if edge.target is None}
    if not exits:
        raise IpetError("the graph has no way out (no return)")
    rows.append((exits, 1.0, 1.0))
    for loop in loops:
        if loop.header not in block_index:
            raise IpetError(f"loop header {loop.header} is no block of the graph")
        row = {block_index[loop.header]: 1.0}
        for source in loop.entries:
            column = edge_index.get((source, loop.header))
            if column is None:
                raise IpetError(f"no edge {source} -> {loop.header} enters the loop")
            row[column] = row.get(column, 0.0) - float(loop.iterations)
        # a loop headed by the entry block is entered once more, by the call itself (the virtual edge in)
        rows.append((row, -np.inf, float(loop.iterations) if loop.header == graph.entry else 0.0))
    for fact in facts:
        row: dict[int, float] = {}
        for block, coefficient in fact.blocks.items():
            row[block_index[block]] = row.get(block_index[block], 0.0) + coefficient
        for key, coefficient in fact.edges.items():
            if key not in edge_index:
                raise IpetError(f"a fact names edge {key[0]} -> {key[1]}, which the graph does not have")
            row[edge_index[key]] = row.get(edge_index[key], 0.0) + coefficient
        rows.append((row, -np.inf, float(fact.upper)))
    matrix = lil_matrix((len(rows), count))
    lower, upper = np.empty(len(rows)), np.empty(len(rows))
    for r, (row, low, high) in enumerate(rows):
        for column, value in row.items():
            matrix[r, column] = value
        lower[r], upper[r] = low, high
    cost = np.array([float(graph.blocks[block]) for block in blocks] + [float(edge.cycles) for edge in edges])
    result = milp(-cost, constraints=LinearConstraint(matrix.tocsr(), lower, upper), integrality=np.ones(count),
                  bounds=Bounds(0.0, np.inf))
    if result.status == 3 or (result.status != 0 and "unbounded" in str(result.message).lower()):
        raise IpetError("the longest path is unbounded: a loop has no bound")
    if result.status != 0 or result.x is None:
        raise IpetError(f"the integer program has no solution ({result.message})")
    counts = np.rint(result.x).astype(int)
    return Solution(cycles=int(round(float(cost @ counts))),
                    block_counts={block: int(counts[block_index[block]]) for block in blocks},
                    edge_counts={key: int(counts[column]) for key, column in edge_index.items()})
