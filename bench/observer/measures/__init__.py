"""The lab's side of the observer's measurement kinds (`target_sim.observer.measurements`), one module per kind,
under the name the target's kind has (`lagged_sensor`, `flux_linkage`, `winding_resistance`); each registers itself in
`LAB_MEASUREMENT_KINDS`, which loads them on first use. A test checks that this table and the target's name the same
kinds.

A lab measurement (`LabMeasurement`) knows its dataset columns (the raw channels the host sends), what it sees
(`sees`, `lag_pole(dt)`), its readings per model step in float64 for the reference filter (`readings`: z0, z1,
rel — reading = z0 + z1·ŷ_winding, variance R·rel) and its entry of the artifact's `observer.measurements` for a
tuned variance scale R (`entry`). Its kind (`LabMeasurementKind`) reads such an entry back and says where the
tuning starts R. A kind that `bench observer` builds from its options adds them (`add_arguments`) and builds its
measurement from them (`from_arguments`), so the command asks each kind instead of naming it. The calibrations share
the helpers below: the training files' step means (`training_steps`), least squares that keep only what the data
determine (`identifiable_fit`), the variance's fit to the residual (`variance_fit`) and the verdict on a calibration
(`judge_calibration`: a warning, or a refusal unless forced). `sensor_fit` is no kind: it estimates a lagged sensor's
lag, gradient and offset (`--lag auto` ...).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
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

    @property
    def warnings(self) -> tuple[str, ...]:
        """What makes its calibration doubtful, one sentence each (`bench observer` warns)."""


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

    def add_arguments(self, parser) -> None:
        """Add the options `bench observer` builds this kind's measurement from (default: none)."""

    def from_arguments(self, args, artifact, datasets: Sequence) -> LabMeasurement | None:
        """The measurement `bench observer`'s options ask for (calibrated on `datasets`), None when not asked."""
        return None


LAB_MEASUREMENT_KINDS: Registry[LabMeasurementKind] = Registry("measurement kind", __name__,
                                                               first=("lagged-sensor", "flux-linkage",
                                                                      "winding-resistance"))


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


class FromVoltages:
    """What the measurements computed from the d/q voltages, currents and speed (the flux linkage, the winding
    resistance) share: their columns, the one node they read (`node`), no lag, and their artifact entry (the kind's
    arrays, the calibration); a frozen dataclass with `kind`, `name`, `node` and `calibration` mixes it in."""

    kind: str
    name: str
    node: str
    calibration: dict

    @property
    def columns(self) -> tuple[str, ...]:
        from target_sim.observer.measurements.flux_linkage import COLUMNS

        return COLUMNS

    @property
    def sees(self) -> np.ndarray:
        from target_sim.artifact import OUTPUTS

        return np.eye(len(OUTPUTS))[OUTPUTS.index(self.node)]

    def lag_pole(self, dt: float) -> float:
        return 0.0

    def voltage_entry(self, values: Mapping[str, float]) -> dict:
        """The artifact entry with the kind's arrays `values`."""
        from target_sim.artifact import encode_array

        return {"kind": self.kind, "name": self.name, "columns": list(self.columns), "node": self.node,
                "arrays": {k: encode_array(v) for k, v in values.items()}, "calibration": self.calibration}


class FromVoltagesKind(LabMeasurementKind):
    """The lab kind of a `FromVoltages` measurement: its entry's arrays (`arrays`, in the order of the measurement's
    fields) read back into the measurement (`measurement`), the tuned variance scale folded into its calibrated
    variance (so R starts at 1 and is stored as 1)."""

    measurement: ClassVar[type]
    arrays: ClassVar[tuple[str, ...]]
    start_r = 1.0

    def from_entry(self, entry: dict, dt: float):
        from target_sim.artifact import decode_array

        values = (float(decode_array(entry["arrays"][k], k, np.float64)) for k in self.arrays)
        return self.measurement(*values, calibration=entry.get("calibration", {}))

    def stored_r(self, entry: dict) -> float:
        return 1.0     # the measurement's entry() folds the tuned scale into its variance's arrays


def training_steps(datasets: Sequence, columns: Sequence[str], dt: float, what: str,
                   required: Sequence[str] = ()) -> np.ndarray:
    """The columns' step means over every training file, one row per model step, (steps, columns); a file without one
    of them or of `required` is one sentence naming `what` needs it."""
    from bench.errors import BenchError

    rows = []
    for d in datasets:
        missing = [c for c in (*required, *columns) if c != "speed_rpm" and not d.has(c)]
        if missing:
            raise BenchError(f"{d.path} has no column {missing[0]!r}, which {what} needs; map it with --mapping")
        steps = len(step_means(d, ("speed_rpm",), dt, 10 ** 9))
        rows.append(step_means(d, columns, dt, steps))
    return np.concatenate(rows)


