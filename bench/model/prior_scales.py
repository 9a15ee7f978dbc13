"""Adapting a foreign prior to this motor: a few common scale factors of its network fitted before the swarm.

Why: a named parameter set (`table1`, `table1-refined`) is another machine's network (the paper's 200 kW motor).
Its shape (which paths are wide or narrow, how the heat capacity is shared) is a fair guess for a similar machine,
its size is not: the IPM example's resistances and capacitances differ from Table 1's by more than the 0.5-2 box
of `bench motor template`, so the box cannot hold this motor's network (20 of 22 parameters on a bound). Thermal
resistance and heat capacity scale with the machine's size in a few common ways, so the prior is first scaled by
SCALE_GROUPS common factors (stator and rotor resistances, stator and rotor capacitances), fitted to the training
data on the swarm's own cost (lptn_fit.batch_cost), and the user's box is placed around the scaled prior.

The fit: a log-spaced grid over one resistance and one capacitance scale (GRID points each in SCALE_RANGE,
every candidate in one parallel batch: a global look that needs no start), then the polish's Levenberg-Marquardt
(polish.polish_one: the same likelihood, variances re-estimated each round, the range kept by a smooth map) over
the four group log-scales from the grid's best. Deterministic and cheap: a few hundred model simulations, about
one swarm iteration. Only the scales move; the dimensionless parameters (speed exponents, alpha_cy, the k's) keep
the prior's values. If the scaled prior does not fit the training data better than the prior as given, the prior
is kept (all factors 1).

Then each path on its own (`adapt_paths`): common factors fix the network's size, not its shape, and another
machine's shape can be off by more than the user's box in single paths (on the IPM example Table 1's winding-tooth
resistance is 11 times this motor's relative to the other stator paths, its magnet-shaft path a thirteenth). So
every resistance and capacitance of SCALE_GROUPS gets its own factor within SCALE_RANGE of its scaled value,
fitted by the same LM, maximum a posteriori with the polish's weak prior centred on the scaled network
(polish.PriorPenalty: σ a quarter of the range, a factor 10^½), so that a path the data do not see stays at the
scaled value instead of drifting to a wall. The dimensionless parameters still keep the prior's values (as the
automatic prior keeps Table 1's). The result is the adapted prior the user's box is placed around.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from bench.model.lptn_fit import (
    batch_cost,
    from_search,
    log_scaled,
    measured_nodes,
    parameter_bounds,
    search_bounds,
    to_search,
)
from bench.model.polish import INSET, Residuals, polish_one, prior_penalty
from bench.model.runs import ModelRun
from bench.thermal.parameters import LptnParameters

SCALE_GROUPS = {
    "stator_R": ("R_yw", "R_yt", "R_wt", "R_cy0"),
    "stator_C": ("C_y", "C_w", "C_t"),
    "rotor_R": ("R_wm0", "a_wm", "R_tm0", "a_tm", "R_ma0", "a_ma"),
    "rotor_C": ("C_m",),
}
# adapt_paths: each its own factor (in the parameters' order)
PATH_NAMES = tuple(n for n in LptnParameters.names() if any(n in group for group in SCALE_GROUPS.values()))
SCALE_RANGE = (0.1, 10.0)     # each factor's search range
GRID = 13                     # grid points per scale (one R and one C scale): factors 10^(-1 … 1 by 1/6)


@dataclass(frozen=True)
class AdaptedPrior:
    parameters: LptnParameters
    scales: dict[str, float]     # group -> factor
    cost_prior: float            # the swarm's cost at the prior as given
    cost: float                  # at the adapted prior (scaled, then each path)
    paths: dict[str, float] = field(default_factory=dict)   # parameter -> its own factor on the scaled value
    cost_scaled: float = math.nan                             # at the scaled prior, before the paths

    def record(self) -> dict:
        return {"scales": self.scales, "paths": self.paths, "cost_prior": self.cost_prior,
                "cost_scaled": self.cost_scaled, "cost": self.cost,
                "groups": {g: list(names) for g, names in SCALE_GROUPS.items()}}


def scaled(prior: LptnParameters, log_scales: np.ndarray) -> np.ndarray:
    """(P, 22) parameter vectors: the prior with each group's parameters times exp(log-scale) (P, groups)."""
    names = LptnParameters.names()
    base = np.array(prior.as_vector(), float)
    factors = np.ones((len(log_scales), len(names)))
    for k, group in enumerate(SCALE_GROUPS.values()):
        for name in group:
            factors[:, names.index(name)] = np.exp(log_scales[:, k])
    return base * factors


