"""Build model artifacts (the JSON the target runs) from a parameter set, loss maps and a fitted model."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench import DISTRIBUTION, package_version
from bench.motor.losses import EstimatorMotor, LossModel
from bench.motor.losskinds import LAB_LOSS_KINDS
from bench.thermal.discretize import discretize
from bench.thermal.lptn import lti_matrices
from bench.thermal.parameters import LptnParameters
from bench.thermal.portable import inv
from bench.thermal.realizations import Realization, condition_number, physical, realize
from dbc.contract import DRIVE_SAMPLE_PERIOD_S
from target_sim import artifact as schema
from target_sim.kinds import MODEL_KINDS


@dataclass(frozen=True)
class SigmoidInputs:
    """Per-loss-input nonlinearity S(u) = gain·σ(weight·u + bias) + linear·u + offset, u = P/scale (eqs. 28-30)."""

    scale_W: np.ndarray
    weight: np.ndarray
    bias: np.ndarray
    gain: np.ndarray
    linear: np.ndarray
    offset: np.ndarray

    @classmethod
    def identity(cls, scale_w) -> SigmoidInputs:
        z = np.zeros(4)
        return cls(np.asarray(scale_w, float), np.ones(4), z, z, np.ones(4), z)

    def as_vector(self) -> np.ndarray:
        return np.concatenate([self.weight, self.bias, self.gain, self.linear, self.offset])

    @classmethod
    def from_vector(cls, scale_w, v) -> SigmoidInputs:
        w, b, g, lin, off = np.split(np.asarray(v, float), 5)
        return cls(np.asarray(scale_w, float), w, b, g, lin, off)


@dataclass
class ModelSpec:
    """Everything an artifact is built from."""

    kind: str                          # lti-lptn | pv-lptn | hammerstein
    params: LptnParameters
    dt: float
    discretization: str                # zoh | tustin (euler for pv-lptn)
    realization: str
    loss_maps: LossModel               # LossMaps or ElectricalLosses (bench.motor.losses)
    motor: EstimatorMotor              # I_max, n_max and the copper coefficients (a MotorSpec is one)
    data_sample_period_s: float = DRIVE_SAMPLE_PERIOD_S
    sigmoid: SigmoidInputs | None = None
    linear_block: Realization | None = None   # the fitted block in physical coordinates (default: the LPTN)
    reference_C: float = 0.0           # delta realization: the temperature its states are deviations from
    provenance: dict[str, Any] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)


def physical_block(spec: ModelSpec) -> Realization:
    if spec.linear_block is not None:
        return spec.linear_block
    a, b, c, d = lti_matrices(spec.params)
    a_d, b_d = discretize(a, b, spec.dt, spec.discretization)
    return physical(a_d, b_d, c, d)


def artifact_content(spec: ModelSpec) -> dict[str, Any]:
    """The unsealed artifact dictionary for `spec`."""
    if spec.kind not in MODEL_KINDS:
        raise ValueError(f"unknown model kind {spec.kind!r}")
    enc = schema.encode_array
    content: dict[str, Any] = {
        "schema": schema.SCHEMA,
        "schema_version": schema.schema_version_of({}),   # no observer: version 2 (bench.observer.section adds one)
        "model_kind": spec.kind,
        "discretization": spec.discretization,
        "realization": spec.realization if MODEL_KINDS[spec.kind].realizations else "physical",
        "outputs": list(schema.OUTPUTS),
        "timing": {"dt_s": float(spec.dt), "data_sample_period_s": float(spec.data_sample_period_s),
                   "input_rule": "float32 mean of the data samples in [k*dt, (k+1)*dt); the step runs on the "
                                 "last sample of the interval"},
        "lptn": {"parameters": {k: enc(v) for k, v in spec.params.as_dict().items()},
                 "speed_max_rpm": enc(spec.motor.max_speed_rpm)},
        "losses": losses_section(spec.loss_maps, spec.motor),
        "initial_state": {"rule": "x0 = C_inv @ y0 with y0 = [yoke, winding, tooth, magnet] from the RESET frames; "
                                  "the host sends the first measured coolant temperature for yoke and tooth and the "
                                  "first measured winding and PM temperatures"},
        "provenance": {"generator": f"{DISTRIBUTION} {package_version()}", **spec.provenance},
        "metrics": spec.metrics,
    }
    if MODEL_KINDS[spec.kind].linear_block:
        block = realize(physical_block(spec), spec.realization, spec.dt)
        content["linear_block"] = {"A": enc(block.a), "B": enc(block.b), "C": enc(block.c),
                                   "C_inv": enc(inv(block.c)),  # portable: the same bits on every CPU
                                   "condition_number": condition_number(block.a), "form": block.form}
        if block.form == "delta":
            content["linear_block"]["reference_C"] = enc(spec.reference_C)
    if MODEL_KINDS[spec.kind].input_nonlinearity:
        if spec.sigmoid is None:
            raise ValueError("a hammerstein artifact needs its sigmoid parameters")
        s = spec.sigmoid
        content["input_nonlinearity"] = {
            "kind": "sigmoidnet-1", "inputs": ["P_y", "P_w", "P_t", "P_m"],
            **{k: enc(getattr(s, k)) for k in ("scale_W", "weight", "bias", "gain", "linear", "offset")}}
    return content


def losses_section(loss_model: LossModel, motor: EstimatorMotor) -> dict[str, Any]:
    """The artifact's `losses`: the loss model (tables or electrical coefficients) and the copper constants."""
    enc = schema.encode_array
    section: dict[str, Any] = {"model": loss_model.kind}
    section.update(LAB_LOSS_KINDS[loss_model.kind].artifact_section(loss_model, enc))
    section.update({"current_max_A": enc(motor.i_max_A), "alpha_cu_per_K": enc(motor.alpha_cu_per_K),
                    "copper_reference_C": enc(motor.reference_C)})
    return section


def build_artifact(spec: ModelSpec) -> dict[str, Any]:
    """The sealed artifact (with its sha256)."""
    return schema.seal(artifact_content(spec))
