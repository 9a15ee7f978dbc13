"""The observer in float64, compiled with numba: the reference the target's float32 forms are compared with, and
the likelihood the lab tunes Q and R by.

The same filter as `target_sim.observer` (the model step of `bench.thermal.estimator.model_step`, then the
covariance through F = A + B_s G C, G the sources' dependence on the previous estimate, then the update with one
measured node), in shift form and double precision, with Joseph's update (and P symmetrized after it), so its
covariance stays symmetric positive definite and it can serve as the exact filter. Many (Q, R) candidates run at
once in parallel; each returns the innovations' negative log-likelihood
    sum over updated steps of  log(2π S_k) + ν_k² / S_k,   S_k = h P⁻_k hᵀ + R,
which is what maximum-likelihood tuning minimizes (Mehra 1970; the prediction-error form of the likelihood).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from bench.thermal import portable
from bench.thermal.estimator import StepInputs, identity_sigmoid, model_step

LOG_2PI = float(np.log(2.0 * np.pi))


@numba.njit(cache=True, fastmath=False)
def _source_jacobian(gains, jac):
    g_tm, g_wm, g_ma, g_cy = gains[0], gains[1], gains[2], gains[3]
    jac[:, :] = 0.0
    jac[0, 0] = g_cy / (1.0 + g_cy)
    jac[1, 3] = g_ma / (1.0 + g_ma)
    jac[2, 2] = g_tm / (1.0 + g_tm)
    jac[2, 3] = 1.0 / (1.0 + g_tm)
    jac[3, 1] = 1.0 / (1.0 + g_wm)
    jac[3, 3] = g_wm / (1.0 + g_wm)


@numba.njit(cache=True, fastmath=False)
def _one_filter(a, b, c, c_inv, theta, sig, lut, ratio, coolant, ambient, i_max, alpha_cu, copper_ref, y0, z, nodes,
                offsets, q, r, p0, traj, sigma, keep, use_sigmoid):
    n_steps = ratio.shape[0]
    x = np.zeros(4)
    x_new = np.zeros(4)
    y = y0.copy()
    u = np.empty(8)
    gains = np.empty(4)
    jac = np.zeros((4, 4))
    for i in range(4):
        for j in range(4):
            x[i] += c_inv[i, j] * y0[j]
    p = p0.copy()
    b_s = b[:, 4:].copy()
    eye = np.eye(4)
    nll = 0.0
    updates = 0
    for k in range(n_steps):
        model_step(a, b, c, theta, sig, lut, ratio, coolant, ambient, i_max, alpha_cu, copper_ref, k, x, x_new, y,
                   u, gains, use_sigmoid)
        _source_jacobian(gains, jac)
        f = a + b_s @ jac @ c
        p = f @ p @ f.T + q
        for m in range(nodes.shape[0]):   # sequential scalar updates (R is diagonal)
            if not np.isfinite(z[k, m]):
                continue
            node = nodes[m]
            h = c[node].copy()
            ph = p @ h
            s = h @ ph + r[m]
            nu = (z[k, m] - offsets[m]) - y[node]
            gain = ph / s
            for i in range(4):
                x[i] += gain[i] * nu
            i_kh = eye - np.outer(gain, h)
            p = i_kh @ p @ i_kh.T + r[m] * np.outer(gain, gain)
            p = 0.5 * (p + p.T)
            for i in range(4):
                acc = 0.0
                for j in range(4):
                    acc += c[i, j] * x[j]
                y[i] = acc
            nll += LOG_2PI + np.log(s) + nu * nu / s
            updates += 1
        if keep:
            cp = c @ p @ c.T
            for i in range(4):
                traj[k, i] = y[i]
                sigma[k, i] = np.sqrt(max(cp[i, i], 0.0))
    return nll, updates


@numba.njit(parallel=True, cache=True)
def _batch(a, b, c, c_inv, theta, sig, lut, ratio, coolant, ambient, i_max, alpha_cu, copper_ref, y0, z, nodes,
           offsets, q, r, p0, traj, sigma, keep, use_sigmoid, nll, updates):
    for m in numba.prange(q.shape[0]):
        nll[m], updates[m] = _one_filter(a, b, c, c_inv, theta, sig, lut, ratio, coolant, ambient, i_max, alpha_cu,
                                         copper_ref, y0, z, nodes, offsets, q[m], r[m], p0, traj[m], sigma[m], keep,
                                         use_sigmoid)


@dataclass(frozen=True)
class FilterRuns:
    """Per candidate: the innovations' negative log-likelihood, the number of updates and, when kept, the
    estimate and each node's 1-σ per step."""

    nll: np.ndarray              # (M,)
    updates: np.ndarray          # (M,)
    estimates: np.ndarray | None  # (M, steps, 4)
    sigmas: np.ndarray | None     # (M, steps, 4)


