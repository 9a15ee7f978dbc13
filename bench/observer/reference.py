"""The float64 reference of the observer on an artifact and a file (`bench.thermal.kalman`, the same filter as
`target_sim.observer` in float64): the artifact's values as the filter takes them (`FilterModel`), a file prepared
for it (`filter_data`), the filter runs (`run_filter`), the initial covariance P0 and the process noise Q in the
state coordinates, and the reference run of an artifact's own observer (`reference_run`).

The initial covariance says how little is known at start: P0 = C⁻¹ diag(σ0²) C⁻ᵀ with σ0 = `INITIAL_SIGMA_C` (a
magnet whose temperature at key-on nobody measured).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bench.drive.dataset import Dataset
from bench.errors import BenchError
from bench.model.artifact_values import artifact_loss_model, artifact_parameters, shift_form
from bench.model.runs import ModelRun, model_run
from bench.observer.measured import lab_measurements, r_scales
from bench.thermal import portable
from bench.thermal.estimator import identity_sigmoid, loop_parameters
from bench.thermal.kalman import FilterRuns, Readings, run_filters
from target_sim.artifact import BIAS_KINDS, OUTPUTS, ModelArtifact, consider_release, observer_gate
from target_sim.kinds import MODEL_KINDS

# 1-σ of the initial state (°C): yoke and tooth start as the initial-state rule puts them (bench.model.runs: as
# measured, else at the coolant temperature), the winding as measured, the
# magnet as the host guesses it (the key-on problem: nobody measured it after a short stop)
INITIAL_SIGMA_C = {"yoke": 5.0, "winding": 2.0, "tooth": 5.0, "magnet": 15.0}
SIGMOID_KEYS = ("scale_W", "weight", "bias", "gain", "linear", "offset")
# the bias state's initial 1-σ per kind (W into its node) and the lag states' (K, beyond what their sensor sees).
# The magnet's: of the order of a magnet loss (tens of W; 100s of W at most), so P0 does not let the first
# innovations throw the magnet far (see `bench.observer.tune`'s note on P0)
# An output bias's (°C): the model starts at the measured winding, so its error there starts small
BIAS_SIGMA_W = {"winding-heat": 50.0, "magnet-heat": 20.0, "winding-output": 1.0}
LAG_SIGMA_C = 0.5
# what the section names each bias state, and the node it heats (as the section's rule says it)
BIAS_NAMES = {"winding-heat": "winding heat bias (W)", "magnet-heat": "magnet heat bias (W)",
              "winding-output": "winding output bias (°C)"}
BIAS_RULES = {"winding-heat": "the bias heats the winding (x += b_w beta)",
              "magnet-heat": "the bias heats the magnet (x += b_m beta)",
              "winding-output": "the bias adds to the winding's output (y_w + b_w, what the sensors see and the "
                                "estimate reports) and heats nothing; a winding reading moves the bias, no node"}


def bias_kind(bias) -> str | None:
    """The bias kind of a `bias` argument: a kind of `BIAS_KINDS`, True (the winding's, the one kind there was), or
    None/False (no bias)."""
    kind = "winding-heat" if bias is True else (bias or None)
    if kind is not None and kind not in BIAS_KINDS:
        raise BenchError(f"bias {kind!r} is not one of {', '.join(BIAS_KINDS)}")
    return kind


@dataclass(frozen=True)
class FilterModel:
    """An artifact's float64 values as the reference filter takes them."""

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    theta: np.ndarray
    sigmoid: np.ndarray

    @classmethod
    def of(cls, artifact: ModelArtifact) -> FilterModel:
        if not MODEL_KINDS[artifact.kind].linear_block:
            raise BenchError(f"an observer needs a linear block; a {artifact.kind} artifact has none (use the "
                             "lti-lptn or hammerstein artifact)")
        a, b, c = shift_form(artifact)
        if MODEL_KINDS[artifact.kind].input_nonlinearity:
            sig = np.vstack([artifact.array("input_nonlinearity", k, dtype=np.float64) for k in SIGMOID_KEYS])
        else:
            sig = identity_sigmoid(np.ones(4))
        return cls(a, b, c, loop_parameters(artifact_parameters(artifact)), sig)

    def to_state(self, physical_diag) -> np.ndarray:
        """C⁻¹ diag(v) C⁻ᵀ: a diagonal covariance of the node temperatures in the state coordinates."""
        c_inv = portable.inv(self.c)
        return (c_inv * np.asarray(physical_diag, dtype=float)) @ c_inv.T


@dataclass(frozen=True)
class FilterData:
    """One file prepared for the filter: the model run and the readings per model step."""

    run: ModelRun
    readings: Readings
    measurements: tuple


def filter_data(artifact: ModelArtifact, dataset: Dataset, measurements: Sequence, bias=None,
                consider: str | None = None, release_C2: float | None = None) -> FilterData:
    for m in measurements:
        for column in m.columns:
            if not dataset.has(column):
                raise BenchError(f"{dataset.path} has no column {column!r}, the observer's measurement; map the "
                                 f"file's column of that sensor onto {column} with --mapping (a mapping file's "
                                 f"[columns] YOUR_COLUMN = \"{column}\") or choose another with --measure")
    loss_model, motor = artifact_loss_model(artifact)
    run = model_run(dataset, loss_model, motor, artifact.dt, name=dataset.name)
    steps = len(run.step_time_s)
    parts = [m.readings(dataset, artifact.dt, steps) for m in measurements]
    z0, z1, rel = (np.column_stack([p[i] for p in parts]) for i in range(3))
    readings = Readings(z0, z1, rel, np.array([m.sees for m in measurements]),
                        np.array([m.lag_pole(artifact.dt) for m in measurements]), bias_kind(bias), consider,
                        release_C2)
    return FilterData(run, readings, tuple(measurements))



def run_filter(model: FilterModel, data: FilterData, q, r, p0, keep=False,
               gate_sigma: float | None = None) -> FilterRuns:
    """The float64 filter over one prepared file, once per (q, r) of the batch (`bench.thermal.kalman.run_filters`);
    `keep`: with the estimates and 1-σ per step."""
    return run_filters(model.a, model.b, model.c, model.theta, model.sigmoid, data.run.inputs, data.run.initial,
                       data.readings, q, r, p0, keep, gate_sigma)


def initial_covariance(model: FilterModel, readings: Readings | None = None) -> np.ndarray:
    """P0: the nodes' `INITIAL_SIGMA_C` in the state coordinates; a lag state as its sensor's view of them plus
    `LAG_SIGMA_C`; the bias its kind's `BIAS_SIGMA_W`."""
    p = model.to_state([INITIAL_SIGMA_C[n] ** 2 for n in OUTPUTS])
    if readings is None or readings.states == 4:
        return p
    n = readings.states
    t = np.zeros((n, 4))
    t[:4] = np.eye(4)
    extra = np.zeros(n)
    for m, lag in enumerate(readings.lag_index):
        if lag >= 0:
            t[lag] = readings.sees[m] @ model.c
            extra[lag] = LAG_SIGMA_C ** 2
    if readings.bias:
        extra[n - 1] = BIAS_SIGMA_W[readings.bias] ** 2
    return t @ p @ t.T + np.diag(extra)


def process_noise(model: FilterModel, q: np.ndarray) -> np.ndarray:
    """Q: the nodes' diagonal in the state coordinates (C⁻¹ diag(q) C⁻ᵀ), the extra states' own diagonal."""
    out = np.diag(np.asarray(q, dtype=float))
    out[:4, :4] = model.to_state(q[:4])
    return out


def reference_run(artifact: ModelArtifact, dataset: Dataset) -> tuple[FilterData, FilterRuns]:
    """The float64 reference of the artifact's observer on one file (estimate and 1-σ per step), with the section's
    innovation gate (`observer_gate`; its rejections counted in the runs' `rejections`)."""
    model = FilterModel.of(artifact)
    section = artifact.content["observer"]
    data = filter_data(artifact, dataset, lab_measurements(artifact), section.get("bias"), section.get("consider"),
                       consider_release(section))
    q = artifact.array("observer", "Q", dtype=np.float64)
    p0 = artifact.array("observer", "P0", dtype=np.float64)
    gate = observer_gate(section)
    return data, run_filter(model, data, q[None], [r_scales(artifact)], p0, keep=True,
                      gate_sigma=None if gate is None else gate[0])
