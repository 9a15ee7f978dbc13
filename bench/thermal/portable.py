"""Small dense linear algebra, exp and log that give the same bits on every x86-64 CPU.

Why: identification must write the same artifact on any machine. numpy's matmul and inv and scipy's expm,
solve_discrete_lyapunov, cholesky and svd go through OpenBLAS, whose kernels are chosen by CPU type (Haswell,
SkylakeX, Zen, Sandybridge, ... or OPENBLAS_CORETYPE) and sum in kernel-specific orders, with or without FMA;
numpy's float64 exp and log have AVX-512 loops whose last bits differ from the AVX2 ones, and glibc's exp has an
FMA variant. Those last-bit differences change the LM fit (it stops at its evaluation budget, not at a converged
optimum) and with it every Hammerstein coefficient at the 1e-3 level.

Everything here uses only +, -, *, / and sqrt (IEEE 754, correctly rounded) plus exact frexp/ldexp, in loops of a
fixed order that numba compiles without fastmath (no reassociation, no FMA contraction), so a result depends on
the inputs alone. The matrices are 4x4 to 16x16: plain loops are fast enough.

numba's on-disk cache of a caller (estimator._one_model inlines `exp`) is keyed to the caller's file only: after
changing this file, delete bench/thermal/__pycache__/*.nbi and *.nbc.
"""

from __future__ import annotations

import decimal
import math

import numba
import numpy as np

# exp: Tang's table method, exp(x) = 2**e · 2**(j/64) · exp(r) with |r| <= ln2/128, no division; the table is
# computed in decimal arithmetic (the same digits on any machine) and kept as a double and its remainder.
# Accurate to about 0.51 ulp.
_EXP_N = 64


def _exp_constants() -> tuple[np.ndarray, np.ndarray, float]:
    ctx = decimal.Context(prec=50)
    ln2 = ctx.ln(decimal.Decimal(2))
    values = [ctx.exp(ctx.divide(ctx.multiply(ln2, j), _EXP_N)) for j in range(_EXP_N)]
    hi = [float(v) for v in values]
    lo = [float(ctx.subtract(v, decimal.Decimal(h))) for v, h in zip(values, hi, strict=True)]
    return np.array(hi), np.array(lo), float(ctx.divide(_EXP_N, ln2))


EXP_TABLE_HI, EXP_TABLE_LO, N_OVER_LN2 = _exp_constants()
# ln 2 / 64 split so that k·hi is exact for |k| < 2**21 (fdlibm's ln2_hi has 21 trailing zero bits).
LN2_HI_N = 6.93147180369123816490e-01 / _EXP_N
LN2_LO_N = 1.90821492927058770002e-10 / _EXP_N
EXP_C = (0.5, 1.0 / 6.0, 1.0 / 24.0, 1.0 / 120.0, 1.0 / 720.0)  # Taylor: |r|**7/5040 < 1e-19
POW2 = np.array([math.ldexp(1.0, e) for e in range(-1022, 1024)])  # exact powers of two, normal range
EXP_OVERFLOW = 7.09782712893383973096e+02
EXP_UNDERFLOW = -7.45133219101941108420e+02
# log: fdlibm's (Sun, 1993) e_log.c: ln 2 split, and the minimax polynomial in s = f/(2+f); < 1 ulp.
LN2_HI = 6.93147180369123816490e-01
LN2_LO = 1.90821492927058770002e-10
LOG_LG = (6.666666666666735130e-01, 3.999999999940941908e-01, 2.857142874366239149e-01, 2.222219843214978396e-01,
          1.818357216161805012e-01, 1.531383769920937332e-01, 1.479819860511658591e-01)
SQRT_HALF = 0.70710678118654752440

# Padé(13, 13) coefficients and the 1-norm up to which it needs no scaling (Higham 2005, as scipy's expm).
PADE13 = (64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0, 129060195264000.0,
          10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0,
          1.0)
THETA13 = 5.371920351148152

_JIT = {"cache": True, "fastmath": False, "nogil": True}


