"""Float32 arithmetic the target's Python code and its generated C firmware share, operation for operation.

The firmware (`bench firmware export`) must give the same bits as `target_sim.model`, so neither side may use
an operation whose rounding depends on the machine or the library:

* no BLAS: numpy's `@` calls sgemv, whose summation order and FMA use depend on the CPU's OpenBLAS kernel. A
  matrix-vector product is `matvec`: row i is ((m_i0·v_0 + m_i1·v_1) + m_i2·v_2) + ..., left to right, every
  product and every sum rounded to float32 (numpy's elementwise ufuncs round each operation, like the C; the C
  is compiled with -ffp-contract=off so no multiply-add is fused);
* no `np.exp`/libm `expf` (numpy's float32 exp differs between its SIMD paths): `exp_f32` below, whose
  operations the C function `fw_exp` repeats in the same order.

`exp_f32(x)`, for float32 x (scalar or array, elementwise):

1. clamp x to [EXP_X_MIN, EXP_X_MAX] = [-80, 80] (NaN becomes -80): exp stays a normal float32 there
   (e^-80 ≈ 1.8e-35, e^80 ≈ 5.5e34), so 2^n below is a normal number and no step overflows. The model's
   arguments: -n/n_max/b of eq. 15 (-7.8..4.5 for the packaged parameters, whose b_ma < 0) and the sigmoid's
   -(w·u + b) (within ±20 in practice; beyond ±80 the sigmoid is 0 or 1 in float32 anyway);
2. n = round(x·log2 e) to nearest even, as k = (x·LOG2E + SHIFTER) - SHIFTER with SHIFTER = 1.5·2^23
   (adding it pushes the fraction bits out of the float32 significand);
3. r = (x - k·LN2_HI) - k·LN2_LO (Cody-Waite: LN2_HI has 9 significant bits, so k·LN2_HI is exact for
   |k| <= 116), |r| <= ~0.35;
4. e^r ≈ 1 + r + r²·P(r), P(r) = ((((P0·r + P1)·r + P2)·r + P3)·r + P4)·r + P5 by Horner, evaluated as
   ((P(r)·r² + r) + 1); P0..P5 are the coefficients of Cephes' expf (S. L. Moshier, Cephes Math Library,
   single/expf.c) rounded to float32, given below as float32 hex;
5. times 2^n, built from its bits ((n + 127) << 23) and exact (one rounding less than a libm would do).

Accuracy, measured against math.exp (the float64 exp, then the error in float32 ulps of the exact value) on every
float32 x with 1/8 <= |x| <= 80 (155 million arguments) and 20 million random ones with |x| < 1/8: max 0.9903 ulp
(at x = 70.403), 9.6 % of the results not correctly rounded (error > 0.5 ulp); it took 10 s here
(tests/target_sim/test_fmath.py re-measures a sample). The firmware's fw_exp equals exp_f32 bit for bit
(tested in the emulator).
"""

from __future__ import annotations

import numpy as np

F32 = np.float32
ONE = F32(1.0)


def _hex32(text: str) -> np.float32:
    """A float32 constant from its exact hex spelling (refuses a value float32 cannot hold exactly)."""
    value = float.fromhex(text)
    if float(F32(value)) != value:
        raise ValueError(f"{text} is not a float32 value")
    return F32(value)


# The constants of exp_f32, by the names the generated C uses (EXP_<name>), in float32 hex.
EXP_CONSTANTS: dict[str, np.float32] = {
    "X_MIN": _hex32("-0x1.4p+6"),              # -80
    "X_MAX": _hex32("0x1.4p+6"),               # +80
    "LOG2E": _hex32("0x1.715476p+0"),          # log2(e) rounded to float32
    "SHIFTER": _hex32("0x1.8p+23"),            # 1.5·2^23: x + SHIFTER - SHIFTER rounds x to an integer
    "LN2_HI": _hex32("0x1.63p-1"),             # 0.693359375: ln 2 to 9 bits
    "LN2_LO": _hex32("-0x1.bd0106p-13"),       # ln 2 - LN2_HI (-2.12194440e-4)
    "P0": _hex32("0x1.a0d2cep-13"),            # 1.9875691500e-4   Cephes expf
    "P1": _hex32("0x1.6e879cp-10"),            # 1.3981999507e-3
    "P2": _hex32("0x1.111210p-7"),             # 8.3334519073e-3
    "P3": _hex32("0x1.555382p-5"),             # 4.1665795894e-2
    "P4": _hex32("0x1.555554p-3"),             # 1.6666665459e-1
    "P5": _hex32("0x1.000000p-1"),             # 5.0000001201e-1 (rounds to 0.5 in float32)
}
EXP_POLYNOMIAL = ("P0", "P1", "P2", "P3", "P4", "P5")   # Horner order, highest degree first
EXP_EXPONENT_BIAS = 127                                  # float32's; 2^n has the bits (n + 127) << 23
EXP_MAX_ULP = 0.991                                      # measured (module docstring)


