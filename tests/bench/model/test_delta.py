"""The delta realization: the same model as the balanced one, with its float32 error cut by its coefficients."""

from dataclasses import replace

import numpy as np
import pytest

from bench.model.artifact_eval import evaluate_artifact
from bench.model.default import default_artifact_path
from bench.model.evaluate import in_memory, physical_from_artifact, sigmoid_from_artifact, spec_at
from bench.thermal.parameters import TABLE1_REFINED
from bench.thermal.precision import discrete_lptn
from bench.thermal.realizations import realize
from bench.thermal.simulate import simulate
from target_sim.artifact import ArtifactError, dumps, load_artifact, verify
from target_sim.model import Float32Estimator


def _packaged_as(realization: str, reference: float = 0.0):
    art = load_artifact(default_artifact_path())
    spec = spec_at(art, "hammerstein", art.dt, realization, physical_from_artifact(art), sigmoid_from_artifact(art))
    return in_memory(replace(spec, reference_C=reference))


def test_delta_is_the_balanced_block_in_delta_form():
    base = discrete_lptn(TABLE1_REFINED, 0.5, "zoh")
    bal, dlt = realize(base, "balanced"), realize(base, "delta", 0.5)
    assert dlt.form == "delta" and dlt.dt == 0.5
    np.testing.assert_allclose(dlt.shift().a, bal.a, rtol=0, atol=1e-12)
    np.testing.assert_allclose(dlt.shift().b, bal.b, rtol=1e-12, atol=0)
    inputs = np.random.default_rng(3).normal(size=(400, 8)) * [100, 300, 100, 50, 1, 1, 1, 1] + [0, 0, 0, 0, 40, 25, 50,
                                                                                                  60]
    np.testing.assert_allclose(simulate(dlt, inputs), simulate(bal, inputs), atol=1e-9)
    with pytest.raises(ValueError, match="needs the model step"):
        realize(base, "delta")


def test_the_deviation_form_is_the_same_model_in_double_precision(validation_dataset):
    bal, dlt = _packaged_as("balanced"), _packaged_as("delta", 75.0)
    assert dlt.realization == "delta" and dlt.content["linear_block"]["form"] == "delta"
    one = {}
    for name, art in (("balanced", bal), ("delta", dlt)):
        model = Float32Estimator(art, dtype=np.float64)
        model.reset([40.0, 45.0, 40.0, 44.0])
        one[name] = np.array([model.step(300.0, 3000.0, 40.0, 25.0) for _ in range(2000)])
    np.testing.assert_allclose(one["delta"], one["balanced"], rtol=0, atol=1e-9)


def test_delta_about_the_reference_keeps_float32_within_1e_4_on_the_whole_run(validation_dataset):
    """The issue's bound: largest |float32 - float64| over the whole 40 °C run <= 1e-4 °C on all four nodes, for
    the Hammerstein model at Δt 0.5 s (measured: 2.8e-5 °C about 75 °C, 8.6e-5 about 0 °C; balanced 3.3e-3)."""
    ev = evaluate_artifact(_packaged_as("delta", 75.0), validation_dataset)
    worst = np.max(np.abs(ev.float32 - ev.float64), axis=0)
    assert np.all(worst <= 1e-4), worst
    balanced = evaluate_artifact(_packaged_as("balanced"), validation_dataset)
    assert np.max(np.abs(balanced.float32 - balanced.float64)) > 10 * worst.max()
    assert ev.metrics["float32"]["winding"]["rmse"] == pytest.approx(balanced.metrics["float64"]["winding"]["rmse"],
                                                                    abs=1e-4)


def test_a_delta_artifact_needs_its_reference():
    content = dict(_packaged_as("delta", 75.0).content)
    content["linear_block"] = {k: v for k, v in content["linear_block"].items() if k != "reference_C"}
    import json

    with pytest.raises(ArtifactError, match="linear_block.reference_C"):
        verify(json.loads(dumps(content)))
