"""Every numba kernel of the bench compiled, or loaded from numba's on-disk cache, at once and ahead of its use.

Why: numba compiles a kernel at its first call and keeps it in its on-disk cache (`cache=True`: an index and the
object code per kernel, in bench/thermal/__pycache__ or under NUMBA_CACHE_DIR). With a cold cache the first process
to call each kernel compiles it, and processes that start together (pytest-xdist workers, a campaign's Dask
workers) each compile the same kernels side by side: numba has no lock across processes, and the one that writes
the cache last wins. `compile_kernels()` calls every kernel once, through the wrapper the bench calls it by, on a
tiny problem with the argument types the bench passes (C-contiguous float64 arrays, Python floats and bools, int64
indices), so one process fills the cache and the others load it. The test suite runs it before its workers start
(tests/conftest.py); `python -m bench.thermal.kernels` runs it from a shell (a CI image after installing, say).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable

import numpy as np


def _estimator() -> None:
    from bench.thermal.estimator import StepInputs, identity_sigmoid, run_batch

    steps = 3
    inputs = StepInputs(np.ones((steps, 5)), np.full(steps, 0.5), np.full(steps, 40.0), np.full(steps, 25.0), 100.0)
    a = np.repeat(np.eye(4)[None] * 0.9, 2, axis=0)
    b = np.full((2, 4, 8), 0.01)
    theta = np.ones((2, 14))     # two models with the same loop parameters: their gains shared (shared_gains)
    sig = identity_sigmoid(np.ones((2, 4)))
    for keep in (False, True):   # one signature: `keep` is a bool either way
        run_batch(a, b, np.repeat(np.eye(4)[None], 2, axis=0), theta, sig, inputs, np.full(4, 40.0),
                  keep_trajectories=keep)


def _kalman() -> None:
    from bench.thermal.estimator import StepInputs, identity_sigmoid
    from bench.thermal.kalman import Readings, run_filters, source_jacobian

    steps = 3
    inputs = StepInputs(np.ones((steps, 5)), np.full(steps, 0.5), np.full(steps, 40.0), np.full(steps, 25.0), 100.0)
    readings = Readings(np.full((steps, 1), 41.0), np.zeros((steps, 1)), np.ones((steps, 1)),
                        np.array([[0.0, 1.0, 0.0, 0.0]]), np.array([0.5]), bias=True)
    n = readings.states
    run_filters(np.eye(4) * 0.9, np.full((4, 8), 0.01), np.eye(4), np.ones(14), identity_sigmoid(np.ones(4)), inputs,
                np.full(4, 40.0), readings, np.eye(n)[None] * 1e-4, np.array([[0.1]]), np.eye(n), keep=True)
    source_jacobian([0.1, 0.2, 0.3, 0.4])


def _portable() -> None:
    from bench.thermal import portable

    m = np.array([[2.0, 0.5, 0.0], [0.5, 3.0, 0.2], [0.0, 0.2, 1.5]])
    portable.exp(0.5)
    portable.log(2.0)
    portable.exp_array(np.ones(3))
    portable.log_array(np.ones(3))
    portable.matmul(m, m)
    portable.solve(m, np.ones(3))
    portable.inv(m)
    portable.inv(np.stack([m, m]))
    portable.expm(m)
    portable.expm(np.stack([m, m]))
    portable.cholesky_lower(m)
    portable.svd(m)
    portable.blended_matvec(np.stack([m, m]), np.array([1, 0]), np.array([0.25, 0.75]), np.ones(3))
    portable.sum_of_products(np.ones(3), np.ones(3))
    portable.transposed_matvec(m, np.ones(3))


def _blocked_qr() -> None:
    from bench.thermal import blocked_qr

    rows = np.array([[1.0, 2.0, 3.0, 4.0], [0.5, -1.0, 2.0, 0.0]])
    residuals = np.array([1.0, 0.0, -1.0, 2.0])
    r, ipvt, qtf, acnorm = blocked_qr.pivoted(blocked_qr.triangle(rows, residuals))
    blocked_qr.reduce(rows, residuals, two_threads=True)
    blocked_qr.norm(residuals)
    blocked_qr.lm_parameter(r, ipvt, acnorm, qtf, 1.0, 0.0)
    blocked_qr.predicted(r, ipvt, qtf)
    blocked_qr.gradient_norm(r, ipvt, qtf, acnorm, 1.0)


# each entry calls the kernels of one module through their wrappers
KERNEL_MODULES = {"bench.thermal.estimator": _estimator, "bench.thermal.kalman": _kalman,
                  "bench.thermal.portable": _portable, "bench.thermal.blocked_qr": _blocked_qr}


def compile_kernels(modules: Iterable[str] = tuple(KERNEL_MODULES)) -> None:
    """Compile the kernels of `modules` (all by default), or load them from the cache, with the signatures the
    bench uses."""
    for module in modules:
        KERNEL_MODULES[module]()


def main(argv: list[str] | None = None) -> int:
    """`python -m bench.thermal.kernels [MODULE ...]`: the kernels of the modules named (all by default)."""
    modules = sys.argv[1:] if argv is None else argv
    unknown = [m for m in modules if m not in KERNEL_MODULES]
    if unknown:
        print(f"{unknown[0]} is not one of {', '.join(KERNEL_MODULES)}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    compile_kernels(modules or tuple(KERNEL_MODULES))
    print(f"numba kernels of {', '.join(modules) or 'every module'} compiled or loaded in "
          f"{time.perf_counter() - start:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
