"""The observer in float64, compiled with numba: the reference the target's float32 forms are compared with, and
the likelihood the lab tunes Q and R by.

The same filter as `target_sim.observer` (the model step of `bench.thermal.estimator.model_step`, then the
covariance through F = A + B_s G C, G the sources' dependence on the previous estimate, then the update with one
measured node), in shift form and double precision, with Joseph's update (and P symmetrized after it), so its
covariance stays symmetric positive definite and it can serve as the exact filter. Many (Q, R) candidates run at
once in parallel; each returns the innovations' negative log-likelihood
    sum over updated steps of  log(2π S_k) + ν_k² / S_k,   S_k = h P⁻_k hᵀ + R,
which is what maximum-likelihood tuning minimizes (Mehra 1970; the prediction-error form of the likelihood).
Consider states (`Readings.consider`, Schmidt-Kalman): a measurement that does not read them has their rows of the
gain (node coordinates) set to zero, and Joseph's form keeps the covariance that of the gain actually used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from bench.thermal import portable
from bench.thermal.estimator import StepInputs, identity_sigmoid, model_step, step_buffers
from target_sim.artifact import BIAS_KINDS, CONSIDER_KINDS, OUTPUT_BIAS_KINDS, consider_held, consider_released

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


# The filter's small matrix algebra as loops into buffers allocated once per run: numba's '@' on (n, n) arrays calls
# BLAS and allocates its result, which cost ~5 µs per step on a 6-state filter (issue 40); the loops below cost a
# tenth of that. Sums run in index order without fused multiply-adds (no fastmath), so the filter gives the same bits
# on every x86-64 CPU (the BLAS kernels did not: OpenBLAS picks its kernel, FMA or not, by CPU).
@numba.njit(cache=True, fastmath=False)
def _product(left, right, out):
    """out = left @ right for small square-or-not matrices, summed in index order."""
    for i in range(left.shape[0]):
        for j in range(right.shape[1]):
            acc = 0.0
            for m in range(left.shape[1]):
                acc += left[i, m] * right[m, j]
            out[i, j] = acc


@numba.njit(cache=True, fastmath=False)
def _congruence(f, p, add, tmp, out):
    """out = f @ p @ fᵀ + add (f, p, add, tmp, out: (n, n)); tmp receives f @ p."""
    n = f.shape[0]
    _product(f, p, tmp)
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for m in range(n):
                acc += tmp[i, m] * f[j, m]
            out[i, j] = acc + add[i, j]


@numba.njit(cache=True, fastmath=False)
def _dot(u, v):
    acc = 0.0
    for i in range(u.shape[0]):
        acc += u[i] * v[i]
    return acc


@numba.njit(cache=True, fastmath=False)
def _apply(m, v, out):
    """out = m @ v."""
    for i in range(m.shape[0]):
        acc = 0.0
        for j in range(m.shape[1]):
            acc += m[i, j] * v[j]
        out[i] = acc


@numba.njit(cache=True, fastmath=False)
def _one_filter(a, b, c, c_inv, theta, sig, lut, ratio, coolant, ambient, i_max, alpha_cu, copper_ref, y0, z0, z1,
                rel, sees, lag_pole, lag_index, bias_index, bias_input, bias_output, held, released, release, q, r, p0,
                traj, sigma, keep, use_sigmoid, gate, rejected):
    n_steps = ratio.shape[0]
    n = q.shape[0]
    x, x_new, y, u, gains = step_buffers(c_inv, y0)
    jac = np.zeros((4, 4))
    xa = np.zeros(n)
    for m in range(sees.shape[0]):
        if lag_index[m] >= 0:
            xa[lag_index[m]] = _dot(sees[m], y0)
    p = p0.copy()
    b_s = b[:, 4:].copy()
    bias_column = b[:, bias_input].copy()
    sees_c = np.zeros((sees.shape[0], 4))
    _product(sees, c, sees_c)
    held_any = np.zeros(sees.shape[0], dtype=np.bool_)
    for m in range(sees.shape[0]):
        held_any[m] = np.any(held[m])
    full = np.zeros((n, n))
    b_jac = np.zeros((4, 4))
    b_jac_c = np.zeros((4, 4))
    tmp = np.zeros((n, n))
    p_new = np.zeros((n, n))
    i_kh = np.zeros((n, n))
    added = np.zeros((n, n))
    h = np.zeros(n)
    ph = np.zeros(n)
    gain = np.zeros(n)
    gy = np.zeros(4)
    p_nodes = np.zeros((4, 4))
    cp_tmp = np.zeros((4, 4))
    cp = np.zeros((4, 4))
    nll = 0.0
    updates = 0
    for k in range(n_steps):
        model_step(a, b, c, theta, sig, lut, ratio, coolant, ambient, i_max, alpha_cu, copper_ref, k, x, x_new, y,
                   u, gains, use_sigmoid)
        _source_jacobian(gains, jac)
        full[:, :] = 0.0
        _product(b_s, jac, b_jac)          # A + (B_s G) C
        _product(b_jac, c, b_jac_c)
        for i in range(4):
            for j in range(4):
                full[i, j] = a[i, j] + b_jac_c[i, j]
        if bias_index >= 0:
            full[bias_index, bias_index] = 1.0
        if bias_index >= 0 and bias_output < 0:   # a heat bias heats its node (the column of its node's loss)
            for i in range(4):
                full[i, bias_index] = bias_column[i]
            for i in range(4):
                x[i] += bias_column[i] * xa[bias_index]
            _apply(c, x, y)
        for m in range(sees.shape[0]):   # each lag follows what its sensor sees
            lag = lag_index[m]
            if lag >= 0:
                for j in range(n):
                    acc = 0.0
                    for i in range(4):
                        acc += sees_c[m, i] * full[i, j]
                    if bias_output >= 0:   # the sensor sees its node's output, the output bias with it
                        acc += sees[m, bias_output] * full[bias_index, j]
                    full[lag, j] = (1.0 - lag_pole[m]) * acc
                full[lag, lag] += lag_pole[m]
                view = _dot(sees[m], y)
                if bias_output >= 0:
                    view += sees[m, bias_output] * xa[bias_index]
                xa[lag] = lag_pole[m] * xa[lag] + (1.0 - lag_pole[m]) * view
        for i in range(4):
            xa[i] = x[i]
        _congruence(full, p, q, tmp, p_new)    # P = F P Fᵀ + Q
        p[:, :] = p_new
        for m in range(sees.shape[0]):   # sequential scalar updates (R is diagonal)
            if not np.isfinite(z0[k, m]):
                continue
            h[:] = 0.0
            lag = lag_index[m]
            if lag >= 0:
                h[lag] = 1.0
                predicted = xa[lag]
            else:
                for i in range(4):
                    h[i] = sees_c[m, i]
                predicted = _dot(sees[m], y)
                if bias_output >= 0:
                    h[bias_index] = sees[m, bias_output]
                    predicted += sees[m, bias_output] * xa[bias_index]
            r_k = r[m] * rel[k, m]
            _apply(p, h, ph)
            s = _dot(h, ph) + r_k
            nu = (z0[k, m] + z1[k, m] * y[1]) - predicted
            if gate > 0.0 and nu * nu > gate * s:   # the innovation gate (sigma², 0: none): predict only
                rejected[m] += 1
                continue
            for i in range(n):
                gain[i] = ph[i] / s
            if held_any[m]:   # consider states: the gain's rows of the held nodes (node coordinates) and states 0
                mask = held[m]
                if release > 0.0:   # the magnet is held only while its variance (node coordinates) is at most this
                    variance = 0.0
                    for i in range(4):
                        for j in range(4):
                            variance += c[3, i] * p[i, j] * c[3, j]
                    if variance > release:
                        mask = released[m]
                _apply(c, gain[:4], gy)
                for i in range(4):
                    if mask[i]:
                        gy[i] = 0.0
                _apply(c_inv, gy, gain[:4])
                for j in range(4, n):
                    if mask[j]:
                        gain[j] = 0.0
            for i in range(n):
                xa[i] += gain[i] * nu
            for i in range(n):    # Joseph: (I − K h) P (I − K h)ᵀ + r K Kᵀ, then symmetrized
                for j in range(n):
                    i_kh[i, j] = (1.0 if i == j else 0.0) - gain[i] * h[j]
                    added[i, j] = r_k * (gain[i] * gain[j])
            _congruence(i_kh, p, added, tmp, p_new)
            for i in range(n):
                for j in range(n):
                    p[i, j] = 0.5 * (p_new[i, j] + p_new[j, i])
            for i in range(4):
                x[i] = xa[i]
            _apply(c, x, y)
            nll += LOG_2PI + np.log(s) + nu * nu / s
            updates += 1
        if keep:
            for i in range(4):
                for j in range(4):
                    p_nodes[i, j] = p[i, j]
            _product(c, p_nodes, cp_tmp)     # C P Cᵀ of the nodes
            for i in range(4):
                for j in range(4):
                    acc = 0.0
                    for m in range(4):
                        acc += cp_tmp[i, m] * c[j, m]
                    cp[i, j] = acc
            for i in range(4):
                traj[k, i] = y[i]
                sigma[k, i] = np.sqrt(max(cp[i, i], 0.0))
            if bias_output >= 0:   # the reported node: its output plus the bias, and their joint variance
                cross = 0.0
                for j in range(4):
                    cross += c[bias_output, j] * p[j, bias_index]
                traj[k, bias_output] += xa[bias_index]
                sigma[k, bias_output] = np.sqrt(max(cp[bias_output, bias_output] + 2.0 * cross
                                                    + p[bias_index, bias_index], 0.0))
    return nll, updates


# nogil: the observer's tuning runs its files in threads, one per core (bench.observer.tune)
@numba.njit(parallel=True, cache=True, nogil=True)
def _batch(a, b, c, c_inv, theta, sig, lut, ratio, coolant, ambient, i_max, alpha_cu, copper_ref, y0, z0, z1, rel,
           sees, lag_pole, lag_index, bias_index, bias_input, bias_output, held, released, release, q, r, p0, traj,
           sigma, keep, use_sigmoid, nll, updates, gate, rejected):
    for m in numba.prange(q.shape[0]):
        nll[m], updates[m] = _one_filter(a, b, c, c_inv, theta, sig, lut, ratio, coolant, ambient, i_max, alpha_cu,
                                         copper_ref, y0, z0, z1, rel, sees, lag_pole, lag_index, bias_index,
                                         bias_input, bias_output, held, released, release, q[m], r[m], p0,
                                         traj[m], sigma[m], keep, use_sigmoid, gate, rejected[m])


@dataclass(frozen=True)
class FilterRuns:
    """Per candidate: the innovations' negative log-likelihood, the number of updates and, when kept, the
    estimate and each node's 1-σ per step."""

    nll: np.ndarray              # (M,)
    updates: np.ndarray          # (M,)
    estimates: np.ndarray | None  # (M, steps, 4)
    sigmas: np.ndarray | None     # (M, steps, 4)
    rejections: np.ndarray | None = None   # (M, measurements): readings the innovation gate rejected


