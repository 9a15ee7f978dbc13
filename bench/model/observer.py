"""The lab's side of the observer: tune its process and measurement noise on training files, and write it into a
model artifact (the optional `observer` section, schema version 3; `target_sim.observer` runs it).

Process noise Q is diagonal in the node temperatures (°C² per model step for yoke, winding, tooth, magnet) and
brought into the realization's coordinates, Q_x = C⁻¹ diag(q) C⁻ᵀ; R is the measurement's variance (°C²). Both are
tuned on the training files (float64 filter, `bench.thermal.kalman`; Nelder-Mead over log10 q and log10 R), every
file its own run from its own initial state, by one of two criteria (`TUNING_CRITERIA`):
- `magnet` (the default): the sum of log magnet MSE of the deployed filter (the sensor only) over every training
  file started with the magnet as measured, 30 K too warm and 30 K too cold: what the observer is for, scored by
  the lab's magnet reference (pm_C), which the deployed filter never sees;
- `likelihood`: the innovations' likelihood (Mehra), with the magnet reference as a second measurement while
  tuning (its variance a nuisance parameter), so the magnet's process noise is tuned where it is observable.
Measured on the built-in motor: the likelihood of the winding sensor's innovations alone is best when the magnet
state soaks up the winding model's errors (40 °C run: magnet RMSE 0.21 K open loop, 5.6 K with that filter), and
even with the reference while tuning, P0's magnet uncertainty lets the first minutes' winding innovations throw the
magnet 23 K off; hence the magnet criterion. The initial covariance says how
little is known at start: P0 = C⁻¹ diag(σ0²) C⁻ᵀ with σ0 = `INITIAL_SIGMA_C` (a magnet whose temperature at key-on
nobody measured). The steady-state gain K_ss and covariance P_ss are the Riccati solution at the training runs'
median speed and mean coolant temperature.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from bench.drive.dataset import Dataset
from bench.errors import BenchError
from bench.model.artifact_values import artifact_loss_model, artifact_parameters, shift_form
from bench.model.runs import ModelRun, model_run
from bench.thermal import portable
from bench.thermal.estimator import identity_sigmoid, loop_parameters
from bench.thermal.excitation import interval_means
from bench.thermal.kalman import FilterRuns, run_filters, source_jacobian, steady_state
from target_sim.artifact import OUTPUTS, ModelArtifact, encode_array, schema_version_of, seal, verify
from target_sim.kinds import MODEL_KINDS
from target_sim.network import COOLANT_REFERENCE_C

# 1-σ of the initial state (°C): yoke and tooth start at the coolant temperature, the winding as measured, the
# magnet as the host guesses it (the key-on problem: nobody measured it after a short stop)
INITIAL_SIGMA_C = {"yoke": 5.0, "winding": 2.0, "tooth": 5.0, "magnet": 15.0}
# the covariance form the target runs unless told otherwise (chosen from `bench numerics --observer`)
DEPLOYED_FORM = "ud"
SIGMOID_KEYS = ("scale_W", "weight", "bias", "gain", "linear", "offset")
START_Q_C2 = 1e-4       # the search starts here for every node (°C² per step) ...
START_R_C2 = 0.1        # ... and here for the measurement
LOG10_BOUNDS = (-12.0, 3.0)


@dataclass(frozen=True)
class Measurement:
    """A temperature sensor of one model node: which output it sees, its dataset column, its offset (subtracted
    from the reading) and its lag (described; the filter ignores it in this version)."""

    node: str = "winding"
    column: str = "winding_C"
    offset_C: float = 0.0
    lag_s: float = 0.0

    @property
    def index(self) -> int:
        return OUTPUTS.index(self.node)


# the lab's reference of the magnet in the training files, used while tuning only
TUNING_REFERENCE = Measurement("magnet", "pm_C")


@dataclass(frozen=True)
class ObserverFit:
    measurement: Measurement
    q_C2: np.ndarray            # (4,) process noise per node, °C² per step
    r_C2: float
    r_reference_C2: float | None   # the magnet reference's variance while tuning (None: not used)
    criterion: str
    cost: float                 # the criterion's value at the optimum
    nll: float                  # the deployed filter's innovations' negative log-likelihood on the training files
    updates: int
    evaluations: int
    files: list[str] = field(default_factory=list)


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
    """One file prepared for the filter: the model run and the measurements per model step (interval means),
    (steps, measurements)."""

    run: ModelRun
    z: np.ndarray
    measurements: tuple[Measurement, ...]


def filter_data(artifact: ModelArtifact, dataset: Dataset, measurements: Sequence[Measurement]) -> FilterData:
    for m in measurements:
        if not dataset.has(m.column):
            raise BenchError(f"{dataset.path} has no column {m.column!r}, the observer's measurement; map it with "
                             "--mapping or choose another with --measure")
    loss_model, motor = artifact_loss_model(artifact)
    run = model_run(dataset, loss_model, motor, artifact.dt, name=dataset.name)
    columns = np.column_stack([dataset.column(m.column) for m in measurements])
    z = interval_means(columns, dataset.sample_period_s, artifact.dt)
    return FilterData(run, z[: len(run.step_time_s)], tuple(measurements))


def _run(model: FilterModel, data: FilterData, q, r, p0, keep=False) -> FilterRuns:
    return run_filters(model.a, model.b, model.c, model.theta, model.sigmoid, data.run.inputs, data.run.initial,
                       data.z, [m.index for m in data.measurements], [m.offset_C for m in data.measurements], q, r,
                       p0, keep)


def initial_covariance(model: FilterModel) -> np.ndarray:
    return model.to_state([INITIAL_SIGMA_C[n] ** 2 for n in OUTPUTS])


TUNING_CRITERIA = ("magnet", "likelihood")
# the magnet criterion starts every training file with the magnet as measured and this much too warm and too cold
TUNING_START_OFFSETS_K = (0.0, 30.0, -30.0)


def tune_observer(artifact: ModelArtifact, datasets: Sequence[Dataset], measurement: Measurement,
                  criterion: str = "magnet", max_evaluations: int = 800,
                  progress: Callable[[int, float], None] | None = None) -> ObserverFit:
    """q and R on the training files by Nelder-Mead over their log10 values, minimizing either
    - "magnet": the sum of log magnet MSE over every training file started with the magnet as measured and
      `TUNING_START_OFFSETS_K` off (the deployed filter, the sensor only; the reference only scores it), or
    - "likelihood": the innovations' negative log-likelihood, with the magnet reference as a second measurement
      where every training file has it (its variance a nuisance parameter)."""
    from scipy.optimize import minimize

    if criterion not in TUNING_CRITERIA:
        raise BenchError(f"tuning criterion {criterion!r} is not one of {', '.join(TUNING_CRITERIA)}")
    model = FilterModel.of(artifact)
    p0 = initial_covariance(model)
    deployed = [filter_data(artifact, d, (measurement,)) for d in datasets]
    if criterion == "likelihood":
        use_reference = measurement.node != TUNING_REFERENCE.node and all(d.has(TUNING_REFERENCE.column)
                                                                         for d in datasets)
        measurements = (measurement, TUNING_REFERENCE) if use_reference else (measurement,)
        data = [filter_data(artifact, d, measurements) for d in datasets]

        def score(q, r):
            return sum(float(_run(model, d, q, [r], p0).nll[0]) for d in data)
    else:
        use_reference, measurements = False, (measurement,)
        magnet = OUTPUTS.index("magnet")

        def score(q, r):
            total = 0.0
            for d in deployed:
                for offset in TUNING_START_OFFSETS_K:
                    start = d.run.initial.copy()
                    start[magnet] += offset
                    shifted = FilterData(replace(d.run, initial=start), d.z, d.measurements)
                    estimate = _run(model, shifted, q, [r], p0, keep=True).estimates[0][:, magnet]
                    total += float(np.log(np.mean((estimate - d.run.ref_pm) ** 2)))
            return total

    calls = [0]
    low, high = LOG10_BOUNDS

    def cost(v):
        v = np.clip(v, low, high)
        total = score(model.to_state(10.0 ** v[:4])[None], 10.0 ** v[4:])
        calls[0] += 1
        if progress:
            progress(calls[0], total)
        return total if np.isfinite(total) else 1e300

    start = np.log10([START_Q_C2] * 4 + [START_R_C2] * len(measurements))
    size = len(start)
    result = minimize(cost, start, method="Nelder-Mead",
                      options={"maxfev": max_evaluations, "xatol": 1e-3, "fatol": 1e-3,
                               "initial_simplex": start + np.vstack([np.zeros(size), np.eye(size)])})
    best = np.clip(result.x, low, high)
    q, r = 10.0 ** best[:4], float(10.0 ** best[4])
    runs = [_run(model, d, model.to_state(q)[None], [[r]], p0) for d in deployed]
    return ObserverFit(measurement, q, r, float(10.0 ** best[5]) if use_reference else None, criterion,
                       float(cost(best)), sum(float(x.nll[0]) for x in runs), sum(int(x.updates[0]) for x in runs),
                       calls[0], [str(d.path) for d in datasets])


def nominal_transition(artifact: ModelArtifact, model: FilterModel, datasets: Sequence[Dataset]) -> tuple:
    """F (shift form) at the training runs' median speed ratio and mean coolant temperature, and that point."""
    loss_model, motor = artifact_loss_model(artifact)
    runs = [model_run(d, loss_model, motor, artifact.dt) for d in datasets]
    ratio = float(np.median(np.concatenate([r.inputs.speed_ratio for r in runs])))
    coolant = float(np.mean(np.concatenate([r.inputs.coolant for r in runs])))
    th = model.theta
    g_wm = th[4] * np.exp(-ratio / th[5]) / th[6]
    g_tm = th[7] * np.exp(-ratio / th[8]) / th[9]
    g_ma = th[10] * np.exp(-ratio / th[11]) / th[12]
    g_cy = th[13] * (coolant - COOLANT_REFERENCE_C)
    f = model.a + model.b[:, 4:] @ source_jacobian([g_tm, g_wm, g_ma, g_cy]) @ model.c
    return f, {"speed_ratio": ratio, "coolant_C": coolant}