@numba.njit(**_JIT)
def exp(x: float) -> float:
    """e**x."""
    if x != x:
        return x
    if x > EXP_OVERFLOW:
        return math.inf
    if x < EXP_UNDERFLOW:
        return 0.0
    k = math.floor(x * N_OVER_LN2 + 0.5)
    kd = float(k)
    r = (x - kd * LN2_HI_N) - kd * LN2_LO_N  # the first subtraction is exact
    j = k & (_EXP_N - 1)
    e = k >> 6  # floor(k / 64)
    p = r + r * r * (EXP_C[0] + r * (EXP_C[1] + r * (EXP_C[2] + r * (EXP_C[3] + r * EXP_C[4]))))
    t = EXP_TABLE_HI[j]
    y = t + (EXP_TABLE_LO[j] + t * p)
    if e > 1023:  # x near the overflow threshold: k = 65536
        return (2.0 * y) * POW2[e - 1 + 1022]
    if e >= -1022:
        return y * POW2[e + 1022]  # exact
    return math.ldexp(y, e)  # subnormal result: one rounding


# exp_into: `exp`'s normal path for |x| <= VECTOR_EXP_LIMIT, where it is the whole of `exp` (no overflow, underflow
# or subnormal branch is taken), written without branches so LLVM vectorizes it across a row of values (the table
# index and exponent from floor, exact on these small integers, instead of integer shifts); the rest by `exp`.
VECTOR_EXP_LIMIT = 700.0
_C0, _C1, _C2, _C3, _C4 = EXP_C


@numba.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def exp_into(x: np.ndarray, out: np.ndarray) -> None:
    """out[i] = exp(x[i]) for a 1-D row, the same bits as `exp`."""
    for i in range(x.shape[0]):
        v = x[i]
        v = v if v >= -VECTOR_EXP_LIMIT else -VECTOR_EXP_LIMIT    # NaN too: fixed below
        v = v if v <= VECTOR_EXP_LIMIT else VECTOR_EXP_LIMIT
        kd = np.floor(v * N_OVER_LN2 + 0.5)
        r = (v - kd * LN2_HI_N) - kd * LN2_LO_N
        ed = np.floor(kd * (1.0 / _EXP_N))          # k >> 6
        j = np.int32(kd - _EXP_N * ed)              # k & 63
        p = r + r * r * (_C0 + r * (_C1 + r * (_C2 + r * (_C3 + r * _C4))))
        t = EXP_TABLE_HI[j]
        out[i] = (t + (EXP_TABLE_LO[j] + t * p)) * POW2[np.int32(ed) + np.int32(1022)]
    for i in range(x.shape[0]):
        if not (-VECTOR_EXP_LIMIT <= x[i] <= VECTOR_EXP_LIMIT):
            out[i] = exp(x[i])


@numba.njit(**_JIT)
def log(x: float) -> float:
    """Natural logarithm (fdlibm's algorithm)."""
    if x != x or x < 0.0:
        return math.nan
    if x == 0.0:
        return -math.inf
    if x == math.inf:
        return x
    m, e = math.frexp(x)  # x = m·2**e, 0.5 <= m < 1
    if m < SQRT_HALF:
        m *= 2.0
        e -= 1
    f = m - 1.0  # exact: sqrt(1/2) <= m < sqrt(2)
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    r = (w * (LOG_LG[1] + w * (LOG_LG[3] + w * LOG_LG[5]))
         + z * (LOG_LG[0] + w * (LOG_LG[2] + w * (LOG_LG[4] + w * LOG_LG[6]))))
    half_f2 = 0.5 * f * f
    dk = float(e)
    return dk * LN2_HI - ((half_f2 - (s * (half_f2 + r) + dk * LN2_LO)) - f)


@numba.njit(**_JIT)
def _exp_flat(x: np.ndarray) -> np.ndarray:
    out = np.empty_like(x)
    for i in range(x.size):
        out[i] = exp(x[i])
    return out


@numba.njit(**_JIT)
def _log_flat(x: np.ndarray) -> np.ndarray:
    out = np.empty_like(x)
    for i in range(x.size):
        out[i] = log(x[i])
    return out


