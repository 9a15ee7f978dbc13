"""Sphinx configuration of the bench's documentation (`python -m sphinx -W --keep-going -b html docs docs/_build/html`).

The CLI reference is generated from `bench.cli.build_parser()` (sphinx-argparse), the protocol and artifact-schema
pages from the DBC and `target_sim` at build time (`_ext/bench_docs.py`), the API reference from docstrings
(autodoc). Markdown pages go through myst-parser.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))            # the packages, as an installed checkout would see them
sys.path.insert(0, str(DOCS / "_ext"))
os.environ.setdefault("MPLBACKEND", "Agg")  # importing the analysis modules must not need a display
os.environ.setdefault("NUMEXPR_MAX_THREADS", str(os.cpu_count() or 1))  # no log line from numexpr's import

project = "pmsm-thermal-bench"
author = "pmsm-thermal-bench contributors"
copyright = "the pmsm-thermal-bench contributors, Apache-2.0"
try:
    import tomllib
    release = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["version"]
except (OSError, KeyError, ValueError):
    release = "0"
version = release

extensions = [
    "myst_parser",
    "sphinxarg.ext",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "bench_docs",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "_generated", "Thumbs.db", ".DS_Store"]
templates_path: list[str] = []

# Markdown: strict cross-references. A link to a page or a heading that does not exist is a warning (so an error
# under -W); no link is taken as external by default. `#anchor` links to headings need the anchors generated.
myst_enable_extensions = ["colon_fence", "deflist", "dollarmath", "attrs_inline"]
myst_heading_anchors = 4
myst_all_links_external = False
suppress_warnings: list[str] = []

# The docstrings are written with Markdown-like `code` spans: single backticks are code, not a title reference.
default_role = "code"
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_preserve_defaults = True
autodoc_inherit_docstrings = False   # the stdlib's docstrings (Enum's) are not ours to render
autosummary_generate = False
# Heavy optional imports stay lazy; autodoc imports our modules, which import nothing at import time that needs a bus,
# a compiler or a display (the DBC is read on first use). pytest is a test dependency, not a docs one: the pytest
# plugin (`bench.pytest_plugin`) is documented from a mock of it, so the `docs` extra alone builds these pages
# (autodoc unwraps the mocked `@pytest.fixture` to document the function itself).
autodoc_mock_imports: list[str] = ["pytest"]

html_theme = "furo"
html_title = f"pmsm-thermal-bench {release}"
html_static_path: list[str] = []
html_show_sourcelink = True