def observer_section(artifact: ModelArtifact, fit: ObserverFit, datasets: Sequence[Dataset],
                     form: str = DEPLOYED_FORM) -> dict:
    """The artifact's `observer` section for a tuned fit."""
    model = FilterModel.of(artifact)
    q = model.to_state(fit.q_C2)
    f, nominal = nominal_transition(artifact, model, datasets)
    gain, p_steady = steady_state(f, model.c[fit.measurement.index], q, fit.r_C2)
    m, enc = fit.measurement, encode_array
    return {
        "kind": "kalman-linear-block", "node": m.node, "column": m.column, "lag_s": float(m.lag_s),
        "form": form,
        "rule": "after each model step: F = A + B_s G C (delta: I + dt (A + B_s G C)), G the sources' Jacobian; "
                "P- = F P F' + Q; with a measurement z: nu = (z - offset_C) - y[node], h = C[node], "
                "K = P- h' / (h P- h' + R), x += K nu, y = C x (+ r)",
        "Q": enc(q), "q_nodes_C2": enc(fit.q_C2), "R": enc(fit.r_C2), "P0": enc(initial_covariance(model)),
        "offset_C": enc(m.offset_C),
        "K_ss": enc(gain), "P_ss": enc(p_steady),
        "tuning": {"method": f"{fit.criterion} criterion (float64 filter, Nelder-Mead on log10 q and R)",
                   "criterion_value": fit.cost,
                   "q_C2_per_step": dict(zip(OUTPUTS, (float(v) for v in fit.q_C2), strict=True)),
                   "R_C2": fit.r_C2, "negative_log_likelihood": fit.nll, "updates": fit.updates,
                   "reference_while_tuning": None if fit.r_reference_C2 is None else
                   {"column": TUNING_REFERENCE.column, "R_C2": fit.r_reference_C2},
                   "evaluations": fit.evaluations, "files": [str(p) for p in fit.files],
                   "initial_sigma_C": INITIAL_SIGMA_C, "steady_state_at": nominal},
    }


def with_observer(artifact: ModelArtifact, section: dict) -> dict:
    """The artifact's content with `section` as its observer (schema version 3), sealed."""
    content = {k: v for k, v in artifact.content.items() if k != "sha256"}
    content["observer"] = section
    content["schema_version"] = schema_version_of(content)
    sealed = seal(content)
    verify(sealed)
    return sealed


def reference_run(artifact: ModelArtifact, dataset: Dataset) -> tuple[FilterData, FilterRuns]:
    """The float64 reference of the artifact's observer on one file (estimate and 1-σ per step)."""
    model = FilterModel.of(artifact)
    data = filter_data(artifact, dataset, (measurement_of(artifact),))
    q = artifact.array("observer", "Q", dtype=np.float64)
    r = float(artifact.array("observer", "R", dtype=np.float64))
    p0 = artifact.array("observer", "P0", dtype=np.float64)
    return data, _run(model, data, q[None], [[r]], p0, keep=True)


def measurement_of(artifact: ModelArtifact) -> Measurement:
    section = artifact.content["observer"]
    return Measurement(section["node"], section["column"],
                       float(artifact.array("observer", "offset_C", dtype=np.float64)), float(section["lag_s"]))
