"""The structure of the observer's UD filter that is known when the filter is built: which elements are always
zero, in what order the remaining operations run. The Python reference (`target_sim.observer`) and the generated C
(`bench.firmware.observergen`) follow the same schedules, so the C can drop every multiplication by a structural zero
and still equal the reference bit for bit.

Structural zeros: an element of a constant that is exactly 0 (A, B, C, C⁻¹, q, h, ...), the zeros of the sources'
Jacobian (`SOURCE_JACOBIAN_NONZERO`), U below its diagonal, and whatever only such zeros feed. Exact ones (U's
diagonal) are multiplied in Python (x·1 = x exactly) and left out of the C.

Why the reference stores a structural zero as -0.0: -0 is the additive identity of IEEE arithmetic, x + (-0) = x
for every x, +0 and -0 included (+0 would turn a -0 sum into +0). So a left-to-right sum whose skipped products are
replaced by -0 (numpy, whole rows at a time) equals the C's sum of the kept products alone, bit for bit, and
-0 - p = -p is the C's -(p) where a Gram-Schmidt row fills in. The products themselves are masked, not computed:
0·x is +0 or -0 (or NaN), which is not the identity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NEG_ZERO = -0.0


def structural(values: np.ndarray, nonzero: np.ndarray) -> np.ndarray:
    """`values` with -0 wherever `nonzero` is False (the reference's spelling of a structural zero)."""
    return np.where(nonzero, values, values.dtype.type(NEG_ZERO)).astype(values.dtype)


def held_gain(gain: np.ndarray, held: np.ndarray) -> np.ndarray:
    """The gain with the rows of the held (consider) states a structural zero (-0: x + (-0)·ν is x)."""
    return structural(gain, ~held)


def masked_matmul(a: np.ndarray, b: np.ndarray, a_nonzero: np.ndarray, b_nonzero: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(A B, its structural nonzeros) in `fmath.matmul`'s order, (i, j) = ((a_ik0·b_k0j + a_ik1·b_k1j) + ...), over
    only the k where both factors are structurally nonzero; -0 where there is no such k. Products by exact ones are
    computed (exact); the C leaves them out."""
    keep = a_nonzero[:, :, None] & b_nonzero[None, :, :]
    products = np.where(keep, a[:, :, None] * b[None, :, :], a.dtype.type(NEG_ZERO))
    # accumulate is a running sum in index order (never reduce's pairwise summation): the loop's bits, in C
    return np.add.accumulate(products, axis=1)[:, -1, :], keep.any(axis=1)


def pattern_product(a_nonzero: np.ndarray, b_nonzero: np.ndarray) -> np.ndarray:
    """The structural nonzeros of A B."""
    return (a_nonzero[:, :, None] & b_nonzero[None, :, :]).any(axis=1)


def masked_dot(a: np.ndarray, b: np.ndarray, zero):
    """a·b left to right, ((a_0·b_0 + a_1·b_1) + ...); `zero` (-0 of the dtype) when there is no product."""
    if len(a) == 0:
        return zero
    return np.add.accumulate(a * b)[-1]     # a running sum left to right (reduce would sum pairwise)


def upper_unit(n: int) -> np.ndarray:
    """The structural nonzeros of a unit upper-triangular U: the diagonal (ones) and above."""
    return np.triu(np.ones((n, n), dtype=bool))


@dataclass(frozen=True)
class PivotRow:
    """Row i's part in the pivot's step: u_ij from the products over `shared` (positions into the pivot's columns
    where row i is nonzero), then w_i -= u_ij w_j over all the pivot's columns; `fills` are the positions where
    row i was a structural zero (the C writes -(u_ij w_jk) there)."""

    row: int
    shared: tuple[int, ...]
    fills: tuple[int, ...]


@dataclass(frozen=True)
class Pivot:
    """One step of the modified weighted Gram-Schmidt: row j against every row above it."""

    row: int
    columns: tuple[int, ...]         # the columns where w_j is nonzero, ascending
    rows: tuple[PivotRow, ...]       # i = 0 .. j-1


def gram_schmidt_schedule(nonzero: np.ndarray) -> tuple[Pivot, ...]:
    """The pivots of Thornton's MWGS over W (n rows, last row first) whose structural nonzeros are `nonzero`:
    each pivot's columns, and for each row above it the shared columns and the fill-in (the pattern grows by the
    pivot row's columns)."""
    pattern = nonzero.copy()
    pivots = []
    for j in range(pattern.shape[0] - 1, -1, -1):
        columns = np.flatnonzero(pattern[j])
        rows = []
        for i in range(j):
            here = pattern[i, columns]
            rows.append(PivotRow(i, tuple(int(p) for p in np.flatnonzero(here)),
                                 tuple(int(p) for p in np.flatnonzero(~here))))
            pattern[i, columns] = True
        pivots.append(Pivot(j, tuple(int(c) for c in columns), tuple(rows)))
    return tuple(pivots)


@dataclass(frozen=True)
class BiermanStep:
    """Column j of Bierman's update (a_j = (Uᵀh)_j structurally nonzero): the rows i < j whose b_i is nonzero
    (u_ij and b_i change) and those where b_i is still a structural zero (b_i = b_j u_ij, u_ij unchanged)."""

    column: int
    updated: tuple[int, ...]
    filled: tuple[int, ...]


@dataclass(frozen=True)
class BiermanSchedule:
    """Bierman's scalar update for a constant row h: a = Uᵀh over h's nonzeros (`terms[j]`: the i <= j with
    h_i != 0), and the columns whose a_j is nonzero (a column with a_j = 0 leaves U, d and b as they are: it is
    skipped)."""

    terms: tuple[tuple[int, ...], ...]
    steps: tuple[BiermanStep, ...]
    gain_nonzero: tuple[bool, ...] = ()     # b's structural nonzeros at the end (the gain's)


def bierman_schedule(h_nonzero: np.ndarray) -> BiermanSchedule:
    """The schedule of Bierman's update for a row h whose structural nonzeros are `h_nonzero` (U unit upper
    triangular: a_j gathers h_i for i <= j)."""
    n = len(h_nonzero)
    terms = tuple(tuple(int(i) for i in np.flatnonzero(h_nonzero[: j + 1])) for j in range(n))
    b_nonzero = [bool(t) for t in terms]
    steps = []
    for j in range(n):
        if not terms[j]:
            continue
        updated = tuple(i for i in range(j) if b_nonzero[i])
        filled = tuple(i for i in range(j) if not b_nonzero[i])
        for i in filled:
            b_nonzero[i] = True
        steps.append(BiermanStep(j, updated, filled))
    return BiermanSchedule(terms, tuple(steps), tuple(b_nonzero))


@dataclass(frozen=True)
class RankOneStep:
    """Column j of the Agee-Turner update (v_j structurally nonzero): the rows i < j whose v_i is nonzero (v_i -= v_j
    u_ij) and those where v_i is still a structural zero (v_i = -(v_j u_ij)); u_ij changes in both."""

    column: int
    updated: tuple[int, ...]
    filled: tuple[int, ...]


def rank_one_schedule(v_nonzero: np.ndarray) -> tuple[RankOneStep, ...]:
    """The columns of the Agee-Turner update U D Uᵀ + c v vᵀ (U unit upper triangular), last first, for a v whose
    structural nonzeros are `v_nonzero`: a column with v_j = 0 changes nothing and is skipped; after a column every
    row above it is nonzero (U's upper triangle is)."""
    nonzero = [bool(v) for v in v_nonzero]
    steps = []
    for j in range(len(nonzero) - 1, -1, -1):
        if not nonzero[j]:
            continue
        updated = tuple(i for i in range(j) if nonzero[i])
        filled = tuple(i for i in range(j) if not nonzero[i])
        for i in filled:
            nonzero[i] = True
        steps.append(RankOneStep(j, updated, filled))
    return tuple(steps)
