"""`bench robustness` with an observer artifact: the observer's lanes are the target's float32 observer bit for bit
(`run_observer_offline` on the same rows), its measurement channel is an input every kind perturbs (a dropped
reading: predict only), and the table, json and report hold open loop and observer side by side."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench.drive.dataset import load_dataset
from bench.model.artifact_eval import artifact_drive
from bench.model.runs import initial_temperatures
from bench.observer.evaluate import measurement_matrix
from bench.robustness.channels import input_channels, lane_columns
from bench.robustness.kinds import PERTURBATIONS, Lane
from bench.robustness.lanes import nominal_steps, run_lanes, run_observer_lanes
from target_sim.artifact import load_artifact
from target_sim.model import run_offline
from target_sim.observer import run_observer_offline

from helpers import run_cli

ROWS = 400
SPEC = """
[study]
seeds = 2
kinds = ["noise", "bias", "dropout", "parameter", "initial"]
[perturbations.noise]
subjects = ["winding_C"]
winding_C = [1.0]
[perturbations.bias]
subjects = ["winding_C", "coolant"]
winding_C = [3.0]
coolant = [2.0]
[perturbations.dropout]
subjects = ["winding_C"]
winding_C = [0.5]
[perturbations.parameter]
subjects = ["k_split"]
[perturbations.initial]
subjects = ["magnet"]
magnet = [10.0]
[filters]
enabled = false
"""


@pytest.fixture(scope="module")
def observed(observer_artifact, small_dataset):
    artifact = load_artifact(observer_artifact)
    dataset = load_dataset(small_dataset)
    return artifact, dataset


def test_the_measurement_channel_is_an_input_of_the_lanes(observed):
    artifact, _ = observed
    assert lane_columns(artifact) == (*artifact.drive_signals, "winding_C")
    channel = input_channels(artifact)[-1]
    assert (channel.name, channel.unit, channel.measured) == ("winding_C", "K", True)
    assert "winding_C" in PERTURBATIONS["noise"].subjects(artifact)
    assert PERTURBATIONS["noise"].defaults(artifact, "winding_C") == (0.2, 1.0)


def test_observer_lanes_are_run_observer_offline_bit_for_bit(observed):
    artifact, dataset = observed
    drive, z, start = artifact_drive(artifact, dataset), measurement_matrix(artifact, dataset), \
        initial_temperatures(dataset)
    noisy_z = z + np.random.default_rng(5).normal(0.0, 1.0, z.shape)
    noisy_z[::7] = np.nan                                    # readings missing: predict only
    rows = [np.column_stack([drive, z]), np.column_stack([drive, noisy_z])]
    lanes = [nominal_steps(r, artifact.data_sample_period, artifact.dt) for r in rows]
    starts = np.stack([start, start + np.array([0, 0, 0, 10.0])], axis=1)
    got = run_observer_lanes(artifact, lanes, starts)
    for index, (measured, y0) in enumerate([(z, start), (noisy_z, starts[:, 1])]):
        expected = run_observer_offline(artifact, drive, measured, y0).outputs
        assert np.array_equal(got[index], expected)
    _, open_loop = run_offline(artifact, drive, start)       # the open loop ignores the measurement columns
    assert np.array_equal(run_lanes(artifact, lanes[:1], starts[:, :1])[0], open_loop)
    assert not np.array_equal(got[1], open_loop)


def test_a_dropped_reading_is_missing_and_a_dropped_drive_sample_is_held(observed):
    artifact, dataset = observed
    rows = np.column_stack([artifact_drive(artifact, dataset), measurement_matrix(artifact, dataset)])
    lane = Lane(rows, initial_temperatures(dataset), dataset.sample_period_s, artifact.dt)
    dropout = PERTURBATIONS["dropout"]
    reading = dropout.apply(lane, artifact, "winding_C", 0.5, np.random.default_rng(1)).drive[:, -1]
    assert 0.3 < np.mean(np.isnan(reading)) < 0.7
    assert np.array_equal(reading[~np.isnan(reading)], rows[~np.isnan(reading), -1])
    speed = dropout.apply(lane, artifact, "speed", 0.5, np.random.default_rng(1)).drive[:, 1]
    assert np.all(np.isfinite(speed)) and not np.array_equal(speed, rows[:, 1])


def test_a_study_with_an_observer_reports_both_side_by_side(tmp_path, observer_artifact, small_dataset):
    spec = tmp_path / "observer.toml"
    spec.write_text(SPEC)
    out = tmp_path / "out"
    result = run_cli("-m", "bench", "robustness", "--model", str(observer_artifact), "--data", str(small_dataset),
                     "--spec", str(spec), "--out", str(out), "--rows", str(ROWS), "--serial", "--json")
    assert result.returncode == 0, result.stderr
    (study,) = json.loads((out / "report" / "robustness.json").read_text())["studies"]
    observer = study["observer"]
    assert observer["measured_nodes"] == ["winding"]
    assert observer["measurements"] == [{"kind": "lagged-sensor", "columns": ["winding_C"], "node": "winding"}]
    assert [c["case_id"] for c in observer["cases"]] == [c["case_id"] for c in study["cases"]]
    by = {(c["kind"], c["subject"], c["magnitude"]): c for c in study["cases"]}
    obs = {(c["kind"], c["subject"], c["magnitude"]): c for c in observer["cases"]}
    # the open loop reads no measurement: perturbing it moves the observer only
    for key in (("noise", "winding_C", 1.0), ("bias", "winding_C", 3.0), ("dropout", "winding_C", 0.5)):
        assert by[key]["nodes"]["winding"]["d_rmse_C"]["mean"] == 0.0
        assert obs[key]["nodes"]["winding"]["d_rmse_C"]["mean"] != 0.0
    # a 3 K sensor bias pulls the observer's winding estimate toward it: about that much more error
    assert 0.5 < obs[("bias", "winding_C", 3.0)]["nodes"]["winding"]["d_rmse_C"]["mean"] < 3.5
    # the split moved by points: both move, and the unit says so
    split = by[("parameter", "k_split", 5.0)]
    assert split["unit"] == "points" and split["nodes"]["pm"]["d_rmse_C"]["mean"] != 0.0
    # the observer corrects a wrong magnet start no worse than the open loop
    start = ("initial", "magnet", 10.0)
    assert obs[start]["nodes"]["pm"]["d_rmse_C"]["mean"] <= by[start]["nodes"]["pm"]["d_rmse_C"]["mean"] + 1e-9
    md = (out / "report" / "report.md").read_text()
    assert "### winding (measured by the observer)" in md and "With the observer:" in md
    assert "open loop: Δ RMSE °C" in md and "observer: Δ RMSE °C" in md
    assert "lagged-sensor (winding_C) of the winding" in md


@pytest.mark.parametrize("points", [-5.0, 5.0])
def test_the_split_moves_by_points_of_the_iron_loss(points):
    from bench.model.artifact_values import artifact_parameters
    from bench.model.default import default_artifact_path
    from bench.robustness.models import perturbed_model

    artifact = load_artifact(default_artifact_path())
    old = artifact_parameters(artifact)
    new = artifact_parameters(perturbed_model(artifact, "k_split", points))
    assert new.k_0 == pytest.approx(old.k_0 + points / 100.0, abs=1e-12)
    assert (new.k_1, new.k_2, new.k_3) == (old.k_1, old.k_2, old.k_3)
    assert PERTURBATIONS["parameter"].unit(artifact, "k_split") == "points"
    assert PERTURBATIONS["parameter"].defaults(artifact, "k_split") == (-5.0, 5.0)
    assert PERTURBATIONS["parameter"].defaults(artifact, "C_w") == (-10.0, 10.0)
