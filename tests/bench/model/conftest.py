import pytest

from bench.drive.dataset import load_dataset
from bench.drive.generate import ensure_default_datasets


@pytest.fixture(scope="session")
def default_data_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("data")
    ensure_default_datasets(out)
    return out


@pytest.fixture(scope="session")
def validation_dataset(default_data_dir):
    return load_dataset(default_data_dir / "cycle_coolant40.csv")
