import pytest

from bench.drive.dataset import ensure_default_datasets, load_dataset


@pytest.fixture(scope="session")
def default_data_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("data")
    ensure_default_datasets(out)
    return out


@pytest.fixture(scope="session")
def validation_dataset(default_data_dir):
    return load_dataset(default_data_dir / "cycle_coolant40.csv")
