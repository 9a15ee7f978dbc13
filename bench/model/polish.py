"""Local polish after the swarm: Levenberg-Marquardt on the swarm's likelihood, in log-parameter space.

Why: a particle swarm finds the right basin but stops short of its bottom (its last steps are random), and with a
wide search box that gap is large. The polish starts from the swarm's best distinct particles (multi-start), each
start in its own thread on the available cores, and keeps the lowest training cost (ties: the earlier start).

The cost is the swarm's J = Σ w_n log MSE_n (lptn_fit.NODE_WEIGHTS). A sum of logs is not a sum of squares, so
each round fixes the variances at their current values, σ_n² = MSE_n (the `pooled` criterion, J = log Σ w_n MSE_n:
one σ² = Σ w_n MSE_n for every node; bench.model.criteria), and minimizes Σ w_n ‖r_n‖²/(N σ_n²) by LM
(MINPACK's lmder as scipy's least_squares method "lm" runs it; bench.model.minpack); the next round re-estimates
σ_n. At a fixed point the gradient of J is zero (the concentrated-likelihood iteration). The search box is kept
by a smooth map u -> x = lo + (hi − lo)(1 + u/√(1+u²))/2 made of +, −, ×, / and √ only. MINPACK uses no BLAS
and the simulations run on bench.thermal.portable, so the result is the same bits on every x86-64 CPU and at any
number of threads.

Standard errors (`uncertainty`): at the optimum, the Jacobian of the residuals scaled by 1/σ_n, each node's rows
shrunk by √(N_eff/N) with N_eff = N(1 − ρ)/(1 + ρ) for the residuals' lag-1 autocorrelation ρ (model errors are
slow, so the samples are far from independent and the plain Fisher information would be far too optimistic).
Covariance = (JᵀJ)⁻¹ by the eigen-decomposition of JᵀJ (portable SVD); directions with eigenvalues below
1e-12 × the largest carry no information. Standard errors of the log-scaled parameters are relative (of ln x).
A parameter is named unidentifiable when its standard error exceeds ln 2 (log-scaled: the data cannot tell it
within a factor of two) or half its search range (the others), or when it lies in an uninformative direction.
"""

from __future__ import annotations

import contextvars
import math
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np

from bench import stop
from bench.model.choices import POLISH_STARTS
from bench.model.criteria import CRITERIA, DEFAULT_CRITERION
from bench.model.lm import levenberg_marquardt
from bench.model.lptn_fit import (
    NODE_WEIGHTS,
    LptnFit,
    batch_cost,
    discrete_blocks,
    from_search,
    log_scaled,
    parameters_on_bounds,
    search_bounds,
    to_search,
)
from bench.model.metrics import finite_in_place
from bench.model.runs import ModelRun
from bench.thermal import portable
from bench.thermal.estimator import LOOP_PARAMETERS, identity_sigmoid, run_batch
from bench.thermal.parameters import LptnParameters

ROUNDS = 3                 # variance re-estimations
ROUND_EVALUATIONS = 40     # LM function evaluations per round
DISTINCT = 1e-3            # starts closer than this (share of the box, RMS over dimensions) are one start
STEP = 1e-6                # forward-difference step in u (and in x for the standard errors)
UNIDENTIFIED_LOG_SE = math.log(2.0)
UNIDENTIFIED_RANGE_SHARE = 0.5     # of a linear parameter's search range (the module docstring)
UNIDENTIFIED_EIGEN = 1e-12
OUTPUT_INDEX = {"winding": 1, "pm": 3, "yoke": 0, "tooth": 2}
# The weak prior of the polish (`PriorPenalty`): the search box is its ±2σ interval (σ a quarter of the box's width
# in search coordinates: a factor of 10^(1/2) for the auto prior's 0.1-10), and its weight is 1/N_eff.
PRIOR_SIGMAS_IN_BOX = 4.0
FREEZE_ROUNDS = 2          # freeze_unidentified: re-polishes at most
INSET = 1e-3               # a start on a wall is moved this share of the box inside (the box map is flat there)