class _ScaledResiduals(Residuals):
    """The polish's residuals with the group log-scales as the coordinates."""

    def __init__(self, runs: Sequence[ModelRun], dt: float, prior: LptnParameters):
        super().__init__(runs, dt, measured_nodes(runs), ())
        self.prior = prior

    def errors(self, coords: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        return self.vector_errors(scaled(self.prior, coords), out)


def adapt_prior(runs: Sequence[ModelRun], dt: float, prior: LptnParameters) -> AdaptedPrior:
    """The prior adapted to these runs: common factors per SCALE_GROUPS, then each path (`adapt_paths`)."""
    return adapt_paths(runs, dt, scale_prior(runs, dt, prior))


def scale_prior(runs: Sequence[ModelRun], dt: float, prior: LptnParameters) -> AdaptedPrior:
    """The prior scaled to these runs: common factors per SCALE_GROUPS at the lowest swarm cost."""
    groups = list(SCALE_GROUPS)
    lo, hi = math.log(SCALE_RANGE[0]), math.log(SCALE_RANGE[1])
    axis = np.linspace(lo, hi, GRID)
    r, c = np.meshgrid(axis, axis, indexing="ij")
    grid = np.zeros((GRID * GRID, len(groups)))
    for k, group in enumerate(groups):
        grid[:, k] = (r if group.endswith("_R") else c).ravel()
    costs = batch_cost(scaled(prior, grid), runs, dt, np.ones(4), measured_nodes(runs))
    costs = np.where(np.isfinite(costs), costs, np.inf)
    start = grid[int(np.argmin(costs))]
    problem = _ScaledResiduals(runs, dt, prior)
    lower, upper = np.full(len(groups), lo), np.full(len(groups), hi)
    best, cost, _ = polish_one(problem, np.clip(start, lower + INSET * (hi - lo), upper - INSET * (hi - lo)),
                               lower, upper)
    cost_prior = problem.cost(problem.errors(np.zeros((1, len(groups))))[0])
    if not cost < cost_prior:     # the prior as given fits better: keep it
        best, cost = np.zeros(len(groups)), cost_prior
    params = LptnParameters.from_vector(scaled(prior, best[None])[0])
    return AdaptedPrior(params, {g: float(math.exp(v)) for g, v in zip(groups, best, strict=True)}, cost_prior,
                        cost)


def adapt_paths(runs: Sequence[ModelRun], dt: float, scaled_prior: AdaptedPrior) -> AdaptedPrior:
    """Each resistance and capacitance of SCALE_GROUPS fitted on its own within SCALE_RANGE of the scaled prior
    (LM, maximum a posteriori around it); the dimensionless parameters stay. Kept only if the cost falls."""
    centre = scaled_prior.parameters
    bounds = parameter_bounds(centre, SCALE_RANGE)
    scaled_names = log_scaled(bounds)
    lower, upper = search_bounds(bounds)
    free = np.isin(LptnParameters.names(), PATH_NAMES)
    problem = Residuals(runs, dt, measured_nodes(runs), scaled_names)
    start = to_search(np.array(centre.as_vector()), scaled_names)
    penalty = prior_penalty(problem, start, start, lower, upper)
    coords, _, _ = polish_one(problem, start, lower, upper, penalty, free)
    params = LptnParameters.from_vector(from_search(coords[None], scaled_names)[0])
    cost = problem.cost(problem.errors(coords[None])[0])
    if not cost < scaled_prior.cost:
        return replace(scaled_prior, cost_scaled=scaled_prior.cost)
    paths = {n: getattr(params, n) / getattr(centre, n) for n in PATH_NAMES}
    return replace(scaled_prior, parameters=params, cost=cost, paths=paths, cost_scaled=scaled_prior.cost)
