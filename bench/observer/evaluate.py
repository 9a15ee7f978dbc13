"""The observer on data: open loop vs observer per node, the recovery from a wrong initial magnet temperature, and
the float32 comparison of the covariance forms (`bench evaluate`, `bench numerics --observer`).

Every float32 figure comes from the target's own code (`target_sim.model.run_offline`, `target_sim.observer`);
the float64 reference is `bench.thermal.kalman` through `bench.observer.reference.reference_run`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from bench.drive.dataset import MEASURED_NODES, Dataset
from bench.model.artifact_eval import artifact_drive
from bench.model.deploy import DEPLOYED_NODES
from bench.model.fileeval import OUTPUT_INDEX, measured_nodes
from bench.model.metrics import error_metrics
from bench.model.runs import initial_temperatures
from bench.observer.measured import measured_nodes_of, measurement_columns
from bench.observer.reference import reference_run
from target_sim.artifact import OUTPUTS, ModelArtifact
from target_sim.model import run_offline
from target_sim.observer import OBSERVER_FORMS, run_observer_offline

RECOVERY_OFFSETS_K = (30.0, -30.0)
RECOVERY_BAND_K = 2.0
MAGNET = OUTPUTS.index("magnet")


@dataclass(frozen=True)
class FormRow:
    """One covariance form over a whole run in float32 against the float64 filter."""

    form: str
    min_eigenvalue: float          # smallest eigenvalue of (P + Pᵀ)/2 over the run (state coordinates)
    max_symmetry_error: float      # max over the run of max|P - Pᵀ| / max|P| (the filter's own P: node coordinates)
    max_abs_f32_minus_f64_C: float
    worst_node: str
    finite: bool

    def as_dict(self) -> dict:
        return {"form": self.form, "min_eigenvalue": self.min_eigenvalue,
                "max_symmetry_error": self.max_symmetry_error, "max_abs_f32_minus_f64_C": self.max_abs_f32_minus_f64_C,
                "worst_node": self.worst_node, "finite": self.finite}


def form_comparison(artifact: ModelArtifact, dataset: Dataset, forms: Sequence[str] | None = None,
                    say: Callable[[str], None] | None = None) -> list[FormRow]:
    """Each form of the artifact's observer over the whole file in float32, against the float64 filter (the
    steady-state gain, another filter, against the same code in float64: `target_sim.observer` with dtype
    float64, which follows the float64 filter within 1e-4 °C where both run the same filter)."""
    data, reference = reference_run(artifact, dataset)
    drive = artifact_drive(artifact, dataset)
    z = measurement_matrix(artifact, dataset)
    rows = []
    for form in forms or OBSERVER_FORMS.names():
        if say:
            say(f"observer: the {form} form in float32")
        if OBSERVER_FORMS[form].propagates:
            y64 = reference.estimates[0]
        else:
            y64 = run_observer_offline(artifact, drive, z, data.run.initial, form, dtype=np.float64).outputs
        with np.errstate(all="ignore"):
            run = run_observer_offline(artifact, drive, z, data.run.initial, form, keep_covariance=True)
            p, own = run.covariances, run.filter_covariances
            scale = np.maximum(np.max(np.abs(own), axis=(1, 2)), np.finfo(float).tiny)
            asym = float(np.max(np.max(np.abs(own - np.transpose(own, (0, 2, 1))), axis=(1, 2)) / scale))
            finite = bool(np.all(np.isfinite(p)) and np.all(np.isfinite(run.outputs)))
            low = float(np.min(np.linalg.eigvalsh(0.5 * (p + np.transpose(p, (0, 2, 1)))))) if finite else float("nan")
            diff = np.abs(run.outputs.astype(np.float64) - y64[: len(run.outputs)])
        worst = int(np.argmax(np.nanmax(diff, axis=0))) if finite else 0
        rows.append(FormRow(form, low, asym, float(np.max(diff)) if finite else float("inf"), OUTPUTS[worst], finite))
    return rows


def measurement_matrix(artifact: ModelArtifact, dataset: Dataset) -> np.ndarray:
    """The raw channels of the observer's measurements per row, (rows, channels)."""
    return np.column_stack([dataset.column(c) for c in measurement_columns(artifact)])


def recovery_time_s(error: np.ndarray, step_time_s: np.ndarray, band: float = RECOVERY_BAND_K) -> float:
    """Time from the start until |error| stays within the band (0 if it always is; inf if it never settles)."""
    outside = np.nonzero(~(np.abs(error) <= band))[0]
    if not len(outside):
        return 0.0
    if outside[-1] == len(error) - 1:
        return float("inf")
    return float(step_time_s[outside[-1] + 1] - (step_time_s[0] - (step_time_s[1] - step_time_s[0])))


@dataclass(frozen=True)
class ObserverFileResult:
    name: str
    measured_node: str
    nodes: dict            # node -> {"open_loop": metrics, "observer": metrics}
    recovery: list         # [{offset_K, open_loop_s, observer_s}]
    max_abs_f32_minus_f64_C: float
    measured_nodes: list = field(default_factory=list)   # every node a measurement reads ("pm": the magnet)
    trace: dict | None = None      # per step: time, reference, open loop, observer and its 1-σ (plots)

    def as_dict(self) -> dict:
        return {"file": self.name, "measured_node": self.measured_node, "measured_nodes": self.measured_nodes,
                "nodes": self.nodes, "recovery": self.recovery,
                "max_abs_f32_minus_f64_C": self.max_abs_f32_minus_f64_C}


