"""Discretization of a continuous state-space model at a step Δt.

All three keep C and D unchanged (C = I, D = 0 for the LPTN), so every discrete model is
x[k+1] = A_d x[k] + B_d u[k], the form the target executes:
- `zoh`: exact for inputs held over the step (eqs. 49-50).
- `tustin`: the bilinear pole map z = (1 + λΔt/2)/(1 - λΔt/2) with B_d = (I - AΔt/2)^-1 B Δt; this keeps
  the DC gain exact without the feed-through a full bilinear transform adds.
- `euler`: forward Euler, eq. 51, as the paper ran the parameter-varying LPTN.
The matrix functions come from bench.thermal.portable, so a discrete model is the same bits on every CPU.
"""

from __future__ import annotations

import numpy as np

from bench.thermal import portable

METHODS = ("zoh", "tustin", "euler")


def discretize(a: np.ndarray, b: np.ndarray, dt: float, method: str) -> tuple[np.ndarray, np.ndarray]:
    """Return (A_d, B_d) for `method` in METHODS."""
    if dt <= 0:
        raise ValueError(f"the step must be positive, got {dt}")
    n, m = b.shape
    if method == "zoh":
        block = np.zeros((n + m, n + m))
        block[:n, :n], block[:n, n:] = a, b
        phi = portable.expm(block * dt)
        return phi[:n, :n], phi[:n, n:]
    if method == "tustin":
        left = np.eye(n) - a * dt / 2
        return portable.solve(left, np.eye(n) + a * dt / 2), portable.solve(left, b * dt)
    if method == "euler":
        return np.eye(n) + a * dt, b * dt
    raise ValueError(f"unknown discretization {method!r}; choose one of {', '.join(METHODS)}")
