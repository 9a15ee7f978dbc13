"""The identification pipeline: datasets -> PSO LPTN -> LM Hammerstein -> artifacts of the three model kinds."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.model import lm
from bench.model.auto_prior import auto_prior
from bench.model.baselines import fit_baselines
from bench.model.builder import ModelSpec, SigmoidInputs, artifact_content, physical_block
from bench.model.choices import (
    DEFAULT_FREEZE,
    DEFAULT_LM_FACTORIZATION,
    DEPLOYED_REALIZATION,
    POLE_CHOICES,
    POLES_FIT,
    POLES_FIXED,
    REGULARIZATIONS,
    STATOR_RULE,
)
from bench.model.criteria import CRITERIA, DEFAULT_CRITERION
from bench.model.hammerstein_fit import (
    HammersteinFit,
    cv_steps,
    fit_hammerstein,
    fit_hammerstein_cv,
    poles_kept_reason,
)
from bench.model.loss_scales import fit_loss_scales
from bench.model.lptn_fit import (
    DEFAULT_WIDTH,
    FITTED_ALWAYS,
    NODE_WEIGHTS,
    LptnFit,
    identify_lptn,
    log_scaled,
    measured_nodes,
    prior_lptn,
    to_search,
)
from bench.model.metrics import error_metrics
from bench.model.polish import polish_lptn, uncertainty
from bench.model.prior_scales import adapt_prior
from bench.model.runs import ModelRun, model_run
from bench.motor.description import MotorDescription, ThermalPrior, default_motor
from bench.motor.losses import EstimatorMotor, LossModel
from bench.motor.losskinds import LAB_LOSS_KINDS
from bench.thermal.estimator import identity_sigmoid, loop_parameters, run_batch
from bench.thermal.parameters import TABLE1, LptnParameters
from bench.thermal.pso import Stall
from bench.thermal.realizations import Realization
from dbc.contract import DRIVE_SAMPLE_PERIOD_S
from target_sim.kinds import MODEL_KINDS

IDENTIFICATION_COOLANTS = (20, 60)
VALIDATION_COOLANT = 40
# A swarm the polish follows stops once its best cost fell by less than 0.01 in 10 iterations (pso.Stall): 2200
# simulations that gain less than a typical LM step of the polish (23 simulations) are better spent polishing.
# On the IPM example the swarm then stops after 69 of its 100 iterations. Without a polish (the packaged model's
# path) the swarm runs all its iterations.
POLISHED_SWARM_STALL = Stall(window=10, tolerance=0.01)


@dataclass
class Identification:
    """Everything one `bench identify` produced."""

    dt: float
    discretization: str
    lptn: LptnFit
    hammerstein: HammersteinFit
    loss_model: LossModel
    motor: EstimatorMotor
    provenance: dict
    data_sample_period_s: float = DRIVE_SAMPLE_PERIOD_S
    timings_s: dict = field(default_factory=dict)
    reference_C: float = 0.0            # of a delta realization (delta_reference)

    def spec(self, kind: str, realization: str = DEPLOYED_REALIZATION, metrics: dict | None = None) -> ModelSpec:
        common = {"params": self.lptn.params, "dt": self.dt, "loss_maps": self.loss_model, "motor": self.motor,
                  "data_sample_period_s": self.data_sample_period_s, "reference_C": self.reference_C,
                  "provenance": self.provenance, "metrics": metrics or {}}
        if MODEL_KINDS[kind].input_nonlinearity:     # the fitted block behind the fitted sigmoid
            return ModelSpec(kind, discretization=self.discretization, realization=realization,
                             sigmoid=self.hammerstein.model.sigmoid, linear_block=self.hammerstein.model.block,
                             **common)
        if not MODEL_KINDS[kind].linear_block:       # the network itself, stepped by forward Euler
            return ModelSpec(kind, discretization="euler", realization="physical", **common)
        return ModelSpec(kind, discretization=self.discretization, realization=realization, **common)

    def content(self, kind: str, realization: str = DEPLOYED_REALIZATION, metrics: dict | None = None) -> dict:
        return artifact_content(self.spec(kind, realization, metrics))


def prepare_runs(datasets, loss_model: LossModel, motor: EstimatorMotor, dt: float) -> list[ModelRun]:
    """One run per dataset, each with its own initial state (files are never joined)."""
    return [model_run(d, loss_model, motor, dt, name=str(d.path)) for d in datasets]


def _standard_errors(lptn, runs, dt: float) -> dict:
    """The LPTN parameters' standard errors at the fit's result (bench.model.polish.uncertainty)."""
    return uncertainty(runs, dt, lptn.nodes, log_scaled(lptn.bounds), to_search(
        np.array(lptn.params.as_vector()), log_scaled(lptn.bounds)), lptn.bounds)


def identify(datasets, *, dt: float = 0.5, discretization: str = "zoh", swarm_size: int = 220,
             pso_iterations: int = 100, lm_iterations: int = 100, seed: int = 0, fit_path: str = "statespace",
             motor: MotorDescription | None = None, prior: ThermalPrior | None = None,
             width: tuple[float, float] | None = None, validation=(), polish_starts: int = 0,
             regularization: str = "fixed", adapt: bool = False, standard_errors: bool = False,
             freeze: bool = DEFAULT_FREEZE, stator_weight: str = STATOR_RULE, loss_scales: bool = False,
             hammerstein_poles: str = POLES_FIXED, network_cost: str = DEFAULT_CRITERION,
             prior_factor: float | None = None, lm_factorization: str = DEFAULT_LM_FACTORIZATION,
             progress: Callable[[str, int, int, float], None] | None = None) -> Identification:
    """Identify the LPTN (PSO, then `polish_starts` local LM polishes) and the Hammerstein model (LM; its ridge
    `fixed` or chosen by leave-one-file-out cross-validation, `cv`) on the training datasets of `motor` (default:
    the built-in virtual motor). The prior and bounds: `prior`, else the motor's thermal_prior, else Table 1 at
    0.6-1.6; an `auto` prior is read from the training data (bench.model.auto_prior); `adapt` scales a given
    prior to the training data first (bench.model.prior_scales); `width` overrides the prior's bounds.
    `validation` datasets are only recorded in the provenance. `standard_errors` computes the parameters' standard
    errors (`uncertainty`) without a polish too, at the swarm's result (a polish always does). `freeze`: the polish
    freezes at the prior what the data cannot place (bench.model.polish.freeze_unidentified). `stator_weight`: with
    `cv`, the Hammerstein fit's stator weight chosen by its rule or kept fixed (STATOR_WEIGHT_CHOICES). `loss_scales`:
    the stator iron and magnet losses scaled by factors fitted with the network after the swarm and the polish
    (bench.model.loss_scales); the artifacts then carry the scaled loss model. `hammerstein_poles`: the Hammerstein
    fit keeps the network's poles or fits its modes' time constants too (POLE_CHOICES). `network_cost`: the swarm's
    and the polish's criterion (bench.model.criteria.CRITERIA; a foreign prior's adaptation keeps the likelihood).
    `swarm_size` 0: no swarm, the polish starts from the prior (lptn_fit.prior_lptn). `prior_factor`: the polish's
    prior believes each positive parameter within that factor at 2σ (bench.model.polish.prior_sigmas; None: the
    search box's quarter). `lm_factorization`: how the LM fits factor their Jacobian (bench.model.lm).
    The defaults (no polish, fixed ridge, no adaptation, no standard errors, no loss scales) are the packaged model's
    path. `progress`
    is called with (stage "pso", "polish", "scales" or "lm", steps done, steps at most, cost) as each stage goes;
    a stage may end before its most (a stalled swarm, a converged fit)."""
    if discretization != "zoh":
        raise ValueError("identification discretizes by zero-order hold, as the paper's Hammerstein fit did")
    if regularization not in REGULARIZATIONS:
        raise ValueError(f"unknown regularization {regularization!r}; choose one of {', '.join(REGULARIZATIONS)}")
    if hammerstein_poles not in POLE_CHOICES:
        raise ValueError(f"unknown Hammerstein poles {hammerstein_poles!r}; choose one of {', '.join(POLE_CHOICES)}")
    if network_cost not in CRITERIA:
        raise ValueError(f"unknown network cost {network_cost!r}; choose one of {', '.join(CRITERIA)}")
    with lm.using(lm_factorization):     # every LM fit below factors so, in worker threads too
        motor = motor or default_motor()
        prior = prior or motor.prior
        width = width or (prior.bounds if prior else DEFAULT_WIDTH)
        constants = motor.constants()
        runs = prepare_runs(datasets, motor.loss_model, constants, dt)
        timings = {}
        started = time.perf_counter()
        derived = None
        if prior is not None and prior.automatic:
            derived = auto_prior(runs, measured_nodes(runs), motor.limits.torque_Nm)
            start = derived.parameters
        else:
            start = prior.parameters if prior else TABLE1
        adapted = None
        if adapt and derived is None:
            adapted = adapt_prior(runs, dt, start)
            start = adapted.parameters
        if swarm_size:
            lptn = identify_lptn(runs, dt, swarm_size=swarm_size, iterations=pso_iterations, seed=seed, start=start,
                                 width=width, stall=POLISHED_SWARM_STALL if polish_starts > 0 else None,
                                 on_iteration=(lambda i, c: progress("pso", i + 1, pso_iterations, c)) if progress
                                 else None, criterion=network_cost)
        else:
            lptn = prior_lptn(runs, dt, start=start, width=width, criterion=network_cost)
        timings["pso"] = time.perf_counter() - started
        polished, errors = None, None
        if polish_starts > 0:
            started = time.perf_counter()
            if progress:
                progress("polish", 0, 1, lptn.cost)
            # a parameter the data cannot place is frozen at the prior: the motor's own guess (its file's network, or
            # read from its data), or a foreign prior adapted to the data path by path (bench.model.prior_scales)
            lptn, polished = polish_lptn(lptn, runs, dt, polish_starts, prior=start, freeze=freeze,
                                         prior_factor=prior_factor)
            if progress:
                progress("polish", 1, 1, lptn.cost)
            if not loss_scales:     # else at the network the loss scales move, on the scaled losses
                errors = _standard_errors(lptn, runs, dt)
            timings["polish"] = time.perf_counter() - started
        elif standard_errors and not loss_scales:
            started = time.perf_counter()
            errors = _standard_errors(lptn, runs, dt)
            timings["standard_errors"] = time.perf_counter() - started
        loss_model, scales = motor.loss_model, None
        if loss_scales:
            started = time.perf_counter()
            if progress:
                progress("scales", 0, 1, lptn.cost)
            lptn, scales = fit_loss_scales(lptn, runs, dt, start)
            loss_model = LAB_LOSS_KINDS[loss_model.kind].scaled(loss_model, scales.factors)
            runs = prepare_runs(datasets, loss_model, constants, dt)     # the Hammerstein fit's losses
            if polish_starts > 0 or standard_errors:
                errors = _standard_errors(lptn, runs, dt)
            if progress:
                progress("scales", 1, 1, lptn.cost)
            timings["scales"] = time.perf_counter() - started
        started = time.perf_counter()
        base = physical_block(ModelSpec("lti-lptn", lptn.params, dt, discretization, "physical", loss_model,
                                        constants))
        # a network whose modes have no time constant to move (unstable, or a pole on the negative real axis) keeps them
        poles_kept = poles_kept_reason(base.a) if hammerstein_poles == POLES_FIT else None
        if poles_kept:
            hammerstein_poles = POLES_FIXED
        lm_steps = cv_steps(runs, lm_iterations) if regularization == "cv" else lm_iterations + 1
        on_lm = (lambda i, c: progress("lm", i, lm_steps, c)) if progress else None
        if regularization == "cv":
            ham, selection = fit_hammerstein_cv(base, lptn.params, runs, path=fit_path, iterations=lm_iterations,
                                                on_iteration=on_lm, stator_weight=stator_weight,
                                                poles=hammerstein_poles)
        else:
            ham, selection = fit_hammerstein(base, lptn.params, runs, path=fit_path, iterations=lm_iterations,
                                             on_iteration=on_lm, poles=hammerstein_poles), None
        timings["lm"] = time.perf_counter() - started
    provenance = {
        "motor": motor.provenance(),
        "split": {"train": [_file_record(d) for d in datasets], "validate": [_file_record(d) for d in validation]},
        "seed": seed, "pso": {"swarm": swarm_size, "iterations": pso_iterations, "cost": "sum of log MSE "
                              "(winding, PM): Gaussian maximum likelihood with unknown variances",
                              "prior": prior.source if prior else "table1", "bounds": list(width),
                              "on_bounds": lptn.on_bounds},
        "lm": {"iterations": lm_iterations, "path": fit_path, "coordinates": ham.coordinates},
        "baselines": fit_baselines(runs),
        "versions": _versions(),
    }
    # what the new options add (absent on the packaged model's path, so its artifact keeps its bytes)
    if lptn.nodes != FITTED_ALWAYS:
        provenance["pso"]["nodes"] = {node: NODE_WEIGHTS[node] for node in lptn.nodes}
        provenance["pso"]["cost"] = ("weighted sum of log MSE over the measured nodes: Gaussian maximum "
                                     "likelihood with unknown variances")
    if network_cost != DEFAULT_CRITERION:
        provenance["pso"]["cost"] = CRITERIA[network_cost].description
        provenance["pso"]["criterion"] = network_cost
    if lptn.stalled_at is not None:
        provenance["pso"]["stalled_at"] = lptn.stalled_at
    if derived is not None:
        provenance["pso"]["auto_prior"] = {"parameters": derived.parameters.as_dict(),
                                           "responses": {n: r.as_dict() for n, r in derived.responses.items()},
                                           "rotor": derived.rotor.as_dict(),
                                           "winding": derived.winding.as_dict() if derived.winding else None,
                                           "fallbacks": list(derived.fallbacks)}
    if adapted is not None:
        provenance["pso"]["adapted_prior"] = adapted.record()
    if polished is not None:
        method = (f"Levenberg-Marquardt ({lm.DESCRIPTIONS[lm_factorization]}) in log-parameter space, variances "
                  "re-estimated each round")
        provenance["polish"] = {"starts": len(polished.start_costs), "method": method, "start_costs":
                                polished.start_costs, "final_costs": polished.final_costs, "kept": polished.kept,
                                "cost": polished.cost, "swarm_cost": polished.swarm_cost,
                                "prior": polished.prior.record() if polished.prior else None,
                                "frozen": list(polished.frozen)}
    if scales is not None:
        provenance["loss_scales"] = scales.record()
    if errors is not None:
        provenance["uncertainty"] = errors
    if selection is not None:
        provenance["lm"]["regularization"] = selection
    if lm_factorization != DEFAULT_LM_FACTORIZATION:
        provenance["lm"]["factorization"] = lm.DESCRIPTIONS[lm_factorization]
    if hammerstein_poles == POLES_FIT:
        provenance["lm"]["poles"] = {"fit": "each mode's time constant × exp(p), its static gain kept, ridge "
                                     "toward the network's", "time_constant_factors": ham.time_constant_factors}
    elif poles_kept:
        provenance["lm"]["poles"] = {"kept": poles_kept}
    period = datasets[0].sample_period_s
    return Identification(dt, discretization, lptn, ham, loss_model, constants, provenance, period, timings,
                          delta_reference(datasets))


def delta_reference(datasets) -> float:
    """The temperature a delta realization's states are deviations from: the middle of the winding and PM
    temperatures measured in the training runs, in whole °C (the float32 state then holds the smallest values)."""
    low = min(min(float(d.winding_C.min()), float(d.pm_C.min())) for d in datasets)
    high = max(max(float(d.winding_C.max()), float(d.pm_C.max())) for d in datasets)
    return float(round((low + high) / 2))


def _file_record(dataset) -> dict:
    record = {"file": Path(dataset.path).name, "sha256": dataset.sha256, "rows": dataset.rows}
    if getattr(dataset, "coolant_setpoint_C", None) is not None:
        record["coolant_C"] = dataset.coolant_setpoint_C
    return record


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
