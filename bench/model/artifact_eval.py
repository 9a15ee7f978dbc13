"""Evaluate a model artifact on a dataset: float64 reference, float32 as the target runs it, and metrics."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.drive.dataset import Dataset
from bench.model.artifact_values import artifact_loss_model, artifact_parameters, shift_form
from bench.model.identify import winding_pm_metrics
from bench.model.runs import ModelRun, drive_matrix, model_run
from bench.thermal.estimator import loop_parameters, run_batch
from bench.thermal.excitation import interval_means
from target_sim.artifact import ModelArtifact
from target_sim.kinds import MODEL_KINDS
from target_sim.model import Float32Estimator, run_offline

SIGMOID_KEYS = ("scale_W", "weight", "bias", "gain", "linear", "offset")


def float64_estimate(artifact: ModelArtifact, dataset: Dataset, run: ModelRun) -> np.ndarray:
    """(steps, 4) in double precision from the artifact's float64 coefficients.

    The LTI and Hammerstein kinds go through the compiled batch kernel (an independent implementation of
    the target's step); the PV LPTN through the target's own code in float64.
    """
    if not MODEL_KINDS[artifact.kind].linear_block:
        model = Float32Estimator(artifact, dtype=np.float64)
        model.reset(run.initial)
        means = interval_means(artifact_drive(artifact, dataset), artifact.data_sample_period, artifact.dt)
        return np.array([model.step(*row) for row in means])
    f64 = np.float64
    a, b, c = shift_form(artifact)
    if MODEL_KINDS[artifact.kind].input_nonlinearity:
        sig = np.vstack([artifact.array("input_nonlinearity", k, dtype=f64) for k in SIGMOID_KEYS])
    else:
        sig = np.vstack([np.ones(4), np.ones(4), np.zeros(4), np.zeros(4), np.ones(4), np.zeros(4)])
    _, traj = run_batch(a[None], b[None], c[None], loop_parameters(artifact_parameters(artifact))[None],
                        sig[None], run.inputs, run.initial, keep_trajectories=True)
    return traj[0]


@dataclass(frozen=True)
class ArtifactEvaluation:
    run: ModelRun
    float64: np.ndarray
    float32: np.ndarray
    metrics: dict

    @property
    def max_abs_f32_minus_f64(self) -> float:
        diff = np.abs(self.float32 - self.float64)
        return float(np.max(diff)) if np.all(np.isfinite(diff)) else float("inf")


def artifact_drive(artifact: ModelArtifact, dataset: Dataset) -> np.ndarray:
    """The dataset's rows as the target receives them for this artifact (with the currents if it needs them)."""
    return drive_matrix(dataset, artifact.drive_signals)


def evaluate_artifact(artifact: ModelArtifact, dataset: Dataset) -> ArtifactEvaluation:
    loss_model, motor = artifact_loss_model(artifact)
    run = model_run(dataset, loss_model, motor, artifact.dt, name=dataset.name)
    y64 = float64_estimate(artifact, dataset, run)
    _, y32 = run_offline(artifact, artifact_drive(artifact, dataset), run.initial)
    y32 = y32.astype(np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        metrics = {"float64": winding_pm_metrics(y64, run), "float32": winding_pm_metrics(y32, run)}
    return ArtifactEvaluation(run, y64, y32, metrics)
