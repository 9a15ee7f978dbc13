"""Accuracy metrics of paper eqs. 52-54."""

from __future__ import annotations

import numpy as np


def mse(estimate, reference) -> float:
    """Mean squared error (eq. 52), °C²."""
    e = np.asarray(estimate, dtype=np.float64) - np.asarray(reference, dtype=np.float64)
    return float(np.mean(e * e))


def rmse(estimate, reference) -> float:
    """Root mean squared error (eq. 53), °C."""
    return float(np.sqrt(mse(estimate, reference)))


def nrmse(estimate, reference) -> float:
    """RMSE divided by the standard deviation of the reference (eq. 54), dimensionless."""
    ref = np.asarray(reference, dtype=np.float64)
    sigma = float(np.std(ref))
    return rmse(estimate, ref) / sigma if sigma > 0 else float("nan")


def max_abs_error(estimate, reference) -> float:
    """Largest |estimate - reference|, °C."""
    e = np.asarray(estimate, dtype=np.float64) - np.asarray(reference, dtype=np.float64)
    return float(np.max(np.abs(e))) if e.size else float("nan")


def error_metrics(estimate, reference) -> dict[str, float]:
    return {"mse": mse(estimate, reference), "rmse": rmse(estimate, reference), "nrmse": nrmse(estimate, reference),
            "max_abs": max_abs_error(estimate, reference)}


BLOWN_UP = 1e6   # °C: the error a diverged simulation's non-finite samples count as in a fit


def finite_errors(errors: np.ndarray) -> np.ndarray:
    """`errors` with NaN and ±inf replaced by ±BLOWN_UP, so a fit sees a diverged candidate as merely bad. The
    same array when all are finite (the usual case: np.nan_to_num would copy it and scan it three times)."""
    errors = np.asarray(errors)
    if np.isfinite(errors).all():
        return errors
    return np.nan_to_num(errors, nan=BLOWN_UP, posinf=BLOWN_UP, neginf=-BLOWN_UP)


def finite_in_place(errors: np.ndarray) -> np.ndarray:
    """`finite_errors` written into `errors` itself (an array a fit's residual rows are built in), which it returns."""
    if not np.isfinite(errors).all():
        np.nan_to_num(errors, copy=False, nan=BLOWN_UP, posinf=BLOWN_UP, neginf=-BLOWN_UP)
    return errors
