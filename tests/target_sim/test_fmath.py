"""target_sim.fmath: the float32 exp the target and its firmware share (accuracy as documented, clamps, NaN), and
the fixed-order matrix-vector product; the estimator uses them (no np.exp, no BLAS) in float32."""

from __future__ import annotations

import numpy as np
import pytest

from target_sim import fmath
from target_sim.fmath import EXP_CONSTANTS, EXP_MAX_ULP, exp_f32, matvec

F32 = np.float32


def ulp_error(x: np.ndarray) -> np.ndarray:
    exact = np.exp(x.astype(np.float64))
    return np.abs(exp_f32(x).astype(np.float64) - exact) / np.spacing(exact.astype(F32)).astype(np.float64)


def test_exp_accuracy_is_as_documented():
    rng = np.random.default_rng(2)
    x = np.concatenate([rng.uniform(-80, 80, 1_000_000), rng.uniform(-12, 12, 500_000),
                        rng.uniform(-0.5, 0.5, 200_000), [70.4030990600586]]).astype(F32)
    err = ulp_error(x)
    assert err.max() <= EXP_MAX_ULP
    assert err.max() > 0.9                       # the documented bound is tight, not a loose guess
    assert 0.05 < np.mean(err > 0.5) < 0.15      # ~9.6 % not correctly rounded
    assert exp_f32(F32(0.0)) == 1.0 and exp_f32(F32(1.0)) == F32(np.e)


def test_exp_clamps_and_nan():
    low, high = exp_f32(EXP_CONSTANTS["X_MIN"]), exp_f32(EXP_CONSTANTS["X_MAX"])
    assert 1e-35 < low < 2e-35 and 5e34 < high < 6e34                   # normal float32 numbers
    for x, expected in ((-1e30, low), (-np.inf, low), (np.nan, low), (85.0, high), (np.inf, high)):
        assert exp_f32(F32(x)) == expected
    # one code path for scalars and arrays: the same bits
    x = np.linspace(-90, 90, 1001, dtype=F32)
    array = exp_f32(x)
    assert array.dtype == F32 and isinstance(exp_f32(F32(0.5)), np.float32)
    np.testing.assert_array_equal(array.view(np.uint32), np.array([exp_f32(v) for v in x], F32).view(np.uint32))


def test_exp_constants_are_exact_float32_and_the_reduction_exact():
    for name, value in EXP_CONSTANTS.items():
        assert isinstance(value, np.float32), name
    # LN2_HI has 9 significant bits, so k·LN2_HI is exact for every |k| the clamp allows (|k| <= 116)
    k = np.arange(-116, 117, dtype=np.float64)
    assert np.array_equal((k.astype(F32) * EXP_CONSTANTS["LN2_HI"]).astype(np.float64),
                          k * float(EXP_CONSTANTS["LN2_HI"]))
    assert abs(float(EXP_CONSTANTS["LN2_HI"]) + float(EXP_CONSTANTS["LN2_LO"]) - np.log(2)) < 1e-11


def test_matvec_sums_left_to_right_in_float32():
    m = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]], F32)
    v = np.array([1e8, 1.0, -1e8], F32)
    # ((1e8 + 1) - 1e8): 1e8 + 1 rounds back to 1e8 in float32, so 0; another order would give 1
    np.testing.assert_array_equal(matvec(m, v), [0.0, 0.0])
    assert float(np.float64(1e8) + 1.0 - 1e8) == 1.0
    rng = np.random.default_rng(4)
    a, x = rng.normal(size=(4, 8)).astype(F32), rng.normal(size=8).astype(F32)
    expected = []
    for row in a:
        acc = row[0] * x[0]
        for j in range(1, 8):
            acc = F32(acc + row[j] * x[j])
        expected.append(acc)
    np.testing.assert_array_equal(matvec(a, x).view(np.uint32), np.array(expected, F32).view(np.uint32))
    assert matvec(a, x).dtype == F32


def test_the_float32_estimator_uses_neither_np_exp_nor_blas(monkeypatch, artifacts):
    from target_sim.artifact import load_artifact
    from target_sim.model import Float32Estimator

    def refuse(*_args, **_kwargs):
        raise AssertionError("np.exp used in float32")

    for name in ("hammerstein", "pv"):
        model = Float32Estimator(load_artifact(artifacts[name]))
        model.reset([40.0, 50.0, 45.0, 48.0])
        with monkeypatch.context() as patch:
            patch.setattr(np, "exp", refuse)
            patch.setattr(np, "matmul", refuse)
            patch.setattr(np, "dot", refuse)
            y = model.step(F32(200.0), F32(4000.0), F32(40.0), F32(25.0))
        assert y.dtype == F32 and np.all(np.isfinite(y))
    assert model.exp is fmath.exp_f32
    assert Float32Estimator(load_artifact(artifacts["pv"]), dtype=np.float64).exp is np.exp


@pytest.mark.parametrize("name", ["hammerstein", "lti", "pv"])
def test_float64_mode_runs_the_same_code_in_double(name, artifacts):
    from target_sim.artifact import load_artifact
    from target_sim.model import Float32Estimator

    artifact = load_artifact(artifacts[name])
    m32, m64 = Float32Estimator(artifact), Float32Estimator(artifact, dtype=np.float64)
    for model in (m32, m64):
        model.reset([40.0, 50.0, 45.0, 48.0])
    for k in range(200):
        inputs = (150.0 + k, 3000.0 + 5 * k, 40.0, 25.0)
        y32, y64 = m32.step(*map(F32, inputs)), m64.step(*inputs)
    assert y64.dtype == np.float64
    assert np.max(np.abs(y32 - y64)) < 1e-3      # float32 rounding only
    assert np.max(np.abs(y32 - y64)) > 0
