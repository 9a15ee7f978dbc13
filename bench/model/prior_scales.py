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
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bench.model.lptn_fit import batch_cost, measured_nodes
from bench.model.polish import INSET, Residuals, polish_one
from bench.model.runs import ModelRun
from bench.thermal.parameters import LptnParameters

SCALE_GROUPS = {
    "stator_R": ("R_yw", "R_yt", "R_wt", "R_cy0"),
    "stator_C": ("C_y", "C_w", "C_t"),
    "rotor_R": ("R_wm0", "a_wm", "R_tm0", "a_tm", "R_ma0", "a_ma"),
    "rotor_C": ("C_m",),
}
SCALE_RANGE = (0.1, 10.0)     # each factor's search range
GRID = 13                     # grid points per scale (one R and one C scale): factors 10^(-1 … 1 by 1/6)


@dataclass(frozen=True)
class AdaptedPrior:
    parameters: LptnParameters
    scales: dict[str, float]     # group -> factor
    cost_prior: float            # the swarm's cost at the prior as given
    cost: float                  # at the scaled prior

    def record(self) -> dict:
        return {"scales": self.scales, "cost_prior": self.cost_prior, "cost": self.cost,
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

    def errors(self, coords: np.ndarray) -> np.ndarray:
        return self.vector_errors(scaled(self.prior, coords))


def adapt_prior(runs: Sequence[ModelRun], dt: float, prior: LptnParameters) -> AdaptedPrior:
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
