"""The shipped artifacts: reproducible from the default data and seed, and as good as the issue demands."""

import json

import numpy as np
import pytest

from bench.analysis.metrics import rmse
from bench.model.artifact_eval import evaluate_artifact
from bench.model.default import default_artifact_path
from bench.model.pipeline import identify_from_directory
from target_sim.artifact import load_artifact, seal


@pytest.fixture(scope="module")
def evaluations(validation_dataset):
    return {kind: evaluate_artifact(load_artifact(default_artifact_path(kind)), validation_dataset)
            for kind in ("hammerstein", "lti-lptn")}


def test_hammerstein_halves_the_lti_winding_error_without_worsening_pm(evaluations):
    ham, lti = evaluations["hammerstein"], evaluations["lti-lptn"]
    assert ham.metrics["float64"]["winding"]["rmse"] <= 0.5 * lti.metrics["float64"]["winding"]["rmse"]
    assert ham.metrics["float64"]["pm"]["rmse"] <= lti.metrics["float64"]["pm"]["rmse"]
    assert ham.metrics["float32"]["winding"]["rmse"] <= 0.5 * lti.metrics["float32"]["winding"]["rmse"]


def test_deployed_float32_execution_matches_float64_within_half_the_can_resolution(evaluations):
    ham = evaluations["hammerstein"]
    assert ham.max_abs_f32_minus_f64 < 0.005
    assert rmse(ham.float32[:, 1], ham.run.ref_winding) == pytest.approx(
        ham.metrics["float32"]["winding"]["rmse"])


def test_regenerating_the_default_artifacts_gives_the_same_content(default_data_dir, tmp_path):
    from bench.model.pipeline import validation_metrics

    result, datasets = identify_from_directory(default_data_dir)
    metrics = validation_metrics(result, datasets)
    for kind in ("hammerstein", "lti-lptn", "pv-lptn"):
        shipped = json.loads(default_artifact_path(kind).read_text())
        realization = "physical" if kind == "pv-lptn" else "balanced"
        assert seal(result.content(kind, realization, metrics)) == shipped, kind
    assert np.isfinite(result.lptn.cost)
