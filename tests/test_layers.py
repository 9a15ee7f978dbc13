"""The architecture, read from the source: imports run one way and nothing imports in a circle.

    dbc          the link layer: imports nothing of the project
    target_sim   one node: imports dbc only
    host         the other node: imports dbc only
    bench        the orchestrator: the only package that uses both nodes

Every import counts, also one inside a function (it is a dependency all the same); `TYPE_CHECKING` blocks too.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

from helpers import ROOT

PACKAGES = ("dbc", "target_sim", "host", "bench")
ALLOWED: dict[str, frozenset[str]] = {
    "dbc": frozenset({"dbc"}),
    "target_sim": frozenset({"target_sim", "dbc"}),
    "host": frozenset({"host", "dbc"}),
    "bench": frozenset(PACKAGES),
}


def _module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imported(module: str, is_package: bool, tree: ast.AST) -> Iterator[tuple[str, int]]:
    """(imported module, line) for every import statement of a module, relative ones resolved."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if is_package else module.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                prefix = ".".join(base + ([node.module] if node.module else []))
            else:
                prefix = node.module or ""
            yield prefix, node.lineno
            for alias in node.names:  # `from pkg import submodule` imports the submodule
                yield f"{prefix}.{alias.name}", node.lineno


def project_imports(root: Path, packages=PACKAGES) -> dict[str, dict[str, int]]:
    """module -> {project module it imports: line}, for every module of `packages` under `root`."""
    paths = {_module_name(root, path): path for package in packages for path in (root / package).rglob("*.py")}
    graph: dict[str, dict[str, int]] = {}
    for module, path in paths.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        edges: dict[str, int] = {}
        for name, line in _imported(module, path.name == "__init__.py", tree):
            if name.split(".")[0] not in packages:
                continue
            while name not in paths and "." in name:  # `from pkg.mod import function` -> pkg.mod
                name = name.rsplit(".", 1)[0]
            if name in paths and name != module:
                edges.setdefault(name, line)
        graph[module] = edges
    return graph


def layer_violations(graph: dict[str, dict[str, int]]) -> list[str]:
    out = []
    for module, edges in sorted(graph.items()):
        package = module.split(".")[0]
        for target, line in sorted(edges.items()):
            if target.split(".")[0] not in ALLOWED[package]:
                out.append(f"{module}:{line} imports {target}")
    return out


def cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for succ in graph.get(node, {}):
            if succ not in index:
                visit(succ)
                low[node] = min(low[node], low[succ])
            elif succ in on_stack:
                low[node] = min(low[node], index[succ])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


# a package's __init__ that re-exports its submodules is not a cycle with them
def _without_reexports(graph: dict[str, dict[str, int]]) -> dict[str, dict[str, int]]:
    return {module: {t: line for t, line in edges.items() if not t.startswith(module + ".")}
            for module, edges in graph.items()}


@pytest.fixture(scope="module")
def graph() -> dict[str, dict[str, int]]:
    return project_imports(ROOT)


def test_imports_run_one_way(graph):
    assert layer_violations(graph) == []


def test_no_import_cycles(graph):
    assert cycles(_without_reexports(graph)) == []


def _subpackages(graph: dict[str, dict[str, int]]) -> dict[str, dict[str, int]]:
    """The graph between bench's parts (bench.drive, bench.analysis, ..., bench.run.execute): module -> its part."""
    def part(module: str) -> str:
        return ".".join(module.split(".")[:2])

    out: dict[str, dict[str, int]] = {}
    for module, edges in graph.items():
        if module.startswith("bench."):
            targets = out.setdefault(part(module), {})
            for target, line in edges.items():
                if target.startswith("bench.") and part(target) != part(module):
                    targets.setdefault(part(target), line)
    return out


def test_no_cycles_between_the_parts_of_bench(graph):
    assert cycles(_subpackages(graph)) == []


def test_subcommands_do_not_import_each_other(graph):
    """Each `bench` subcommand is a module of its own; what two share lives in commands.args or .common, or below."""
    shared = {"bench.commands", "bench.commands.args", "bench.commands.common"}
    assert [f"{m} imports {t}" for m, edges in sorted(graph.items()) if m.startswith("bench.commands.")
            and m not in shared for t in edges if t.startswith("bench.commands.") and t not in shared] == []


def test_a_subcommand_named_as_a_part_of_bench_is_its_adapter(graph):
    """`bench/commands/X.py` is `bench X`; where a part `bench/X/` does the work (run, campaign, robustness, ...) the
    module bears its name because it is only that part's command line: it imports the part, never the reverse."""
    parts = {m for m in graph if m.count(".") == 1 and (ROOT / Path(*m.split("."))).is_dir()}
    named = {f"bench.{m.rsplit('.', 1)[1]}": m for m in graph if m.startswith("bench.commands.")}
    pairs = {part: command for part, command in named.items() if part in parts}
    assert {"bench.run", "bench.campaign"} <= set(pairs)
    assert [f"{c} does not import {p}" for p, c in sorted(pairs.items())
            if not any(t == p or t.startswith(p + ".") for t in graph[c])] == []


def test_the_nodes_stand_on_dbc(graph):
    """The layering is not vacuous: both nodes use the link layer, and bench uses both nodes."""
    used = {package: {t.split(".")[0] for m, edges in graph.items() if m.split(".")[0] == package for t in edges}
            for package in PACKAGES}
    assert used["dbc"] == {"dbc"}
    assert used["target_sim"] == {"target_sim", "dbc"}
    assert used["host"] == {"host", "dbc"}
    assert {"target_sim", "host", "dbc"} <= used["bench"]


@pytest.mark.parametrize(("where", "source", "expected"), [
    ("host/probe.py", "from target_sim.node import TargetNode\n", "host.probe:1 imports target_sim.node"),
    ("host/probe.py", "def f():\n    from bench.drive import dataset\n", "host.probe:2 imports bench.drive.dataset"),
    ("target_sim/probe.py", "import host.session\n", "target_sim.probe:1 imports host.session"),
    ("dbc/probe.py", "from ..target_sim import model\n", "dbc.probe:1 imports target_sim.model"),
])
def test_a_forbidden_import_is_found(tmp_path, where, source, expected):
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            copy = tmp_path / path.relative_to(ROOT)
            copy.parent.mkdir(parents=True, exist_ok=True)
            copy.write_bytes(path.read_bytes())
    (tmp_path / where).write_text(source)
    assert expected in layer_violations(project_imports(tmp_path))


def test_a_cycle_is_found():
    graph = {"bench.a": {"bench.b": 1}, "bench.b": {"bench.c": 3}, "bench.c": {"bench.a": 2}, "bench.d": {}}
    assert cycles(graph) == [["bench.a", "bench.b", "bench.c"]]
