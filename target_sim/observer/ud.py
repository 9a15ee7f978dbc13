"""The UD form of the observer's covariance: P = U diag(d) Uᵀ (U unit upper triangular), Thornton's modified
weighted Gram-Schmidt prediction over [F U, G] with diag(d, q_G), Bierman's scalar measurement update, Agee and
Turner's rank-one update for consider states; P0 and Q factored once at start (`ud_factor`). Every operation runs
over the structure known when the filter is built (`target_sim.observer.ud_structure`: structural zeros skipped,
U's ones not multiplied), in a fixed order, so the C (`bench.firmware.udgen`) repeats it bit for bit.
"""

from __future__ import annotations

import numpy as np

from target_sim.observer.ud_structure import (
    NEG_ZERO,
    BiermanSchedule,
    Pivot,
    RankOneStep,
    bierman_schedule,
    gram_schmidt_schedule,
    held_gain,
    masked_dot,
    masked_matmul,
    pattern_product,
    rank_one_schedule,
    structural,
    upper_unit,
)


def ud_factor(m: np.ndarray, f) -> tuple[np.ndarray, np.ndarray]:
    """(U, d) with M = U diag(d) Uᵀ, U unit upper triangular, for a symmetric positive definite M, column by column
    from the last (C: fw_ud_factor)."""
    n = m.shape[0]
    u = np.eye(n, dtype=f)
    d = np.zeros(n, dtype=f)
    for j in range(n - 1, -1, -1):
        s = m[j, j]
        for k in range(j + 1, n):
            s = s - (d[k] * u[j, k]) * u[j, k]
        d[j] = s
        if not s > 0:           # not positive definite in this precision: the column carries nothing
            d[j] = f(0.0)
            continue
        for i in range(j - 1, -1, -1):
            s = m[i, j]
            for k in range(j + 1, n):
                s = s - (d[k] * u[i, k]) * u[j, k]
            u[i, j] = s / d[j]
    return u, d