def evaluate_observer(artifact: ModelArtifact, dataset: Dataset, offsets: Sequence[float] = RECOVERY_OFFSETS_K,
                      say: Callable[[str], None] | None = None) -> ObserverFileResult:
    """Open loop and observer (its deployed form), both float32, per measured node; then each initial magnet
    offset: the time until the magnet error stays within `RECOVERY_BAND_K`."""
    data, reference = reference_run(artifact, dataset)
    run = data.run
    drive = artifact_drive(artifact, dataset)
    z = measurement_matrix(artifact, dataset)
    references = {n: np.interp(run.step_time_s, dataset.time_s, dataset.column(c))
                  for n, c in MEASURED_NODES.items()
                  if n in measured_nodes(dataset)}
    initial = initial_temperatures(dataset)

    def both(start, keep=None):
        _, open_loop = run_offline(artifact, drive, start)
        run_obs = run_observer_offline(artifact, drive, z, start)
        if keep is not None:
            keep["sigma"] = run_obs.sigmas
        return open_loop.astype(np.float64), run_obs.outputs.astype(np.float64)

    if say:
        say(f"observer: {dataset.name}, open loop and observer")
    kept: dict = {}
    open_loop, observed = both(initial, kept)
    nodes = {node: {"open_loop": error_metrics(open_loop[:, OUTPUT_INDEX[node]], ref),
                    "observer": error_metrics(observed[:, OUTPUT_INDEX[node]], ref)}
             for node, ref in references.items()}
    recovery = []
    for offset in offsets:
        if say:
            say(f"observer: {dataset.name}, magnet started {offset:+g} K off")
        start = initial.copy()
        start[MAGNET] += offset
        shifted_open, shifted_obs = both(start)
        recovery.append({"offset_K": float(offset),
                         "open_loop_s": recovery_time_s(shifted_open[:, MAGNET] - references["pm"], run.step_time_s),
                         "observer_s": recovery_time_s(shifted_obs[:, MAGNET] - references["pm"], run.step_time_s)})
    diff = float(np.max(np.abs(observed - reference.estimates[0][: len(observed)])))
    measured = ["pm" if n == "magnet" else n for n in measured_nodes_of(artifact)]
    trace = {"time_s": run.step_time_s, "references": references, "open_loop": open_loop, "observer": observed,
             "sigma": kept["sigma"]}
    return ObserverFileResult(dataset.name, measured[0], nodes, recovery, diff, measured, trace)


@dataclass(frozen=True)
class ValidationCheck:
    """The tuned observer against its open loop on files it was not tuned on: pooled float32 MSE (K²) per measured
    node, open loop and observer (the target's own code, from each file's own initial state)."""

    files: tuple[str, ...]
    open_loop_mse: dict[str, float]
    observer_mse: dict[str, float]

    @property
    def worse(self) -> list[str]:
        """The nodes where the observer is worse than the open loop."""
        return [n for n, mse in self.observer_mse.items() if mse > self.open_loop_mse[n]]

    def warning(self) -> str | None:
        """One sentence when the observer is worse than the open loop at a node, else None."""
        if not self.worse:
            return None
        figures = ", ".join(f"the {'magnet' if n == 'pm' else n} {self.observer_mse[n]:.3g} K² against "
                            f"{self.open_loop_mse[n]:.3g} K²" for n in self.worse)
        return (f"on the validation files ({', '.join(self.files)}) the observer is worse than the open loop: "
                f"{figures} (float32 MSE); do not deploy it as it is: try --consider magnet, another --criterion "
                "or --bias, or check the sensor's lag, gradient and offset")

    def as_dict(self) -> dict:
        return {"files": list(self.files), "open_loop_mse_K2": self.open_loop_mse, "observer_mse_K2": self.observer_mse,
                "worse": self.worse}


def validation_check(artifact: ModelArtifact, datasets: Sequence[Dataset]) -> ValidationCheck:
    """`ValidationCheck` of an artifact with an observer on `datasets` (each run from its own initial state)."""
    errors: dict[str, dict[str, list[np.ndarray]]] = {}
    for dataset in datasets:
        drive = artifact_drive(artifact, dataset)
        initial = initial_temperatures(dataset)
        _, open_loop = run_offline(artifact, drive, initial)
        observed = run_observer_offline(artifact, drive, measurement_matrix(artifact, dataset), initial).outputs
        times = float(dataset.time_s[0]) + np.arange(1, len(open_loop) + 1) * artifact.dt   # as `model_run`'s
        for node in measured_nodes(dataset):
            reference = np.interp(times, dataset.time_s, dataset.column(MEASURED_NODES[node]))
            index = OUTPUT_INDEX[node]
            pair = errors.setdefault(node, {"open_loop": [], "observer": []})
            pair["open_loop"].append(open_loop[:, index].astype(np.float64) - reference)
            pair["observer"].append(observed[:, index].astype(np.float64) - reference)
    mse = {kind: {n: float(np.mean(np.concatenate(e[kind]) ** 2)) for n, e in errors.items() if n in DEPLOYED_NODES}
           for kind in ("open_loop", "observer")}
    return ValidationCheck(tuple(d.name for d in datasets), mse["open_loop"], mse["observer"])
