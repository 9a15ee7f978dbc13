"""The covariance forms of the observer's filter (`OBSERVER_FORMS`), equal in exact arithmetic, not in float32.

- `conventional`: P⁻ = F P Fᵀ + Q, K = P⁻hᵀ/(h P⁻ hᵀ + R), P = P⁻ - K (h P⁻), no symmetrization;
- `joseph`: the same prediction, P = (I - K h) P⁻ (I - K h)ᵀ + R K Kᵀ;
- `ud`: P = U D Uᵀ (U unit upper triangular), Thornton's prediction and Bierman's update over the structure known
  when the filter is built (`target_sim.observer.ud`);
- `steady`: the steady-state gain K_ss of the artifact (the lab solves the Riccati equation at a nominal operating
  point), no covariance at all: x <- x + K_ss ν, a few multiply-adds.

Each form takes a measurement's update with the gain's held (consider) rows zero and keeps the covariance of that
gain (`target_sim.observer.filter` says which rows a measurement holds). Every operation has a fixed order and a
float32 rounding, so the C repeats it bit for bit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from target_sim.fmath import dot, matmul, matvec
from target_sim.observer.ud import BiermanThornton
from target_sim.observer.ud_structure import held_gain
from target_sim.registry import Registry


class Conventional:
    """P⁻ = F P Fᵀ + Q; P = P⁻ - K (h P⁻)."""

    def __init__(self, p0: np.ndarray, q: np.ndarray, f):
        self.f, self.q = f, q
        self.p = p0.copy()

    def predict(self, transition: np.ndarray, nonzero: np.ndarray | None = None) -> None:
        """P⁻ = F P Fᵀ + Q (`nonzero`, F's structural nonzeros, only the UD form's schedules need)."""
        self.p = matmul(matmul(transition, self.p), transition.T) + self.q

    def _gain(self, h: np.ndarray, r) -> tuple[np.ndarray, np.ndarray, np.floating]:
        ph = matvec(self.p, h)                 # P⁻ hᵀ
        s = dot(h, ph) + r
        return ph / s, ph, s

    def innovation_variance(self, h: np.ndarray, r, index: int = 0):
        """S = h P⁻ hᵀ + R, as the update computes it (the gate's denominator, the same bits)."""
        return self._gain(h, r)[2]

    def update(self, h: np.ndarray, r, index: int = 0, held: np.ndarray | None = None) -> np.ndarray:
        """The optimal update; with `held` (consider states) P += s δ δᵀ after it, δ the optimal gain's held rows
        (the covariance of the gain with those rows zero), and that gain is returned."""
        k, _, s = self._gain(h, r)
        hp = matvec(self.p.T, h)               # h P⁻ (a row; equal to (P⁻hᵀ)ᵀ only while P⁻ is symmetric)
        self.p = self.p - k[:, None] * hp[None, :]
        if held is not None:
            rows = np.flatnonzero(held)
            delta = k[rows]
            self.p[np.ix_(rows, rows)] = self.p[np.ix_(rows, rows)] + (s * delta)[:, None] * delta[None, :]
            k = held_gain(k, held)
        return k

    def covariance(self) -> np.ndarray:
        return self.p

    def variance(self, row: np.ndarray):
        """row·(P row) in a fixed order: the variance of a linear combination of the states."""
        return dot(row, matvec(self.p, row))

    def checkpoint(self) -> np.ndarray:
        """P row by row (the covariance's part of the filter's checkpoint)."""
        return self.p.reshape(-1)

    def restore(self, values: np.ndarray) -> None:
        """P from `checkpoint()`'s values."""
        self.p = values.reshape(self.p.shape).copy()


class Joseph(Conventional):
    """P = (I - K h) P⁻ (I - K h)ᵀ + R K Kᵀ."""

    def update(self, h: np.ndarray, r, index: int = 0, held: np.ndarray | None = None) -> np.ndarray:
        """Joseph's form holds for any gain: with `held` (consider states) the optimal gain's held rows zero."""
        k, _, _ = self._gain(h, r)
        if held is not None:
            k = held_gain(k, held)
        f = self.f
        i_kh = np.eye(len(k), dtype=f) - k[:, None] * h[None, :]
        self.p = matmul(matmul(i_kh, self.p), i_kh.T) + (r * k)[:, None] * k[None, :]
        return k


class SteadyState:
    """The constant gain K_ss; the covariance is the artifact's steady-state P (posterior)."""

    def __init__(self, gain: np.ndarray, p_steady: np.ndarray, rows: Sequence[np.ndarray] = ()):
        self.gain, self.p = gain, p_steady
        # per measurement h P⁻ hᵀ of the steady prior, from the posterior and the gain (float64, once):
        # h P hᵀ = h P⁻ hᵀ (1 - h K), since K = P⁻hᵀ/S
        p64 = np.asarray(p_steady, dtype=np.float64)
        self.prior = [p_steady.dtype.type(float(h @ p64 @ h) / (1.0 - float(h @ np.asarray(k, dtype=np.float64))))
                      for h, k in zip((np.asarray(h, dtype=np.float64) for h in rows), gain, strict=False)]

    def predict(self, transition: np.ndarray, nonzero: np.ndarray | None = None) -> None:
        pass

    def innovation_variance(self, h: np.ndarray, r, index: int = 0):
        """S = h P⁻ hᵀ + R with the steady prior's h P⁻ hᵀ (constant: the gate of a steady filter never widens)."""
        return self.prior[index] + r

    def update(self, h: np.ndarray, r, index: int = 0, held: np.ndarray | None = None) -> np.ndarray:
        return self.gain[index]           # the held rows are already zero (ConsiderStates.steady_gain)

    def covariance(self) -> np.ndarray:
        return self.p

    def variance(self, row: np.ndarray):
        return dot(row, matvec(self.p, row))

    def checkpoint(self) -> np.ndarray:
        """Nothing: the steady-state gain keeps no covariance of its own."""
        return np.zeros(0, dtype=self.p.dtype)

    def restore(self, values: np.ndarray) -> None:
        pass


@dataclass(frozen=True)
class ObserverForm:
    """One way to keep the filter's covariance."""

    name: str
    summary: str
    propagates: bool          # a covariance is propagated every step (else the steady-state gain)


OBSERVER_FORMS: Registry[ObserverForm] = Registry("observer form")
for _form in (
    ObserverForm("conventional", "P = P⁻ - K h P⁻ (no symmetrization)", True),
    ObserverForm("joseph", "P = (I - K h) P⁻ (I - K h)ᵀ + R K Kᵀ", True),
    ObserverForm("ud", "P = U D Uᵀ: Thornton's prediction, Bierman's update (Agee-Turner's for consider states)",
                 True),
    ObserverForm("steady", "constant steady-state gain, no covariance", False),
):
    OBSERVER_FORMS.register(_form.name, _form)


def covariance_form(form: str, p0: np.ndarray, q: np.ndarray, q_nodes: np.ndarray, gain_steady: np.ndarray,
                    p_steady: np.ndarray, rows: Sequence[np.ndarray], f):
    """The covariance of a filter in `form`, in node coordinates. The conventional and Joseph forms add `q` itself
    (the filter calibrates it in place); the UD form takes Q = G diag(q_nodes) Gᵀ with G = I, Q being diagonal in
    node coordinates (its structural zeros skipped); the steady form keeps the gain and its steady covariance."""
    if form == "steady":
        return SteadyState(gain_steady, p_steady, rows)
    if form == "ud":
        return BiermanThornton(p0, np.eye(p0.shape[0], dtype=f), q_nodes, f)
    return {"conventional": Conventional, "joseph": Joseph}[form](p0, q, f)
