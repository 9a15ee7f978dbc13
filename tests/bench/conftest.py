"""Fixtures of the CAN bench tests: a small dataset and artifacts of every kind (`udp_bus`: tests/conftest.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from helpers import artifact_text, synthetic_columns, write_synthetic_dataset


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