@dataclass(frozen=True)
class Readings:
    """The measurements per model step as the filter takes them: reading_k = z0 + z1·ŷ_winding (the flux
    linkage's resistance at the winding estimate; 0 for a sensor), NaN z0: none; variance R·rel_k; each reads
    sees·y, through its lag state when lag_pole > 0 (the lag states follow the model's, in order, then the bias).
    `bias`: the bias state's kind (`target_sim.artifact.BIAS_KINDS`: watts into the node whose loss column of
    B it heats) or None; True is read as "winding-heat" (the one kind there was). `consider`: a kind of
    `target_sim.artifact.CONSIDER_KINDS` (states a measurement that does not read them never updates) or None."""

    z0: np.ndarray           # (steps, m)
    z1: np.ndarray           # (steps, m)
    rel: np.ndarray          # (steps, m)
    sees: np.ndarray         # (m, 4)
    lag_pole: np.ndarray     # (m,)
    bias: str | bool | None = None
    consider: str | None = None
    release_C2: float | None = None   # the magnet is held only while its variance is at most this (None: always)

    def __post_init__(self):
        kind = "winding-heat" if self.bias is True else (self.bias or None)
        if kind is not None and kind not in BIAS_KINDS:
            raise ValueError(f"bias {kind!r} is not one of {', '.join(BIAS_KINDS)}")
        if self.consider is not None and self.consider not in CONSIDER_KINDS:
            raise ValueError(f"consider {self.consider!r} is not one of {', '.join(CONSIDER_KINDS)}")
        object.__setattr__(self, "bias", kind)

    @property
    def held(self) -> np.ndarray:
        """(m, n) booleans: the states (node coordinates) each measurement's update leaves as they are."""
        return consider_held(self.consider, np.reshape(self.sees, (-1, 4)), self.bias, self.states)

    @property
    def released(self) -> np.ndarray:
        """(m, n) booleans: `held` with the magnet (and a magnet bias) free: the states held while the magnet's
        variance exceeds `release_C2` (key-on: a magnet nobody measured)."""
        return consider_released(self.held, self.bias)

    @property
    def bias_input(self) -> int:
        """The loss input whose column of B the bias heats (-1: no bias)."""
        return BIAS_KINDS[self.bias] if self.bias else -1

    @property
    def bias_output(self) -> int:
        """The node an output bias adds to (`OUTPUT_BIAS_KINDS`; -1: no bias, or one that heats)."""
        return BIAS_KINDS[self.bias] if self.bias in OUTPUT_BIAS_KINDS else -1

    @property
    def lag_index(self) -> np.ndarray:
        index, nxt = [], 4
        for a in self.lag_pole:
            index.append(nxt if a > 0 else -1)
            nxt += 1 if a > 0 else 0
        return np.array(index, dtype=np.int64)

    @property
    def states(self) -> int:
        return 4 + int(np.sum(self.lag_pole > 0)) + int(self.bias is not None)

    @property
    def bias_index(self) -> int:
        return self.states - 1 if self.bias else -1


