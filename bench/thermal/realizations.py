"""Realizations of the discrete linear block: same input-output behaviour, different coordinates.

- `physical`: nodal temperatures as states (the discretized LPTN itself).
- `original`: what the paper's polynomial round trip produced: the companion matrix of
  F(z) = det(zI - A_d), then LAPACK's diagonal balancing (MATLAB's `ss`/`ssbal`; REFERENCE.md §3).
- `balanced`: Gramian-balanced, square-root method (Laub, Heath, Paige, Ward 1987); the paper's
  eigendecomposition method (eqs. 35-42) is kept as `balance_by_eigendecomposition` for cross-checks.
- `modal`: real diagonal A; attains the bound κ₂(A) = |λ|max/|λ|min.

`physical` and `balanced` (what identification and the packaged artifacts use), similarity transforms and the
condition number are computed with bench.thermal.portable, the same bits on every CPU; `original` and `modal`
need eigenvectors and use LAPACK's, whose last bits depend on the OpenBLAS kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import matrix_balance

from bench.thermal import portable
from target_sim.kinds import REALIZATIONS as REALIZATION_KINDS

REALIZATIONS = REALIZATION_KINDS.names()   # target_sim.kinds: what each realization is


@dataclass(frozen=True)
class Realization:
    """A discrete state-space model x[k+1] = A x[k] + B u[k], y[k] = C x[k] + D u[k] (form "shift"), or in delta
    form (Middleton and Goodwin) x[k+1] = x[k] + Δ·(A x[k] + B u[k]) with A = A_δ = (A_shift - I)/Δ, B = B_shift/Δ."""

    name: str
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    form: str = "shift"
    dt: float | None = None          # Δ of the delta form

    def shift(self) -> Realization:
        """The same model in shift form (float64): A = I + Δ·A_δ, B = Δ·B_δ."""
        if self.form == "shift":
            return self
        return Realization(self.name, np.eye(self.a.shape[0]) + self.dt * self.a, self.dt * self.b, self.c, self.d)

    def transition(self) -> np.ndarray:
        """The state transition matrix of the shift form (what the poles are the eigenvalues of)."""
        return self.shift().a

    def transformed(self, name: str, t: np.ndarray, t_inv: np.ndarray | None = None) -> Realization:
        """The similar realization with x = T z."""
        t_inv = portable.inv(t) if t_inv is None else t_inv
        mm = portable.matmul
        return Realization(name, mm(t_inv, self.a, t), mm(t_inv, self.b), mm(self.c, t), self.d.copy())

    def astype(self, dtype) -> Realization:
        return Realization(self.name, *(np.asarray(m, dtype=dtype) for m in (self.a, self.b, self.c, self.d)),
                           self.form, self.dt)


def physical(a_d: np.ndarray, b_d: np.ndarray, c: np.ndarray, d: np.ndarray) -> Realization:
    return Realization("physical", a_d, b_d, c, d)


def _sorted_eig(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigen-decomposition with real eigenvalues sorted descending (the LPTN's poles are real and distinct)."""
    lam, vec = np.linalg.eig(a)
    if np.max(np.abs(lam.imag)) > 1e-12 * np.max(np.abs(lam)):
        raise ValueError("the linear block has complex poles; modal and companion forms here need real poles")
    order = np.argsort(-lam.real)
    return lam.real[order], vec.real[:, order]


def companion_matrix(a: np.ndarray) -> np.ndarray:
    """Companion matrix of det(zI - A): first row -a_1..-a_n, ones on the subdiagonal (MATLAB's tf2ss)."""
    coeffs = np.poly(a)
    n = a.shape[0]
    comp = np.zeros((n, n))
    comp[0, :] = -coeffs[1:]
    comp[1:, :-1] = np.eye(n - 1)
    return comp


def original(sys: Realization) -> Realization:
    """The companion realization after diagonal balancing, with B and C carried along."""
    comp = companion_matrix(sys.a)
    _, v = _sorted_eig(sys.a)
    _, w = _sorted_eig(comp)
    # Both share the same distinct poles, so x = V W^-1 z maps one onto the other. A is then set to the
    # companion matrix itself: the similarity reproduces it only up to the round-off of an ill-conditioned T.
    t = v @ np.linalg.inv(w)
    mapped = sys.transformed("original", t)
    balanced_comp, scale = matrix_balance(comp, permute=False)  # scale is diagonal: exact inverse below
    scale_inv = np.diag(1.0 / np.diag(scale))
    return Realization("original", balanced_comp, scale_inv @ mapped.b, mapped.c @ scale, mapped.d)


