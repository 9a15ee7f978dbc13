"""The identification pipeline: datasets -> PSO LPTN -> LM Hammerstein -> artifacts of the three model kinds."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.drive.motor import VIRTUAL_MOTOR, LossMaps, MotorSpec, nominal_loss_maps
from bench.model.builder import ModelSpec, SigmoidInputs, artifact_content, physical_block
from bench.model.hammerstein_fit import HammersteinFit, fit_hammerstein
from bench.model.lptn_fit import LptnFit, identify_lptn
from bench.model.metrics import error_metrics
from bench.model.runs import ModelRun, model_run
from bench.thermal.estimator import identity_sigmoid, loop_parameters, run_batch
from bench.thermal.parameters import LptnParameters
from bench.thermal.realizations import Realization

IDENTIFICATION_COOLANTS = (20, 60)
VALIDATION_COOLANT = 40


@dataclass
class Identification:
    """Everything one `bench identify` produced."""

    dt: float
    discretization: str
    lptn: LptnFit
    hammerstein: HammersteinFit
    loss_maps: LossMaps
    motor: MotorSpec
    provenance: dict
    timings_s: dict = field(default_factory=dict)

    def spec(self, kind: str, realization: str = "balanced", metrics: dict | None = None) -> ModelSpec:
        common = {"params": self.lptn.params, "dt": self.dt, "loss_maps": self.loss_maps, "motor": self.motor,
                  "provenance": self.provenance, "metrics": metrics or {}}
        if kind == "hammerstein":
            return ModelSpec("hammerstein", discretization=self.discretization, realization=realization,
                             sigmoid=self.hammerstein.model.sigmoid, linear_block=self.hammerstein.model.block,
                             **common)
        if kind == "pv-lptn":
            return ModelSpec("pv-lptn", discretization="euler", realization="physical", **common)
        return ModelSpec("lti-lptn", discretization=self.discretization, realization=realization, **common)

    def content(self, kind: str, realization: str = "balanced", metrics: dict | None = None) -> dict:
        return artifact_content(self.spec(kind, realization, metrics))


def prepare_runs(datasets, loss_maps: LossMaps, motor: MotorSpec, dt: float) -> list[ModelRun]:
    return [model_run(d, loss_maps, motor, dt, name=str(d.path)) for d in datasets]


def identify(datasets, *, dt: float = 0.5, discretization: str = "zoh", swarm_size: int = 220,
             pso_iterations: int = 100, lm_iterations: int = 100, seed: int = 0, fit_path: str = "statespace",
             motor: MotorSpec = VIRTUAL_MOTOR, progress: Callable[[str, int, float], None] | None = None
             ) -> Identification:
    """Identify the LPTN (PSO) and the Hammerstein model (LM) on the identification datasets."""
    if discretization != "zoh":
        raise ValueError("identification discretizes by zero-order hold, as the paper's Hammerstein fit did")
    loss_maps = nominal_loss_maps(motor)
    runs = prepare_runs(datasets, loss_maps, motor, dt)
    timings = {}
    started = time.perf_counter()
    lptn = identify_lptn(runs, dt, swarm_size=swarm_size, iterations=pso_iterations, seed=seed,
                         on_iteration=(lambda i, c: progress("pso", i, c)) if progress else None)
    timings["pso"] = time.perf_counter() - started
    started = time.perf_counter()
    base = physical_block(ModelSpec("lti-lptn", lptn.params, dt, discretization, "physical", loss_maps, motor))
    ham = fit_hammerstein(base, lptn.params, runs, path=fit_path, iterations=lm_iterations,
                          on_iteration=(lambda i, c: progress("lm", i, c)) if progress else None)
    timings["lm"] = time.perf_counter() - started
    provenance = {
        "datasets": [{"path": Path(d.path).name, "sha256": d.sha256,
                      "coolant_C": getattr(d, "coolant_setpoint_C", None)} for d in datasets],
        "seed": seed, "pso": {"swarm": swarm_size, "iterations": pso_iterations, "cost": "sum of log MSE "
                              "(winding, PM): Gaussian maximum likelihood with unknown variances"},
        "lm": {"iterations": lm_iterations, "path": fit_path, "coordinates": ham.coordinates},
        "versions": _versions(),
    }
    return Identification(dt, discretization, lptn, ham, loss_maps, motor, provenance, timings)


def _versions() -> dict:
    import scipy

    return {"numpy": np.__version__, "scipy": scipy.__version__}


def simulate_float64(block: Realization, params: LptnParameters, sigmoid: SigmoidInputs | None,
                     run: ModelRun) -> np.ndarray:
    """(steps, 4) float64 estimate of one model on one run."""
    sig = identity_sigmoid(np.ones(4)) if sigmoid is None else np.vstack(
        [sigmoid.scale_W, sigmoid.weight, sigmoid.bias, sigmoid.gain, sigmoid.linear, sigmoid.offset])
    _, traj = run_batch(block.a[None], block.b[None], block.c[None], loop_parameters(params)[None], sig[None],
                        run.inputs, run.initial, keep_trajectories=True)
    return traj[0]


def winding_pm_metrics(estimate: np.ndarray, run: ModelRun) -> dict:
    return {"winding": error_metrics(estimate[:, 1], run.ref_winding), "pm": error_metrics(estimate[:, 3], run.ref_pm)}
