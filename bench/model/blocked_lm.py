"""Moré's Levenberg-Marquardt, MINPACK's lmder step for step, on the blocked factorization of
bench.thermal.least_squares: the same iteration as bench.model.minpack, with the Jacobian reduced in cache and
without the GIL (see that module for why), so its results differ from MINPACK's in the last bits of each step."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.optimize import OptimizeResult

from bench.model.minpack import LM_CONVERGED, LM_STEP_BOUND, LM_TOLERANCE
from bench.thermal import blocked_qr as kernels

_EPSMCH = np.finfo(np.float64).eps

# MINPACK's info codes and what they mean
MESSAGES = {
    1: "the actual and predicted relative reductions of the sum of squares are at most ftol",
    2: "the relative error between two consecutive iterates is at most xtol",
    3: "the relative reductions are at most ftol and the relative error of the iterates at most xtol",
    4: "the residuals are orthogonal to the Jacobian's columns within gtol",
    5: "the number of evaluations reached its limit",
    6: "ftol is too small: no further reduction of the sum of squares is possible",
    7: "xtol is too small: no further improvement of the approximate solution is possible",
    8: "gtol is too small: the residuals are orthogonal to the Jacobian's columns to machine precision",
}


def levenberg_marquardt(fun: Callable[[np.ndarray], np.ndarray], jac_rows: Callable[[np.ndarray], np.ndarray],
                        x0: np.ndarray, max_nfev: int) -> OptimizeResult:
    """Minimize |fun(x)|² from x0 with at most `max_nfev` evaluations of fun; `jac_rows(x)` is the Jacobian
    transposed, (parameters, residuals). Tolerances, scaling (the Jacobian's column norms) and step bound are
    MINPACK's as bench.model.minpack uses them; the result as that module gives it."""
    x = np.array(x0, dtype=float)
    fvec = np.asarray(fun(x), dtype=float)
    nfev, njev, info = 1, 0, 0
    fnorm = kernels.norm(fvec)
    par, iteration, delta, xnorm = 0.0, 1, 0.0, 0.0
    diag = np.empty(0)
    while info == 0:
        reduced = kernels.reduce(np.ascontiguousarray(jac_rows(x)), fvec)
        njev += 1
        r, ipvt, qtf, acnorm = kernels.pivoted(reduced)
        if iteration == 1:
            diag = np.where(acnorm == 0.0, 1.0, acnorm)
            xnorm = kernels.norm(diag * x)
            delta = LM_STEP_BOUND * xnorm if xnorm != 0.0 else LM_STEP_BOUND
        gnorm = kernels.gradient_norm(r, ipvt, qtf, acnorm, fnorm)
        if gnorm <= LM_TOLERANCE:
            info = 4
            break
        diag = np.maximum(diag, acnorm)
        while True:
            par, step = kernels.lm_parameter(r, ipvt, diag, qtf, delta, par)
            step = -step
            trial = x + step
            pnorm = kernels.norm(diag * step)
            if iteration == 1:
                delta = min(delta, pnorm)
            ftrial = np.asarray(fun(trial), dtype=float)
            nfev += 1
            fnorm1 = kernels.norm(ftrial)
            actred = -1.0
            if 0.1 * fnorm1 < fnorm:
                actred = 1.0 - (fnorm1 / fnorm) ** 2
            temp1 = kernels.predicted(r, ipvt, step) / fnorm
            temp2 = np.sqrt(par) * pnorm / fnorm
            prered = temp1 * temp1 + temp2 * temp2 / 0.5
            dirder = -(temp1 * temp1 + temp2 * temp2)
            ratio = actred / prered if prered != 0.0 else 0.0
            if ratio <= 0.25:     # a poor step: shrink the trust region
                temp = 0.5 if actred >= 0.0 else 0.5 * dirder / (dirder + 0.5 * actred)
                if 0.1 * fnorm1 >= fnorm or temp < 0.1:
                    temp = 0.1
                delta = temp * min(delta, pnorm / 0.1)
                par /= temp
            elif par == 0.0 or ratio >= 0.75:
                delta = pnorm / 0.5
                par *= 0.5
            if ratio >= 1e-4:     # a successful step
                x, fvec, fnorm = trial, ftrial, fnorm1
                xnorm = kernels.norm(diag * x)
                iteration += 1
            info = _converged(actred, prered, ratio, delta, xnorm)
            if info == 0:
                info = _stuck(nfev, max_nfev, actred, prered, ratio, delta, xnorm, gnorm)
            if info != 0 or ratio >= 1e-4:
                break
    return OptimizeResult(x=x, fun=fvec, nfev=nfev, njev=njev, status=info, message=MESSAGES[info],
                          success=info in LM_CONVERGED)


def _converged(actred: float, prered: float, ratio: float, delta: float, xnorm: float) -> int:
    reductions = abs(actred) <= LM_TOLERANCE and prered <= LM_TOLERANCE and 0.5 * ratio <= 1.0
    steps = delta <= LM_TOLERANCE * xnorm
    return 3 if reductions and steps else 2 if steps else 1 if reductions else 0


def _stuck(nfev: int, max_nfev: int, actred: float, prered: float, ratio: float, delta: float, xnorm: float,
           gnorm: float) -> int:
    """MINPACK's tests for the budget and for tolerances below machine precision (the last one met wins)."""
    info = 5 if nfev >= max_nfev else 0
    if abs(actred) <= _EPSMCH and prered <= _EPSMCH and 0.5 * ratio <= 1.0:
        info = 6
    if delta <= _EPSMCH * xnorm:
        info = 7
    if gnorm <= _EPSMCH:
        info = 8
    return info
