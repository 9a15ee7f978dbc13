"""`bench observer --criterion nodes`: the winding's and the magnet's log MSE, with a steep penalty wherever the
filter leaves the magnet (started as measured) worse than the open loop, and the search started from the better of
the default and a cautious point. A sensor of the winding then improves the winding only as far as the magnet, which
it cannot see, stays no worse than the open loop on the training file."""

from __future__ import annotations

import numpy as np
import pytest

from bench.drive.dataset import load_dataset
from bench.model.default import default_artifact_path
from bench.observer.measures.lagged_sensor import Sensor
from bench.observer.reference import FilterModel, filter_data, initial_covariance, process_noise, run_filter
from bench.observer.tune import (
    CAUTIOUS_DECADES,
    LOG10_BOUNDS,
    NODES_R_MAX_LOG10,
    TUNING_CRITERIA,
    search_starts,
    tune_observer,
)
from target_sim.artifact import OUTPUTS, load_artifact


def _magnet_and_winding_mse(artifact, data, q, r) -> np.ndarray:
    model = FilterModel.of(artifact)
    p0 = initial_covariance(model, data.readings)
    runs = run_filter(model, data, process_noise(model, q)[None], [np.atleast_1d(r)], p0, keep=True)
    estimate = runs.estimates[0]
    return np.array([np.mean((estimate[:, OUTPUTS.index("magnet")] - data.run.ref_pm) ** 2),
                     np.mean((estimate[:, OUTPUTS.index("winding")] - data.run.ref_winding) ** 2)])


def test_the_cautious_start_trusts_the_measurements_far_less():
    start = np.log10([1e-4] * 5 + [0.1])
    default, cautious = search_starts(start, 5)
    assert np.array_equal(default, start)
    assert np.all(cautious[:5] == start[:5] - CAUTIOUS_DECADES) and cautious[5] == -1 + CAUTIOUS_DECADES
    assert NODES_R_MAX_LOG10 > LOG10_BOUNDS[1] and "nodes" in TUNING_CRITERIA


@pytest.mark.parametrize("criterion", ["magnet", "nodes"])
def test_nodes_keeps_the_magnet_no_worse_than_the_open_loop_on_its_training_file(criterion, small_dataset):
    artifact = load_artifact(default_artifact_path("hammerstein"))
    dataset = load_dataset(small_dataset)
    sensor = Sensor("winding", "winding_C")
    fit = tune_observer(artifact, [dataset], [sensor], criterion, max_evaluations=40)
    data = filter_data(artifact, dataset, [sensor])
    tuned = _magnet_and_winding_mse(artifact, data, fit.q_C2, fit.r_scale)
    open_loop = _magnet_and_winding_mse(artifact, data, np.zeros(4), [1e30])
    if criterion == "nodes":
        assert tuned[0] <= open_loop[0] * 1.05, (tuned, open_loop)     # the guard
        assert tuned[1] <= open_loop[1] * 1.001                          # and the winding no worse either
    assert fit.criterion == criterion and np.all(np.isfinite(tuned))
