"""The estimator in float64, compiled with numba and run for many parameter sets at once.

It is the model the target runs (target_sim.model), step for step: losses from the look-up tables with eqs. 3-8
at the previous winding estimate, the optional sigmoid input nonlinearity, temperature sources (eqs. 9-18) from
the previous estimate, and the discrete linear block. Identification evaluates hundreds of candidate models per
iteration, so the kernel runs a batch of them in parallel and can return either trajectories or error sums.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from bench.thermal import portable
from bench.thermal.losses import COPPER_REFERENCE_C
from bench.thermal.parameters import ALPHA_CU_PER_K, LptnParameters

# The per-model scalars the closed loop needs besides the linear block, in this order.
LOOP_PARAMETERS = ("k_0", "k_1", "k_2", "k_3", "R_wm0", "b_wm", "a_wm", "R_tm0", "b_tm", "a_tm",
                   "R_ma0", "b_ma", "a_ma", "alpha_cy")
SIGMOID_ROWS = ("scale_W", "weight", "bias", "gain", "linear", "offset")


@dataclass(frozen=True)
class StepInputs:
    """Per-model-step inputs of one run, independent of the model: table losses and operating point."""

    table_losses: np.ndarray   # (steps, 5): p_dc0, p_ac0, p_stator, p_magnet, current
    speed_ratio: np.ndarray    # (steps,) ω/ω_max
    coolant: np.ndarray        # (steps,)
    ambient: np.ndarray        # (steps,)
    current_max: float
    alpha_cu: float = ALPHA_CU_PER_K          # the motor's copper temperature coefficient (eqs. 3-4)
    copper_reference: float = COPPER_REFERENCE_C   # the temperature its copper losses are given at


def loop_parameters(params: LptnParameters) -> np.ndarray:
    return np.array([getattr(params, n) for n in LOOP_PARAMETERS])


def identity_sigmoid(scale_w) -> np.ndarray:
    """(…, 6, 4) sigmoid rows that pass the losses through unchanged (the LTI LPTN)."""
    scale_w = np.asarray(scale_w, dtype=float)
    sig = np.zeros(scale_w.shape[:-1] + (6, 4))
    sig[..., 0, :], sig[..., 1, :], sig[..., 4, :] = scale_w, 1.0, 1.0
    return sig


# No fastmath (it would let LLVM reorder sums and fuse multiply-adds by CPU), and exp from portable (glibc's
# has an FMA variant): the kernel's results are the same bits on every x86-64 CPU and at any thread count.
@numba.njit(cache=True, fastmath=False)
def model_step(a, b, c, theta, sig, lut, ratio, coolant, ambient, i_max, alpha_cu, copper_ref, k, x, x_new, y, u,
               gains, use_sigmoid):
    """Model step k in place: x <- A x + B u with u from the losses and the sources at the previous estimate y,
    then y = C x; `gains` receives (g_tm, g_wm, g_ma, g_cy) of the step (an observer's source Jacobian)."""
    # losses at the previous winding estimate (eqs. 3-8)
    factor = 1.0 + alpha_cu * (y[1] - copper_ref)
    i_ratio = lut[k, 4] / i_max
    k_s = theta[0] + theta[1] * i_ratio + theta[2] * ratio[k] + theta[3] * i_ratio * ratio[k]
    u[0] = k_s * lut[k, 2]
    u[1] = lut[k, 0] * factor + lut[k, 1] / factor
    u[2] = (1.0 - k_s) * lut[k, 2]
    u[3] = lut[k, 3]
    if use_sigmoid:  # sigmoid input nonlinearity on normalized losses (eqs. 28-30)
        for i in range(4):
            v = u[i] / sig[0, i]
            s = sig[3, i] / (1.0 + portable.exp(-(sig[1, i] * v + sig[2, i]))) + sig[4, i] * v + sig[5, i]
            u[i] = s * sig[0, i]
    # temperature sources from the previous estimate (eqs. 9-18)
    g_wm = theta[4] * portable.exp(-ratio[k] / theta[5]) / theta[6]
    g_tm = theta[7] * portable.exp(-ratio[k] / theta[8]) / theta[9]
    g_ma = theta[10] * portable.exp(-ratio[k] / theta[11]) / theta[12]
    g_cy = theta[13] * (coolant[k] - 40.0)
    gains[0], gains[1], gains[2], gains[3] = g_tm, g_wm, g_ma, g_cy
    u[4] = coolant[k] + g_cy * (y[0] - coolant[k]) / (1.0 + g_cy)
    u[5] = ambient[k] + g_ma * (y[3] - ambient[k]) / (1.0 + g_ma)
    u[6] = (y[3] + g_tm * y[2]) / (1.0 + g_tm)
    u[7] = (y[1] + g_wm * y[3]) / (1.0 + g_wm)
    for i in range(4):  # x <- A x + B u, y = C x, without allocating
        acc = 0.0
        for j in range(4):
            acc += a[i, j] * x[j]
        for j in range(8):
            acc += b[i, j] * u[j]
        x_new[i] = acc
    for i in range(4):
        x[i] = x_new[i]
    for i in range(4):
        acc = 0.0
        for j in range(4):
            acc += c[i, j] * x[j]
        y[i] = acc


@numba.njit(cache=True, fastmath=False)
def step_buffers(c_inv, y0):
    """The buffers `model_step` works in, for a run from the estimate y0: (x = C⁻¹ y0, x_new, y = y0, u, gains)."""
    x = np.zeros(4)
    for i in range(4):
        for j in range(4):
            x[i] += c_inv[i, j] * y0[j]
    return x, np.zeros(4), y0.copy(), np.empty(8), np.empty(4)


# Particles as lanes: `_lanes` steps LANES models side by side, each lane doing exactly `model_step`'s operations in
# its order (so its bits), the lanes in the innermost loops. One model's step is a chain of dependent operations
# (its estimate feeds the next step's losses and sources), so a single model waits on latency; LANES independent
# chains fill the core's pipelines and SIMD units instead, and the drive inputs of a step are read once for all.
LANES = 16


# error_model numpy: a division by zero gives inf or nan (a diverging candidate, the worst cost) instead of a check
# per division, which would keep LLVM from vectorizing the lane loops
@numba.njit(cache=True, fastmath=False, error_model="numpy")
def _lanes(a, b, c, theta, sig, lut, ratio, coolant, ambient, i_max, alpha_cu, copper_ref, x, y, ref_w, ref_m, ref_y,
           ref_t, traj, first, count, keep, sse, use_sigmoid, res, res_at, res_stride, res_nodes, res_refs,
           res_weights, shared, gains):
    """LANES models (lane-last arrays: a (4,4,L), b (4,8,L), c (4,4,L), theta (14,L), sig (6,4,L)) over one run
    from the states x (4,L) and estimates y (4,L); error sums into sse (4,L); with `keep` the first `count` lanes'
    trajectories into traj[first:first + count]; for each residual row r (none: res_nodes empty) the first `count`
    lanes' weighted errors res_weights[r] * (y[res_nodes[r]] - res_refs[r]) into res[first + lane, res_at +
    r·res_stride + k] (a fit's residuals written where it wants them, no trajectory kept). `shared`: every lane has
    the same loop parameters, and `gains` (steps, 4) holds their sources' (g_wm, g_tm, g_ma, g_cy) per step
    (`shared_gains`), which the lanes then read instead of computing them each."""
    n_steps, lanes = ratio.shape[0], x.shape[1]   # lanes as a run-time count: LLVM then vectorizes the lane loops
    u = np.empty((8, lanes))
    x_new = np.empty((4, lanes))
    # a step's exp arguments and values, lane after lane (portable.exp_into: one vectorized row, `exp`'s bits)
    argument, exps, normalized = np.empty(4 * lanes), np.empty(4 * lanes), np.empty(4 * lanes)
    for k in range(n_steps):
        i_ratio = lut[k, 4] / i_max
        r_k = ratio[k]
        for lane in range(lanes):   # losses at the previous winding estimate (eqs. 3-8)
            factor = 1.0 + alpha_cu * (y[1, lane] - copper_ref)
            k_s = theta[0, lane] + theta[1, lane] * i_ratio + theta[2, lane] * r_k + theta[3, lane] * i_ratio * r_k
            u[0, lane] = k_s * lut[k, 2]
            u[1, lane] = lut[k, 0] * factor + lut[k, 1] / factor
            u[2, lane] = (1.0 - k_s) * lut[k, 2]
            u[3, lane] = lut[k, 3]
        if use_sigmoid:  # sigmoid input nonlinearity on normalized losses (eqs. 28-30)
            for i in range(4):
                for lane in range(lanes):
                    v = u[i, lane] / sig[0, i, lane]
                    normalized[i * lanes + lane] = v
                    argument[i * lanes + lane] = -(sig[1, i, lane] * v + sig[2, i, lane])
            portable.exp_into(argument, exps)    # the exps of a step in one vectorized row
            for i in range(4):
                for lane in range(lanes):
                    v = normalized[i * lanes + lane]
                    s = sig[3, i, lane] / (1.0 + exps[i * lanes + lane]) + sig[4, i, lane] * v + sig[5, i, lane]
                    u[i, lane] = s * sig[0, i, lane]
        if shared:   # the same sources' gains in every lane, computed once per step by shared_gains
            g_wm, g_tm, g_ma, g_cy = gains[k, 0], gains[k, 1], gains[k, 2], gains[k, 3]
            for lane in range(lanes):
                u[4, lane] = coolant[k] + g_cy * (y[0, lane] - coolant[k]) / (1.0 + g_cy)
                u[5, lane] = ambient[k] + g_ma * (y[3, lane] - ambient[k]) / (1.0 + g_ma)
                u[6, lane] = (y[3, lane] + g_tm * y[2, lane]) / (1.0 + g_tm)
                u[7, lane] = (y[1, lane] + g_wm * y[3, lane]) / (1.0 + g_wm)
        else:   # temperature sources from the previous estimate (eqs. 9-18)
            for lane in range(lanes):
                argument[lane] = -r_k / theta[5, lane]
                argument[lanes + lane] = -r_k / theta[8, lane]
                argument[2 * lanes + lane] = -r_k / theta[11, lane]
            portable.exp_into(argument[:3 * lanes], exps[:3 * lanes])
            for lane in range(lanes):
                g_wm = theta[4, lane] * exps[lane] / theta[6, lane]
                g_tm = theta[7, lane] * exps[lanes + lane] / theta[9, lane]
                g_ma = theta[10, lane] * exps[2 * lanes + lane] / theta[12, lane]
                g_cy = theta[13, lane] * (coolant[k] - 40.0)
                u[4, lane] = coolant[k] + g_cy * (y[0, lane] - coolant[k]) / (1.0 + g_cy)
                u[5, lane] = ambient[k] + g_ma * (y[3, lane] - ambient[k]) / (1.0 + g_ma)
                u[6, lane] = (y[3, lane] + g_tm * y[2, lane]) / (1.0 + g_tm)
                u[7, lane] = (y[1, lane] + g_wm * y[3, lane]) / (1.0 + g_wm)
        for i in range(4):  # x <- A x + B u, y = C x
            for lane in range(lanes):
                acc = 0.0
                for j in range(4):
                    acc += a[i, j, lane] * x[j, lane]
                for j in range(8):
                    acc += b[i, j, lane] * u[j, lane]
                x_new[i, lane] = acc
        for i in range(4):
            for lane in range(lanes):
                x[i, lane] = x_new[i, lane]
        for i in range(4):
            for lane in range(lanes):
                acc = 0.0
                for j in range(4):
                    acc += c[i, j, lane] * x[j, lane]
                y[i, lane] = acc
        if keep:
            for lane in range(count):
                for i in range(4):
                    traj[first + lane, k, i] = y[i, lane]
        for r in range(res_nodes.shape[0]):
            node, at, weight = res_nodes[r], res_at + r * res_stride + k, res_weights[r]
            for lane in range(count):
                res[first + lane, at] = weight * (y[node, lane] - res_refs[r, k])
        for lane in range(lanes):   # yoke and tooth summed separately, so winding and PM keep their bits
            dw = y[1, lane] - ref_w[k]
            dm = y[3, lane] - ref_m[k]
            d_y = y[0, lane] - ref_y[k]
            d_t = y[2, lane] - ref_t[k]
            sse[0, lane] += dw * dw
            sse[1, lane] += dm * dm
            sse[2, lane] += d_y * d_y
            sse[3, lane] += d_t * d_t


# nogil: the local polish runs its starts in threads, one per core (bench.model.polish)
@numba.njit(parallel=True, cache=True, nogil=True)
def _batch(a, b, c, c_inv, theta, sig, lut, ratio, coolant, ambient, i_max, alpha_cu, copper_ref, y0, ref_w, ref_m,
           ref_y, ref_t, traj, keep, sse, use_sigmoid, width, res, res_at, res_stride, res_nodes, res_refs,
           res_weights, shared, gains):
    n_models = a.shape[0]
    groups = (n_models + width - 1) // width
    for g in numba.prange(groups):
        # the group's models lane-last; a short last group repeats its last model in the spare lanes
        first = g * width
        a_l, b_l, c_l = np.empty((4, 4, width)), np.empty((4, 8, width)), np.empty((4, 4, width))
        theta_l, sig_l = np.empty((14, width)), np.empty((6, 4, width))
        x, y = np.empty((4, width)), np.empty((4, width))
        for lane in range(width):
            p = min(first + lane, n_models - 1)
            a_l[:, :, lane], b_l[:, :, lane], c_l[:, :, lane] = a[p], b[p], c[p]
            theta_l[:, lane], sig_l[:, :, lane] = theta[p], sig[p]
            x0, _, y_0, _, _ = step_buffers(c_inv[p], y0)
            x[:, lane], y[:, lane] = x0, y_0
        sums = np.zeros((4, width))
        count = min(width, n_models - first)
        _lanes(a_l, b_l, c_l, theta_l, sig_l, lut, ratio, coolant, ambient, i_max, alpha_cu, copper_ref, x, y,
               ref_w, ref_m, ref_y, ref_t, traj, first, count, keep, sums, use_sigmoid, res, res_at, res_stride,
               res_nodes, res_refs, res_weights, shared, gains)
        for lane in range(count):
            for i in range(4):
                sse[first + lane, i] = sums[i, lane]


def run_batch(a, b, c, theta, sig, inputs: StepInputs, y0, ref_w=None, ref_m=None, keep_trajectories=False,
              ref_y=None, ref_t=None, residuals=None):
    """Run P models over one run. Shapes: a (P,4,4), b (P,4,8), c (P,4,4), theta (P,14), sig (P,6,4).

    Returns (sse (P, 4) for winding, PM, yoke and tooth against the references (a missing reference counts as
    zeros), trajectories (P, steps, 4) or None). `residuals` = (out (P, M), at, nodes, refs, weights[, stride]): each
    model's weighted errors weights[r] * (y[nodes[r]] - refs[r]) (r a row of steps) written into out[:, at + r·stride
    + k] (stride default: the steps, the rows one after the other), as a fit's residual vector wants them, without
    keeping trajectories.
    """
    f64 = portable.kernel_array    # one compiled signature whatever the arrays' flags (read-only, strided)
    a, b, c, theta, sig, y0 = (f64(m) for m in (a, b, c, theta, sig, y0))
    n_models, n_steps = a.shape[0], inputs.speed_ratio.shape[0]
    c_inv = portable.inv(c)
    zeros = np.zeros(n_steps)
    ref_w, ref_m, ref_y, ref_t = (zeros if ref is None else f64(ref) for ref in (ref_w, ref_m, ref_y, ref_t))
    traj = np.zeros((n_models, n_steps if keep_trajectories else 1, 4))
    sse = np.zeros((n_models, 4))
    use_sigmoid = not np.allclose(sig, identity_sigmoid(sig[:, 0, :]), rtol=0, atol=0)
    if residuals is None:
        res, at, stride = np.zeros((1, 1)), 0, 0
        nodes, refs, weights = np.zeros(0, np.int64), np.zeros((0, 1)), np.zeros(0)
    else:
        res, at, nodes, refs, weights = residuals[:5]
        stride = residuals[5] if len(residuals) > 5 else n_steps
        nodes = np.ascontiguousarray(nodes, dtype=np.int64)
        refs, weights = f64(np.reshape(refs, (len(nodes), n_steps))), f64(weights)
        if res.dtype != np.float64 or not res.flags.c_contiguous or res.shape[0] != n_models or \
                stride < n_steps or at + (len(nodes) - 1) * stride + n_steps > res.shape[1]:
            raise ValueError("residuals: a C-contiguous float64 (models, M) array with room for every row at `at`")
    ratio, coolant = f64(inputs.speed_ratio), f64(inputs.coolant)
    # a Hammerstein fit's candidates share the network's loop parameters: their sources' gains once for all lanes
    shared = n_models > 1 and bool(np.all(theta == theta[0]))
    gains = shared_gains(theta[0], ratio, coolant) if shared else np.zeros((1, 4))
    _batch(a, b, c, c_inv, theta, sig, f64(inputs.table_losses), ratio, coolant,
           f64(inputs.ambient), float(inputs.current_max), float(inputs.alpha_cu), float(inputs.copper_reference), y0,
           ref_w, ref_m, ref_y, ref_t, traj, bool(keep_trajectories), sse, use_sigmoid, lane_width(n_models), res,
           int(at), int(stride), nodes, refs, weights, shared, gains)
    return sse, (traj if keep_trajectories else None)


@numba.njit(cache=True, fastmath=False)
def shared_gains(theta, ratio, coolant):
    """(steps, 4): the sources' (g_wm, g_tm, g_ma, g_cy) of one set of loop parameters at every step, by the
    operations `_lanes` does per lane (so the same bits)."""
    gains = np.empty((ratio.shape[0], 4))
    for k in range(ratio.shape[0]):
        r_k = ratio[k]
        gains[k, 0] = theta[4] * portable.exp(-r_k / theta[5]) / theta[6]
        gains[k, 1] = theta[7] * portable.exp(-r_k / theta[8]) / theta[9]
        gains[k, 2] = theta[10] * portable.exp(-r_k / theta[11]) / theta[12]
        gains[k, 3] = theta[13] * (coolant[k] - 40.0)
    return gains


def lane_width(n_models: int) -> int:
    """Models per group of lanes: at most LANES, and groups enough to give every thread one (37 models on 2 threads:
    4 groups of 10, not 3 of 16 of which one thread runs two); one model runs in one lane. The results do not
    depend on it: the lanes are independent."""
    threads = numba.get_num_threads()
    groups = math.ceil(n_models / LANES)
    groups = min(n_models, math.ceil(groups / threads) * threads)
    return math.ceil(n_models / groups)
