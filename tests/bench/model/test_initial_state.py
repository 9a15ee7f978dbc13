"""The initial-state rule every run starts from (offline evaluation, identification, the host's reset on the bus)."""

from __future__ import annotations

import numpy as np
import pytest

from bench.drive.dataset import load_dataset
from bench.model.runs import initial_temperatures

from helpers import synthetic_columns, write_synthetic_dataset


def _hot_start(path, *, stator: bool):
    """A machine soaked at 70 °C on 30 °C coolant; with stator=True the file also measures yoke and tooth."""
    columns = synthetic_columns(50)
    rows = len(columns["time_s"])
    columns["coolant_C"] = np.full(rows, 30.0)
    for name in ("winding_C", "pm_C", *(("yoke_C", "tooth_C") if stator else ())):
        columns[name] = np.full(rows, 70.0)
    return load_dataset(write_synthetic_dataset(path, columns, "hot start"))


def test_a_file_that_measures_yoke_and_tooth_starts_them_as_measured(tmp_path):
    assert initial_temperatures(_hot_start(tmp_path / "bench.csv", stator=True)) == pytest.approx([70, 70, 70, 70])


def test_without_yoke_and_tooth_columns_they_start_at_the_coolant(tmp_path):
    assert initial_temperatures(_hot_start(tmp_path / "ecu.csv", stator=False)) == pytest.approx([30, 70, 30, 70])
