"""The filter's innovation gate (the section's optional `gate`, `target_sim.artifact.observer_gate`; absent: none,
every valid reading updates).

A reading with ν·ν > sigma²·S (S = h P⁻ hᵀ + R as the form's update computes it, `innovation_variance`; the steady
form: its steady prior's h P⁻ hᵀ, from P_ss and K_ss, + R) is rejected: that measurement predicts only this step (its
innovation NaN). Rejections are counted per measurement; `flag_after` of one measurement in a row flag its sensor
(latched until a reset or restore). Re-admission: the propagated forms' covariance grows while a sensor is rejected,
so a sensor that truly moved passes again; the steady form admits the next reading after `flag_after` rejections in
a row.
"""

from __future__ import annotations

import numpy as np


class InnovationGate:
    """The gate of a filter with `count` measurements (`gate`: (sigma, flag_after), None: every valid reading updates);
    `steady`: the filter keeps the steady-state gain (its S never widens)."""

    def __init__(self, gate: tuple[float, int] | None, count: int, steady: bool, f):
        self.threshold = None if gate is None else f(gate[0]) * f(gate[0])     # sigma²: ν² > sigma² S rejects
        self.flag_after = None if gate is None else gate[1]
        self.count, self.steady, self.f = count, steady, f
        self.clear()

    def clear(self) -> None:
        """No reading rejected yet, no sensor flagged (a reset, and so a restore: the counts start again, in C too)."""
        count = self.count
        self.rejections = np.zeros(count, dtype=np.int64)       # each measurement's rejected readings
        self.consecutive = np.zeros(count, dtype=np.int64)      # ... rejected in a row, up to now
        self.flagged = np.zeros(count, dtype=bool)              # ... flag_after in a row at least once (latched)
        self.rejected = np.zeros(count, dtype=bool)             # ... rejected this step

    def new_step(self) -> None:
        """A step starts with no reading rejected yet."""
        self.rejected[:] = False

    def rejects(self, index: int, nu, s) -> bool:
        """Whether the gate rejects the index-th measurement's reading of innovation ν and variance S
        (ν·ν > sigma²·S in the filter's precision, the C's comparison), counting it."""
        readmit = self.steady and self.consecutive[index] >= self.flag_after
        if self.threshold is None or not nu * nu > self.threshold * s or readmit:
            # re-admission: a propagated covariance grows while a sensor's readings are rejected (S widens until a
            # sensor that truly moved passes); the steady form's S never widens, so after flag_after rejections in
            # a row its next reading is admitted (the flag stays)
            self.consecutive[index] = 0
            return False
        self.rejected[index] = True
        self.rejections[index] += 1
        self.consecutive[index] += 1
        if self.consecutive[index] >= self.flag_after:
            self.flagged[index] = True
        return True

    @property
    def in_checkpoint(self) -> bool:
        """Whether the filter's checkpoint carries the rejections in a row: the steady form's re-admission
        depends on them."""
        return self.steady and self.threshold is not None

    def checkpoint(self) -> np.ndarray:
        """Each measurement's rejections in a row when `in_checkpoint`, else nothing."""
        return self.consecutive.astype(self.f) if self.in_checkpoint else np.zeros(0, dtype=self.f)

    def restore(self, values: np.ndarray) -> None:
        """The rejections in a row from `checkpoint()`'s values; a count that is not one (a forged element: NaN,
        negative, huge) is 0, as the C's conversion guard."""
        if self.in_checkpoint:
            self.consecutive = np.array([int(v) if 0 < v < 1e9 else 0 for v in values], dtype=np.int64)