def dot(x: np.ndarray, y: np.ndarray) -> float:
    """Σ x·y of two float64 vectors, exactly rounded: the same sum on every CPU, unlike a BLAS dot (whose kernel,
    and so its summation order, depends on the CPU and OPENBLAS_CORETYPE). math.fsum(x * y) to the bit."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    return sum_of_products(x, y) if x.shape == y.shape else math.fsum(x * y)


@numba.njit(**_JIT)
def _fsum_of_products(x: np.ndarray, y: np.ndarray) -> tuple[float, bool]:
    # CPython's math.fsum (Shewchuk's partials, then its half-even correction) over the rounded products x[k]·y[k]:
    # both round the exact sum correctly, so the result is fsum's to the bit. (sum, False) when a product or a
    # partial sum is not finite: fsum's infinity, NaN and overflow rules are left to fsum itself
    partials = np.empty(32)      # the non-overlapping partials: a few for a fit's residuals
    n = 0
    for k in range(x.size):
        v = x[k] * y[k]
        if not math.isfinite(v):
            return 0.0, False
        i = 0
        for j in range(n):
            p = partials[j]
            if abs(v) < abs(p):
                v, p = p, v
            hi = v + p
            lo = p - (hi - v)
            if lo != 0.0:
                partials[i] = lo
                i += 1
            v = hi
        n = i
        if not math.isfinite(v):
            return 0.0, False
        if v != 0.0:
            if n == partials.size:       # wide-ranging summands (fsum grows its list likewise)
                grown = np.empty(2 * n)
                grown[:n] = partials[:n]
                partials = grown
            partials[n] = v
            n += 1
    hi = 0.0
    if n > 0:
        n -= 1
        hi = partials[n]
        lo = 0.0
        while n > 0:
            v = hi
            n -= 1
            p = partials[n]
            hi = v + p
            lo = p - (hi - v)
            if lo != 0.0:
                break
        if n > 0 and ((lo < 0.0 and partials[n - 1] < 0.0) or (lo > 0.0 and partials[n - 1] > 0.0)):
            p = lo * 2.0
            v = hi + p
            if p == v - hi:
                hi = v
    return hi, True


def sum_of_products(x: np.ndarray, y: np.ndarray) -> float:
    """math.fsum(x * y) of two finite float64 vectors of one length, to the bit, compiled (no temporary, no Python
    float per element: a fit's cross-validation sums 400 000 squared residuals per trial step)."""
    x, y = kernel_array(x).ravel(), kernel_array(y).ravel()
    total, finite = _fsum_of_products(x, y)
    return total if finite else math.fsum(x * y)


@numba.njit(**_JIT)
def _transposed_matvec(rows: np.ndarray, r: np.ndarray) -> np.ndarray:
    # out[i] = Σ_k rows[k, i]·r[k], each summed over k in ascending order from 0.0 as _matmul sums aᵀ·r: the same
    # bits; the i's side by side (contiguous in rows) so LLVM vectorizes across them, not along a sum
    out = np.zeros(rows.shape[1])
    for k in range(rows.shape[0]):
        rk = r[k]
        for i in range(rows.shape[1]):
            out[i] += rows[k, i] * rk
    return out


def transposed_matvec(rows: np.ndarray, r: np.ndarray) -> np.ndarray:
    """rowsᵀ·r for a tall (N, n) `rows` and an N-vector `r`: `matmul(rows.T, r[:, None])[:, 0]` to the bit."""
    return _transposed_matvec(kernel_array(rows), kernel_array(r).ravel())


def exp_array(x) -> np.ndarray:
    """Element-wise exp of a float64 array (any shape)."""
    x = kernel_array(x)
    return _exp_flat(x.ravel()).reshape(x.shape)


def log_array(x) -> np.ndarray:
    """Element-wise natural logarithm of a float64 array (any shape)."""
    x = kernel_array(x)
    return _log_flat(x.ravel()).reshape(x.shape)


@numba.njit(**_JIT)
def _matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    # each out[i, j] is summed over k in ascending order from 0.0, as in the plain i-j-k loop; the k-j order only
    # runs a row of them side by side (contiguous in b and out, which LLVM vectorizes: a Gram matrix of 36 columns
    # over 400 000 rows in a fit's cross-validation)
    out = np.zeros((a.shape[0], b.shape[1]))
    for i in range(a.shape[0]):
        for k in range(a.shape[1]):
            aik = a[i, k]
            for j in range(b.shape[1]):
                out[i, j] += aik * b[k, j]
    return out


@numba.njit(**_JIT)
def _blended_matvec(mats: np.ndarray, which: np.ndarray, weights: np.ndarray, z: np.ndarray) -> np.ndarray:
    out = np.zeros(mats.shape[1])
    for c in range(which.shape[0]):
        m, w = mats[which[c]], weights[c]
        for i in range(m.shape[0]):
            acc = 0.0
            for j in range(m.shape[1]):
                acc += m[i, j] * z[j]
            out[i] += w * acc
    return out


def blended_matvec(mats: np.ndarray, which: np.ndarray, weights: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Σ_c weights[c] · (mats[which[c]] @ z), each product summed over j in ascending order and the blend over c in
    order: an interpolation between precomputed matrices (a plant's exact steps at grid corners). The arrays must
    be float64 C-contiguous (mats, weights, z) and integer (which): a plant step calls this once per step and
    converts nothing."""
    return _blended_matvec(mats, which, weights, z)


@numba.njit(**_JIT)
def _solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x = b by Gaussian elimination with partial pivoting (b: n x m)."""
    n = a.shape[0]
    lu = a.copy()
    x = b.copy()
    for k in range(n):
        pivot, big = k, abs(lu[k, k])
        for i in range(k + 1, n):
            if abs(lu[i, k]) > big:
                pivot, big = i, abs(lu[i, k])
        if not big > 0.0:
            raise np.linalg.LinAlgError("singular matrix")
        if pivot != k:
            for j in range(n):
                lu[k, j], lu[pivot, j] = lu[pivot, j], lu[k, j]
            for j in range(x.shape[1]):
                x[k, j], x[pivot, j] = x[pivot, j], x[k, j]
        for i in range(k + 1, n):
            f = lu[i, k] / lu[k, k]
            for j in range(k + 1, n):
                lu[i, j] -= f * lu[k, j]
            for j in range(x.shape[1]):
                x[i, j] -= f * x[k, j]
    for i in range(n - 1, -1, -1):
        for j in range(x.shape[1]):
            acc = x[i, j]
            for k in range(i + 1, n):
                acc -= lu[i, k] * x[k, j]
            x[i, j] = acc / lu[i, i]
    return x


@numba.njit(**_JIT)
def _expm(a: np.ndarray) -> np.ndarray:
    """Matrix exponential: scaling and squaring with the Padé(13, 13) approximant (Higham 2005)."""
    n = a.shape[0]
    norm = 0.0
    for j in range(n):
        col = 0.0
        for i in range(n):
            col += abs(a[i, j])
        norm = max(norm, col)
    squarings = 0
    if norm > THETA13:
        m, e = math.frexp(norm / THETA13)
        squarings = e if m > 0.5 else e - 1  # ceil(log2(norm / THETA13)), exactly
    a = a * math.ldexp(1.0, -squarings)
    ident = np.eye(n)
    b = PADE13
    a2 = _matmul(a, a)
    a4 = _matmul(a2, a2)
    a6 = _matmul(a4, a2)
    u = _matmul(a, _matmul(a6, b[13] * a6 + b[11] * a4 + b[9] * a2)
                + b[7] * a6 + b[5] * a4 + b[3] * a2 + b[1] * ident)
    v = _matmul(a6, b[12] * a6 + b[10] * a4 + b[8] * a2) + b[6] * a6 + b[4] * a4 + b[2] * a2 + b[0] * ident
    r = _solve(v - u, v + u)
    for _ in range(squarings):
        r = _matmul(r, r)
    return r


@numba.njit(**_JIT)
def _expm_batch(a: np.ndarray) -> np.ndarray:
    out = np.empty_like(a)
    for p in range(a.shape[0]):
        out[p] = _expm(a[p])
    return out


@numba.njit(**_JIT)
def _inv_batch(a: np.ndarray) -> np.ndarray:
    out = np.empty_like(a)
    ident = np.eye(a.shape[1])
    for p in range(a.shape[0]):
        out[p] = _solve(a[p], ident)
    return out


@numba.njit(**_JIT)
def _cholesky(a: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor (reads the lower triangle)."""
    n = a.shape[0]
    low = np.zeros((n, n))
    for j in range(n):
        acc = a[j, j]
        for k in range(j):
            acc -= low[j, k] * low[j, k]
        if not acc > 0.0:
            raise np.linalg.LinAlgError("matrix is not positive definite")
        low[j, j] = math.sqrt(acc)
        for i in range(j + 1, n):
            acc = a[i, j]
            for k in range(j):
                acc -= low[i, k] * low[j, k]
            low[i, j] = acc / low[j, j]
    return low


@numba.njit(**_JIT)
def _svd(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Thin SVD a = U diag(s) V^T (rows >= columns) by one-sided Jacobi (Hestenes), s descending."""
    rows, n = a.shape
    w = a.copy()
    v = np.eye(n)
    for _ in range(100):
        rotated = False
        for p in range(n - 1):
            for q in range(p + 1, n):
                alpha, beta, gamma = 0.0, 0.0, 0.0
                for i in range(rows):
                    alpha += w[i, p] * w[i, p]
                    beta += w[i, q] * w[i, q]
                    gamma += w[i, p] * w[i, q]
                if abs(gamma) <= 1e-15 * math.sqrt(alpha * beta):
                    continue
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                if abs(zeta) > 1e150:  # 1 + zeta² would overflow; t -> 1/(2 zeta)
                    t = 0.5 / zeta
                else:
                    t = (1.0 if zeta >= 0.0 else -1.0) / (abs(zeta) + math.sqrt(1.0 + zeta * zeta))
                c = 1.0 / math.sqrt(1.0 + t * t)
                s = c * t
                for i in range(rows):
                    wp, wq = w[i, p], w[i, q]
                    w[i, p] = c * wp - s * wq
                    w[i, q] = s * wp + c * wq
                for i in range(n):
                    vp, vq = v[i, p], v[i, q]
                    v[i, p] = c * vp - s * vq
                    v[i, q] = s * vp + c * vq
        if not rotated:
            break
    norms = np.zeros(n)
    for j in range(n):
        acc = 0.0
        for i in range(rows):
            acc += w[i, j] * w[i, j]
        norms[j] = math.sqrt(acc)
    order = np.argsort(-norms, kind="mergesort")
    u = np.empty((rows, n))
    sv = np.empty(n)
    vt = np.empty((n, n))
    for jj in range(n):
        j = order[jj]
        sv[jj] = norms[j]
        for i in range(rows):
            u[i, jj] = w[i, j] / norms[j] if norms[j] > 0.0 else 0.0
        for i in range(n):
            vt[jj, i] = v[i, j]
    return u, sv, vt


def kernel_array(a) -> np.ndarray:
    """`a` as every kernel here takes its arrays: float64, C-contiguous and writable. numba compiles a kernel for
    each combination of argument types it meets, and a read-only array (an artifact's decoded matrix, a broadcast)
    or a strided view is a type of its own: without this, one more compile of the kernel per combination, and one
    that `bench.thermal.kernels` cannot foresee. The copy this may take is of a small matrix."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    return a if a.flags.writeable else a.copy()


def matmul(*matrices) -> np.ndarray:
    """The product of 2-D matrices, left to right (like a @ b @ c)."""
    out = kernel_array(matrices[0])
    for m in matrices[1:]:
        out = _matmul(out, kernel_array(m))
    return out


def solve(a, b) -> np.ndarray:
    """x with a x = b; b a vector or a matrix."""
    b = kernel_array(b)
    x = _solve(kernel_array(a), b.reshape(b.shape[0], -1))
    return x.reshape(b.shape)


def inv(a) -> np.ndarray:
    """Inverse of one matrix (n, n) or of a stack (..., n, n)."""
    a = kernel_array(a)
    if a.ndim == 2:
        return _solve(a, np.eye(a.shape[0]))
    return _inv_batch(a.reshape(-1, *a.shape[-2:])).reshape(a.shape)


def expm(a) -> np.ndarray:
    """Matrix exponential of one matrix (n, n) or of a stack (..., n, n)."""
    a = kernel_array(a)
    if a.ndim == 2:
        return _expm(a)
    return _expm_batch(a.reshape(-1, *a.shape[-2:])).reshape(a.shape)


def cholesky_lower(a) -> np.ndarray:
    return _cholesky(kernel_array(a))


def svd(a) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(U, s, V^T) of a square or tall matrix, singular values descending."""
    return _svd(kernel_array(a))


def singular_values(a) -> np.ndarray:
    return _svd(kernel_array(a))[1]


def solve_discrete_lyapunov(a, q) -> np.ndarray:
    """X with A X A^T - X + Q = 0, by the Kronecker form (I - A⊗A) vec X = vec Q (scipy's 'direct' method)."""
    a, q = kernel_array(a), kernel_array(q)
    n = a.shape[0]
    lhs = np.eye(n * n) - np.kron(a, a)  # np.kron multiplies element by element: exact products, no BLAS
    return _solve(lhs, q.reshape(n * n, 1)).reshape(n, n)
