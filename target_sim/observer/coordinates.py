"""The observer's node coordinates: the filter keeps its covariance over the node temperatures (y = C x, less the
delta form's reference) and the extra states (lags, bias), not over the realization's states x.

Why: there the section's process noise is diagonal (the lab tunes one variance per node, `q_nodes_C2`; the artifact's
Q is C⁻¹ diag(q) C⁻ᵀ), a measurement's row h is what its sensor sees (the flux linkage: the magnet alone, one
nonzero instead of four), and the transition needs no product by C: F' = T F T⁻¹ with T = diag(C, I) is
C (I + Δ A) C⁻¹ + (Δ C B_s) J (shift form: C A C⁻¹ + (C B_s) J), J the sources' Jacobian, so every step saves the
4×4×4 product (B_s J)(Δ C). The model itself still steps x; the filter's gain K' moves the node temperatures
(y += K' ν) and x by C⁻¹ of the step's whole correction.

The constants (C A C⁻¹, C B_s, C⁻¹, T P0 Tᵀ, T K_ss) are computed once at load in float64 with a fixed order
(`fmath.matmul`; a Gauss-Jordan inverse, no LAPACK), then rounded to the filter's precision, so every machine gets
the same bits and the generated C the same literals.
"""

from __future__ import annotations

import numpy as np

from target_sim.fmath import matmul, matvec

F64 = np.float64


def inverse(m: np.ndarray) -> np.ndarray:
    """M⁻¹ in float64 by Gauss-Jordan with partial pivoting, in a fixed order (ValueError for a singular M)."""
    n = m.shape[0]
    work = np.concatenate([np.asarray(m, dtype=F64), np.eye(n)], axis=1)
    for col in range(n):
        pivot = col + int(np.argmax(np.abs(work[col:, col])))
        if work[pivot, col] == 0:
            raise ValueError("the output matrix C is singular")
        work[[col, pivot]] = work[[pivot, col]]
        work[col] = work[col] / work[col, col]
        for row in range(n):
            if row != col:
                work[row] = work[row] - work[row, col] * work[col]
    return work[:, n:]


class NodeCoordinates:
    """T = diag(C, I) of a filter with `n` states (the model's len(C), then its extra states)."""

    def __init__(self, c: np.ndarray, n: int):
        k = c.shape[0]
        self.k = k
        self.c = np.asarray(c, dtype=F64)
        self.c_inv = inverse(self.c)
        self.t = np.eye(n)
        self.t[:k, :k] = self.c
        self.t_inv = np.eye(n)
        self.t_inv[:k, :k] = self.c_inv

    def covariance(self, p: np.ndarray, f) -> np.ndarray:
        """T P Tᵀ of a state-coordinate covariance, symmetric, in the precision f."""
        m = matmul(matmul(self.t, np.asarray(p, dtype=F64)), self.t.T)
        return ((m + m.T) / 2.0).astype(f)

    def vectors(self, rows: np.ndarray, f) -> np.ndarray:
        """Each row of state-coordinate vectors (a gain per measurement) as T v."""
        return np.array([matvec(self.t, np.asarray(v, dtype=F64)) for v in rows]).astype(f)

    def outputs_of(self, m: np.ndarray, f) -> np.ndarray:
        """C M (M with the model's states as rows) in the precision f."""
        return matmul(self.c, np.asarray(m, dtype=F64)).astype(f)

    def similar(self, m: np.ndarray, f) -> np.ndarray:
        """C M C⁻¹ of a map of the model's states, in the precision f."""
        return matmul(matmul(self.c, np.asarray(m, dtype=F64)), self.c_inv).astype(f)

    def state_covariance(self, p: np.ndarray) -> np.ndarray:
        """T⁻¹ P T⁻ᵀ in float64: a node-coordinate covariance back in the state coordinates (for reports)."""
        return matmul(matmul(self.t_inv, np.asarray(p, dtype=F64)), self.t_inv.T)

    def process_noise_error(self, q_state: np.ndarray, q_nodes: np.ndarray) -> float:
        """How far T Q Tᵀ is from diag(q_nodes), relative to the largest q (0: Q is diagonal in node coordinates)."""
        m = matmul(matmul(self.t, np.asarray(q_state, dtype=F64)), self.t.T)
        scale = max(float(np.max(np.abs(q_nodes))), np.finfo(F64).tiny)
        return float(np.max(np.abs(m - np.diag(np.asarray(q_nodes, dtype=F64))))) / scale