def run_filters(a, b, c, theta, sig, inputs: StepInputs, y0, readings: Readings, q, r, p0,
                keep: bool = False, gate_sigma: float | None = None) -> FilterRuns:
    """Run M filters (Q: (M, n, n), R: (M, measurements)) of one model (A, B, C in shift form) over one run;
    `gate_sigma`: the innovation gate (a reading with ν² > sigma² S predicts only, counted; None: none)."""
    f64 = portable.kernel_array    # one compiled signature whatever the arrays' flags (read-only, strided)
    a, b, c, theta, sig, y0, q, p0 = (f64(m) for m in (a, b, c, theta, sig, y0, q, p0))
    steps = inputs.speed_ratio.shape[0]

    def per_step(v):
        return f64(np.asarray(v, dtype=np.float64).reshape(steps, -1))

    z0, z1, rel = per_step(readings.z0), per_step(readings.z1), per_step(readings.rel)
    r = f64(np.asarray(r, dtype=np.float64).reshape(q.shape[0], z0.shape[1]))
    n_models = q.shape[0]
    use_sigmoid = not np.allclose(sig, identity_sigmoid(sig[0, :]), rtol=0, atol=0)
    traj = np.zeros((n_models, steps if keep else 1, 4))
    sigma = np.zeros_like(traj)
    nll = np.zeros(n_models)
    updates = np.zeros(n_models, dtype=np.int64)
    lag_index = np.ascontiguousarray(readings.lag_index, dtype=np.int64)
    rejected = np.zeros((n_models, z0.shape[1]), dtype=np.int64)
    gate = 0.0 if gate_sigma is None else float(gate_sigma) ** 2
    _batch(a, b, c, portable.inv(c), theta, sig, f64(inputs.table_losses), f64(inputs.speed_ratio),
           f64(inputs.coolant), f64(inputs.ambient), float(inputs.current_max), float(inputs.alpha_cu),
           float(inputs.copper_reference), y0, z0, z1, rel, f64(np.reshape(readings.sees, (-1, 4))),
           f64(np.reshape(readings.lag_pole, -1)), lag_index, int(readings.bias_index), max(readings.bias_input, 0),
           readings.bias_output,
           np.ascontiguousarray(readings.held), np.ascontiguousarray(readings.released),
           float(readings.release_C2 or 0.0), q, r, p0, traj, sigma, bool(keep), use_sigmoid, nll, updates, gate,
           rejected)
    return FilterRuns(nll, updates, traj if keep else None, sigma if keep else None, rejected)


