"""`dbc.files`, the one atomic write every layer uses, and the small facts every layer shares, each defined once:
the file name limit, the reply timeout's default, the temperature nodes' order."""

from __future__ import annotations

import ast
import os
import stat

import pytest

from dbc.files import NAME_MAX, fitted_name, write_atomically

from helpers import ROOT

LAYERS = ("dbc", "target_sim", "host", "bench")


def test_a_write_is_whole_or_not_at_all(tmp_path):
    path = tmp_path / "deep" / "out.json"
    write_atomically(path, lambda tmp: tmp.write_text("first"))
    assert path.read_text() == "first"
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask     # as any new file, not mkstemp's 0600

    def fails(tmp):
        tmp.write_text("half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_atomically(path, fails)
    assert path.read_text() == "first" and sorted(p.name for p in path.parent.iterdir()) == ["out.json"]


def test_a_long_legal_name_gets_a_legal_temporary_name_with_its_suffix(tmp_path):
    path = tmp_path / ("é" * ((NAME_MAX - 5) // 2) + ".json")
    seen = []
    write_atomically(path, lambda tmp: (seen.append(tmp), tmp.write_text("{}")))
    assert seen[0].suffix == ".json" and len(os.fsencode(seen[0].name)) <= NAME_MAX
    assert fitted_name("x" * 300, lambda s: f"{s}.replay.blf") == "x" * (NAME_MAX - 11) + ".replay.blf"


NODE_SETS = ({"yoke", "winding", "tooth", "magnet"}, {"yoke", "winding", "tooth", "pm"})


class _Facts:
    """One walk over the four layers' modules: where each name is assigned a literal value (not an import, not a
    rebinding), where the four temperature nodes are written out as a tuple (in any order), where each function
    name is called (plain or as an attribute)."""

    def __init__(self):
        self.assigned: dict[str, list[str]] = {}
        self.node_tuples: list[str] = []
        self.called: dict[str, list[str]] = {}
        for layer in LAYERS:
            for path in sorted((ROOT / layer).rglob("*.py")):
                module = str(path.relative_to(ROOT))
                for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                    self._note(module, node)

    def _note(self, module: str, node: ast.AST) -> None:
        if isinstance(node, ast.Assign | ast.AnnAssign) and isinstance(node.value, ast.Constant):
            for target in node.targets if isinstance(node, ast.Assign) else [node.target]:
                if isinstance(target, ast.Name):
                    self.assigned.setdefault(target.id, []).append(module)
        elif isinstance(node, ast.Tuple) and all(isinstance(e, ast.Constant) for e in node.elts):
            if {e.value for e in node.elts} in NODE_SETS:
                self.node_tuples.append(f"{module}:{node.lineno}")
        elif isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
            self.called.setdefault(name, []).append(module)


def test_each_shared_fact_is_defined_once():
    facts = _Facts()
    assert facts.assigned["NAME_MAX"] == ["dbc/files.py"]
    assert facts.assigned["DEFAULT_REPLY_TIMEOUT_S"] == ["dbc/contract.py"]
    # the one atomic file write: the only temporary file made beside an output (a directory's write and a streamed
    # log's partial file are their own)
    assert facts.called["mkstemp"] == ["dbc/files.py"]
    assert sorted(p.split(":")[0] for p in facts.node_tuples) == ["bench/commands/common.py", "dbc/contract.py"]
