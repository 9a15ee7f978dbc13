"""The lab's side of the observer's measurement kinds (`target_sim.measurements`), one module per kind.

A lab measurement (`LabMeasurement`) knows its dataset columns (the raw channels the host sends), what it sees
(`sees`, `lag_pole(dt)`), its readings per model step in float64 for the reference filter (`readings`: z0, z1,
rel — reading = z0 + z1·ŷ_winding, variance R·rel) and its entry of the artifact's `observer.measurements` for a
tuned variance scale R (`entry`).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np


class LabMeasurement(Protocol):
    kind: str
    name: str
    columns: tuple[str, ...]
    node: str

    @property
    def sees(self) -> np.ndarray: ...

    def lag_pole(self, dt: float) -> float: ...

    def readings(self, dataset, dt: float, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

    def entry(self, dt: float, r_scale: float) -> dict: ...

    def describe(self) -> dict: ...


def step_means(dataset, columns, dt: float, steps: int) -> np.ndarray:
    """The columns' interval means per model step (what the target's accumulator forms), (steps, columns)."""
    from bench.thermal.excitation import interval_means

    raw = np.column_stack([dataset.column(c) for c in columns])
    return interval_means(raw, dataset.sample_period_s, dt)[:steps]
