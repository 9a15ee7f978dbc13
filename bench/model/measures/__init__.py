"""The lab's side of the observer's measurement kinds (`target_sim.measurements`), one module per kind, under the
name the target's kind has (`lagged_sensor`, `flux_linkage`); each registers itself in `LAB_MEASUREMENT_KINDS`,
which loads them on first use. A test checks that this table and the target's name the same kinds.

A lab measurement (`LabMeasurement`) knows its dataset columns (the raw channels the host sends), what it sees
(`sees`, `lag_pole(dt)`), its readings per model step in float64 for the reference filter (`readings`: z0, z1,
rel — reading = z0 + z1·ŷ_winding, variance R·rel) and its entry of the artifact's `observer.measurements` for a
tuned variance scale R (`entry`). Its kind (`LabMeasurementKind`) reads such an entry back and says where the
tuning starts R.
"""

from __future__ import annotations

from typing import ClassVar, Protocol

import numpy as np

from target_sim.registry import Registry


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

    def calibration_text(self) -> str | None:
        """What `bench observer` prints of the measurement's calibration on the training files (None: it has none)."""


class LabMeasurementKind:
    """One measurement kind as the lab knows it. Subclasses set the class attributes and implement the methods."""

    name: ClassVar[str]
    # where the tuning's search starts the kind's variance scale R (its entry's R is the tuned value times its own
    # variance, if it has one)
    start_r: ClassVar[float]

    def from_entry(self, entry: dict, dt: float) -> LabMeasurement:
        """The lab measurement of an artifact's `observer.measurements` entry, its tuned variance folded in."""
        raise NotImplementedError

    def stored_r(self, entry: dict) -> float:
        """The variance scale R the entry stores apart from the measurement (1: folded into its own arrays)."""
        raise NotImplementedError


LAB_MEASUREMENT_KINDS: Registry[LabMeasurementKind] = Registry("measurement kind", __name__,
                                                               first=("lagged-sensor", "flux-linkage"))


def register(kind: LabMeasurementKind) -> LabMeasurementKind:
    return LAB_MEASUREMENT_KINDS.register(kind.name, kind)


def kind_of(measurement: LabMeasurement) -> LabMeasurementKind:
    """The kind of a lab measurement."""
    return LAB_MEASUREMENT_KINDS[measurement.kind]


def step_means(dataset, columns, dt: float, steps: int) -> np.ndarray:
    """The columns' interval means per model step (what the target's accumulator forms), (steps, columns)."""
    from bench.thermal.excitation import interval_means

    raw = np.column_stack([dataset.column(c) for c in columns])
    return interval_means(raw, dataset.sample_period_s, dt)[:steps]
