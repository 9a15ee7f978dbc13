"""A model artifact with its parameters off: the LPTN's thermal resistances and capacitances (each group), the
stator loss split (moved by percentage points of the iron loss between yoke and tooth), and the loss model's
coefficients, rebuilt into an artifact the target loads (sealed and
verified, so an unstable result is refused as the target would refuse it).

The parameter-varying LPTN runs from its `lptn` parameters: they are changed and nothing else. A linear block
(the LTI LPTN, the Hammerstein model's fitted block) was built from the parameters, or fitted: it is brought back
to continuous time in the nodes' coordinates, every entry scaled by the relative change the same parameter change
makes to that entry of the LTI LPTN's matrices (a capacitance scales its node's row, a resistance the two
conductance entries and the diagonals it adds to), discretized again as the artifact was (zoh, tustin) and
realized as the artifact is. The loss model's coefficients are scaled in the groups its kind declares
(`robustness_groups` of `bench.motor.losskinds`: loss maps table by table, the electrical model coefficient by
coefficient).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping

import numpy as np
import scipy.linalg

from bench.model.artifact_values import artifact_parameters
from bench.model.builder import artifact_content
from bench.model.evaluate import physical_from_artifact, sigmoid_from_artifact, spec_at
from bench.motor.losskinds import LAB_LOSS_KINDS
from bench.thermal.discretize import discretize
from bench.thermal.lptn import lti_matrices
from bench.thermal.parameters import LptnParameters
from bench.thermal.realizations import physical
from target_sim.artifact import ModelArtifact, decode_array, encode_array, seal, verify
from target_sim.kinds import MODEL_KINDS

# the LPTN's parameter groups: a group's parameters move together (a path's constant and speed-dependent parts)
PARAMETER_GROUPS: dict[str, tuple[str, ...]] = {
    "C_y": ("C_y",), "C_w": ("C_w",), "C_t": ("C_t",), "C_m": ("C_m",),
    "R_yw": ("R_yw",), "R_yt": ("R_yt",), "R_wt": ("R_wt",),
    "R_cy": ("R_cy0",), "R_wm": ("R_wm0", "a_wm"), "R_tm": ("R_tm0", "a_tm"), "R_ma": ("R_ma0", "a_ma"),
}
# the stator iron loss split between yoke and tooth (eqs. 6-8): moved in percentage points, not scaled (a share
# near 1 scaled by 1.1 would put more than the whole loss into the yoke and a negative loss into the tooth)
SPLIT = "k_split"
SPLIT_UNIT = "points"
BLOCK_PARAMETERS = ("C_y", "C_w", "C_t", "C_m", "R_yw", "R_yt", "R_wt", "R_cy0", "a_wm", "a_tm", "a_ma")


def loss_groups(artifact: ModelArtifact) -> Mapping[str, tuple[tuple[str, ...], ...]]:
    """The loss model's coefficient groups: group name -> the keys under the artifact's `losses` it scales (each
    loss kind declares its own: `bench.motor.losskinds`)."""
    return LAB_LOSS_KINDS[artifact.loss_model].robustness_groups


def parameter_subjects(artifact: ModelArtifact) -> tuple[str, ...]:
    return (*PARAMETER_GROUPS, SPLIT, *loss_groups(artifact))


def continuous(a_d: np.ndarray, b_d: np.ndarray, dt: float, method: str) -> tuple[np.ndarray, np.ndarray]:
    """The continuous (A, B) that `discretize(A, B, dt, method)` turns into (A_d, B_d)."""
    n = len(a_d)
    if method == "zoh":
        a = np.real(scipy.linalg.logm(a_d)) / dt
        return a, np.linalg.solve(a_d - np.eye(n), a @ b_d)
    if method == "tustin":
        a = (2.0 / dt) * (a_d - np.eye(n)) @ np.linalg.inv(a_d + np.eye(n))
        return a, (np.eye(n) - a * dt / 2) @ b_d / dt
    raise ValueError(f"a {method} linear block cannot be brought back to continuous time")


def _ratio(new: np.ndarray, old: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(old != 0, new / np.where(old != 0, old, 1.0), 1.0)


def scaled_block(artifact: ModelArtifact, old: LptnParameters, new: LptnParameters) -> dict:
    """The artifact's `linear_block` section with the parameter change old -> new carried into its block."""
    block = physical_from_artifact(artifact)
    method = artifact.content.get("discretization", "zoh")
    a_c, b_c = continuous(block.a, block.b, artifact.dt, method)
    a_old, b_old = lti_matrices(old)[:2]
    a_new, b_new = lti_matrices(new)[:2]
    a_d, b_d = discretize(a_c * _ratio(a_new, a_old), b_c * _ratio(b_new, b_old), artifact.dt, method)
    sigmoid = sigmoid_from_artifact(artifact) if MODEL_KINDS[artifact.kind].input_nonlinearity else None
    spec = spec_at(artifact, artifact.kind, artifact.dt, artifact.realization,
                   physical(a_d, b_d, np.eye(4), np.zeros((4, 8))), sigmoid)
    spec.params = new
    return artifact_content(spec)["linear_block"]


def with_parameters(artifact: ModelArtifact, factors: Mapping[str, float]) -> ModelArtifact:
    """The artifact with LPTN parameters multiplied by `factors` (name -> factor); ArtifactError when the result
    is refused (unstable)."""
    old = artifact_parameters(artifact)
    return with_values(artifact, {name: getattr(old, name) * factor for name, factor in factors.items()})


def with_values(artifact: ModelArtifact, values: Mapping[str, float]) -> ModelArtifact:
    """The artifact with LPTN parameters set to `values` (name -> value), its linear block carried along."""
    old = artifact_parameters(artifact)
    new = old.with_values(**values)
    content = copy.deepcopy({k: v for k, v in artifact.content.items() if k != "sha256"})
    for name in values:
        content["lptn"]["parameters"][name] = encode_array(getattr(new, name))
    if MODEL_KINDS[artifact.kind].linear_block and any(name in BLOCK_PARAMETERS for name in values):
        content["linear_block"] = scaled_block(artifact, old, new)
    return verify(seal(content))


def with_losses(artifact: ModelArtifact, keys: tuple[tuple[str, ...], ...], factor: float) -> ModelArtifact:
    """The artifact with the loss-model entries `keys` (under `losses`) multiplied by `factor`."""
    content = copy.deepcopy({k: v for k, v in artifact.content.items() if k != "sha256"})
    for key in keys:
        node = content["losses"]
        for part in key[:-1]:
            node = node[part]
        node[key[-1]] = encode_array(decode_array(node[key[-1]], ".".join(key), np.float64) * factor)
    return verify(seal(content))


def shifted_split(artifact: ModelArtifact, points: float) -> ModelArtifact:
    """The artifact with `points` percentage points of the stator iron loss moved from the tooth to the yoke at
    every operating point (k_0 + points/100; k_1..k_3, the share's dependence on current and speed, kept)."""
    return with_values(artifact, {"k_0": artifact_parameters(artifact).k_0 + points / 100.0})


def perturbed_model(artifact: ModelArtifact, subject: str, magnitude: float) -> ModelArtifact:
    """The artifact with parameter group `subject` off by `magnitude` % (the stator loss split: moved by
    `magnitude` percentage points, `shifted_split`)."""
    if subject == SPLIT:
        return shifted_split(artifact, magnitude)
    factor = 1.0 + magnitude / 100.0
    if subject in PARAMETER_GROUPS:
        return with_parameters(artifact, {name: factor for name in PARAMETER_GROUPS[subject]})
    return with_losses(artifact, loss_groups(artifact)[subject], factor)
