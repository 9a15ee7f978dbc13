"""The linear algebra of a Levenberg-Marquardt step on a tall Jacobian, in loops of a fixed order.

Why: MINPACK's lmder (scipy's leastsq) factors the whole m x n Jacobian column by column, one sequential sum per
pair of columns over all m rows, and holds the GIL while it does: on the Hammerstein fit's 400 000 x 36 Jacobian
that is 1.2-1.5 s per Jacobian (one core; the polish's two starts cannot overlap it). Here the Jacobian, with the
residuals as an extra column, is reduced BLOCK rows at a time onto an n x (n+1) triangle (Householder reflections of
the triangle stacked on each block), in cache, with sums kept in LANES fixed partial sums, and without the GIL.
What lmder needs of the factorization is only R, the column pivots and the first n entries of Qᵀf; the pivoting
is done afterwards on the small triangle (MINPACK's qrfac on n x n), the same factorization in exact arithmetic.

Every sum runs in an order fixed by the code, not by the CPU: the partial sums are LANES independent chains that
numba may put into vector registers of any width without changing a bit (no fastmath: no reassociation, no FMA
contraction). So the result depends on the inputs alone, as everything in bench.thermal.portable does.
lm_parameter and _solve_damped follow MINPACK's lmpar and qrsolv (Moré 1978) step for step.
"""

from __future__ import annotations

import numba
import numpy as np

_JIT = {"cache": True, "fastmath": False, "nogil": True}

BLOCK = 256      # rows of the Jacobian reflected onto the triangle at a time: (n + 1) x BLOCK doubles stay in L2
LANES = 8        # partial sums of a long dot product; fixed, so the bits do not depend on the vector width
_DWARF = np.finfo(np.float64).tiny
_EPSMCH = np.finfo(np.float64).eps


@numba.njit(**_JIT)
def _lane_dot(a: np.ndarray, b: np.ndarray, count: int) -> float:
    """Σ a[i]·b[i] for i < count: LANES chains over i mod LANES, then the chains and the tail in order."""
    acc = np.zeros(LANES)
    full = count - count % LANES
    for i in range(0, full, LANES):
        for lane in range(LANES):
            acc[lane] += a[i + lane] * b[i + lane]
    total = 0.0
    for lane in range(LANES):
        total += acc[lane]
    for i in range(full, count):
        total += a[i] * b[i]
    return total


@numba.njit(**_JIT)
def norm(v: np.ndarray) -> float:
    """The Euclidean norm of v, summed in the fixed lane order."""
    return np.sqrt(_lane_dot(v, v, len(v)))


@numba.njit(**_JIT)
def _apply(triangle: np.ndarray, j: int, first: int, block: np.ndarray, v: np.ndarray, v0: float, beta: float,
           rows: int) -> None:
    """Reflector j (vector (v0, v), 2/|v|² = beta) applied to the columns k ≥ `first` of `triangle`: each one's
    entry in row j and its block rows block[k]."""
    for k in range(first, triangle.shape[1]):
        column = block[k]
        w = beta * (v0 * triangle[j, k] + _lane_dot(v, column, rows))
        triangle[j, k] -= v0 * w
        for i in range(rows):
            column[i] -= w * v[i]


@numba.njit(**_JIT)
def _reflect_own(triangle: np.ndarray, block: np.ndarray, rows: int, first: int, v0s: np.ndarray,
                 betas: np.ndarray, made: np.ndarray) -> None:
    """The reflections of `triangle`'s rows first … n−1 in place, their columns local: row j's diagonal entry is
    triangle[j, j − first], its block column block[j − first]; each reflector made from them (Householder, on the
    diagonal entry and the block column; the entries below the diagonal are zero) and applied to the columns after
    it. Reflector c's v0, beta and whether it was made go to v0s[c], betas[c], made[c] (its vector stays in
    block[c])."""
    for j in range(first, triangle.shape[0]):
        c = j - first
        v = block[c]
        rjj = triangle[j, c]
        squares = rjj * rjj + _lane_dot(v, v, rows)
        made[c] = squares != 0.0
        if squares == 0.0:
            continue
        size = np.sqrt(squares)
        alpha = -size if rjj >= 0.0 else size
        v0 = rjj - alpha
        beta = 1.0 / (size * (size + abs(rjj)))      # 2 / |v|², v = (v0, block[c])
        v0s[c], betas[c] = v0, beta
        _apply(triangle, j, c + 1, block, v, v0, beta, rows)
        triangle[j, c] = alpha


