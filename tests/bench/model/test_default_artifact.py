"""The shipped artifacts: reproducible from the default data and seed, and as good as the issue demands."""

import json

import numpy as np
import pytest

from bench.model.artifact_eval import evaluate_artifact
from bench.model.default import default_artifact_path
from bench.model.metrics import rmse
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
    # issue 16's bound for the deployed (delta) realization, all four nodes over the whole run: measured 2.8e-5 °C
    # (the Hammerstein model) and 3.1e-5 °C (the LTI LPTN); the balanced realization gave 3.3e-3 and 2.2e-3
    for kind in ("hammerstein", "lti-lptn"):
        assert evaluations[kind].max_abs_f32_minus_f64 <= 1e-4, kind
    assert rmse(ham.float32[:, 1], ham.run.ref_winding) == pytest.approx(
        ham.metrics["float32"]["winding"]["rmse"])


# Bit for bit on any x86-64 CPU: the fit runs on bench.thermal.portable (fixed-order numba routines instead of
# OpenBLAS and libm, whose kernels and SIMD loops are chosen by CPU) and the float32 figures come from the target's
# float32 code, which uses no BLAS and its own exp (target_sim.fmath). Before that, over OPENBLAS_CORETYPE=Haswell,
# SkylakeX, Sandybridge, Zen and a Nehalem/no-FMA/generic-numba setup, coefficients moved by up to 20 % (the LM fit
# stops at its evaluation budget and amplifies last-bit differences) and max |f32 - f64| by 3.5e-5 °C; with both
# in place the same configurations gave identical artifacts. tests/bench/model/test_portable_numerics.py checks
# the fit's stages under a forced other kernel in a subprocess.
# 90 s (the full identification of every kind): `-m slow`, which .ci/run runs after the default run.
@pytest.mark.slow
def test_regenerating_the_default_artifacts_gives_the_same_content(default_data_dir, tmp_path):
    from bench.model.pipeline import validation_metrics

    result, datasets = identify_from_directory(default_data_dir)
    metrics = validation_metrics(result, [datasets[40]])
    for kind in ("hammerstein", "lti-lptn", "pv-lptn"):
        shipped = json.loads(default_artifact_path(kind).read_text())
        realization = "physical" if kind == "pv-lptn" else "delta"
        content = result.content(kind, realization, metrics)
        assert seal(content) == shipped, kind   # every coefficient and figure, and so the same sha256
    assert np.isfinite(result.lptn.cost)
