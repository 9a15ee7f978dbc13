"""The documentation builds from the `docs` extra alone: every module the API page documents imports without the
packages only the test extra brings (pytest, hypothesis, control, ...), except those `docs/conf.py` mocks.

`.ci/run` builds the pages in a fresh venv with only that extra; this test finds the same failure in seconds (a
documented module that imports a test-only package at import time) without building a venv.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import textwrap
import tomllib
from importlib.metadata import packages_distributions
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"


def _extra(name: str) -> set[str]:
    """The distribution names of an extra of pyproject.toml (lower case, `-` for `_`)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    requirements = project["optional-dependencies"][name] if name else project["dependencies"]
    return {re.split(r"[\[<>=!~ ;]", line, maxsplit=1)[0].lower().replace("_", "-") for line in requirements}


def _test_only_modules() -> set[str]:
    """The top-level modules that only the test extra installs (those of the docs extra and the core excluded)."""
    test_only = _extra("test") - _extra("docs") - _extra("")
    return {module for module, dists in packages_distributions().items()
            if any(dist.lower().replace("_", "-") in test_only for dist in dists)}


def _mocked() -> list[str]:
    """`autodoc_mock_imports` of docs/conf.py, read without running the configuration."""
    for node in ast.walk(ast.parse((DOCS / "conf.py").read_text(encoding="utf-8"))):
        if isinstance(node, ast.AnnAssign | ast.Assign):
            targets = [node.target] if isinstance(node, ast.AnnAssign) else node.targets
            if any(isinstance(t, ast.Name) and t.id == "autodoc_mock_imports" for t in targets):
                return list(ast.literal_eval(node.value))
    raise AssertionError("docs/conf.py sets no autodoc_mock_imports")


def _documented_modules() -> list[str]:
    modules = []
    for page in DOCS.rglob("*.md"):
        modules += re.findall(r"^\.\. automodule:: (\S+)", page.read_text(encoding="utf-8"), flags=re.M)
    return sorted(set(modules))


def test_the_api_page_documents_modules():
    assert "bench.pytest_plugin" in _documented_modules()


def test_the_documented_modules_import_with_the_docs_extra_alone():
    pytest.importorskip("sphinx")  # the mock is autodoc's own
    mocked = _mocked()
    blocked = sorted(_test_only_modules() - set(mocked))
    assert {"hypothesis", "control"} <= set(blocked), blocked  # the test extra is found, so the check can fail
    script = textwrap.dedent(f"""
        import importlib, sys
        from sphinx.ext.autodoc.mock import mock
        for name in {blocked!r}:
            sys.modules[name] = None   # `import name` raises ModuleNotFoundError, as in a venv without it
        failed = []
        with mock({mocked!r}):
            for module in {_documented_modules()!r}:
                try:
                    importlib.import_module(module)
                except ImportError as exc:
                    failed.append(f"{{module}}: {{exc}}")
        print("\\n".join(failed))
        sys.exit(1 if failed else 0)
    """)
    done = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