@numba.njit(**_JIT)
def triangle(jacobian_rows: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    """(n, n+1) [R | Qᵀr]: R upper triangular with RᵀR = JᵀJ and Qᵀr its projection of the residuals (RᵀQᵀr =
    Jᵀr), from the Jacobian transposed (n, m) (a row per parameter) and the residuals (m,). Neither is changed."""
    n, m = jacobian_rows.shape
    out = np.zeros((n, n + 1))
    block = np.empty((n + 1, BLOCK))
    v0s, betas, made = np.empty(n), np.empty(n), np.empty(n, dtype=np.bool_)    # kept by nobody here
    for start in range(0, m, BLOCK):
        rows = min(BLOCK, m - start)
        for c in range(n):
            block[c, :rows] = jacobian_rows[c, start:start + rows]
        block[n, :rows] = residuals[start:start + rows]
        _reflect_own(out, block, rows, 0, v0s, betas, made)
    return out


# The same reduction on two cores, to the bit: the columns split at `split`, the left ones' reflections made by one
# thread a chunk of blocks ahead, the right ones (and the residuals) reflected by the other with the left's
# reflectors as they were made, then their own. Every column sees the same reflections in the same order and every
# entry the same operations as in `triangle`, so the triangle is `triangle`'s bit for bit; only who computes which
# column changes. A thread whose numba kernels run on one thread (a polish start's, bench.model.polish) keeps the
# one-thread reduction.
CHUNK_BLOCKS = 32        # blocks handed from the left thread to the right at a time (8 192 rows)
SPLIT_MIN_ROWS = 4 * CHUNK_BLOCKS * BLOCK    # below this the hand-over costs more than the second core saves
SPLIT_MIN_COLUMNS = 8


def split_column(columns: int) -> int:
    """Where the work of reflecting `columns` columns (the residuals included) halves: the left thread's reflectors
    touch only its own columns (about split²/2 updates a block), the right thread's columns take every reflector."""
    return max(1, min(columns - 1, round(columns / np.sqrt(2.0))))


@numba.njit(**_JIT)
def _left_chunk(jacobian_rows: np.ndarray, start: int, stop: int, triangle: np.ndarray, vectors: np.ndarray,
                v0s: np.ndarray, betas: np.ndarray, made: np.ndarray) -> None:
    """The left columns of the blocks from row `start` to `stop`: block b's reflectors into vectors[b], v0s[b], …"""
    split = triangle.shape[0]
    for b, first in enumerate(range(start, stop, BLOCK)):
        rows = min(BLOCK, stop - first)
        block = vectors[b]
        for c in range(split):
            block[c, :rows] = jacobian_rows[c, first:first + rows]
        _reflect_own(triangle, block, rows, 0, v0s[b], betas[b], made[b])


@numba.njit(**_JIT)
def _right_chunk(jacobian_rows: np.ndarray, residuals: np.ndarray, start: int, stop: int, triangle: np.ndarray,
                 block: np.ndarray, vectors: np.ndarray, v0s: np.ndarray, betas: np.ndarray, made: np.ndarray) -> None:
    """The right columns and the residuals (`triangle` (n, n+1−split), `block` (n+1−split, BLOCK)) of the blocks
    from `start` to `stop`: the left thread's reflectors of each block applied in their order, then the right
    columns' own."""
    n = jacobian_rows.shape[0]
    split = vectors.shape[1]
    own_v0s, own_betas, own_made = np.empty(n - split), np.empty(n - split), np.empty(n - split, dtype=np.bool_)
    for b, first in enumerate(range(start, stop, BLOCK)):
        rows = min(BLOCK, stop - first)
        for c in range(split, n):
            block[c - split, :rows] = jacobian_rows[c, first:first + rows]
        block[n - split, :rows] = residuals[first:first + rows]
        left, left_v0s, left_betas, left_made = vectors[b], v0s[b], betas[b], made[b]
        for j in range(split):
            if left_made[j]:
                _apply(triangle, j, 0, block, left[j], left_v0s[j], left_betas[j], rows)
        _reflect_own(triangle, block, rows, split, own_v0s, own_betas, own_made)


def reduce(jacobian_rows: np.ndarray, residuals: np.ndarray, two_threads: bool | None = None) -> np.ndarray:
    """`triangle(jacobian_rows, residuals)`, bit for bit, on two threads when the calling thread's numba kernels may
    use two or more and the Jacobian is large enough to gain by it (the Hammerstein fit's and the freeze's LM);
    `two_threads` True or False decides instead (the kernels' warm-up, the tests)."""
    n, m = jacobian_rows.shape
    if two_threads is None:
        two_threads = m >= SPLIT_MIN_ROWS and n >= SPLIT_MIN_COLUMNS and numba.get_num_threads() >= 2
    if not two_threads or n < 1:
        return triangle(jacobian_rows, residuals)
    import threading

    split = split_column(n + 1)
    left = np.zeros((split, split))
    right = np.zeros((n, n + 1 - split))
    # two sets of hand-over buffers: the left thread fills one while the right one reads the other
    vectors = np.empty((2, CHUNK_BLOCKS, split, BLOCK))
    v0s, betas = np.zeros((2, CHUNK_BLOCKS, split)), np.zeros((2, CHUNK_BLOCKS, split))
    made = np.zeros((2, CHUNK_BLOCKS, split), dtype=np.bool_)
    chunks = list(range(0, m, CHUNK_BLOCKS * BLOCK))
    free, ready = threading.Semaphore(2), threading.Semaphore(0)
    failed: list[BaseException] = []

    def lead() -> None:
        try:
            for c, start in enumerate(chunks):
                free.acquire()
                if given_up:
                    return
                _left_chunk(jacobian_rows, start, min(m, start + CHUNK_BLOCKS * BLOCK), left, vectors[c % 2],
                            v0s[c % 2], betas[c % 2], made[c % 2])
                ready.release()
        except BaseException as error:     # re-raised by the calling thread
            failed.append(error)
            ready.release()

    given_up: list[bool] = []
    leader = threading.Thread(target=lead, name="qr-left", daemon=True)
    leader.start()
    block = np.empty((n + 1 - split, BLOCK))
    try:
        for c, start in enumerate(chunks):
            ready.acquire()
            if failed:
                break
            _right_chunk(jacobian_rows, residuals, start, min(m, start + CHUNK_BLOCKS * BLOCK), right, block,
                         vectors[c % 2], v0s[c % 2], betas[c % 2], made[c % 2])
            free.release()
    except BaseException:
        given_up.append(True)    # a stop signal in this thread: the leader ends at its next chunk
        free.release()
        raise
    leader.join()
    if failed:
        raise failed[0]
    out = np.zeros((n, n + 1))
    out[:split, :split] = left
    out[:, split:] = right
    return out


@numba.njit(**_JIT)
def _column_norm(a: np.ndarray, column: int, first: int) -> float:
    """|a[first:, column]|, summed in row order (qrfac's column norms)."""
    total = 0.0
    for i in range(first, a.shape[0]):
        total += a[i, column] * a[i, column]
    return np.sqrt(total)


@numba.njit(**_JIT)
def pivoted(reduced: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """MINPACK's qrfac with column pivoting, then its Qᵀf, on the small [R | Qᵀr] of `triangle`: (r, ipvt, qtf,
    acnorm) as lmder holds them after its own factorization of J: r's upper triangle the pivoted factor with its
    diagonal, ipvt the permutation (J P = Q r), qtf the first n entries of Qᵀ f, acnorm the norms of J's columns."""
    n = reduced.shape[0]
    a = reduced[:, :n].copy()
    wa4 = reduced[:, n].copy()
    acnorm = np.empty(n)
    rdiag = np.empty(n)
    wa = np.empty(n)
    ipvt = np.arange(n)
    for j in range(n):
        acnorm[j] = _column_norm(a, j, 0)
        rdiag[j] = acnorm[j]
        wa[j] = rdiag[j]
    for j in range(n):
        kmax = j
        for k in range(j, n):
            if rdiag[k] > rdiag[kmax]:
                kmax = k
        if kmax != j:
            for i in range(n):
                a[i, j], a[i, kmax] = a[i, kmax], a[i, j]
            rdiag[kmax] = rdiag[j]
            wa[kmax] = wa[j]
            ipvt[j], ipvt[kmax] = ipvt[kmax], ipvt[j]
        ajnorm = _column_norm(a, j, j)
        if ajnorm != 0.0:
            if a[j, j] < 0.0:
                ajnorm = -ajnorm
            for i in range(j, n):
                a[i, j] /= ajnorm
            a[j, j] += 1.0
            for k in range(j + 1, n):
                total = 0.0
                for i in range(j, n):
                    total += a[i, j] * a[i, k]
                temp = total / a[j, j]
                for i in range(j, n):
                    a[i, k] -= temp * a[i, j]
                if rdiag[k] != 0.0:
                    temp = a[j, k] / rdiag[k]
                    rdiag[k] *= np.sqrt(max(0.0, 1.0 - temp * temp))
                    if 0.05 * (rdiag[k] / wa[k]) ** 2 <= _EPSMCH:
                        rdiag[k] = _column_norm(a, k, j + 1)
                        wa[k] = rdiag[k]
        rdiag[j] = -ajnorm
    qtf = np.empty(n)
    for j in range(n):     # lmder's Qᵀf with the Householder vectors qrfac left below the diagonal
        if a[j, j] != 0.0:
            total = 0.0
            for i in range(j, n):
                total += a[i, j] * wa4[i]
            temp = -total / a[j, j]
            for i in range(j, n):
                wa4[i] += a[i, j] * temp
        a[j, j] = rdiag[j]
        qtf[j] = wa4[j]
    return a, ipvt, qtf, acnorm


@numba.njit(**_JIT)
def _small_norm(v: np.ndarray) -> float:
    total = 0.0
    for x in v:
        total += x * x
    return np.sqrt(total)


@numba.njit(**_JIT)
def _solve_damped(r: np.ndarray, ipvt: np.ndarray, diag: np.ndarray, qtb: np.ndarray, x: np.ndarray,
                  sdiag: np.ndarray) -> None:
    """MINPACK's qrsolv: x solving J x = b, D x = 0 in the least-squares sense, from J's pivoted factor r (upper
    triangle, kept) and Qᵀb; the factor S of the damped system goes to r's strict lower triangle and sdiag."""
    n = r.shape[0]
    wa = np.empty(n)
    for j in range(n):
        for i in range(j, n):
            r[i, j] = r[j, i]
        x[j] = r[j, j]
        wa[j] = qtb[j]
    for j in range(n):
        pj = ipvt[j]
        if diag[pj] != 0.0:
            for k in range(j, n):
                sdiag[k] = 0.0
            sdiag[j] = diag[pj]
            qtbpj = 0.0
            for k in range(j, n):     # Givens rotations eliminate the row of D
                if sdiag[k] == 0.0:
                    continue
                if abs(r[k, k]) < abs(sdiag[k]):
                    cotan = r[k, k] / sdiag[k]
                    sin = 0.5 / np.sqrt(0.25 + 0.25 * (cotan * cotan))
                    cos = sin * cotan
                else:
                    tan = sdiag[k] / r[k, k]
                    cos = 0.5 / np.sqrt(0.25 + 0.25 * (tan * tan))
                    sin = cos * tan
                r[k, k] = cos * r[k, k] + sin * sdiag[k]
                temp = cos * wa[k] + sin * qtbpj
                qtbpj = -sin * wa[k] + cos * qtbpj
                wa[k] = temp
                for i in range(k + 1, n):
                    temp = cos * r[i, k] + sin * sdiag[i]
                    sdiag[i] = -sin * r[i, k] + cos * sdiag[i]
                    r[i, k] = temp
        sdiag[j] = r[j, j]
        r[j, j] = x[j]
    nsing = n
    for j in range(n):
        if sdiag[j] == 0.0 and nsing == n:
            nsing = j
        if nsing < n:
            wa[j] = 0.0
    for k in range(nsing):
        j = nsing - k - 1
        total = 0.0
        for i in range(j + 1, nsing):
            total += r[i, j] * wa[i]
        wa[j] = (wa[j] - total) / sdiag[j]
    for j in range(n):
        x[ipvt[j]] = wa[j]


@numba.njit(**_JIT)
def lm_parameter(r: np.ndarray, ipvt: np.ndarray, diag: np.ndarray, qtb: np.ndarray, delta: float,
                 par: float) -> tuple[float, np.ndarray]:
    """MINPACK's lmpar: (par, x) with x the step solving J x = b, √par D x = 0 in the least-squares sense and
    |D x| within 10 % of `delta` (or par = 0 and |D x| below it), from J's pivoted factor (r, ipvt) and Qᵀb; `par`
    the previous value as the first guess. r's strict lower triangle is overwritten."""
    n = r.shape[0]
    x = np.empty(n)
    sdiag = np.empty(n)
    wa1 = np.empty(n)
    wa2 = np.empty(n)
    nsing = n
    for j in range(n):     # the Gauss-Newton direction; a least-squares one if r is singular
        wa1[j] = qtb[j]
        if r[j, j] == 0.0 and nsing == n:
            nsing = j
        if nsing < n:
            wa1[j] = 0.0
    for k in range(nsing):
        j = nsing - k - 1
        wa1[j] /= r[j, j]
        temp = wa1[j]
        for i in range(j):
            wa1[i] -= r[i, j] * temp
    for j in range(n):
        x[ipvt[j]] = wa1[j]
    iteration = 0
    for j in range(n):
        wa2[j] = diag[j] * x[j]
    dxnorm = _small_norm(wa2)
    fp = dxnorm - delta
    if fp <= 0.1 * delta:
        return 0.0, x
    parl = 0.0     # a lower bound for par: from the Newton step, unless r is singular
    if nsing >= n:
        for j in range(n):
            pj = ipvt[j]
            wa1[j] = diag[pj] * (wa2[pj] / dxnorm)
        for j in range(n):
            total = 0.0
            for i in range(j):
                total += r[i, j] * wa1[i]
            wa1[j] = (wa1[j] - total) / r[j, j]
        temp = _small_norm(wa1)
        parl = fp / delta / temp / temp
    for j in range(n):     # an upper bound: the gradient's norm over delta
        total = 0.0
        for i in range(j + 1):
            total += r[i, j] * qtb[i]
        wa1[j] = total / diag[ipvt[j]]
    gnorm = _small_norm(wa1)
    paru = gnorm / delta
    if paru == 0.0:
        paru = _DWARF / min(delta, 0.1)
    par = min(max(par, parl), paru)
    if par == 0.0:
        par = gnorm / dxnorm
    while True:
        iteration += 1
        if par == 0.0:
            par = max(_DWARF, 0.001 * paru)
        temp = np.sqrt(par)
        for j in range(n):
            wa1[j] = temp * diag[j]
        _solve_damped(r, ipvt, wa1, qtb, x, sdiag)
        for j in range(n):
            wa2[j] = diag[j] * x[j]
        dxnorm = _small_norm(wa2)
        temp = fp
        fp = dxnorm - delta
        if abs(fp) <= 0.1 * delta or (parl == 0.0 and fp <= temp and temp < 0.0) or iteration == 10:
            break
        for j in range(n):     # the Newton correction
            pj = ipvt[j]
            wa1[j] = diag[pj] * (wa2[pj] / dxnorm)
        for j in range(n):
            wa1[j] /= sdiag[j]
            temp = wa1[j]
            for i in range(j + 1, n):
                wa1[i] -= r[i, j] * temp
        temp = _small_norm(wa1)
        parc = fp / delta / temp / temp
        if fp > 0.0:
            parl = max(parl, par)
        elif fp < 0.0:
            paru = min(paru, par)
        par = max(parl, par + parc)
    return par, x


@numba.njit(**_JIT)
def predicted(r: np.ndarray, ipvt: np.ndarray, step: np.ndarray) -> float:
    """|J step| from J's pivoted factor: |r Pᵀ step| (lmder's predicted reduction)."""
    n = r.shape[0]
    wa3 = np.zeros(n)
    for j in range(n):
        temp = step[ipvt[j]]
        for i in range(j + 1):
            wa3[i] += r[i, j] * temp
    return _small_norm(wa3)


@numba.njit(**_JIT)
def gradient_norm(r: np.ndarray, ipvt: np.ndarray, qtf: np.ndarray, acnorm: np.ndarray, fnorm: float) -> float:
    """lmder's scaled gradient norm: the largest |cosine| between the residuals and a column of J."""
    n = r.shape[0]
    gnorm = 0.0
    if fnorm == 0.0:
        return gnorm
    for j in range(n):
        pj = ipvt[j]
        if acnorm[pj] != 0.0:
            total = 0.0
            for i in range(j + 1):
                total += r[i, j] * (qtf[i] / fnorm)
            gnorm = max(gnorm, abs(total / acnorm[pj]))
    return gnorm
