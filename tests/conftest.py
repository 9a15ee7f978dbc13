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

from helpers import artifact_text, private_udp_bus, synthetic_columns, write_synthetic_dataset  # noqa: E402


@pytest.fixture
def udp_bus():
    """A udp_multicast bus no other test (or run) shares, on the machine-local group `auto` uses."""
    return private_udp_bus()


@pytest.fixture(scope="session")
def small_dataset(tmp_path_factory) -> Path:
    return write_synthetic_dataset(tmp_path_factory.mktemp("data") / "small.csv", synthetic_columns(600),
                                   "synthetic test data")


@pytest.fixture(scope="session")
def artifacts(tmp_path_factory) -> dict[str, Path]:
    """lti (balanced), original (lti, the paper's polynomial realization), modal (lti), pv, hammerstein (a real
    sigmoid)."""
    kinds = {"lti": ("lti-lptn", "balanced"), "original": ("lti-lptn", "original"), "modal": ("lti-lptn", "modal"),
             "pv": ("pv-lptn", "physical"), "hammerstein": ("hammerstein", "balanced")}
    out = tmp_path_factory.mktemp("artifacts")
    paths = {}
    for name, (kind, realization) in kinds.items():
        paths[name] = out / f"{name}.json"
        paths[name].write_text(artifact_text(kind, realization), encoding="utf-8")
    return paths
