"""Generate the three default datasets once per test session."""

from __future__ import annotations

import pytest

from bench.drive.dataset import load_dataset
from bench.drive.generate import DEFAULT_SEED, ensure_default_datasets


@pytest.fixture(scope="session")
def dataset_paths(default_data_root):
    return ensure_default_datasets(default_data_root, DEFAULT_SEED)


@pytest.fixture(scope="session")
def datasets(dataset_paths):
    return {c: load_dataset(p) for c, p in dataset_paths.items()}
