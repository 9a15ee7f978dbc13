import pytest

from bench.drive.dataset import load_dataset
from bench.drive.generate import ensure_default_datasets


@pytest.fixture(scope="session")
def default_data_dir(default_data_root):
    ensure_default_datasets(default_data_root)
    return default_data_root


@pytest.fixture(scope="session")
def validation_dataset(default_data_dir):
    return load_dataset(default_data_dir / "cycle_coolant40.csv")
