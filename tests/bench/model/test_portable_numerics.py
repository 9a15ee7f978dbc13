"""bench.thermal.portable: accurate, and identification's numerics the same bits whatever the CPU picks.

The cross-CPU test runs the identification's stages (PSO cost, ZOH blocks, LM, balanced realization, artifact
coefficients) in a subprocess that uses other kernels than this one: OpenBLAS forced to its SSE (Nehalem) kernels,
numpy's SIMD loops at their baseline, numba compiling for a generic x86-64, glibc without FMA, one thread.
"""

import dataclasses
import hashlib
import json
import math
import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from bench.thermal import portable


def test_exp_and_log_are_within_one_ulp_of_libm():
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.uniform(-745, 709.78, 20000), rng.uniform(-3, 3, 20000), [0.0, -0.0, 1e-300, -1e-17]])
    ours = portable.exp_array(x)
    ref = np.array([math.exp(v) for v in x])
    assert np.all(np.abs(ours - ref) <= np.spacing(ref))
    y = np.concatenate([np.exp(rng.uniform(-700, 700, 20000)), rng.uniform(0.5, 2, 20000), [1.0, 5e-324]])
    ref = np.array([math.log(v) for v in y])
    assert np.all(np.abs(portable.log_array(y) - ref) <= np.spacing(np.abs(ref)))
    assert portable.exp(710.0) == math.inf and portable.exp(-746.0) == 0.0 and math.isnan(portable.exp(math.nan))
    assert portable.log(0.0) == -math.inf and math.isnan(portable.log(-1.0)) and portable.log(1.0) == 0.0


