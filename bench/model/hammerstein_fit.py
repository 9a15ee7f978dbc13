"""Levenberg-Marquardt fit of the Hammerstein model (paper eqs. 1, 28-30; section II-D).

Structure: one single-neuron sigmoid network per power-loss input, S(u) = gain·σ(weight·u + bias) + linear·u
+ offset on the normalized loss u = P/scale, followed by the discrete LTI LPTN whose poles stay fixed. The
numerator of the linear block, i.e. the loss columns of B in the coordinates the fit works in, is fitted too
(as a relative change of each entry), the source columns and C are kept. Two fit paths, same model set:
- `polynomial`: the paper's: the linear block in transfer-function form, which comes back to state space as the
  companion (`original`) realization; the fit works in those ill-conditioned coordinates.
- `statespace`: the fit works directly in `balanced` (default) or `modal` coordinates.
The temperature sources and copper losses use the model's own previous estimate, as the target does.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from bench.model.builder import SigmoidInputs
from bench.model.lptn_fit import NODE_WEIGHTS, measured_nodes
from bench.model.runs import ModelRun
from bench.thermal import portable
from bench.thermal.estimator import loop_parameters, run_batch
from bench.thermal.parameters import LptnParameters
from bench.thermal.realizations import Realization, realize

FIT_PATHS = {"polynomial": "original", "statespace": "balanced", "statespace-modal": "modal"}
N_SIGMOID = 20
# The PM error counts double: its reference is near its noise floor, and the fit must not buy winding accuracy
# with PM accuracy. Yoke and tooth, when every training file measures them, enter with the swarm's weight 1/2 on
# their squared errors (lptn_fit.NODE_WEIGHTS): without them the refitted loss columns of B are free to move the
# stator iron's estimates (on the IPM example the tooth's RMSE went from 2.3 to 14.8 °C).
PM_WEIGHT = 2.0
STATOR_WEIGHT = math.sqrt(NODE_WEIGHTS["yoke"])
# Ridge weights (°C of RMS error per unit of parameter change) for [weight, bias, gain, linear, offset] and the
# relative B changes. Without them the fit makes the sigmoids into steep steps that tell the 20 °C run from the
# 60 °C one by their loss level (copper losses rise with temperature) and then interpolates badly at 40 °C.
RIDGE = np.concatenate([np.full(4, 0.01), np.full(4, 0.01), np.full(4, 0.002), np.full(4, 0.002),
                        np.full(4, 0.002), np.full(16, 0.02)])
# `cv`: the ridge's overall strength (a factor on RIDGE) chosen by leave-one-file-out cross-validation among these;
# `fixed`: the factor 1 (the packaged model's path). Larger factors keep the model nearer the LTI network.
STATOR_OUTPUT = {"yoke": 0, "tooth": 2}
REGULARIZATIONS = ("fixed", "cv")
CV_FACTORS = (100.0, 10.0, 1.0)    # strongest first: each fold's next fit starts from the more regular one
CV_EVALUATIONS = 10                # LM function evaluations per fold fit (warm-started along the factors)


@dataclass(frozen=True)
class HammersteinModel:
    """A fitted Hammerstein model: its sigmoid inputs and its linear block in physical coordinates."""

    sigmoid: SigmoidInputs
    block: Realization


@dataclass(frozen=True)
class HammersteinFit:
    model: HammersteinModel
    path: str
    coordinates: str
    cost_initial: float
    cost_final: float
    iterations: int
    evaluations: int
    status: str
    vector: np.ndarray | None = None     # the fitted sigmoid and B-change parameters


def loss_scales(runs: Sequence[ModelRun], params: LptnParameters) -> np.ndarray:
    """Normalization of each loss input: its largest nominal value over the identification runs."""
    peak = np.zeros(4)
    for run in runs:
        t = run.inputs.table_losses
        peak = np.maximum(peak, [t[:, 2].max(), (t[:, 0] + t[:, 1]).max() * 1.3, t[:, 2].max(), t[:, 3].max()])
    return np.maximum(peak, 1.0)


def initial_sigmoid_vector() -> np.ndarray:
    """Close to the identity (so the fit starts from the LTI LPTN) with a small sigmoid term to learn from."""
    gain = np.full(4, 0.05)
    bias = np.zeros(4)
    offset = -gain / 2  # gain·σ(0) = gain/2 is taken back by the offset
    return np.concatenate([np.ones(4), bias, gain, np.ones(4), offset])


class _Problem:
    """Maps a parameter vector to models in the fit coordinates and to residuals."""

    def __init__(self, base: Realization, coordinates: str, params: LptnParameters, runs: Sequence[ModelRun],
                 scale_w: np.ndarray, nodes: tuple[str, ...] | None = None):
        self.fit_block = realize(base, coordinates)
        self.transform = self.fit_block.c  # x_physical = C_z z, since C is the identity in physical coordinates
        self.theta = loop_parameters(params)
        self.runs, self.scale_w = runs, scale_w
        self.b_loss0 = self.fit_block.b[:, :4].copy()
        self.stator = [n for n in ("yoke", "tooth") if n in (measured_nodes(runs) if nodes is None else nodes)]

    def models(self, vectors: np.ndarray):
        n = len(vectors)
        sig = np.zeros((n, 6, 4))
        b = np.broadcast_to(self.fit_block.b, (n, 4, 8)).copy()
        for p, v in enumerate(vectors):
            sig[p, 0] = self.scale_w
            sig[p, 1:] = v[:N_SIGMOID].reshape(5, 4)
            b[p, :, :4] = self.b_loss0 * (1.0 + v[N_SIGMOID:].reshape(4, 4))
        a = np.broadcast_to(self.fit_block.a, (n, 4, 4))
        c = np.broadcast_to(self.fit_block.c, (n, 4, 4))
        return a, b, c, np.broadcast_to(self.theta, (n, self.theta.size)), sig

    def residuals(self, vectors: np.ndarray) -> np.ndarray:
        """(P, residuals): winding and PM errors over every run, in °C."""
        a, b, c, theta, sig = self.models(vectors)
        parts = []
        for run in self.runs:
            _, traj = run_batch(a, b, c, theta, sig, run.inputs, run.initial, keep_trajectories=True)
            parts += [traj[:, :, 1] - run.ref_winding, PM_WEIGHT * (traj[:, :, 3] - run.ref_pm)]
            parts += [STATOR_WEIGHT * (traj[:, :, STATOR_OUTPUT[n]] - run.reference(n)) for n in self.stator]
        return np.concatenate(parts, axis=1)

    def physical_model(self, v: np.ndarray) -> HammersteinModel:
        _, b, _, _, sig = self.models(v[None])
        t, t_inv, mm = self.transform, portable.inv(self.transform), portable.matmul  # same bits on every CPU
        fitted = Realization("physical", mm(t, self.fit_block.a, t_inv), mm(t, b[0]), mm(self.fit_block.c, t_inv),
                             self.fit_block.d)
        return HammersteinModel(SigmoidInputs.from_vector(self.scale_w, sig[0, 1:].ravel()), fitted)


def fit_hammerstein(base: Realization, params: LptnParameters, runs: Sequence[ModelRun], *,
                    path: str = "statespace", iterations: int = 100,
                    on_iteration: Callable[[int, float], None] | None = None, ridge_factor: float = 1.0,
                    start: np.ndarray | None = None, scale_w: np.ndarray | None = None,
                    nodes: tuple[str, ...] | None = None) -> HammersteinFit:
    """Fit sigmoid inputs and B's loss columns with the poles of `base` (physical, discrete) held fixed; the ridge
    pulls toward the LTI network with `ridge_factor` × RIDGE, the fit starts from `start` (default: there)."""
    if path not in FIT_PATHS:
        raise ValueError(f"unknown fit path {path!r}; choose one of {', '.join(FIT_PATHS)}")
    coordinates = FIT_PATHS[path]
    problem = _Problem(base, coordinates, params, runs, loss_scales(runs, params) if scale_w is None else scale_w,
                       nodes)
    v0 = lti_vector()
    calls = {"n": 0}

    def fun(v):
        r = problem.residuals(v[None])[0]
        calls["n"] += 1
        if on_iteration is not None:
            on_iteration(calls["n"], float(np.sqrt(np.mean(r * r))))
        return np.nan_to_num(r, nan=1e6, posinf=1e6, neginf=-1e6)

    def jac(v):
        # Forward differences, all perturbed models simulated in one parallel batch.
        steps = 1e-6 * np.maximum(1.0, np.abs(v))
        batch = np.vstack([v, v + np.diag(steps)])
        r = np.nan_to_num(problem.residuals(batch), nan=1e6, posinf=1e6, neginf=-1e6)
        return ((r[1:] - r[0]) / steps[:, None]).T

    n_data = problem.residuals(v0[None]).shape[1]
    ridge = np.sqrt(n_data) * RIDGE * ridge_factor

    def fun_ridge(v):
        return np.concatenate([fun(v), ridge * (v - v0)])

    def jac_ridge(v):
        return np.vstack([jac(v), np.diag(ridge)])

    r0 = fun(v0)
    result = least_squares(fun_ridge, v0 if start is None else start, jac=jac_ridge, method="lm",
                           max_nfev=iterations, x_scale="jac")
    final = result.fun[:n_data]
    return HammersteinFit(problem.physical_model(result.x), path, coordinates,
                          float(np.sqrt(np.mean(r0 ** 2))), float(np.sqrt(np.mean(final ** 2))),
                          int(result.njev or 0), int(result.nfev), result.message, result.x)


def lti_vector() -> np.ndarray:
    """Where the fit starts and what its ridge pulls toward: near-identity sigmoids and B unchanged."""
    return np.concatenate([initial_sigmoid_vector(), np.zeros(16)])


def exact_lti_vector() -> np.ndarray:
    """The LTI network itself: S(u) = u (no sigmoid term) and B unchanged."""
    return np.concatenate([np.ones(4), np.zeros(4), np.zeros(4), np.ones(4), np.zeros(4), np.zeros(16)])


def _exact_rms(parts: Sequence[np.ndarray]) -> float:
    return math.sqrt(math.fsum(math.fsum(p * p) for p in parts) / sum(p.size for p in parts))


def fit_hammerstein_cv(base: Realization, params: LptnParameters, runs: Sequence[ModelRun], *,
                       path: str = "statespace", iterations: int = 100,
                       on_iteration: Callable[[int, float], None] | None = None) -> tuple[HammersteinFit, dict]:
    """The Hammerstein fit with its ridge strength chosen by leave-one-file-out cross-validation.

    For each training file in turn, the model is fitted to the other files with each factor of CV_FACTORS
    (strongest first, each fit starting from the previous, more regular one, CV_EVALUATIONS LM evaluations each)
    and simulated on the left-out file; a factor's score is the RMS error on the left-out files (winding and PM,
    weighted as in the fit), pooled over the folds. The LTI network is scored on the same files (it saw them in the
    swarm, so the comparison favours it). The final fit uses all files and the best factor, starting from the mean
    of that factor's fold fits; `recommended` says which model did better on the left-out files.
    """
    if len(runs) < 2:
        fit = fit_hammerstein(base, params, runs, path=path, iterations=iterations, on_iteration=on_iteration)
        return fit, {"method": "fixed (cross-validation needs two training files or more)", "factor": 1.0}
    scale_w = loss_scales(runs, params)
    nodes = measured_nodes(runs)
    v_lti = exact_lti_vector()
    held = {factor: [] for factor in CV_FACTORS}
    folds = {factor: [] for factor in CV_FACTORS}
    lti = []
    for f, left_out in enumerate(runs):
        others = [r for k, r in enumerate(runs) if k != f]
        check = _Problem(base, FIT_PATHS[path], params, [left_out], scale_w, nodes)
        start = None
        for factor in CV_FACTORS:
            fold = fit_hammerstein(base, params, others, path=path, iterations=CV_EVALUATIONS, ridge_factor=factor,
                                   start=start, scale_w=scale_w, nodes=nodes)
            start = fold.vector
            folds[factor].append(fold.vector)
            held[factor].append(_finite(check.residuals(fold.vector[None])[0]))
        lti.append(_finite(check.residuals(v_lti[None])[0]))
        if on_iteration is not None:
            on_iteration(f + 1, _exact_rms(held[CV_FACTORS[-1]]))
    scores = {factor: _exact_rms(parts) for factor, parts in held.items()}
    lti_rms = _exact_rms(lti)
    best = min(CV_FACTORS, key=lambda factor: (scores[factor], -factor))   # a tie goes to the stronger ridge
    start = np.array([math.fsum(column) / len(runs) for column in np.array(folds[best]).T])   # exact sums
    fit = fit_hammerstein(base, params, runs, path=path, iterations=max(iterations // 3, 1),
                          on_iteration=on_iteration, ridge_factor=best, start=start, scale_w=scale_w)
    return fit, {"method": "leave-one-file-out cross-validation", "factor": best,
                 "cv_rms_C": {f"{f:g}": scores[f] for f in CV_FACTORS}, "selected_rms_C": scores[best],
                 "lti_rms_C": lti_rms, "recommended": "hammerstein" if scores[best] < lti_rms else "lti-lptn",
                 "fold_evaluations": CV_EVALUATIONS}


def _finite(r: np.ndarray) -> np.ndarray:
    return np.nan_to_num(r, nan=1e6, posinf=1e6, neginf=-1e6)
