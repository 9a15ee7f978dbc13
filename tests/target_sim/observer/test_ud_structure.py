"""The UD filter over its structure (target_sim/observer/ud_structure.py): skipping structural zeros with -0 as the
additive identity gives the C's sums bit for bit, and the schedules (fill-in of the Gram-Schmidt rows, Bierman's skipped
columns) compute the same filter as the dense Joseph form."""

from __future__ import annotations

import numpy as np

from target_sim.observer.forms import Joseph
from target_sim.observer.ud import BiermanThornton
from target_sim.observer.ud_structure import (
    NEG_ZERO,
    bierman_schedule,
    gram_schmidt_schedule,
    masked_dot,
    masked_matmul,
)

F32 = np.float32


def _kept_sum(a: np.ndarray, b: np.ndarray, a_nz: np.ndarray, b_nz: np.ndarray, i: int, j: int):
    """What the generated C writes for element (i, j): the kept products alone, left to right (None: no term)."""
    acc = None
    for k in range(a.shape[1]):
        if a_nz[i, k] and b_nz[k, j]:
            p = a[i, k] * b[k, j]
            acc = p if acc is None else acc + p
    return acc


def test_a_masked_product_equals_the_sum_of_the_kept_products_bit_for_bit():
    rng = np.random.default_rng(3)
    for _ in range(20):
        a = rng.standard_normal((5, 5)).astype(F32) * F32(1e3)
        b = rng.standard_normal((5, 4)).astype(F32)
        a[rng.random((5, 5)) < 0.3] = F32(-0.0)              # signed zeros among the kept values too
        a_nz, b_nz = rng.random((5, 5)) < 0.6, rng.random((5, 4)) < 0.6
        got, nonzero = masked_matmul(a, b, a_nz, b_nz)
        for i in range(5):
            for j in range(4):
                want = _kept_sum(a, b, a_nz, b_nz, i, j)
                assert nonzero[i, j] == (want is not None)
                want = F32(NEG_ZERO) if want is None else want
                assert got[i, j].tobytes() == F32(want).tobytes(), (i, j)


def test_a_masked_dot_of_nothing_is_minus_zero():
    zero = F32(NEG_ZERO)
    assert masked_dot(np.zeros(0, F32), np.zeros(0, F32), zero).tobytes() == zero.tobytes()
    assert F32(0.0) + zero == 0.0 and np.signbit(F32(-0.0) + zero)     # the identity keeps either zero


def test_the_gram_schmidt_schedule_fills_each_row_with_the_pivots_columns():
    nonzero = np.array([[1, 0, 0, 1], [0, 1, 0, 0], [0, 0, 1, 1]], dtype=bool)
    pivots = gram_schmidt_schedule(nonzero)
    assert [p.row for p in pivots] == [2, 1, 0]
    assert pivots[0].columns == (2, 3)
    assert [(r.row, r.shared, r.fills) for r in pivots[0].rows] == [(0, (1,), (0,)), (1, (), (0, 1))]
    assert pivots[1].columns == (1, 2, 3)           # row 1 gained the columns of row 2
    assert pivots[2].columns == (0, 1, 2, 3)


def test_bierman_skips_the_columns_before_the_rows_first_nonzero():
    schedule = bierman_schedule(np.array([0, 0, 1, 0, 1], dtype=bool))
    assert schedule.terms == ((), (), (2,), (2,), (2, 4))
    assert [s.column for s in schedule.steps] == [2, 3, 4]
    assert schedule.steps[0].updated == () and schedule.steps[0].filled == (0, 1)
    assert schedule.steps[1].updated == (0, 1, 2)


def test_the_structured_ud_filter_is_the_joseph_filter_in_float64():
    """Sparse F (a lag row, a bias column), G with zeros and a zero weight, a sparse h: the same covariance and gain
    as the dense Joseph form."""
    rng = np.random.default_rng(4)
    n = 6
    m = rng.standard_normal((n, n))
    p0 = m @ m.T + n * np.eye(n)
    f = np.eye(n) + 0.1 * rng.standard_normal((n, n))
    f[:4, 4] = 0.0                                   # nothing feeds from the lag state
    f[4, 5] = f[5, :5] = 0.0                          # the bias is a random walk
    f_nonzero = f != 0
    g = np.triu(rng.standard_normal((n, n)))
    g[1, 3] = 0.0
    q_nodes = rng.uniform(0.1, 1.0, n)
    q_nodes[2] = 0.0
    q = (g * q_nodes) @ g.T
    ud = BiermanThornton(p0, g, q_nodes, np.float64)
    joseph = Joseph(p0, q, np.float64)
    for h in (np.eye(n)[4], np.array([0.0, 0.3, 0.0, 0.7, 0.0, 0.0]), rng.standard_normal(n)):
        ud.predict(f, f_nonzero)
        joseph.predict(f)
        assert np.allclose(ud.covariance(), joseph.covariance(), rtol=1e-10)
        assert np.allclose(ud.update(h, 0.3), joseph.update(h, 0.3), rtol=1e-10)
        assert np.allclose(ud.covariance(), joseph.covariance(), rtol=1e-10)
