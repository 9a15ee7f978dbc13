"""One error base per layer, caught once by the `bench` CLI: every error class of a layer derives from its base."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

from bench.errors import BenchError
from dbc.errors import CanLinkError
from host.errors import HostError
from target_sim.errors import TargetError

ROOT = Path(__file__).resolve().parents[1]
BASES = {"dbc": CanLinkError, "target_sim": TargetError, "host": HostError, "bench": BenchError}


def _error_classes(package: str) -> list[tuple[str, str]]:
    """(module, class) of every top-level class of `package` whose name says it is an error."""
    found = []
    for path in sorted((ROOT / package).rglob("*.py")):
        module = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, ast.ClassDef) and node.name.endswith(("Error", "Fault", "Unavailable", "OtherSender")):
                found.append((module, node.name))
    return found


@pytest.mark.parametrize("package", sorted(BASES))
def test_every_error_of_a_layer_derives_from_its_base(package):
    classes = _error_classes(package)
    assert classes, package
    wrong = [f"{module}.{name}" for module, name in classes
             if not issubclass(getattr(importlib.import_module(module), name), BASES[package])]
    assert wrong == []


def test_value_errors_stay_value_errors():
    from dbc.contract import FrameError
    from host.faults.spec import FaultSpecError
    from host.replay import DataRangeError

    assert all(issubclass(cls, ValueError) for cls in (FrameError, FaultSpecError, DataRangeError))


def test_the_cli_prints_a_layer_error_in_one_sentence(capsys, monkeypatch):
    from bench import cli
    from host.canlog import LogError
    from host.faults.spec import FaultSpecError

    def fail(error):
        def build_parser():
            raise error
        return build_parser

    monkeypatch.setattr(cli, "build_parser", fail(LogError("log x.blf cannot be read\n(truncated); check it")))
    assert cli.main([]) == 1
    assert capsys.readouterr().err == "bench: error: log x.blf cannot be read (truncated); check it\n"
    monkeypatch.setattr(cli, "build_parser", fail(FaultSpecError("unknown fault kind 'x'")))
    assert cli.main([]) == 2   # a bad --fault option is a usage error
    assert capsys.readouterr().err == "bench: error: unknown fault kind 'x'\n"