def least_squares(y: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least squares: (coefficients, their standard errors, residual)."""
    beta, *_ = np.linalg.lstsq(x, y, rcond=None)
    resid = y - x @ beta
    dof = max(len(y) - x.shape[1], 1)
    cov = np.linalg.pinv(x.T @ x) * float(resid @ resid) / dof
    return beta, np.sqrt(np.maximum(np.diag(cov), 0.0)), resid


def identifiable_fit(y: np.ndarray, columns: Mapping[str, np.ndarray], optional: Sequence[str], largest_error: float,
                     fixed_value: Callable[[str], float]):
    """y ≈ Σ value·column by least squares, keeping an `optional` coefficient only where the data determine it
    (relative standard error below largest_error, and not collinear with the others); the first loose one is fixed
    to fixed_value(name) and the rest fitted again. (values by name, fitted names, their standard errors, residual,
    {fixed name: value})."""
    fixed: dict[str, float] = {}
    while True:
        names = [n for n in columns if n not in fixed]
        target = y - sum(columns[n] * v for n, v in fixed.items())
        x = np.column_stack([columns[n] for n in names])
        beta, se, resid = least_squares(target, x)
        loose = [n for n in optional if n in names and not se[names.index(n)] < largest_error * abs(
            beta[names.index(n)])]
        scaled = x / np.maximum(np.abs(x).max(axis=0), np.finfo(float).tiny)
        if np.linalg.matrix_rank(scaled, tol=1e-9) < len(names):     # collinear: no standard error says so
            loose = [n for n in optional if n in names][:1] or loose
        if not loose:
            return dict(zip(names, beta, strict=True)) | fixed, names, se, resid, fixed
        fixed[loose[0]] = fixed_value(loose[0])


def variance_fit(resid_k: np.ndarray, ratio: np.ndarray) -> tuple[float, float]:
    """(R_floor, R_growth): the squared residual (K²) fitted as R_floor + R_growth·ratio², each at least 1e-6."""
    ratio2 = ratio ** 2
    coef, *_ = np.linalg.lstsq(np.column_stack([np.ones_like(ratio2), ratio2]), resid_k ** 2, rcond=None)
    floor, growth = (max(float(v), 1e-6) for v in coef)
    return floor, growth


def residual_figures(resid_k: np.ndarray) -> dict:
    """The calibration's residual in kelvin: RMS and largest."""
    return {"residual_rms_K": float(np.sqrt(np.mean(resid_k ** 2))), "residual_max_K": float(np.max(np.abs(resid_k)))}


def loss_value(artifact, key: str) -> float | None:
    """A scalar of the artifact's loss model (pole pairs, copper coefficient, stator resistance), None if absent."""
    return float(artifact.array("losses", key, dtype=np.float64)) if key in artifact.content["losses"] else None


# A calibration's residual (K RMS of its node's temperature) against the lab's reference. Above the first the readings
# are noisier than the model's own error on the training files (a few K on the shipped motors): they may make the
# estimate worse, a warning. Above the second they are useless: the filter would follow kelvins of calibration error,
# a refusal unless forced.
CALIBRATION_WARN_RMS_K = 5.0
CALIBRATION_REFUSE_RMS_K = 15.0
# A fitted stator resistance this many times the model's, or below its reciprocal, is no resistance: the fit took up
# something else (an inverter voltage drop, a wrong unit or pole pair count), a refusal unless forced.
RESISTANCE_RATIO_LIMIT = 3.0


def judge_calibration(what: str, node: str, calibration: Mapping, r_s_fitted: float | None,
                      r_s_model: float | None, advice: str, force_option: str, forced: bool) -> tuple[str, ...]:
    """The warnings of a calibration (`residual_rms_K`, `residual_max_K`) whose fitted stator resistance r_s_fitted
    (None: not fitted) the model's r_s_model (None: unknown) checks. A useless one (`CALIBRATION_REFUSE_RMS_K`,
    `RESISTANCE_RATIO_LIMIT`) is one sentence (UsageError, exit 2) naming `advice` and `force_option`, or with
    `forced` that sentence as a warning."""
    from bench.errors import UsageError

    rms, largest = float(calibration["residual_rms_K"]), float(calibration["residual_max_K"])
    figure = f"{rms:.1f} K RMS (max {largest:.0f} K)"
    problems = []
    if not rms <= CALIBRATION_REFUSE_RMS_K:
        problems.append(f"its residual is {figure}, above the {CALIBRATION_REFUSE_RMS_K:g} K it may have")
    if r_s_fitted is not None and r_s_model is not None and r_s_model > 0:
        ratio = r_s_fitted / r_s_model
        if not 1.0 / RESISTANCE_RATIO_LIMIT <= ratio <= RESISTANCE_RATIO_LIMIT:
            problems.append(f"its fitted R_s {r_s_fitted * 1e3:.3g} mOhm is {ratio:.2g} times the model's "
                            f"{r_s_model * 1e3:.3g} mOhm")
    if problems:
        sentence = (f"the {what} calibration is useless: {' and '.join(problems)}, so its readings would make the "
                    f"{node} estimate worse; {advice}")
        if not forced:
            raise UsageError(f"{sentence}, or give {force_option} to use it anyway")
        return (f"{sentence}; used anyway ({force_option})",)
    if rms > CALIBRATION_WARN_RMS_K:
        return (f"the {what} calibration's residual is {figure}, above {CALIBRATION_WARN_RMS_K:g} K: its readings "
                f"may make the {node} estimate worse; compare the observer with and without it (bench evaluate)",)
    return ()