@dataclass(frozen=True)
class Polish:
    coords: np.ndarray          # the kept optimum, search coordinates
    cost: float                 # its cost: the swarm's likelihood cost (+ the prior's penalty)
    start_costs: list[float]    # the swarm's cost at each start
    final_costs: list[float]    # each start's polished cost
    kept: int                   # index of the kept start
    evaluations: int
    swarm_cost: float = math.nan    # the swarm's best cost, for the record
    prior: PriorPenalty | None = None     # the prior of a maximum-a-posteriori polish
    frozen: tuple[str, ...] = ()          # parameters set to the prior (freeze_unidentified)


class Residuals:
    """The fitted nodes' errors of a batch of parameter vectors, over every run."""

    def __init__(self, runs: Sequence[ModelRun], dt: float, nodes: tuple[str, ...], scaled: tuple[str, ...],
                 criterion: str = DEFAULT_CRITERION):
        self.runs, self.dt, self.nodes, self.scaled = runs, dt, nodes, scaled
        self.criterion = CRITERIA[criterion]
        self.weights = np.array([NODE_WEIGHTS[node] for node in nodes])
        self.count = float(sum(len(r.ref_winding) for r in runs))

    def errors(self, coords: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(P, nodes, samples) model − measurement for search coordinates (P, 22) (`out`: vector_errors')."""
        return self.vector_errors(from_search(coords, self.scaled), out)

    def vector_errors(self, vectors: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(P, nodes, samples) model − measurement for parameter vectors (P, 22). With `out`, a C-contiguous
        (P, M ≥ nodes × samples) array, the errors are written into its first nodes × samples columns (node after
        node) and returned as a (P, nodes, samples) view of them: a fit's residual rows built in place, not copied."""
        a_d, b_d = discrete_blocks(vectors, self.dt)
        n = len(vectors)
        names = LptnParameters.names()
        theta = vectors[:, [names.index(p) for p in LOOP_PARAMETERS]]
        c = np.broadcast_to(np.eye(4), (n, 4, 4))
        sig = np.broadcast_to(identity_sigmoid(np.ones(4)), (n, 6, 4))
        total = int(self.count)
        size = len(self.nodes) * total
        if out is None:
            out = np.empty((n, size))   # written by the kernel, run after run along the samples
        rows = [OUTPUT_INDEX[node] for node in self.nodes]
        at = 0
        for run in self.runs:
            refs = [run.reference(node) for node in self.nodes]
            run_batch(a_d, b_d, c, theta, sig, run.inputs, run.initial,
                      residuals=(out, at, rows, refs, np.ones(len(rows)), total))
            at += len(run.ref_winding)
        errors = out[:, :size].reshape(n, len(self.nodes), total)
        return finite_in_place(errors)

    def mse(self, errors: np.ndarray) -> np.ndarray:
        """(nodes,) mean squared error of one model's errors (nodes, samples), exactly summed."""
        return np.array([portable.sum_of_products(e, e) / self.count for e in errors])

    def cost(self, errors: np.ndarray) -> float:
        """The swarm's cost (its criterion's) of one model's errors (nodes, samples)."""
        return self.criterion.exact_cost(self.mse(errors), self.weights)

    def variances(self, errors: np.ndarray) -> np.ndarray:
        """(nodes,) the variances a polish round divides each node's squared errors by (its criterion's)."""
        return self.criterion.variances(self.mse(errors), self.weights)


@dataclass(frozen=True)
class PriorPenalty:
    """A weak Gaussian prior on the search coordinates (log-normal on the log-scaled parameters), centred on the
    prior network: the polish minimizes J + weight · Σ ((x − centre)/σ)² (maximum a posteriori, not maximum
    likelihood). Why: some directions of the network are not seen by the data (a speed-dependent resistance whose
    fixed part the fit drives to zero leaves its exponent free; the stator split k_0..k_3 trades against the
    iron's resistances); maximum likelihood pushes them to whichever wall of the box is nearest, the prior keeps
    them at its guess, and leaves the directions the data do see to the data.

    The weight: J = Σ w_n log MSE_n is −2 log-likelihood / N_eff for N_eff effective independent samples, so a
    Gaussian prior's −2 log density enters J divided by N_eff. N_eff is the node-weighted mean of
    N(1 − ρ_n)/(1 + ρ_n) for the lag-1 autocorrelation ρ_n of each node's errors at the swarm's best (as in
    `uncertainty`); on the IPM example about 1000, so a parameter on its 2σ wall costs 0.004 in J (0.4 % of MSE).
    """

    centre: np.ndarray      # search coordinates of the prior network
    sigma: np.ndarray       # per coordinate
    weight: float           # 1 / N_eff
    n_eff: float
    factor: float | None = None     # the log-scaled parameters' 2σ factor (prior_sigmas), None: the box's quarter

    def rows(self, coords: np.ndarray) -> np.ndarray:
        """(…, 22) residual rows whose sum of squares is the penalty."""
        return math.sqrt(self.weight) * (coords - self.centre) / self.sigma

    def cost(self, coords: np.ndarray) -> float:
        return self.weight * math.fsum((((coords - self.centre) / self.sigma) ** 2).ravel())

    def record(self) -> dict:
        width = ("σ = a quarter of the search box" if self.factor is None else
                 f"σ = ln({self.factor:g})/2 for the log-scaled parameters (within a factor {self.factor:g} at 2σ), "
                 "a quarter of the search box for the others")
        record = {"kind": "Gaussian in search coordinates (log-normal for the log-scaled parameters), centred on the "
                          f"prior, {width}", "weight": self.weight, "n_eff": self.n_eff}
        return record if self.factor is None else {**record, "factor": self.factor}


def prior_penalty(problem: Residuals, at: np.ndarray, centre: np.ndarray, lower: np.ndarray,
                  upper: np.ndarray, factor: float | None = None) -> PriorPenalty:
    """The prior of the polish, its weight from the errors' autocorrelation at `at` (search coordinates); σ a
    quarter of the box, or with a `factor` ln(factor)/2 for the log-scaled parameters (each believed within that
    factor of the prior at 2σ; `prior_sigmas`)."""
    errors = problem.errors(at[None])[0]
    weights = np.array([NODE_WEIGHTS[node] for node in problem.nodes])
    rho = np.array([max(0.0, _lag1(e)) for e in errors])
    n_eff = math.fsum(weights * problem.count * (1 - rho) / (1 + rho)) / math.fsum(weights)
    return PriorPenalty(np.clip(centre, lower, upper), prior_sigmas(problem.scaled, lower, upper, factor),
                        1.0 / n_eff, n_eff, factor)


def prior_sigmas(scaled: tuple[str, ...], lower: np.ndarray, upper: np.ndarray, factor: float | None) -> np.ndarray:
    """The prior's σ per search coordinate: a quarter of the box; with a `factor`, ln(factor)/2 for the log-scaled
    parameters (a designer's "within a factor of two" is factor 2), the box's quarter for the others (the stator
    split and the coolant's temperature coefficient have fixed physical bounds, not a designer's guess)."""
    sigma = (upper - lower) / PRIOR_SIGMAS_IN_BOX
    if factor is not None:
        logs = np.array([name in scaled for name in LptnParameters.names()])
        sigma = np.where(logs, math.log(factor) / 2.0, sigma)
    return sigma


def _to_box(u: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    return lower + (upper - lower) * (1.0 + u / np.sqrt(1.0 + u * u)) * 0.5


def _from_box(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    s = np.clip(2.0 * (x - lower) / (upper - lower) - 1.0, -1.0 + 1e-9, 1.0 - 1e-9)
    return s / np.sqrt(1.0 - s * s)


def _origin_shift(u: np.ndarray) -> np.ndarray:
    """A constant added to the LM variables when the start lies at the box's centre (u ≈ 0). Why: MINPACK bounds
    its first step by 100·‖D u₀‖, so from u₀ ≈ 0 its first step is about 1e-14 long, it sees no reduction and
    stops at once (the prior's adaptation starts a box centred on its start). Shifting the variables changes no
    cost, only that first bound; starts off the centre (the swarm's particles) are left as they are."""
    if math.sqrt(math.fsum(u * u)) >= 1.0:
        return np.zeros_like(u)
    return np.ones_like(u)


def polish_one(problem: Residuals, start: np.ndarray, lower: np.ndarray, upper: np.ndarray,
               penalty: PriorPenalty | None = None, free: np.ndarray | None = None) -> tuple[np.ndarray, float, int]:
    """(coords, cost, evaluations) of one LM polish from `start` (search coordinates); with a `penalty` the cost
    is J + the prior's penalty and a start on a wall is moved INSET inside (the box map has no slope there);
    coordinates outside the `free` mask keep their start values."""
    free = np.ones(len(start), bool) if free is None else np.asarray(free, bool)
    if penalty is not None:
        margin = INSET * (upper - lower)
        start = np.where(free, np.clip(start, lower + margin, upper - margin), start)
    lo, hi = lower[free], upper[free]

    u = _from_box(start[free], lo, hi)
    shift = _origin_shift(u)

    def box(v):     # (P, free) LM variables -> (P, 22)
        x = np.repeat(start[None], len(v), axis=0)
        x[:, free] = _to_box(v - shift, lo, hi)
        return x

    u = u + shift
    extra = (lambda x: 0.0) if penalty is None else penalty.cost
    # the Jacobian's finite differences are written in one buffer at every evaluation (both LMs copy or reduce
    # what they get before the next call): 23 rows of 400 000 residuals are 74 MB, which fresh arrays would fault
    # in page by page and copy three times over
    width = len(problem.nodes) * int(problem.count) + (0 if penalty is None else len(start))
    jacobian = np.empty((len(u) + 1, width))
    evaluations = 0
    best_x, best_cost = start, problem.cost(problem.errors(start[None])[0]) + extra(start)
    for _ in range(ROUNDS):
        scale = np.sqrt(problem.weights / (problem.count * problem.variances(problem.errors(box(u[None]))[0])))

        def rows(batch, out=None, scale=scale):
            # each row: the scaled errors, then the prior's rows; built in `out` (or a new array) in place
            stop.check()    # a worker thread: the signal handler cannot reach it (bench.stop)
            x = box(batch)
            if out is None:
                out = np.empty((len(batch), width))
            errors = problem.errors(x, out)
            np.multiply(errors, scale[None, :, None], out=errors)
            if penalty is not None:
                out[:, errors[0].size:] = penalty.rows(x)
            return out

        def fun(v):
            return rows(v[None])[0]

        def jac_rows(v):    # the Jacobian transposed, a row per LM variable (bench.model.minpack)
            steps = STEP * np.maximum(1.0, np.abs(v))
            r = rows(np.vstack([v, v + np.diag(steps)]), jacobian)
            np.subtract(r[1:], r[0], out=r[1:])
            np.divide(r[1:], steps[:, None], out=r[1:])
            return r[1:]

        result = levenberg_marquardt(fun, jac_rows, u, ROUND_EVALUATIONS)
        evaluations += int(result.nfev) + int(result.njev or 0) * (len(u) + 1)
        x = box(result.x[None])[0]
        cost = problem.cost(problem.errors(x[None])[0]) + extra(x)
        if not cost < best_cost:
            break
        improvement = best_cost - cost
        best_x, best_cost, u = x, cost, result.x
        if improvement < 1e-6:
            break
    return best_x, best_cost, evaluations


def distinct_starts(candidates: np.ndarray, lower: np.ndarray, upper: np.ndarray, count: int) -> list[np.ndarray]:
    """The first `count` candidates (best first) that are not within DISTINCT of an earlier chosen one."""
    chosen = []
    span = upper - lower
    for c in candidates:
        if all(math.sqrt(math.fsum(((c - o) / span) ** 2) / len(span)) > DISTINCT for o in chosen):
            chosen.append(c)
        if len(chosen) == count:
            break
    return chosen


def _single_threaded(task):
    """Run task in this thread with numba's kernels on one thread (numba's thread count is per calling thread):
    the parallelism is across starts, one per core; in a copy of the caller's context (the LM factorization in use,
    bench.model.lm), which a pool's thread does not inherit."""
    import numba

    context = contextvars.copy_context()

    def run(*args):
        numba.set_num_threads(1)
        return context.copy().run(task, *args)

    return run


def _threadsafe_kernels() -> bool:
    """numba's OpenMP and TBB layers take parallel kernels from several threads; its fallback, workqueue, aborts."""
    import numba

    try:
        return numba.threading_layer() != "workqueue"
    except ValueError:       # no parallel kernel has run yet in this process
        return numba.config.THREADING_LAYER in ("omp", "tbb")


def available_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:     # not Linux
        return os.cpu_count() or 1


def in_threads(task, items: Sequence) -> list:
    """[task(item) for item in items], the items in threads, one per core, each with numba's kernels on one thread
    (the simulation kernel releases the GIL; forking under OpenMP is unsafe); in order, so the result does not
    depend on the number of cores."""
    workers = min(len(items), available_cores()) if _threadsafe_kernels() else 1
    if workers > 1:
        with ThreadPoolExecutor(workers) as pool:
            return list(pool.map(_single_threaded(task), items))
    return [task(item) for item in items]


def polish(runs: Sequence[ModelRun], dt: float, nodes: tuple[str, ...], scaled: tuple[str, ...],
           candidates: np.ndarray, lower: np.ndarray, upper: np.ndarray, starts: int = POLISH_STARTS,
           centre: np.ndarray | None = None, criterion: str = DEFAULT_CRITERION,
           prior_factor: float | None = None) -> Polish:
    """Polish from the best `starts` distinct candidates (search coordinates, best first); keep the lowest cost
    (the swarm's `criterion`'s). With the prior's `centre` (search coordinates) the cost is maximum a posteriori
    (PriorPenalty, its width `prior_factor`'s), its weight from the errors at the best candidate."""
    problem = Residuals(runs, dt, nodes, scaled, criterion)
    chosen = distinct_starts(candidates, lower, upper, starts)
    penalty = None if centre is None else prior_penalty(problem, chosen[0], centre, lower, upper, prior_factor)
    extra = (lambda x: 0.0) if penalty is None else penalty.cost

    def costs(points: list[np.ndarray]) -> list[float]:
        # the swarm's kernel sums, so the comparison with the swarm is exact
        data = batch_cost(from_search(np.array(points), scaled), runs, dt, np.ones(4), nodes, criterion)
        return [float(c) + extra(x) for c, x in zip(data, points, strict=True)]

    start_costs = costs(chosen)
    results = in_threads(lambda s: polish_one(problem, s, lower, upper, penalty), chosen)
    finals = costs([r[0] for r in results])
    kept = min(range(len(results)), key=lambda i: (finals[i], i))
    return Polish(results[kept][0], finals[kept], start_costs, finals, kept, sum(r[2] for r in results),
                  prior=None if penalty is None else penalty)


def polish_lptn(fit: LptnFit, runs: Sequence[ModelRun], dt: float, starts: int = POLISH_STARTS,
                prior: LptnParameters | None = None, freeze: bool = True, prior_factor: float | None = None
                ) -> tuple[LptnFit, Polish]:
    """The swarm's fit polished from its `starts` best distinct particles; the swarm's own best if none improves.
    With a `prior` network the polish is maximum a posteriori around it (PriorPenalty; σ by `prior_factor`,
    `prior_sigmas`), and (if `freeze`) a
    parameter that then still ends on a bound although the data cannot identify it is frozen at the prior
    (`freeze_unidentified`)."""
    scaled = log_scaled(fit.bounds)
    lower, upper = search_bounds(fit.bounds)
    centre = None if prior is None else to_search(np.array(prior.as_vector()), scaled)
    result = polish(runs, dt, fit.nodes, scaled, fit.candidates, lower, upper, starts, centre, fit.criterion,
                    prior_factor)
    swarm = to_search(np.array(fit.params.as_vector()), scaled)
    swarm_cost = fit.cost + (0.0 if result.prior is None else result.prior.cost(swarm))
    result = replace(result, swarm_cost=swarm_cost)
    if result.cost < swarm_cost:
        params = LptnParameters.from_vector(from_search(result.coords, scaled))
        data_cost = result.cost - (0.0 if result.prior is None else result.prior.cost(result.coords))
        fit = replace(fit, params=params, cost=data_cost, on_bounds=parameters_on_bounds(params, fit.bounds))
    if freeze and result.prior is not None and fit.on_bounds:
        fit, result = freeze_unidentified(fit, result, runs, dt, np.clip(centre, lower, upper))
    return fit, result


def freeze_unidentified(fit: LptnFit, result: Polish, runs: Sequence[ModelRun], dt: float, centre: np.ndarray
                        ) -> tuple[LptnFit, Polish]:
    """Parameters on a bound that the data cannot identify (`uncertainty`) are set to the prior and the others
    polished again from there (one start, FREEZE_ROUNDS times at most). Why: such a parameter's place on the wall
    says nothing about the motor (the likelihood is flat along it, or it trades against others), and its wall
    value is a guess the deployed model should not carry; the prior is the better guess. The frozen names are
    recorded (`Polish.frozen`) and reported."""
    scaled = log_scaled(fit.bounds)
    lower, upper = search_bounds(fit.bounds)
    names = LptnParameters.names()
    problem = Residuals(runs, dt, fit.nodes, scaled, fit.criterion)
    frozen = list(result.frozen)
    coords = to_search(np.array(fit.params.as_vector()), scaled)
    for _ in range(FREEZE_ROUNDS):
        blind = uncertainty(runs, dt, fit.nodes, scaled, coords, fit.bounds)["unidentifiable"]
        new = [hit["name"] for hit in fit.on_bounds if hit["name"] in blind and hit["name"] not in frozen]
        if not new:
            break
        frozen += new
        mask = np.array([name in frozen for name in names])
        start = np.where(mask, centre, coords)
        coords, cost, evaluations = polish_one(problem, start, lower, upper, result.prior, ~mask)
        params = LptnParameters.from_vector(from_search(coords, scaled))
        fit = replace(fit, params=params, cost=cost - result.prior.cost(coords),
                      on_bounds=parameters_on_bounds(params, fit.bounds))
        result = replace(result, coords=coords, cost=cost, evaluations=result.evaluations + evaluations)
        if not fit.on_bounds:
            break
    return fit, replace(result, frozen=tuple(n for n in names if n in frozen))


def _lag1(e: np.ndarray) -> float:
    den = math.fsum(e * e)
    return math.fsum(e[1:] * e[:-1]) / den if den > 0 else 0.0


def uncertainty(runs: Sequence[ModelRun], dt: float, nodes: tuple[str, ...], scaled: tuple[str, ...],
                coords: np.ndarray, bounds: dict[str, tuple[float, float]]) -> dict:
    """Standard errors, correlation matrix and the unidentifiable parameters at `coords` (module docstring)."""
    problem = Residuals(runs, dt, nodes, scaled)
    names = LptnParameters.names()
    steps = STEP * np.maximum(1.0, np.abs(coords))
    errors = problem.errors(np.vstack([coords, coords + np.diag(steps)]))
    mse = problem.mse(errors[0])
    rho = [max(0.0, _lag1(e)) for e in errors[0]]
    shrink = np.sqrt([(1 - r) / (1 + r) for r in rho])
    scale = shrink / np.sqrt(mse)
    jac = (((errors[1:] - errors[0]) * scale[None, :, None]).reshape(len(names), -1) / steps[:, None]).T
    info = portable.matmul(jac.T, jac)
    _, eig, vt = portable.svd(info)           # symmetric positive semi-definite: eigenvalues = singular values
    useful = eig > UNIDENTIFIED_EIGEN * eig[0]
    cov = portable.matmul(vt[useful].T * (1.0 / eig[useful]), vt[useful])
    blind = np.zeros(len(names), bool)
    for k in np.flatnonzero(~useful):
        blind |= np.abs(vt[k]) > 0.3
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    se[blind] = math.inf
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = cov / np.outer(se, se)
    corr = np.where(np.isfinite(corr), corr, 0.0)
    np.fill_diagonal(corr, 1.0)
    values = from_search(coords, scaled)
    table, unidentified = {}, []
    for i, name in enumerate(names):
        log = name in scaled
        limit = UNIDENTIFIED_LOG_SE if log else UNIDENTIFIED_RANGE_SHARE * (bounds[name][1] - bounds[name][0])
        entry = {"value": float(values[i]), "se": float(abs(values[i]) * se[i]) if log else float(se[i]),
                 "relative_se": float(se[i]) if log else None}
        table[name] = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in entry.items()}
        if not se[i] <= limit:
            unidentified.append(name)
    return {"parameters": table, "correlation": [[round(float(c), 6) for c in row] for row in corr],
            "names": names, "unidentifiable": unidentified, "nodes": list(nodes),
            "residual_lag1_autocorrelation": {n: float(r) for n, r in zip(nodes, rho, strict=True)},
            "method": "Fisher information of the node errors scaled by 1/σ and by √(N_eff/N) for their lag-1 "
                      "autocorrelation, at the polished optimum; log-scaled parameters' relative_se is that of ln x"}


