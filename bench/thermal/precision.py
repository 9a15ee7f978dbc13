"""Does a realization survive float32? Condition number, poles in double and single, and output error."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass

import numpy as np

from bench.thermal.discretize import discretize
from bench.thermal.lptn import continuous_eigenvalues, lti_matrices, time_constants
from bench.thermal.parameters import LptnParameters
from bench.thermal.realizations import (
    REALIZATIONS,
    Realization,
    condition_number,
    physical,
    realize,
)
from bench.thermal.simulate import simulate


@dataclass(frozen=True)
class PrecisionRow:
    discretization: str
    dt: float
    realization: str
    cond: float
    eig_f64: list[float]
    eig_f32_abs: list[float]
    stable_f32: bool
    max_output_error_f32_C: float
    diverged_f32: bool


def discrete_lptn(p: LptnParameters, dt: float, method: str) -> Realization:
    """The physical discrete realization of the LTI LPTN."""
    a, b, c, d = lti_matrices(p)
    a_d, b_d = discretize(a, b, dt, method)
    return physical(a_d, b_d, c, d)


def sorted_magnitudes(eig: np.ndarray) -> list[float]:
    return sorted((float(abs(v)) for v in eig), reverse=True)


def output_error_f32(sys: Realization, inputs: np.ndarray) -> np.ndarray:
    """|y_f32 - y_f64| per step, largest over the outputs; inf where float32 has overflowed."""
    y64 = simulate(sys, inputs, dtype=np.float64)
    y32 = simulate(sys, inputs, dtype=np.float32).astype(np.float64)
    err = np.max(np.abs(y32 - y64), axis=1)
    return np.where(np.isfinite(err), err, np.inf)


def max_finite(err: np.ndarray) -> float:
    """The largest error before any overflow (JSON and tables cannot carry infinity)."""
    finite = err[np.isfinite(err)]
    return float(finite.max()) if finite.size else float("nan")


def analyse(sys: Realization, method: str, dt: float, inputs: np.ndarray) -> PrecisionRow:
    """One row of the Table 2/3/4 analogue for the realization `sys`."""
    eig64 = np.linalg.eigvals(sys.transition())
    rounded = sys.astype(np.float32).astype(np.float64)   # the float32 coefficients; delta: poles 1 + Δ·λ(A_δ)
    eig32 = np.linalg.eigvals(rounded.transition())
    mags32 = sorted_magnitudes(eig32)
    err = output_error_f32(sys, inputs)
    return PrecisionRow(
        discretization=method, dt=float(dt), realization=sys.name, cond=condition_number(sys.a),
        eig_f64=sorted((float(v.real) for v in eig64), reverse=True),
        eig_f32_abs=mags32, stable_f32=bool(mags32[0] < 1.0),
        max_output_error_f32_C=max_finite(err), diverged_f32=bool(not np.all(np.isfinite(err))),
    )


def precision_table(p: LptnParameters, methods: Iterable[str], dts: Iterable[float],
                    inputs_for_dt, realizations: Iterable[str] = REALIZATIONS) -> list[PrecisionRow]:
    """Rows for every (discretization, Δt, realization); inputs_for_dt(dt) gives the (steps, 8) input sequence."""
    rows = []
    for method in methods:
        for dt in dts:
            base = discrete_lptn(p, dt, method)
            inputs = inputs_for_dt(dt)
            rows.extend(analyse(realize(base, name, dt), method, dt, inputs) for name in realizations)
    return rows


def numerics_report(p: LptnParameters, name: str, rows: list[PrecisionRow]) -> dict:
    """The JSON object of `bench numerics --json`."""
    return {
        "params": name,
        "eigenvalues_continuous": [float(v) for v in continuous_eigenvalues(p)],
        "time_constants_s": [float(v) for v in time_constants(p)],
        "rows": [asdict(r) for r in rows],
    }
