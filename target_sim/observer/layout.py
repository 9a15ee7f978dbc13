"""The filter's augmented state beyond the model's four nodes: each lagged measurement's lag state after the model's,
then the optional heat bias (the section's `bias`); each measurement's row h in node coordinates; how a sample's raw
channels split by measurement. The extra states' own arithmetic, their reset and their propagation after the model
step, is here too, in the fixed order the C repeats (`obs_propagate_extra`, `obs_reset_lags`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from target_sim.artifact import OUTPUTS
from target_sim.fmath import dot
from target_sim.model import Float32Estimator
from target_sim.observer.section import bias_input
from target_sim.observer.ud_structure import NEG_ZERO, masked_dot


class AugmentedLayout:
    """Where each extra state sits in a filter with `n` states over `measurements` (the section's, loaded)."""

    def __init__(self, measurements: Sequence, section: dict, est: Float32Estimator, n: int):
        f, part, k = est.f, est.part, len(OUTPUTS)
        self.measurements, self.n, self.f = measurements, n, f
        self.lag_index: list[int] = []      # each measurement's lag state, -1: none (it reads the nodes at once)
        at = k
        for m in measurements:
            self.lag_index.append(at if m.lag_pole > 0 else -1)
            at += 1 if m.lag_pole > 0 else 0
        self.bias_index = at if section.get("bias") else -1
        self.bias_input = bias_input(section)
        self.bias_column = part.b[:, self.bias_input] * (est.dt if part.delta else f(1.0))
        # each measurement's row h: its lag state, or what its sensor sees of the nodes
        self.rows: list[np.ndarray] = []
        for lag, m in zip(self.lag_index, measurements, strict=True):
            h = np.zeros(n, dtype=f)
            if lag >= 0:
                h[lag] = f(1.0)
            else:
                h[:k] = m.sees
            self.rows.append(h)
        self.sees_nonzero = [m.sees != 0 for m in measurements]
        self.widths = [m.width for m in measurements]

    def initial_extra(self, y: np.ndarray) -> np.ndarray:
        """The extra states at node temperatures y: each lag state at what its sensor sees, the bias 0."""
        extra = np.zeros(self.n - len(OUTPUTS), dtype=self.f)
        for m, lag in zip(self.measurements, self.lag_index, strict=True):
            if lag >= 0:
                extra[lag - len(OUTPUTS)] = dot(m.sees, y)
        return extra

    def propagate(self, extra: np.ndarray, est: Float32Estimator) -> None:
        """After the model step: the bias heats its node (B's column of the node's loss, into est's x and y); each lag
        state (in `extra`, in place) follows what its sensor sees."""
        k = len(OUTPUTS)
        if self.bias_index >= 0:
            est.x = est.x + self.bias_column * extra[self.bias_index - k]
            est.y = est.part.output(est.x)
        for m, lag in zip(self.measurements, self.lag_index, strict=True):
            if lag >= 0:
                i = lag - k
                extra[i] = m.lag_pole * extra[i] + (self.f(1.0) - m.lag_pole) * dot(m.sees, est.y)

    def predicted(self, index: int, extra: np.ndarray, y: np.ndarray):
        """What the index-th measurement should read now: its lag state, or what its sensor sees of y (its structural
        zeros skipped, as the C sums)."""
        lag = self.lag_index[index]
        if lag >= 0:
            return extra[lag - len(OUTPUTS)]
        nonzero = self.sees_nonzero[index]
        return masked_dot(self.measurements[index].sees[nonzero], y[nonzero], self.f(NEG_ZERO))

    def split(self, z) -> list[np.ndarray]:
        """A sample's raw channels by measurement (a lone NaN: no measurement at all)."""
        raw = np.atleast_1d(np.asarray(z, dtype=self.f))
        if len(raw) == 1 and sum(self.widths) > 1:
            raw = np.full(sum(self.widths), raw[0], dtype=self.f)
        parts, at = [], 0
        for w in self.widths:
            parts.append(raw[at: at + w])
            at += w
        return parts
