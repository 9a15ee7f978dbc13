"""Identification of the 22 LPTN parameters by particle swarm (paper section II-D).

Cost: the maximum-likelihood criterion for independent Gaussian output errors with unknown variances,
J = Σ_nodes w_node · log(MSE_node), over every node the training runs measure (winding and PM always, the stator
yoke and tooth when every training file has them; NODE_WEIGHTS) of all identification runs together; it is
scale-free, so the nodes weigh by their relative fit, not by their size in °C. (`--network-cost pooled`: log Σ w MSE
instead, bench.model.criteria.)
Each candidate is simulated exactly as the estimator runs (closed loop, sources from its previous estimate).
The search is done in log coordinates for the positive parameters, so a factor of two up or down is one step.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from bench.drive.dataset import MEASURED_NODES
from bench.model.criteria import CRITERIA, DEFAULT_CRITERION
from bench.model.deploy import DEPLOYED_NODES
from bench.model.runs import ModelRun
from bench.thermal import portable
from bench.thermal.estimator import LOOP_PARAMETERS, identity_sigmoid, run_batch
from bench.thermal.lptn import lti_matrices
from bench.thermal.parameters import TABLE1, LptnParameters
from bench.thermal.pso import Stall, particle_swarm

# Capacitances, resistances and the convection exponents may move by a factor around the prior (Table 1 for the
# built-in motor, a motor file's thermal_prior, or --prior): 0.6-1.6 by default, the prior a machine designer has
# from geometry and materials. Wider bounds let the swarm distort the network until it absorbs loss-map errors,
# which hides them instead of fixing them (that is the Hammerstein nonlinearity's job). The coolant coefficient
# and the stator split (eq. 8) have fixed physical bounds.
DEFAULT_WIDTH = (0.6, 1.6)
SCALED = ("C_y", "C_w", "C_t", "C_m", "R_yw", "R_yt", "R_wt", "R_cy0", "R_wm0", "a_wm", "b_wm", "R_tm0", "a_tm",
          "b_tm", "R_ma0", "a_ma", "b_ma")
FIXED_BOUNDS = {"alpha_cy": (-0.02, 0.0), "k_0": (0.6, 0.95), "k_1": (-0.2, 0.05), "k_2": (-0.1, 0.1),
                "k_3": (-0.25, 0.0)}


def parameter_bounds(prior: LptnParameters = TABLE1, width: tuple[float, float] = DEFAULT_WIDTH
                     ) -> dict[str, tuple[float, float]]:
    """(lower, upper) of every parameter: width × prior for the scaled ones (either sign), fixed for the rest."""
    values = prior.as_dict()
    bounds = {n: tuple(sorted((values[n] * width[0], values[n] * width[1]))) for n in SCALED}
    return {n: bounds[n] if n in bounds else FIXED_BOUNDS[n] for n in LptnParameters.names()}


BOUNDS = parameter_bounds()


def log_scaled(bounds: dict[str, tuple[float, float]]) -> tuple[str, ...]:
    """The parameters searched on a log scale: those whose bounds are both positive."""
    return tuple(n for n, (lo, _) in bounds.items() if lo > 0)


LOG_SCALED = log_scaled(BOUNDS)


def to_search(values: np.ndarray, scaled: tuple[str, ...] = LOG_SCALED) -> np.ndarray:
    """Parameter vectors (…, 22) -> search coordinates (log for positive parameters).

    exp and log here and in the cost come from bench.thermal.portable: numpy's differ in the last bit between
    AVX-512 and AVX2 CPUs, and the swarm's comparisons would amplify that.
    """
    out = np.array(values, dtype=float)
    for i, name in enumerate(LptnParameters.names()):
        if name in scaled:
            out[..., i] = portable.log_array(out[..., i])
    return out


def from_search(coords: np.ndarray, scaled: tuple[str, ...] = LOG_SCALED) -> np.ndarray:
    out = np.array(coords, dtype=float)
    for i, name in enumerate(LptnParameters.names()):
        if name in scaled:
            out[..., i] = portable.exp_array(out[..., i])
    return out


def search_bounds(bounds: dict[str, tuple[float, float]] = BOUNDS) -> tuple[np.ndarray, np.ndarray]:
    names = LptnParameters.names()
    scaled = log_scaled(bounds)
    lower = np.array([bounds[n][0] for n in names])
    upper = np.array([bounds[n][1] for n in names])
    return to_search(lower, scaled), to_search(upper, scaled)


# The nodes in the order of run_batch's error sums, and their weights in the cost. Winding and PM, the outputs a
# model is deployed for, weigh 1 (plain maximum likelihood). Yoke and tooth weigh 1/2 each: both sit in the stator
# iron and move together, so together they count as one more measured node; they pin the network's inner states
# (a fit to winding and PM alone leaves them 6-8 °C off) without outvoting the two deployed outputs.
NODES = tuple(MEASURED_NODES)   # winding, pm, yoke, tooth: the data's measured nodes
NODE_WEIGHTS = {"winding": 1.0, "pm": 1.0, "yoke": 0.5, "tooth": 0.5}
FITTED_ALWAYS = DEPLOYED_NODES      # the outputs a model is deployed for are always fitted


def measured_nodes(runs: Sequence[ModelRun]) -> tuple[str, ...]:
    """The nodes every run measures: winding and PM, plus yoke and tooth when all files have them."""
    return FITTED_ALWAYS + tuple(n for n in NODES[2:] if all(r.reference(n) is not None for r in runs))


# A parameter within this share of its search range from a bound has ended on it.
ON_BOUND_SHARE = 1e-3


def parameters_on_bounds(params: LptnParameters, bounds: dict[str, tuple[float, float]]) -> list[dict]:
    """[{name, value, bound: "lower"|"upper", limit}] for every parameter that ended on a bound of its search."""
    scaled = log_scaled(bounds)
    lower, upper = search_bounds(bounds)
    coords = to_search(np.array(params.as_vector()), scaled)
    found = []
    for i, name in enumerate(LptnParameters.names()):
        margin = ON_BOUND_SHARE * (upper[i] - lower[i])
        for side, limit, hit in (("lower", bounds[name][0], coords[i] <= lower[i] + margin),
                                 ("upper", bounds[name][1], coords[i] >= upper[i] - margin)):
            if hit:
                found.append({"name": name, "value": float(getattr(params, name)), "bound": side,
                              "limit": float(limit)})
    return found


def discrete_blocks(vectors: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """ZOH (A_d, B_d) for a batch of parameter vectors (portable.expm: the same bits on every CPU)."""
    batch = LptnParameters(**dict(zip(LptnParameters.names(), np.asarray(vectors, float).T, strict=True)))
    a, b, _, _ = lti_matrices(batch)
    blocks = np.zeros((len(vectors), 12, 12))
    blocks[:, :4, :4], blocks[:, :4, 4:] = a, b
    phi = portable.expm(blocks * dt)
    return phi[:, :4, :4], phi[:, :4, 4:]


def batch_cost(vectors: np.ndarray, runs: Sequence[ModelRun], dt: float, scale_w: np.ndarray,
               nodes: tuple[str, ...] = FITTED_ALWAYS, criterion: str = DEFAULT_CRITERION) -> np.ndarray:
    """The `criterion`'s cost (bench.model.criteria; the default Σ w·log MSE) of each parameter vector (P, 22) over
    all runs and the given measured nodes."""
    a_d, b_d = discrete_blocks(vectors, dt)
    n = len(vectors)
    c = np.broadcast_to(np.eye(4), (n, 4, 4))
    names = LptnParameters.names()
    theta = np.asarray(vectors, float)[:, [names.index(n) for n in LOOP_PARAMETERS]]
    sig = np.broadcast_to(identity_sigmoid(scale_w), (n, 6, 4))
    columns = [NODES.index(node) for node in nodes]
    sse = np.zeros((n, len(nodes)))
    for run in runs:
        part, _ = run_batch(a_d, b_d, c, theta, sig, run.inputs, run.initial, run.ref_winding, run.ref_pm,
                            ref_y=run.ref_yoke, ref_t=run.ref_tooth)
        sse += part[:, columns]
    counts = np.full(len(nodes), float(sum(len(r.ref_winding) for r in runs)))
    return CRITERIA[criterion].cost(sse / counts, np.asarray([NODE_WEIGHTS[node] for node in nodes], float))


def within_bounds(params: LptnParameters, bounds: dict[str, tuple[float, float]]) -> np.ndarray:
    """The parameter vector clipped into its search box: where the swarm puts the prior, and the --swarm 0 start."""
    return np.clip(params.as_vector(), [b[0] for b in bounds.values()], [b[1] for b in bounds.values()])


@dataclass(frozen=True)
class LptnFit:
    params: LptnParameters
    cost: float
    history: list[float]
    evaluations: int
    seed: int
    swarm_size: int
    iterations: int
    bounds: dict[str, tuple[float, float]]
    on_bounds: list[dict]          # the parameters that ended on a bound (parameters_on_bounds)
    nodes: tuple[str, ...] = FITTED_ALWAYS    # the measured nodes in the cost
    candidates: np.ndarray | None = None      # the swarm's personal bests (search coordinates), best first
    stalled_at: int | None = None             # iterations run when the swarm stopped at a stall (pso.Stall)
    criterion: str = DEFAULT_CRITERION        # the cost's criterion (bench.model.criteria), the polish's too


def identify_lptn(runs: Sequence[ModelRun], dt: float, *, swarm_size: int = 220, iterations: int = 100,
                  seed: int = 0, start: LptnParameters = TABLE1, width: tuple[float, float] = DEFAULT_WIDTH,
                  stall: Stall | None = None, on_iteration: Callable[[int, float], None] | None = None,
                  criterion: str = DEFAULT_CRITERION) -> LptnFit:
    """PSO over the 22 parameters within `width` × `start` (the prior, which is one of the initial particles),
    stopped early at a `stall` if one is given, on the `criterion`'s cost (bench.model.criteria)."""

    scale_w = np.ones(4)
    bounds = parameter_bounds(start, width)
    scaled = log_scaled(bounds)
    lower, upper = search_bounds(bounds)
    initial = to_search(within_bounds(start, bounds), scaled)
    nodes = measured_nodes(runs)
    result = particle_swarm(lambda pos: batch_cost(from_search(pos, scaled), runs, dt, scale_w, nodes, criterion),
                            lower, upper, swarm_size=swarm_size, iterations=iterations, seed=seed,
                            initial=initial, stall=stall, on_iteration=on_iteration)
    params = LptnParameters.from_vector(from_search(result.best, scaled))
    order = np.argsort(result.personal_costs, kind="stable")
    return LptnFit(params, result.best_cost, result.history.tolist(), result.evaluations, seed, swarm_size,
                   iterations, bounds, parameters_on_bounds(params, bounds), nodes, result.personal_bests[order],
                   result.stalled_at, criterion)


def prior_lptn(runs: Sequence[ModelRun], dt: float, *, start: LptnParameters = TABLE1,
               width: tuple[float, float] = DEFAULT_WIDTH, criterion: str = DEFAULT_CRITERION) -> LptnFit:
    """No search (`bench identify --swarm 0`): the prior itself (clipped into its box) as the swarm's result and
    the polish's one start. Why: the swarm's seed moves a fold's held-out score by up to 5x on the motor suite
    (docs/method.md), the prior's local optimum has no seed."""
    bounds = parameter_bounds(start, width)
    scaled = log_scaled(bounds)
    vector = within_bounds(start, bounds)
    nodes = measured_nodes(runs)
    cost = float(batch_cost(vector[None], runs, dt, np.ones(4), nodes, criterion)[0])
    params = LptnParameters.from_vector(vector)
    return LptnFit(params, cost, [cost], 1, 0, 0, 0, bounds, parameters_on_bounds(params, bounds), nodes,
                   to_search(vector, scaled)[None], None, criterion)
