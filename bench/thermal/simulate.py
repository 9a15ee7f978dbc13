"""Simulation of a discrete linear block in float64 or entirely in float32."""

from __future__ import annotations

import numpy as np

from bench.thermal.realizations import Realization


def simulate(sys: Realization, inputs: np.ndarray, x0: np.ndarray | None = None, dtype=np.float64) -> np.ndarray:
    """Outputs y[k] = C x[k] for k = 1..N of x[k+1] = A x[k] + B u[k] (delta form: x[k+1] = x[k] + Δ·(A x[k] +
    B u[k])).

    With dtype=float32 the coefficients, the state, the inputs and every product and sum are float32,
    as on a single-precision FPU. x0 is given in the realization's own coordinates (zero by default).
    """
    a, b, c = (np.asarray(m, dtype=dtype) for m in (sys.a, sys.b, sys.c))
    u = np.asarray(inputs, dtype=dtype)
    x = np.zeros(a.shape[0], dtype=dtype) if x0 is None else np.asarray(x0, dtype=dtype).copy()
    bu = u @ b.T  # the input term does not depend on the state: one matrix product for all steps
    states = np.empty((len(u), a.shape[0]), dtype=dtype)
    step = np.dtype(dtype).type(sys.dt) if sys.form == "delta" else None
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging float32 realization is a result here
        for k in range(len(u)):
            x = a @ x + bu[k] if step is None else x + step * (a @ x + bu[k])
            states[k] = x
        return states @ c.T
