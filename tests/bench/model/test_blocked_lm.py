"""The blocked factorization of the LM fits (bench.thermal.blocked_qr, bench.model.blocked_lm) against what it
replaces: the factor's algebra, MINPACK's iteration on the same problems, and the choice carried into threads."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from bench.model import lm
from bench.model.blocked_lm import levenberg_marquardt as blocked
from bench.model.minpack import levenberg_marquardt as minpack
from bench.model.polish import in_threads
from bench.thermal import blocked_qr


@pytest.mark.parametrize("rows", [5, blocked_qr.BLOCK - 1, 3 * blocked_qr.BLOCK + 17])
def test_the_triangle_is_the_jacobians_factor_and_projects_the_residuals(rows):
    """RᵀR = JᵀJ and Rᵀ(Qᵀr) = Jᵀr whether the rows fill no block, one or several and a part; J untouched."""
    rng = np.random.default_rng(rows)
    jacobian_rows = rng.standard_normal((5, rows)) * np.array([[1.0], [10.0], [0.1], [3.0], [1e3]])
    residuals = rng.standard_normal(rows)
    kept = jacobian_rows.copy()
    reduced = blocked_qr.triangle(jacobian_rows, residuals)
    r, qtr = reduced[:, :5], reduced[:, 5]
    assert np.array_equal(jacobian_rows, kept)
    assert np.allclose(np.tril(r, -1), 0.0)
    gram = jacobian_rows @ jacobian_rows.T
    # measured: 5e-16 of the Gram matrix's largest entry; the tolerance leaves two decades
    assert np.abs(r.T @ r - gram).max() <= 1e-13 * np.abs(gram).max()
    assert np.allclose(r.T @ qtr, jacobian_rows @ residuals, rtol=1e-12, atol=1e-12 * np.abs(gram).max())


@pytest.mark.parametrize("n, rows", [(9, 3 * blocked_qr.CHUNK_BLOCKS * blocked_qr.BLOCK + 301), (36, 70_001), (3, 600)])
def test_the_two_thread_reduction_is_the_one_thread_triangle_to_the_bit(n, rows):
    """blocked_qr.reduce on two threads (the left columns' reflectors handed over a chunk at a time) gives
    `triangle`'s bits: several chunks and a part, a column without data (its reflector not made), two equal
    columns, and a Jacobian too narrow to split but forced to."""
    rng = np.random.default_rng(n)
    jacobian_rows = rng.standard_normal((n, rows)) * 10.0 ** rng.integers(-3, 4, size=(n, 1))
    jacobian_rows[1] = 0.0
    jacobian_rows[-1] = jacobian_rows[-2]
    residuals = rng.standard_normal(rows)
    kept = jacobian_rows.copy()
    one = blocked_qr.triangle(jacobian_rows, residuals)
    two = blocked_qr.reduce(jacobian_rows, residuals, two_threads=True)
    assert np.array_equal(one.view(np.uint64), two.view(np.uint64))
    assert np.array_equal(jacobian_rows, kept)
    assert np.array_equal(blocked_qr.reduce(jacobian_rows, residuals).view(np.uint64), one.view(np.uint64))


def test_a_polish_starts_thread_reduces_on_its_own_core(monkeypatch):
    """In a thread whose numba kernels run on one thread (the polish's starts, in_threads), `reduce` keeps the
    one-thread `triangle`: the two starts already fill the cores."""
    calls = []
    one_thread = blocked_qr.triangle
    monkeypatch.setattr(blocked_qr, "triangle", lambda *a: calls.append(1) or one_thread(*a))
    rng = np.random.default_rng(1)
    rows = rng.standard_normal((12, blocked_qr.SPLIT_MIN_ROWS))
    residuals = rng.standard_normal(blocked_qr.SPLIT_MIN_ROWS)
    reduced = in_threads(lambda _: blocked_qr.reduce(rows, residuals), [0, 1])
    assert len(calls) == 2 and np.array_equal(reduced[0], reduced[1])


def test_the_pivoted_factor_is_minpacks_with_its_column_norms():
    """J P = Q r with |r_jj| non-increasing (MINPACK's pivoting), acnorm J's column norms, qtf = Qᵀf's first n."""
    rng = np.random.default_rng(1)
    jacobian_rows = rng.standard_normal((6, 1000)) * np.array([[1.0], [50.0], [0.2], [5.0], [1.0], [7.0]])
    residuals = rng.standard_normal(1000)
    r, ipvt, qtf, acnorm = blocked_qr.pivoted(blocked_qr.triangle(jacobian_rows, residuals))
    upper = np.triu(r)
    jp = jacobian_rows[ipvt].T
    assert sorted(ipvt) == list(range(6))
    assert np.all(np.diff(np.abs(np.diag(upper))) <= 0.0)
    assert np.allclose(upper.T @ upper, jp.T @ jp, rtol=1e-12, atol=1e-9)
    assert np.allclose(upper.T @ qtf, jp.T @ residuals, rtol=1e-10, atol=1e-9)
    assert np.allclose(acnorm, np.linalg.norm(jacobian_rows, axis=1), rtol=1e-13)


def _decaying_cosines():
    """A nonlinear least-squares problem as the fits pose it: 12 parameters, 20 000 residuals, forward
    differences a row per parameter."""
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 10.0, 20_000)
    truth = rng.uniform(0.5, 2.0, 12)

    def model(p):
        a, b, c = p[:4], p[4:8], p[8:]
        return (a[:, None] * np.exp(-b[:, None] * t[None] / 3) * np.cos(c[:, None] * t[None])).sum(0)

    measured = model(truth) + 0.01 * rng.standard_normal(len(t))

    def fun(p):
        return model(p) - measured

    def jac_rows(p):
        f0, steps = fun(p), 1e-7 * np.maximum(1.0, np.abs(p))
        return np.array([(fun(p + s * e) - f0) / s for s, e in zip(steps, np.eye(len(p)), strict=True)])

    return fun, jac_rows, truth * rng.uniform(0.8, 1.25, 12)


def test_the_blocked_iteration_is_minpacks_within_rounding():
    """The same iteration: on a 12-parameter fit both converge by the same test to the same cost (the steps differ
    in the last bits, so the iterates drift apart at the 1e-3 level on this ill-conditioned problem; measured
    2026-12-07: costs 0.99263084 and 0.99263083, 102 and 103 evaluations); on Rosenbrock's function the same
    evaluations, step for step."""
    fun, jac_rows, start = _decaying_cosines()
    ours, theirs = blocked(fun, jac_rows, start, 400), minpack(fun, jac_rows, start, 400)
    assert ours.status == theirs.status == 1 and ours.success
    assert abs(ours.nfev - theirs.nfev) <= 5
    assert (ours.fun ** 2).sum() == pytest.approx((theirs.fun ** 2).sum(), rel=1e-6)

    def rosenbrock(p):
        return np.array([10.0 * (p[1] - p[0] ** 2), 1.0 - p[0]])

    def rosenbrock_rows(p):
        return np.array([[-20.0 * p[0], -1.0], [10.0, 0.0]])

    ours = blocked(rosenbrock, rosenbrock_rows, np.array([-1.2, 1.0]), 200)
    theirs = minpack(rosenbrock, rosenbrock_rows, np.array([-1.2, 1.0]), 200)
    assert (ours.status, ours.nfev, ours.njev) == (theirs.status, theirs.nfev, theirs.njev)
    assert np.allclose(ours.x, [1.0, 1.0], atol=1e-12)
    capped = blocked(fun, jac_rows, start, 10)
    assert capped.status == 5 and not capped.success and capped.nfev == 10


def test_the_factorization_chosen_reaches_the_worker_threads():
    """lm.using() is one choice for the whole identification, the polish's threads included."""
    assert lm.current() == "minpack"
    with lm.using("blocked"):
        assert in_threads(lambda _: lm.current(), [0, 1, 2]) == ["blocked"] * 3
    assert lm.current() == "minpack"
    with pytest.raises(ValueError, match="unknown LM factorization"):
        with lm.using("cholesky"):
            pass


_DIGEST = """
import hashlib, numpy as np
from bench.thermal import blocked_qr
rng = np.random.default_rng(5)
rows, residuals = rng.standard_normal((9, 3001)), rng.standard_normal(3001)
r, ipvt, qtf, acnorm = blocked_qr.pivoted(blocked_qr.triangle(rows, residuals))
print(hashlib.sha256(b"".join(a.tobytes() for a in (r, ipvt, qtf, acnorm))).hexdigest())
"""


@pytest.mark.slow
def test_the_factor_is_the_same_bits_for_any_vector_width(tmp_path):
    """The partial sums are fixed chains, so numba compiling for a CPU without AVX gives the bits the host's own
    code does (each run compiles afresh in its own cache: ~15 s)."""
    digests = []
    for cpu in ("host", "generic"):
        env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / cpu), "NUMBA_CPU_NAME": cpu}
        done = subprocess.run([sys.executable, "-c", _DIGEST], env=env, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr
        digests.append(done.stdout.strip())
    assert digests[0] == digests[1]
    assert len(digests[0]) == 64     # a digest was printed
