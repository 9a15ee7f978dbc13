"""The filter's augmented state beyond the model's four nodes: each lagged measurement's lag state after the model's,
then the optional bias (the section's `bias`: a heat bias, or an output bias that adds to its node's output); each
measurement's row h in node coordinates; how a sample's raw channels split by measurement. The extra states' own
arithmetic, their reset and their propagation after the model step, is here too, in the fixed order the C repeats
(`obs_propagate_extra`, `obs_reset_lags`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from target_sim.artifact import BIAS_KINDS, OUTPUT_BIAS_KINDS, OUTPUTS
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
        # an output bias (`OUTPUT_BIAS_KINDS`): added to its node's output, heats nothing (-1: none, or a heat bias)
        self.bias_output = BIAS_KINDS[section["bias"]] if section.get("bias") in OUTPUT_BIAS_KINDS else -1
        self.bias_input = bias_input(section)
        self.bias_column = part.b[:, self.bias_input] * (est.dt if part.delta else f(1.0))
        if self.bias_output >= 0:
            self.bias_column = np.zeros_like(self.bias_column)
        # each measurement's row h: its lag state, or what its sensor sees of the nodes
        self.rows: list[np.ndarray] = []
        for lag, m in zip(self.lag_index, measurements, strict=True):
            h = np.zeros(n, dtype=f)
            if lag >= 0:
                h[lag] = f(1.0)
            else:
                h[:k] = m.sees
                if self.bias_output >= 0:
                    h[self.bias_index] = m.sees[self.bias_output]
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
        if self.bias_index >= 0 and self.bias_output < 0:
            est.x = est.x + self.bias_column * extra[self.bias_index - k]
            est.y = est.part.output(est.x)
        for m, lag in zip(self.measurements, self.lag_index, strict=True):
            if lag >= 0:
                i = lag - k
                extra[i] = m.lag_pole * extra[i] + (self.f(1.0) - m.lag_pole) * self.seen(m, extra, est.y)

    def seen(self, m, extra: np.ndarray, y: np.ndarray):
        """What measurement m sees: sees·y, plus an output bias it sees (`plus_bias`)."""
        return self.plus_bias(dot(m.sees, y), m, extra)

    def plus_bias(self, view, m, extra: np.ndarray):
        """`view` plus measurement m's weight of an output bias's node times the bias, where it weighs that node (as
        the C adds it: bench.firmware.observergen)."""
        if self.bias_output < 0 or m.sees[self.bias_output] == 0:
            return view
        return view + m.sees[self.bias_output] * extra[self.bias_index - len(OUTPUTS)]

    def reported(self, extra: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The estimate the target reports: the nodes y, with an output bias added to its node."""
        out = y.copy()
        if self.bias_output >= 0:
            out[self.bias_output] = out[self.bias_output] + extra[self.bias_index - len(OUTPUTS)]
        return out

    def predicted(self, index: int, extra: np.ndarray, y: np.ndarray):
        """What the index-th measurement should read now: its lag state, or what its sensor sees of y (its structural
        zeros skipped, as the C sums)."""
        lag = self.lag_index[index]
        if lag >= 0:
            return extra[lag - len(OUTPUTS)]
        m, nonzero = self.measurements[index], self.sees_nonzero[index]
        return self.plus_bias(masked_dot(m.sees[nonzero], y[nonzero], self.f(NEG_ZERO)), m, extra)

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