def source_jacobian(gains) -> np.ndarray:
    """G = d(sources)/d(estimate) for (g_tm, g_wm, g_ma, g_cy), in float64."""
    jac = np.zeros((4, 4))
    _source_jacobian(np.asarray(gains, dtype=np.float64), jac)
    return jac


def augmented_transition(block: np.ndarray, b: np.ndarray, c: np.ndarray, readings: Readings) -> np.ndarray:
    """The augmented F (shift form) for the model block's F, as the filter forms it each step."""
    n, full = readings.states, np.zeros((readings.states, readings.states))
    full[:4, :4] = block
    if readings.bias:
        full[n - 1, n - 1] = 1.0
        if readings.bias_output < 0:
            full[:4, n - 1] = b[:, readings.bias_input]
    for m, lag in enumerate(readings.lag_index):
        if lag >= 0:
            a = readings.lag_pole[m]
            full[lag] = (1.0 - a) * (output_view(c, readings, m) @ full)
            full[lag, lag] += a
    return full


def output_view(c: np.ndarray, readings: Readings, m: int) -> np.ndarray:
    """What the m-th measurement sees of the augmented state (n,): sees·C on the block's states, and its weight of
    an output bias's node on the bias state."""
    row = np.zeros(readings.states)
    row[:4] = readings.sees[m] @ c
    if readings.bias_output >= 0:
        row[readings.bias_index] = readings.sees[m][readings.bias_output]
    return row


