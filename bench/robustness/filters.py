"""Filters for noisy inputs, in float32 sample by sample as the target would run them before its interval mean:
a first-order low-pass y <- y + α·(x - y), α = T_s/(τ + T_s), started at the first sample, and a moving mean of the
last N = round(τ/T_s) samples (fewer at the start), summed oldest first.

The delay each adds is its group delay at low frequency: τ for the low-pass ((1 - α)/α·T_s exactly, which is τ),
(N - 1)/2·T_s for the moving mean.
"""

from __future__ import annotations

import numpy as np

F32 = np.float32
FILTERS = ("lowpass", "moving-mean")


def window(tau_s: float, sample_period_s: float) -> int:
    return max(1, int(round(tau_s / sample_period_s)))


def delay_s(kind: str, tau_s: float, sample_period_s: float) -> float:
    """The low-frequency group delay the filter adds, s."""
    if kind == "lowpass":
        return tau_s
    return (window(tau_s, sample_period_s) - 1) / 2 * sample_period_s


def lowpass(values: np.ndarray, tau_s: float, sample_period_s: float) -> np.ndarray:
    """values (rows, L...) filtered along the rows in float32."""
    x = np.asarray(values, dtype=F32)
    alpha = F32(sample_period_s / (tau_s + sample_period_s))
    out = np.empty_like(x)
    y = x[0].copy()
    for row in range(len(x)):
        y = y + alpha * (x[row] - y)
        out[row] = y
    return out


def moving_mean(values: np.ndarray, tau_s: float, sample_period_s: float) -> np.ndarray:
    """The mean of the last N samples (rows, L...) in float32: sum oldest first, divided by the count."""
    x = np.asarray(values, dtype=F32)
    n = window(tau_s, sample_period_s)
    total = np.zeros_like(x)
    count = np.zeros(len(x), dtype=F32)
    for age in range(n - 1, -1, -1):               # the oldest sample of the window first
        total[age:] = total[age:] + x[: len(x) - age]
        count[age:] += F32(1)
    return total / count.reshape((-1,) + (1,) * (x.ndim - 1))


def apply_filter(kind: str, values: np.ndarray, tau_s: float, sample_period_s: float) -> np.ndarray:
    if kind == "lowpass":
        return lowpass(values, tau_s, sample_period_s)
    if kind == "moving-mean":
        return moving_mean(values, tau_s, sample_period_s)
    raise ValueError(f"filter {kind!r} is not one of {', '.join(FILTERS)}")
