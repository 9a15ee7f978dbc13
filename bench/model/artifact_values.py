"""The float64 values an artifact was built from, as the lab's objects: its LPTN parameters, its loss model (its
kind's float64 model) and motor constants, its linear block in shift form. Light on purpose (no fitting code): the
run analysis reads these for its float64 reference."""

from __future__ import annotations

import numpy as np

from bench.motor.losses import LossModel, MotorConstants
from bench.motor.losskinds import LAB_LOSS_KINDS
from bench.thermal.parameters import LptnParameters
from target_sim.artifact import LPTN_PARAMETERS, ModelArtifact
from target_sim.kinds import is_delta


def artifact_parameters(artifact: ModelArtifact) -> LptnParameters:
    return LptnParameters(**{n: float(artifact.array("lptn", "parameters", n, dtype=np.float64)) for n in
                             LPTN_PARAMETERS})


def artifact_loss_model(artifact: ModelArtifact) -> tuple[LossModel, MotorConstants]:
    """The artifact's loss model (its kind's float64 model) and motor constants, from its float64 values."""
    def f64(*keys):
        return artifact.array(*keys, dtype=np.float64)

    motor = MotorConstants(i_max_A=float(f64("losses", "current_max_A")),
                           max_speed_rpm=float(f64("lptn", "speed_max_rpm")),
                           alpha_cu_per_K=float(f64("losses", "alpha_cu_per_K")),
                           reference_C=float(f64("losses", "copper_reference_C")))
    return LAB_LOSS_KINDS[artifact.loss_model].from_artifact(artifact, motor.i_max_A), motor


def shift_form(artifact: ModelArtifact) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The artifact's linear block as float64 (A, B, C) of x <- A x + B u, y = C x; a delta block becomes
    A = I + Δ·A_δ, B = Δ·B_δ (its reference temperature drops out: a uniform temperature with no losses is an
    equilibrium of the network, so the deviation form and the absolute form are the same model)."""
    f64 = np.float64
    a, b, c = (artifact.array("linear_block", m, dtype=f64) for m in ("A", "B", "C"))
    if is_delta(artifact.kind, artifact.realization):
        a, b = np.eye(a.shape[0]) + artifact.dt * a, artifact.dt * b
    return a, b, c
