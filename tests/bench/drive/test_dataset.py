from __future__ import annotations

import json

import numpy as np
import pytest

from bench.drive.dataset import COLUMNS, dataset_sha256, sidecar_path
from bench.drive.generate import DEFAULT_SEED, GENERATOR_VERSION, ensure_default_datasets, generate, generate_and_write


def test_three_datasets_with_roles_rows_and_sidecars(dataset_paths, datasets):
    assert sorted(dataset_paths) == [20, 40, 60]
    for coolant, path in dataset_paths.items():
        assert path.name == f"cycle_coolant{coolant}.csv"
        meta = json.loads(sidecar_path(path).read_text())
        assert meta["schema_version"] == 1 and meta["generator_version"] == GENERATOR_VERSION
        assert meta["seed"] == DEFAULT_SEED and meta["coolant_setpoint_C"] == coolant
        assert meta["sample_period_s"] == 0.2 and meta["rows"] == 36371
        assert meta["role"] == ("validation" if coolant == 40 else "identification")
        assert [c["name"] for c in meta["columns"]] == list(COLUMNS)
        assert {c["name"]: c["unit"] for c in meta["columns"]}["winding_C"] == "°C"
        assert meta["sha256"] == dataset_sha256(path) == datasets[coolant].sha256
        assert path.read_text().splitlines()[0] == ",".join(COLUMNS)
        assert datasets[coolant].rows == 36371 and datasets[coolant].coolant_setpoint_C == coolant


def test_time_base_and_quantization(datasets):
    d = datasets[40]
    np.testing.assert_array_equal(d.time_s, np.arange(36371) / 5)
    assert d.time_s[-1] == 7274.0
    for name, q in (("torque_Nm", 0.1), ("speed_rpm", 1.0), ("winding_C", 0.1), ("coolant_C", 0.1)):
        counts = d.column(name) / q
        np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    np.testing.assert_allclose(d.pm_C, d.rotor_surface_C + 5.0, atol=1e-9)


def test_temperature_rises_are_in_the_intended_band(datasets):
    for coolant, d in datasets.items():
        winding_rise = np.max(d.winding_C - d.coolant_C)
        pm_rise = np.max(d.pm_C - d.coolant_C)
        assert 30 <= winding_rise <= 80, coolant
        assert 10 <= pm_rise <= 40, coolant
        assert abs(np.median(d.coolant_C) - coolant) < 1.0


def test_noise_matches_the_documented_sensors():
    g = generate(40.0, seed=11)
    err = g.columns["winding_C"] - g.truth["winding_C"]
    assert np.std(err) == pytest.approx(np.hypot(0.15, 0.1 / np.sqrt(12)), rel=0.05)
    err = g.columns["pm_C"] - g.truth["magnet_C"]
    assert abs(np.mean(err)) < 0.01


def test_same_seed_same_bytes_other_seed_other_bytes(tmp_path, dataset_paths):
    _, sha = generate_and_write(tmp_path / "a" / "cycle_coolant40.csv", 40.0, DEFAULT_SEED)
    assert sha == dataset_sha256(dataset_paths[40])
    _, other = generate_and_write(tmp_path / "b" / "cycle_coolant40.csv", 40.0, DEFAULT_SEED + 1)
    assert other != sha


def test_ensure_reuses_current_files_and_regenerates_stale_ones(tmp_path, dataset_paths):
    for path in dataset_paths.values():
        for src in (path, sidecar_path(path)):
            (tmp_path / src.name).write_bytes(src.read_bytes())
    before = {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    paths = ensure_default_datasets(tmp_path, DEFAULT_SEED)
    assert {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir()} == before
    stale = paths[60]
    stale.write_text(stale.read_text().replace("7274.0,", "7274.0,1", 1))
    ensure_default_datasets(tmp_path, DEFAULT_SEED)
    assert dataset_sha256(stale) == dataset_sha256(dataset_paths[60])
    assert paths[20].stat().st_mtime_ns == before[paths[20].name]


def test_no_row_is_dropped(datasets, dataset_paths):
    lines = dataset_paths[20].read_text().splitlines()
    assert datasets[20].rows == len(lines) - 1
