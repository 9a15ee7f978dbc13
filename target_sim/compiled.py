"""The target's model step compiled (numba), bit for bit the float32 numpy code of `target_sim.model`.

The Python engine steps its model in numpy float32 scalars and small arrays: every operation a numpy call, about
65 µs a step, a quarter of a lockstep row. Here the same operations, in the same order, on float32 scalars in one
compiled function (numba without fastmath: no reassociation, no FMA contraction, every operation rounded to
float32 as numpy rounds it; exp is `fmath.exp_f32`'s steps, the 2^n from `math.ldexp`, exact on its range): a few
µs a step.

It covers what the default and most models are: a linear-block kind (`lti-lptn`, `hammerstein`: the registry's
`linear_block` kinds, the sigmoid where it says `input_nonlinearity`; any realization, delta or not) on loss
maps, one trajectory, float32, no observer (`compiled_step` returns None for anything else, and the node steps
with the numpy code, which stays the reference: the offline reference and every test against it use it).
tests/target_sim/test_compiled.py compares the two bit for bit over a drive cycle for each kind and realization covered.

The step reads the estimator's x and y and writes the new ones into them in place, so a checkpoint, a RESET or
RESTORE (which give the estimator new arrays) and the XCP slave see what the numpy step would have left; the one
coefficient a calibration may change while it runs (XCP's `cal_alpha_cu`, `target_sim.xcp.variables`) is read from
the estimator at every step, the others are the artifact's and copied once.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numba
import numpy as np

from target_sim.fmath import EXP_CONSTANTS, EXP_POLYNOMIAL
from target_sim.network import COOLANT_REFERENCE_C

F32 = np.float32

# the scalar constants' places in the parameter vector
(TORQUE_START, TORQUE_STEP, SPEED_START, SPEED_STEP, ALPHA_CU, COPPER_REF, CURRENT_MAX, SPEED_MAX,
 K0, K1, K2, K3, ALPHA_CY, COOLANT_REF, REFERENCE, DT, *EXP_AT) = range(16 + len(EXP_CONSTANTS))
_EXP_INDEX = dict(zip(EXP_CONSTANTS, EXP_AT, strict=True))


_X_MIN, _X_MAX, _LOG2E, _SHIFTER, _LN2_HI, _LN2_LO = (_EXP_INDEX[name] for name in
                                                     ("X_MIN", "X_MAX", "LOG2E", "SHIFTER", "LN2_HI", "LN2_LO"))
_P0, _P1, _P2, _P3, _P4, _P5 = (_EXP_INDEX[name] for name in EXP_POLYNOMIAL)
_JIT = {"cache": True, "fastmath": False, "nogil": True, "error_model": "numpy"}


@numba.njit(**_JIT)
def exp_f32(c: np.ndarray, x):
    """`fmath.exp_f32` of a float32 scalar, the constants from the parameter vector `c`."""
    v = x
    if not v >= c[_X_MIN]:       # np.fmax(v, X_MIN): NaN -> X_MIN
        v = c[_X_MIN]
    if v > c[_X_MAX]:            # np.fmin(v, X_MAX)
        v = c[_X_MAX]
    k = (v * c[_LOG2E] + c[_SHIFTER]) - c[_SHIFTER]
    r = (v - k * c[_LN2_HI]) - k * c[_LN2_LO]
    z = r * r
    p = c[_P0]
    p = p * r + c[_P1]
    p = p * r + c[_P2]
    p = p * r + c[_P3]
    p = p * r + c[_P4]
    p = p * r + c[_P5]
    scale = np.float32(math.ldexp(1.0, int(k)))       # 2^n, exact: |n| <= 116
    return ((p * z + r) + np.float32(1.0)) * scale


@numba.njit(**_JIT)
def _cell(value, start, step, size: int):
    """`LossTables._cell`: the grid cell holding value and the fraction inside it."""
    pos = (value - start) / step
    if not pos >= 0:
        pos = np.float32(0.0)
    last = np.float32(size - 1)
    if pos > last:
        pos = last
    i = int(pos)
    if i > size - 2:
        i = size - 2
    return i, pos - np.float32(i)


@numba.njit(**_JIT)
def step_kernel(c, tables, a, b, cm, sig, conv, delta, sigmoid, x, y, torque, speed, coolant, ambient) -> None:
    """One `Float32Estimator.step` of a linear-block kind on loss maps; x and y updated in place."""
    one = np.float32(1.0)
    # loss maps (LossTables.lookup, scalar path)
    i, fi = _cell(torque, c[TORQUE_START], c[TORQUE_STEP], tables.shape[1])
    j, fj = _cell(speed, c[SPEED_START], c[SPEED_STEP], tables.shape[2])
    look = np.empty(5, dtype=np.float32)
    for k in range(5):
        t00, t01 = tables[k, i, j], tables[k, i, j + 1]
        t10, t11 = tables[k, i + 1, j], tables[k, i + 1, j + 1]
        low = t00 + fj * (t01 - t00)
        high = t10 + fj * (t11 - t10)
        look[k] = low + fi * (high - low)
    # corrected_losses (eqs. 3-8), from the previous winding estimate
    factor = one + c[ALPHA_CU] * (y[1] - c[COPPER_REF])
    p_w = (look[0] * factor) + (look[1] / factor)
    i_ratio = look[4] / c[CURRENT_MAX]
    n_ratio = speed / c[SPEED_MAX]
    k_s = ((c[K0] + c[K1] * i_ratio) + c[K2] * n_ratio) + (c[K3] * i_ratio) * n_ratio
    u = np.empty(8, dtype=np.float32)
    u[0] = k_s * look[2]
    u[1] = p_w
    u[2] = (one - k_s) * look[2]
    u[3] = look[3]
    if sigmoid:     # HammersteinPart.input_nonlinearity (eqs. 28-30)
        for k in range(4):
            uk = u[k] / sig[0, k]
            z = sig[1, k] * uk + sig[2, k]
            out = (sig[3, k] / (one + exp_f32(c, -z)) + sig[4, k] * uk) + sig[5, k]
            u[k] = out * sig[0, k]
    # temperature sources (eqs. 9-18) from the previous estimate; [tm, wm, ma]: (R0 · exp(-n_ratio / b)) / a
    g_tm = (conv[1, 0] * exp_f32(c, -n_ratio / conv[0, 0])) / conv[2, 0]
    g_wm = (conv[1, 1] * exp_f32(c, -n_ratio / conv[0, 1])) / conv[2, 1]
    g_ma = (conv[1, 2] * exp_f32(c, -n_ratio / conv[0, 2])) / conv[2, 2]
    g_cy = c[ALPHA_CY] * (coolant - c[COOLANT_REF])
    u[4] = coolant + (g_cy * (y[0] - coolant)) / (one + g_cy)
    u[5] = ambient + (g_ma * (y[3] - ambient)) / (one + g_ma)
    u[6] = (y[3] + g_tm * y[2]) / (one + g_tm)
    u[7] = (y[1] + g_wm * y[3]) / (one + g_wm)
    if delta:
        for k in range(4, 8):
            u[k] = u[k] - c[REFERENCE]
    # the linear block: `fmath.matvec` row by row, left to right, zeros included
    new = np.empty(4, dtype=np.float32)
    for r in range(4):
        ax = a[r, 0] * x[0]
        for m in range(1, 4):
            ax = ax + a[r, m] * x[m]
        bu = b[r, 0] * u[0]
        for m in range(1, 8):
            bu = bu + b[r, m] * u[m]
        new[r] = x[r] + c[DT] * (ax + bu) if delta else ax + bu
    for r in range(4):
        x[r] = new[r]
    for r in range(4):
        cx = cm[r, 0] * x[0]
        for m in range(1, 4):
            cx = cx + cm[r, m] * x[m]
        y[r] = cx + c[REFERENCE] if delta else cx


def compiled_step(estimator) -> Callable[..., np.ndarray] | None:
    """The compiled `estimator.step(torque, speed, coolant, ambient)` for what this module covers (see above), or
    None."""
    from target_sim.losses.maps import LossTables

    kind, part = estimator.model_kind, estimator.part
    if estimator.f is not F32 or not kind.linear_block or type(estimator.luts) is not LossTables:
        return None
    kernel = step_kernel
    luts, p = estimator.luts, estimator.p
    values = [luts.torque_axis[0], luts.torque_step, luts.speed_axis[0], luts.speed_step, estimator.alpha_cu,
              estimator.copper_ref, estimator.current_max, estimator.speed_max, p["k_0"], p["k_1"], p["k_2"],
              p["k_3"], p["alpha_cy"], F32(COOLANT_REFERENCE_C), part.reference, estimator.dt,
              *EXP_CONSTANTS.values()]
    c = np.array(values, dtype=F32)
    tables = np.ascontiguousarray(luts.tables, dtype=F32)
    a, b, cm = (np.ascontiguousarray(m, dtype=F32) for m in (part.a, part.b, part.c))
    conv = np.stack([estimator.conv_b, estimator.conv_r0, estimator.conv_a]).astype(F32)
    sigmoid = kind.input_nonlinearity
    if sigmoid:
        from target_sim.modelkinds.hammerstein import SIGMOID_KEYS

        sig = np.stack([part.sigmoid[k] for k in SIGMOID_KEYS]).astype(F32)
    else:
        sig = np.ones((6, 4), dtype=F32)
    delta = bool(part.delta)
    # the first call loads numba's machinery and the kernel (about 0.3 s): here, not in the first row of a run
    kernel(c, tables, a, b, cm, sig, conv, delta, sigmoid, estimator.x.copy(), estimator.y.copy(), F32(0.0),
           F32(0.0), F32(COOLANT_REFERENCE_C), F32(COOLANT_REFERENCE_C))

    def step(torque, speed, coolant, ambient) -> np.ndarray:
        x, y = estimator.x, estimator.y
        c[ALPHA_CU] = estimator.alpha_cu     # calibratable (XCP `cal_alpha_cu`): read at every step, as numpy does
        kernel(c, tables, a, b, cm, sig, conv, delta, sigmoid, x, y, F32(torque), F32(speed), F32(coolant),
               F32(ambient))
        return y.copy()

    return step
