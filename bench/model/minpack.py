"""MINPACK's Levenberg-Marquardt (lmder) with the Jacobian taken a row per parameter: the routine
scipy.optimize.least_squares(method="lm") runs, on the same arguments, without its copies of the Jacobian."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.optimize import OptimizeResult, leastsq

# scipy.optimize.least_squares(method="lm") with its defaults (ftol = xtol = gtol = 1e-8, x_scale "jac": MINPACK's
# own scaling, step bound factor 100), run through MINPACK's lmder as scipy.optimize.leastsq calls it: the same
# routine on the same arguments, so the same iterates bit for bit. Why not least_squares itself: it takes the Jacobian
# a row per residual and copies it four times per evaluation (its own copy, C order, then MINPACK's column order),
# which for 400 000 residuals cost as much as the simulations; leastsq's col_deriv takes it a row per parameter, as
# the finite differences produce it, and copies it once. And least_squares evaluates the Jacobian once more at the
# end, for figures nothing here uses.
LM_TOLERANCE = 1e-8
LM_STEP_BOUND = 100.0
LM_CONVERGED = (1, 2, 3, 4)    # MINPACK's info: a tolerance met; 5: the evaluation budget; 6-8: tolerance too small


def levenberg_marquardt(fun: Callable[[np.ndarray], np.ndarray], jac_rows: Callable[[np.ndarray], np.ndarray],
                        x0: np.ndarray, max_nfev: int) -> OptimizeResult:
    """Minimize |fun(x)|² from x0 by MINPACK's Levenberg-Marquardt with at most `max_nfev` evaluations of fun;
    `jac_rows(x)` is the Jacobian transposed, (parameters, residuals). The result as least_squares gives it (x, fun,
    nfev, njev, status, message, success)."""
    # leastsq calls fun and jac_rows once at x0 to check their shapes, then MINPACK calls them there again
    x, _, info, message, status = leastsq(_last_call(fun), np.array(x0, dtype=float), Dfun=_last_call(jac_rows),
                                           col_deriv=True,
                                           full_output=True, ftol=LM_TOLERANCE, xtol=LM_TOLERANCE, gtol=LM_TOLERANCE,
                                           maxfev=max_nfev, factor=LM_STEP_BOUND)
    return OptimizeResult(x=x, fun=info["fvec"], nfev=info["nfev"], njev=info.get("njev"), status=status,
                          message=message, success=status in LM_CONVERGED)


def _last_call(function: Callable[[np.ndarray], np.ndarray]) -> Callable[[np.ndarray], np.ndarray]:
    """`function` that returns its last result again when called with the same x (as least_squares' own wrapper
    does), so a check of the shapes costs no simulation; MINPACK copies what it gets, so sharing it is safe."""
    last: list = [None, None]

    def call(x: np.ndarray) -> np.ndarray:
        if last[0] is None or not np.array_equal(x, last[0]):
            last[0], last[1] = np.array(x, copy=True), function(x)
        return last[1]

    return call
