import importlib.util
import os
import sys
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


def _load_helpers():
    """tests/helpers.py as the module `helpers`, so any test or conftest can `from helpers import ...`.

    Not through sys.path: --import-mode=importlib adds nothing there, and putting tests/ there would let its
    directories without __init__.py (tests/bench, tests/dbc) shadow the real packages as namespace packages
    whenever the repository root itself is not on sys.path (`pytest` run from elsewhere)."""
    path = Path(__file__).resolve().with_name("helpers.py")
    loaded = sys.modules.get("helpers")
    if loaded is None or Path(getattr(loaded, "__file__", "") or "").resolve() != path:
        spec = importlib.util.spec_from_file_location("helpers", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules["helpers"] = module
        spec.loader.exec_module(module)
    return sys.modules["helpers"]


_load_helpers()

from helpers import private_udp_bus  # noqa: E402


@pytest.fixture
def udp_bus():
    """A udp_multicast bus no other test (or run) shares, on the machine-local group `auto` uses."""
    return private_udp_bus()