def gramians(sys: Realization) -> tuple[np.ndarray, np.ndarray]:
    """Discrete controllability and observability Gramians (eqs. 45-46)."""
    mm = portable.matmul
    wc = portable.solve_discrete_lyapunov(sys.a, mm(sys.b, sys.b.T))
    wo = portable.solve_discrete_lyapunov(sys.a.T, mm(sys.c.T, sys.c))
    return (wc + wc.T) / 2, (wo + wo.T) / 2


def hankel_singular_values(sys: Realization) -> np.ndarray:
    wc, wo = gramians(sys)
    return np.sort(np.sqrt(np.abs(np.linalg.eigvals(wc @ wo).real)))[::-1]


def balanced(sys: Realization) -> Realization:
    """Square-root balancing: Cholesky factors of both Gramians and the SVD of their product."""
    wc, wo = gramians(sys)
    lc, lo = portable.cholesky_lower(wc), portable.cholesky_lower(wo)
    u, s, vt = portable.svd(portable.matmul(lo.T, lc))
    root = np.sqrt(s)
    t = portable.matmul(lc, vt.T) / root
    t_inv = portable.matmul((u / root).T, lo.T)
    return sys.transformed("balanced", t, t_inv)


def balance_by_eigendecomposition(sys: Realization) -> Realization:
    """The paper's method (eqs. 35-42): eigenvectors of Wc·Wo, scaled so both Gramians are equal."""
    wc, wo = gramians(sys)
    _, t = np.linalg.eig(wc @ wo)
    t = t.real
    t_inv = np.linalg.inv(t)
    sigma_o2 = np.diag(t.T @ wo @ t)
    sigma_c2 = np.diag(t_inv @ wc @ t_inv.T)
    scale = (sigma_c2 / sigma_o2) ** 0.25  # Σ_s = Σ_c^½ Σ_o^-½ with Σ² the Gramian diagonals (eq. 39)
    t_s = t * scale
    order = np.argsort(-np.sqrt(sigma_c2 * sigma_o2))
    t_s = t_s[:, order]
    return sys.transformed("balanced", t_s)


def modal(sys: Realization) -> Realization:
    """Real diagonal realization; each mode scaled so its input row and output column have equal norms."""
    lam, v = _sorted_eig(sys.a)
    v_inv = np.linalg.inv(v)
    row = np.linalg.norm(v_inv @ sys.b, axis=1)
    col = np.linalg.norm(sys.c @ v, axis=0)
    scale = np.sqrt(row / col)
    result = sys.transformed("modal", v * scale, v_inv / scale[:, None])
    # V^-1 A V differs from diag(λ) only by round-off; the modal form is diagonal by definition.
    return Realization("modal", np.diag(lam), result.b, result.c, result.d)


def delta(sys: Realization, dt: float) -> Realization:
    """The delta-operator form over the balanced coordinates of `sys` (a shift-form realization) at step Δ = dt.

    With Δ = 0.5 s the slowest pole is z ≈ 0.9989: A is close to I and its float32 entries carry little of A - I,
    which sets the steady-state gain (I - A)⁻¹B; A_δ = (A - I)/Δ keeps A - I at full relative precision."""
    bal = balanced(sys)
    a_delta = (bal.a - np.eye(bal.a.shape[0])) / dt
    return Realization("delta", a_delta, bal.b / dt, bal.c, bal.d, form="delta", dt=float(dt))


def realize(sys: Realization, name: str, dt: float | None = None) -> Realization:
    """One of REALIZATIONS from the physical realization `sys` (`delta` needs the step Δ)."""
    if REALIZATION_KINDS[name].delta:
        if dt is None:
            raise ValueError("the delta realization needs the model step dt")
        return delta(sys, dt)
    builders = {"physical": lambda s: s, "original": original, "balanced": balanced, "modal": modal}
    try:
        return builders[name](sys)
    except KeyError:
        raise ValueError(f"unknown realization {name!r}; choose one of {', '.join(REALIZATIONS)}") from None


def condition_number(a: np.ndarray) -> float:
    """2-norm condition number σ_max/σ_min (eq. 48)."""
    s = portable.singular_values(a)
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


def condition_bound(a: np.ndarray) -> float:
    """|λ|max/|λ|min, the lower bound of κ₂ over all realizations."""
    mags = np.abs(np.linalg.eigvals(a))
    return float(mags.max() / mags.min())
