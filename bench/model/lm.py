"""The Levenberg-Marquardt fits' solver, chosen once per identification: `levenberg_marquardt` runs the
factorization `using()` set (choices.LM_FACTORIZATIONS), MINPACK's by default.

Why a context and not a parameter: the LM runs in four stages (the polish and its freezing, the prior's adaptation,
the loss scales, the Hammerstein fit and its cross-validation) from six call sites; the choice is one fact of the
identification, set where it starts (bench.model.identify) and carried into worker threads by
bench.model.polish.in_threads."""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Callable, Iterator

import numpy as np
from scipy.optimize import OptimizeResult

from bench.model.choices import DEFAULT_LM_FACTORIZATION, LM_FACTORIZATIONS

# how the provenance names each (the polish's method, the Hammerstein fit's record)
DESCRIPTIONS = {"minpack": "MINPACK", "blocked": "MINPACK's lmder iteration on a blocked QR, bench.model.blocked_lm"}
_FACTORIZATION = contextvars.ContextVar("lm_factorization", default=DEFAULT_LM_FACTORIZATION)


@contextlib.contextmanager
def using(factorization: str) -> Iterator[None]:
    """The LM fits inside this block (and the threads in_threads starts from it) factor by `factorization`."""
    if factorization not in LM_FACTORIZATIONS:
        raise ValueError(f"unknown LM factorization {factorization!r}; choose one of {', '.join(LM_FACTORIZATIONS)}")
    token = _FACTORIZATION.set(factorization)
    try:
        yield
    finally:
        _FACTORIZATION.reset(token)


def current() -> str:
    return _FACTORIZATION.get()


def levenberg_marquardt(fun: Callable[[np.ndarray], np.ndarray], jac_rows: Callable[[np.ndarray], np.ndarray],
                        x0: np.ndarray, max_nfev: int) -> OptimizeResult:
    """Minimize |fun(x)|² from x0 with at most `max_nfev` evaluations of fun, by the factorization in use (both
    take and return the same: bench.model.minpack.levenberg_marquardt)."""
    if _FACTORIZATION.get() == "blocked":
        from bench.model.blocked_lm import levenberg_marquardt as solve
    else:
        from bench.model.minpack import levenberg_marquardt as solve
    return solve(fun, jac_rows, x0, max_nfev)