def measurement_rows(c: np.ndarray, readings: Readings) -> np.ndarray:
    """h of each measurement on the augmented state (m, n)."""
    rows = np.zeros((len(readings.lag_pole), readings.states))
    for m, lag in enumerate(readings.lag_index):
        if lag >= 0:
            rows[m, lag] = 1.0
        else:
            rows[m] = output_view(c, readings, m)
    return rows


def consider_projections(c: np.ndarray, held: np.ndarray) -> np.ndarray:
    """(m, n, n): per measurement the map of a gain (state coordinates: x of the block, then the extra states) onto
    the gain with the rows of its held states (node coordinates, `Readings.held`) zero: T⁻¹ diag(1 - held) T with
    T = diag(C, I). A measurement that holds nothing gets the identity."""
    held = np.atleast_2d(held)
    n = held.shape[1]
    t = np.eye(n)
    t[:4, :4] = c
    t_inv = np.eye(n)
    t_inv[:4, :4] = portable.inv(c)
    return np.array([t_inv @ np.diag(1.0 - row) @ t if row.any() else np.eye(n) for row in held])


# the consider filter's steady state: the Lyapunov iteration stops when P⁻ moves less than this (relative), or fails
STEADY_TOLERANCE, STEADY_ITERATIONS = 1e-12, 500


def _sequential(prior: np.ndarray, h: np.ndarray, r: np.ndarray, projections) -> tuple[list, np.ndarray]:
    """The gains and posterior of the sequential scalar updates from `prior`, each gain mapped by its projection
    (None: the optimal gains), Joseph's form (valid for any gain)."""
    p, gains = prior, []
    for i, (row, var) in enumerate(zip(h, r, strict=True)):
        gain = p @ row / (row @ p @ row + var)
        if projections is not None:
            gain = projections[i] @ gain
        i_kh = np.eye(len(gain)) - np.outer(gain, row)
        p = i_kh @ p @ i_kh.T + var * np.outer(gain, gain)
        p = 0.5 * (p + p.T)
        gains.append(gain)
    return gains, p


def steady_state(f: np.ndarray, h: np.ndarray, q: np.ndarray, r, projections: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(K_ss (m, n), P_ss posterior) of the filter with constant F, H (m, n), Q and R (m,): the discrete Riccati
    equation's solution P⁻ (scipy), then the sequential scalar gains the target applies in order,
    K_i = P_i hᵢᵀ/(hᵢ P_i hᵢᵀ + R_i), P_{i+1} = (I - K_i hᵢ) P_i (I - K_i hᵢ)ᵀ + R_i K_i K_iᵀ.

    With `projections` (`consider_projections`: consider states) each K_i is the projected one, and the steady state
    is the consider filter's: from the Riccati solution, P⁻ = F (A P⁻ Aᵀ + W) Fᵀ + Q is solved as a Lyapunov
    equation for the gains of the last P⁻ (A = Π (I - K_i hᵢ), W their noise terms), the gains recomputed from it,
    until P⁻ settles (a ValueError if it does not within `STEADY_ITERATIONS`)."""
    from scipy.linalg import solve_discrete_are, solve_discrete_lyapunov

    h = np.atleast_2d(np.asarray(h, dtype=float))
    r = np.atleast_1d(np.asarray(r, dtype=float))
    prior = solve_discrete_are(f.T, h.T, q, np.diag(r))
    prior = 0.5 * (prior + prior.T)
    if projections is not None:
        n = len(prior)
        for _ in range(STEADY_ITERATIONS):
            gains, _ = _sequential(prior, h, r, projections)
            a, w = np.eye(n), np.zeros((n, n))
            for gain, row, var in zip(gains, h, r, strict=True):
                i_kh = np.eye(n) - np.outer(gain, row)
                a, w = i_kh @ a, i_kh @ w @ i_kh.T + var * np.outer(gain, gain)
            closed = f @ a
            if np.max(np.abs(np.linalg.eigvals(closed))) >= 1.0:
                raise ValueError("the filter with the consider states held is unstable at the nominal operating "
                                 "point: it has no steady state")
            nxt = solve_discrete_lyapunov(closed, f @ w @ f.T + q)
            nxt = 0.5 * (nxt + nxt.T)
            moved = np.max(np.abs(nxt - prior)) / max(np.max(np.abs(nxt)), np.finfo(float).tiny)
            prior = nxt
            if moved <= STEADY_TOLERANCE:
                break
        else:
            raise ValueError(f"the consider filter's steady state did not settle in {STEADY_ITERATIONS} iterations")
    gains, p = _sequential(prior, h, r, projections)
    return np.array(gains), p