def run_filters(a, b, c, theta, sig, inputs: StepInputs, y0, z, nodes, offsets, q, r, p0,
                keep: bool = False) -> FilterRuns:
    """Run M filters (Q: (M, 4, 4), R: (M, measurements)) of one model (A, B, C in shift form) over one run; z holds
    the measurements per model step, (steps, measurements) (NaN: none), of the output nodes `nodes`; each reading
    less its offset is compared with its node."""
    a, b, c = (np.ascontiguousarray(m, dtype=np.float64) for m in (a, b, c))
    q = np.ascontiguousarray(q, dtype=np.float64)
    z = np.ascontiguousarray(np.asarray(z, dtype=np.float64).reshape(len(inputs.speed_ratio), -1))
    r = np.ascontiguousarray(np.asarray(r, dtype=np.float64).reshape(q.shape[0], z.shape[1]))
    n_models, n_steps = q.shape[0], inputs.speed_ratio.shape[0]
    sig = np.ascontiguousarray(sig, dtype=np.float64)
    use_sigmoid = not np.allclose(sig, identity_sigmoid(sig[0, :]), rtol=0, atol=0)
    traj = np.zeros((n_models, n_steps if keep else 1, 4))
    sigma = np.zeros_like(traj)
    nll = np.zeros(n_models)
    updates = np.zeros(n_models, dtype=np.int64)
    _batch(a, b, c, portable.inv(c), np.ascontiguousarray(theta, dtype=np.float64), sig,
           np.ascontiguousarray(inputs.table_losses), np.ascontiguousarray(inputs.speed_ratio),
           np.ascontiguousarray(inputs.coolant), np.ascontiguousarray(inputs.ambient), float(inputs.current_max),
           float(inputs.alpha_cu), float(inputs.copper_reference), np.asarray(y0, dtype=np.float64), z,
           np.asarray(nodes, dtype=np.int64).reshape(-1), np.asarray(offsets, dtype=np.float64).reshape(-1), q, r,
           np.ascontiguousarray(p0, dtype=np.float64), traj, sigma, keep, use_sigmoid, nll, updates)
    return FilterRuns(nll, updates, traj if keep else None, sigma if keep else None)


def source_jacobian(gains) -> np.ndarray:
    """G = d(sources)/d(estimate) for (g_tm, g_wm, g_ma, g_cy), in float64."""
    jac = np.zeros((4, 4))
    _source_jacobian(np.asarray(gains, dtype=np.float64), jac)
    return jac


def steady_state(f: np.ndarray, h: np.ndarray, q: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """(K_ss, P_ss posterior) of the filter with constant F, h, Q, R: the discrete Riccati equation's solution
    P⁻ (scipy), K = P⁻hᵀ/(h P⁻ hᵀ + R), P = (I - K h) P⁻ (I - K h)ᵀ + R K Kᵀ."""
    from scipy.linalg import solve_discrete_are

    h = np.asarray(h, dtype=float).reshape(1, -1)
    prior = solve_discrete_are(f.T, h.T, q, np.array([[r]]))
    prior = 0.5 * (prior + prior.T)
    gain = (prior @ h.T / (h @ prior @ h.T + r)).ravel()
    i_kh = np.eye(len(gain)) - np.outer(gain, h)
    post = i_kh @ prior @ i_kh.T + r * np.outer(gain, gain)
    return gain, 0.5 * (post + post.T)
