"""The filter's consider states (the section's `consider`, `target_sim.artifact.CONSIDER_KINDS`): which states a
measurement's update holds.

A measurement that does not read the kind's node holds it (and the kind's bias state): the gain's held rows are -0,
K = K_opt - δ, and each form keeps the covariance of that gain, P_opt + s δ δᵀ (s = h P⁻ hᵀ + R): `joseph` by its own
formula (valid for any gain), `conventional` by adding s δ δᵀ over the held rows to its optimal update, `ud` by Agee
and Turner's rank-one update (P_opt + γ v vᵀ, v = P⁻hᵀ on the held rows, γ = 1/s) after Bierman's, `steady` with the
lab's consider steady state (the held rows of K_ss set to -0 here, exactly).

The key-on release (the section's `consider_release_C2`; None: held always): while the magnet's variance before an
update exceeds it, a measurement holds only `released` (the magnet and a magnet bias free); the steady form has no
covariance to ask and holds always.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from target_sim.artifact import OUTPUTS, consider_held, consider_release, consider_released
from target_sim.observer.ud_structure import held_gain


class ConsiderStates:
    """Per measurement the states its update holds in a filter with `n` states (node coordinates; None: none);
    `steady`: the filter keeps the steady-state gain."""

    def __init__(self, section: dict, measurements: Sequence, n: int, steady: bool, f):
        self.f = f
        held = consider_held(section.get("consider"), np.array([m.sees for m in measurements]), section.get("bias"), n)
        self.held = [row if row.any() else None for row in held]
        release = consider_release(section)
        self.release = None if release is None or steady else f(release)
        self.released = [None if h is None else (row if row.any() else None)
                         for h, row in zip(self.held, consider_released(held, section.get("bias")), strict=True)]
        self.magnet_row = np.zeros(n, dtype=f)
        self.magnet_row[OUTPUTS.index("magnet")] = f(1.0)

    def steady_gain(self, gain: np.ndarray) -> np.ndarray:
        """K_ss (a row per measurement) with each measurement's held rows exactly -0: the lab wrote them zero up to
        rounding; the target holds them exactly."""
        gain = gain.copy()
        for index, row in enumerate(self.held):
            if row is not None:
                gain[index] = held_gain(gain[index], row)
        return gain

    def holds(self, index: int, cov) -> np.ndarray | None:
        """The states the index-th measurement's update holds now, given the filter's covariance `cov`: its consider
        states, or while the magnet's variance exceeds the key-on release (`innovation_variance` of the magnet's unit
        row with R = 0, the C's obs_magnet_variance, the same bits) those with the magnet free."""
        held = self.held[index]
        if held is None or self.release is None or not held[OUTPUTS.index("magnet")]:
            return held
        if cov.innovation_variance(self.magnet_row, self.f(0.0)) > self.release:
            return self.released[index]
        return held