_X_MIN, _X_MAX, _LOG2E, _SHIFTER, _LN2_HI, _LN2_LO = (EXP_CONSTANTS[name] for name in
                                                     ("X_MIN", "X_MAX", "LOG2E", "SHIFTER", "LN2_HI", "LN2_LO"))
_P = tuple(EXP_CONSTANTS[name] for name in EXP_POLYNOMIAL)


def exp_f32(x):
    """e^x in float32 by the documented steps above (scalar in, scalar out; arrays elementwise)."""
    v = np.asarray(x, dtype=F32)
    v = np.fmax(v, _X_MIN)                      # C: if (!(x >= EXP_X_MIN)) x = EXP_X_MIN;  (NaN -> X_MIN too)
    v = np.fmin(v, _X_MAX)                      # C: if (x > EXP_X_MAX) x = EXP_X_MAX;
    k = (v * _LOG2E + _SHIFTER) - _SHIFTER      # n = round(x·log2 e) to nearest even, as a float
    r = (v - k * _LN2_HI) - k * _LN2_LO         # x - n·ln 2
    z = r * r
    p = _P[0]
    for coefficient in _P[1:]:
        p = p * r + coefficient                 # Horner
    scale = ((k.astype(np.int32) + EXP_EXPONENT_BIAS) << 23).view(F32)   # 2^n from its bits (positive: int32 ok)
    out = ((p * z + r) + ONE) * scale           # exact scaling: 2^n is normal, e^r·2^n too
    return out[()] if out.ndim == 0 else out


def matvec(matrix: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """M v with a fixed order: row i = ((m_i0·v_0 + m_i1·v_1) + m_i2·v_2) + ..., each operation rounded to the
    arrays' dtype (float32 on the target), zeros included. The C's `dot` does the same sums.

    Lanes: a vector (n, L...) is L independent vectors (trajectories run side by side, `bench.robustness`), and a
    matrix (m, n, L...) one matrix per lane; every lane gets exactly the operations of the one-vector case."""
    lanes = vector.ndim - 1
    if lanes and matrix.ndim == 2:
        matrix = matrix.reshape(matrix.shape + (1,) * lanes)
    products = matrix * vector[None]    # every m_ij·v_j, rounded
    acc = products[:, 0]
    for j in range(1, products.shape[1]):
        acc = acc + products[:, j]      # left to right
    return acc


def dot(a: np.ndarray, b: np.ndarray):
    """a·b with a fixed order: ((a_0·b_0 + a_1·b_1) + a_2·b_2) + ..., each operation rounded to the dtype (the C's
    `dot`)."""
    products = a * b
    acc = products[0]
    for j in range(1, products.shape[0]):
        acc = acc + products[j]
    return acc


def matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A B with a fixed order: entry (i, j) = ((a_i0·b_0j + a_i1·b_1j) + a_i2·b_2j) + ..., each operation rounded
    to the arrays' dtype, zeros included (no BLAS; the C's `fw_matmul` repeats it)."""
    products = a[:, :, None] * b[None, :, :]     # every a_ik·b_kj, rounded
    acc = products[:, 0, :]
    for k in range(1, products.shape[1]):
        acc = acc + products[:, k, :]            # left to right over k
    return acc


def lanes(values: np.ndarray, like) -> np.ndarray:
    """`values` (k,) shaped to broadcast against a lane value `like` (a scalar: unchanged; (L...): (k, L...)), so
    per-node constants meet per-node quantities of trajectories run side by side (see `matvec`)."""
    extra = np.ndim(like)
    return values.reshape(values.shape + (1,) * extra) if extra else values