def test_linear_algebra_agrees_with_lapack():
    rng = np.random.default_rng(4)
    for n, scale in ((4, 0.01), (4, 1.0), (12, 0.1), (12, 3.0)):  # the last one needs scaling and squaring
        a = rng.normal(size=(n, n)) * scale
        ref = scipy.linalg.expm(a)
        assert np.abs(portable.expm(a) - ref).max() <= 1e-13 * np.abs(ref).max()
    a, b = rng.normal(size=(4, 4)), rng.normal(size=(4, 3))
    np.testing.assert_allclose(portable.solve(a, b), np.linalg.solve(a, b), rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(portable.inv(np.stack([a, 2 * a])), np.linalg.inv(np.stack([a, 2 * a])), atol=1e-13)
    np.testing.assert_allclose(portable.matmul(a, b, b.T), a @ b @ b.T, atol=1e-13)
    spd = a @ a.T + 4 * np.eye(4)
    np.testing.assert_allclose(portable.cholesky_lower(spd), np.linalg.cholesky(spd), atol=1e-14)
    u, s, vt = portable.svd(a)
    np.testing.assert_allclose(s, np.linalg.svd(a, compute_uv=False), rtol=1e-13)
    np.testing.assert_allclose((u * s) @ vt, a, atol=1e-14)
    np.testing.assert_allclose(u.T @ u, np.eye(4), atol=1e-14)
    stable = 0.9 * a / np.abs(np.linalg.eigvals(a)).max()
    np.testing.assert_allclose(portable.solve_discrete_lyapunov(stable, spd),
                               scipy.linalg.solve_discrete_lyapunov(stable, spd), rtol=1e-11)
    with pytest.raises(np.linalg.LinAlgError):
        portable.inv(np.zeros((3, 3)))


def fingerprint(data_dir: str) -> dict[str, str]:
    """sha256 of each identification stage on the first 1500 steps of the 20 and 60 °C runs."""
    from bench.drive.dataset import dataset_filename, load_dataset
    from bench.drive.motor import VIRTUAL_MOTOR, nominal_loss_maps
    from bench.model.builder import ModelSpec, artifact_content, physical_block
    from bench.model.hammerstein_fit import fit_hammerstein
    from bench.model.identify import prepare_runs
    from bench.model.lptn_fit import batch_cost, discrete_blocks, from_search, search_bounds
    from bench.thermal.parameters import TABLE1

    maps = nominal_loss_maps()
    datasets = [load_dataset(Path(data_dir) / dataset_filename(c)) for c in (20, 60)]
    runs = [_first_steps(run, 1500) for run in prepare_runs(datasets, maps, VIRTUAL_MOTOR, 0.5)]
    lower, upper = search_bounds()
    vectors = from_search(lower + np.random.default_rng(1).random((24, lower.size)) * (upper - lower))
    a_d, b_d = discrete_blocks(vectors, 0.5)
    base = physical_block(ModelSpec("lti-lptn", TABLE1, 0.5, "zoh", "physical", maps, VIRTUAL_MOTOR))
    fit = fit_hammerstein(base, TABLE1, runs, iterations=4)
    content = artifact_content(ModelSpec("hammerstein", TABLE1, 0.5, "zoh", "balanced", maps, VIRTUAL_MOTOR,
                                         sigmoid=fit.model.sigmoid, linear_block=fit.model.block))
    stages = {"pso search coordinates": vectors, "zoh blocks": np.concatenate([a_d.ravel(), b_d.ravel()]),
              "pso cost": batch_cost(vectors, runs, 0.5, np.ones(4)),
              "lm fit": np.concatenate([fit.model.sigmoid.as_vector(), fit.model.block.b.ravel(),
                                        [fit.cost_final]]),
              "artifact coefficients": json.dumps([content["linear_block"], content["input_nonlinearity"]])}
    return {name: hashlib.sha256(value.encode() if isinstance(value, str) else np.ascontiguousarray(value).tobytes())
            .hexdigest() for name, value in stages.items()}


def _first_steps(run, n: int):
    inputs = dataclasses.replace(run.inputs, **{f: getattr(run.inputs, f)[:n] for f in
                                                ("table_losses", "speed_ratio", "coolant", "ambient")})
    return dataclasses.replace(run, inputs=inputs, step_time_s=run.step_time_s[:n], ref_winding=run.ref_winding[:n],
                               ref_pm=run.ref_pm[:n])


@pytest.mark.slow   # 14 s: identifications in subprocesses under each kernel: kept out of the 5-min default run
@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"), reason="x86-64 kernels")
def test_the_compiled_exact_sum_is_math_fsum_to_the_bit():
    """portable.sum_of_products is math.fsum(x * y): cancellation, a wide range of magnitudes (more partials than
    its first buffer holds), ties to even, and fsum's own errors for overflow and infinities."""
    rng = np.random.default_rng(7)
    cases = [(rng.normal(size=1000), rng.normal(size=1000)),
             (rng.normal(size=300) * 10.0 ** rng.integers(-300, 150, size=300),
              rng.normal(size=300) * 10.0 ** rng.integers(-150, 150, size=300)),
             (np.array([1e16, 1.0, -1e16, 1.0, 1e-16] * 40), np.ones(200)),
             (np.array([1.0, 2.0 ** -53, 2.0 ** -106, -(2.0 ** -160)]), np.ones(4)),
             (rng.integers(-5, 5, size=500) * 2.0 ** rng.integers(-60, 60, size=500), np.full(500, 1.5)),
             (np.zeros(0), np.zeros(0))]
    for x, y in cases:
        assert portable.sum_of_products(x, y) == math.fsum(x * y)
    with np.errstate(over="ignore"):
        assert portable.sum_of_products(np.array([1e200, 1.0]), np.array([1e200, 1.0])) == math.inf
        with pytest.raises(OverflowError):
            portable.sum_of_products(np.array([1e308, 1e308]), np.ones(2))


def test_the_transposed_matrix_vector_product_is_matmul_to_the_bit():
    """portable.transposed_matvec sums each output in matmul's order: the same bits as matmul(aᵀ, r)."""
    rng = np.random.default_rng(8)
    rows, r = rng.normal(size=(5000, 37)) * 10.0 ** rng.integers(-3, 3, size=(5000, 37)), rng.normal(size=5000)
    assert np.array_equal(portable.transposed_matvec(rows, r), portable.matmul(rows.T, r[:, None])[:, 0])


def test_identification_numerics_do_not_depend_on_blas_kernel_simd_level_or_threads(default_data_dir):
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

    env = {**os.environ, "OPENBLAS_CORETYPE": "Nehalem", "OPENBLAS_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1",
           "NUMBA_CPU_NAME": "generic", "GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX2,-FMA,-AVX512F",
           "NPY_DISABLE_CPU_FEATURES": " ".join(f for f in __cpu_dispatch__ if __cpu_features__.get(f))}
    code = ("import importlib.util, json\n"
            f"spec = importlib.util.spec_from_file_location('fingerprint_source', {__file__!r})\n"
            "module = importlib.util.module_from_spec(spec)\n"
            "spec.loader.exec_module(module)\n"
            f"print(json.dumps(module.fingerprint({str(default_data_dir)!r})))")
    child = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert child.returncode == 0, child.stderr
    assert json.loads(child.stdout.splitlines()[-1]) == fingerprint(str(default_data_dir))