class BiermanThornton:
    """P = U diag(d) Uᵀ: Thornton's prediction, Bierman's update. Q enters as G diag(q) Gᵀ (Thornton's method
    takes any G; `Float32Observer` gives Q's own UD factors, unit upper triangular).

    Both run over the structure known when the filter is built (`target_sim.observer.ud_structure`): F's structural
    nonzeros (given with F), U's unit upper triangle, G's zeros, the columns of G whose q is 0 (dropped), h's
    zeros; each schedule is computed once per pattern. Skipped products are left out of their sums; the order of
    the rest is fixed, so the C repeats it bit for bit."""

    def __init__(self, p0: np.ndarray, g: np.ndarray, q_nodes: np.ndarray, f):
        self.f = f
        self.u, self.d = ud_factor(p0, f)
        n = len(self.d)
        self.upper = upper_unit(n)
        kept = np.flatnonzero(np.asarray(q_nodes) != 0)      # a column of weight 0 adds nothing to any product
        g = np.asarray(g, dtype=f)[:, kept]
        self.g_nonzero = g != 0
        self.g = structural(g, self.g_nonzero)
        self.q_kept = np.asarray(q_nodes, dtype=f)[kept]
        self.g_columns = kept
        self._pivots: dict[bytes, list] = {}
        self._updates: dict[bytes, tuple[np.ndarray, BiermanSchedule]] = {}

    def schedule(self, f_nonzero: np.ndarray) -> tuple[Pivot, ...]:
        """The MWGS schedule of W = [F U, G] for F's structural nonzeros."""
        w_nonzero = np.concatenate([pattern_product(f_nonzero, self.upper), self.g_nonzero], axis=1)
        return gram_schmidt_schedule(w_nonzero)

    def _pivot_indices(self, f_nonzero: np.ndarray) -> list:
        key = f_nonzero.tobytes()
        if key not in self._pivots:
            self._pivots[key] = [(p.row, np.array(p.columns, dtype=np.intp),
                                  [(r.row, np.array(r.shared, dtype=np.intp)) for r in p.rows])
                                 for p in self.schedule(f_nonzero)]
        return self._pivots[key]

    def predict(self, transition: np.ndarray, f_nonzero: np.ndarray | None = None) -> None:
        """Modified weighted Gram-Schmidt of the rows of W = [F U, G] with weights diag(d, q), last row first:
        d_j = w_j·(w_j ∘ weights), u_ij = (w_i·(w_j ∘ weights))·(1/d_j) (one division per pivot),
        w_i <- w_i - u_ij w_j. `f_nonzero`: F's structural nonzeros (None: all)."""
        f, n = self.f, len(self.d)
        zero, one = f(NEG_ZERO), f(1.0)
        if f_nonzero is None:
            f_nonzero = np.ones((n, n), dtype=bool)
        fu, _ = masked_matmul(transition, self.u, f_nonzero, self.upper)
        w = np.concatenate([fu, self.g], axis=1)
        weights = np.concatenate([self.d, self.q_kept])
        u = np.eye(n, dtype=f)
        d = np.zeros(n, dtype=f)
        for j, columns, rows in self._pivot_indices(f_nonzero):
            w_j = w[j, columns]
            c = w_j * weights[columns]
            d[j] = masked_dot(w_j, c, zero)
            if not rows:
                continue
            inverse = one / d[j]
            for i, shared in rows:
                u[i, j] = masked_dot(w[i, columns[shared]], c[shared], zero) * inverse
                w[i, columns] = w[i, columns] - u[i, j] * w_j
        self.u, self.d = u, d

    def bierman(self, h: np.ndarray) -> BiermanSchedule:
        """The update's schedule for the row h (its zeros are structural)."""
        return self._bierman_entry(h)[1]

    def _bierman_entry(self, h: np.ndarray) -> tuple[np.ndarray, BiermanSchedule]:
        nonzero = np.asarray(h) != 0
        key = nonzero.tobytes()
        if key not in self._updates:
            self._updates[key] = (nonzero, bierman_schedule(nonzero))
        return self._updates[key]

    def innovation_variance(self, h: np.ndarray, r, index: int = 0):
        """S = h P⁻ hᵀ + R as Bierman's update reaches it, its final α: R + a_j b_j over the schedule's columns in
        order (b_j = d_j a_j: a column's b is changed only after its own step), the same bits."""
        nonzero, schedule = self._bierman_entry(h)
        a, a_nonzero = masked_matmul(np.asarray(h, dtype=self.f)[None, :], self.u, nonzero[None, :], self.upper)
        a = a[0]
        b = structural(self.d * a, a_nonzero[0])
        alpha = self.f(r)
        for step in schedule.steps:
            alpha = alpha + a[step.column] * b[step.column]
        return alpha

    def update(self, h: np.ndarray, r, index: int = 0, held: np.ndarray | None = None) -> np.ndarray:
        """Bierman's scalar update (Grewal and Andrews' arrangement) over h's structure: a = Uᵀhᵀ, b = d ∘ a, then
        each column j with a_j != 0 (a column with a_j = 0 changes nothing); returns the gain b·γ.

        With `held` (consider states): Bierman's update is the optimal gain's; the gain with the held rows zero,
        K = K_opt - δ, has the covariance P_opt + s δ δᵀ (s = h P⁻ hᵀ + R, the final α; δ = b_held/s), i.e.
        P_opt + γ v vᵀ with v = b on the held rows: Agee and Turner's rank-one update of U and d, which keeps d
        positive for a positive weight (`rank_one`)."""
        f = self.f
        one = f(1.0)
        nonzero, schedule = self._bierman_entry(h)
        u, d = self.u.copy(), self.d.copy()
        a, a_nonzero = masked_matmul(np.asarray(h, dtype=f)[None, :], u, nonzero[None, :], self.upper)
        a, a_nonzero = a[0], a_nonzero[0]
        b = structural(d * a, a_nonzero)
        alpha = f(r)
        gamma = one / alpha
        for step in schedule.steps:
            j = step.column
            beta = alpha
            alpha = alpha + a[j] * b[j]
            lam = -a[j] * gamma
            gamma = one / alpha
            d[j] = (beta * gamma) * d[j]
            for i in step.updated:
                before = u[i, j]
                u[i, j] = before + b[i] * lam
                b[i] = b[i] + b[j] * before
            for i in step.filled:
                b[i] = b[j] * u[i, j]          # b_i was a structural zero: -0 + b_j u_ij
        gain = b * gamma
        self.alpha = alpha            # S = h P⁻ hᵀ + R (a test checks innovation_variance against it)
        if held is not None:
            v_nonzero = held & np.asarray(schedule.gain_nonzero)
            self.rank_one(u, d, gamma, structural(b, v_nonzero), self._rank_one(v_nonzero))
            gain = held_gain(gain, held)
        self.u, self.d = u, d
        return gain

    def _rank_one(self, v_nonzero: np.ndarray) -> tuple[RankOneStep, ...]:
        key = b"r" + v_nonzero.tobytes()
        if key not in self._pivots:
            self._pivots[key] = rank_one_schedule(v_nonzero)
        return self._pivots[key]

    def rank_one_steps(self, v_nonzero: np.ndarray) -> tuple[RankOneStep, ...]:
        """The Agee-Turner schedule for v's structural nonzeros (the C generator's)."""
        return self._rank_one(np.asarray(v_nonzero, dtype=bool))

    def rank_one(self, u: np.ndarray, d: np.ndarray, c, v: np.ndarray, steps: tuple[RankOneStep, ...]) -> None:
        """U diag(d) Uᵀ + c v vᵀ into u and d in place (c > 0; Agee and Turner, Bierman 1977 ch. V), over the
        schedule, last column first: d̃_j = d_j + (c v_j) v_j, β = (c v_j)/d̃_j, c = (c d_j)/d̃_j, then for each
        row i < j: v_i -= v_j u_ij, u_ij += β v_i (a d̃_j that is not positive: β = 0 and c as it was)."""
        f = self.f
        v = v.copy()
        for step in steps:
            j = step.column
            cv = c * v[j]
            dn = d[j] + cv * v[j]
            positive = dn > f(0.0)
            beta = cv / dn if positive else f(0.0)
            c = (c * d[j]) / dn if positive else c
            d[j] = dn
            for i in step.updated:
                v[i] = v[i] - v[j] * u[i, j]
                u[i, j] = u[i, j] + beta * v[i]
            for i in step.filled:
                v[i] = -(v[j] * u[i, j])
                u[i, j] = u[i, j] + beta * v[i]

    def variance(self, row: np.ndarray):
        """row·(U D Uᵀ row) without forming P, over the row's structure (C: fw_obs_sigma, unrolled): v = Uᵀ row over
        U's unit upper triangle and the row's nonzeros, then ((d_j v_j) v_j + ...) over v's structural nonzeros
        in order (a skipped term would be (d_j·0)·0, +0 for d_j >= 0, but NaN for an infinite d_j)."""
        nonzero = np.asarray(row) != 0
        v, v_nonzero = masked_matmul(np.asarray(row, dtype=self.f)[None, :], self.u, nonzero[None, :], self.upper)
        kept = v_nonzero[0]
        return masked_dot((self.d * v[0])[kept], v[0][kept], self.f(NEG_ZERO))

    def covariance(self) -> np.ndarray:
        """U diag(d) Uᵀ in float64 (for reports; the filter itself never forms it)."""
        u = self.u.astype(np.float64)
        return (u * self.d.astype(np.float64)) @ u.T

    def checkpoint(self) -> np.ndarray:
        """d_0..d_{n-1}, then U above its diagonal row by row (the covariance's part of the filter's checkpoint)."""
        return np.concatenate([self.d, self.u[np.triu_indices(len(self.d), 1)]])

    def restore(self, values: np.ndarray) -> None:
        """d and U from `checkpoint()`'s values (U unit upper triangular, zeros below)."""
        n = len(self.d)
        self.d = values[:n].copy()
        u = np.eye(n, dtype=self.f)
        u[np.triu_indices(n, 1)] = values[n:]
        self.u = u
