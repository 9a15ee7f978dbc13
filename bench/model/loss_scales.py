"""Loss scales: the motor's stator iron and magnet losses scaled by factors fitted together with the network.

Why: a designer's loss model is off by a factor per loss path (0.5-2 on the motor suite's machines), and a network
fitted to wrong losses bends to absorb them: with the suite plants' own iron and magnet factors (and ac copper)
in the motor file, the designer's Hammerstein models' validation winding + magnet MSE went 12.0 / 23.8 / 9.8 →
7.9 / 9.1 / 7.9 K² (air-30kw / ipm-60kw / outrunner-200kw). The data can place the *relative* size of the loss
paths (the iron heats yoke and tooth, the magnet loss the rotor, copper the winding, through one network), not
their common scale (a network with every loss doubled and every resistance halved answers alike), so copper stays
the reference: its dc part is the measured winding resistance. Its ac factor was fitted too in the experiment
that chose this (docs/method.md) and ended on its box wall on all three suite motors, against the plants' truth
on two of them: a compensator, not a loss, so it is left as the motor file says.

After the polish the network's parameters and the log scales are fitted together by the polish's own
Levenberg-Marquardt (`polish_one`: the swarm's likelihood cost, the prior's penalty, the scales' prior centred on
1 with the same box rule), the loss model then carries the factors (`LabLossKind.scaled`: the artifacts hold the
scaled coefficients, so the target needs nothing new), and the Hammerstein fit runs on the scaled losses.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from bench.model.lptn_fit import LptnFit, from_search, log_scaled, parameters_on_bounds, search_bounds, to_search
from bench.model.polish import Residuals, polish_one, prior_penalty
from bench.model.runs import ModelRun
from bench.motor.losses import MAP_TABLES
from bench.thermal.parameters import LptnParameters

SCALED_LOSSES = ("p_stator", "p_magnet")     # the loss inputs scaled (columns of MAP_TABLES)
SCALE_BOX = (0.5, 2.0)                       # a designer's loss path is off by at most this factor


@dataclass(frozen=True)
class LossScales:
    """The fitted factors (loss input -> factor) and the cost they reached."""

    factors: dict[str, float]
    cost_before: float
    cost: float
    evaluations: int

    def record(self) -> dict:
        return {"factors": self.factors, "box": list(SCALE_BOX), "cost_before": self.cost_before,
                "cost": self.cost, "evaluations": self.evaluations,
                "method": "Levenberg-Marquardt with the network's parameters from the polished network (the "
                          "polish's cost and prior), log factors of the loss inputs, copper the reference"}


def scaled_runs(runs: Sequence[ModelRun], factors: Mapping[str, float]) -> list[ModelRun]:
    """The runs with their loss inputs multiplied by `factors` (loss input name -> factor)."""
    out = []
    for run in runs:
        table = run.inputs.table_losses.copy()
        for name, factor in factors.items():
            table[:, MAP_TABLES.index(name)] *= factor
        out.append(replace(run, inputs=replace(run.inputs, table_losses=table)))
    return out


class ScaledResiduals(Residuals):
    """`Residuals` of search coordinates that end in the log factors of SCALED_LOSSES: the models sharing factors
    run as one batch on runs scaled by them (a Jacobian's batch: the network's columns share the current factors,
    each factor's column has its own)."""

    width = len(LptnParameters.names())     # the network's coordinates, before the log factors

    def errors(self, coords: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        coords = np.atleast_2d(coords)
        size = len(self.nodes) * int(self.count)
        out = np.empty((len(coords), size)) if out is None else out
        errors = out[:, :size].reshape(len(coords), len(self.nodes), int(self.count))
        keys = [tuple(c[self.width:]) for c in coords]
        for key in dict.fromkeys(keys):
            rows = [i for i, k in enumerate(keys) if k == key]
            runs = scaled_runs(self.runs, factors_of(np.array(key)))
            errors[rows] = Residuals(runs, self.dt, self.nodes, self.scaled).errors(coords[rows, :self.width])
        return errors


def factors_of(log_factors: np.ndarray) -> dict[str, float]:
    return {name: math.exp(float(v)) for name, v in zip(SCALED_LOSSES, log_factors, strict=True)}


def fit_loss_scales(fit: LptnFit, runs: Sequence[ModelRun], dt: float, prior: LptnParameters
                    ) -> tuple[LptnFit, LossScales]:
    """The network `fit` and the loss scales fitted together from `fit` with factors 1 (module docstring); the
    network's prior penalty is centred on `prior`, the scales' on 1."""
    scaled = log_scaled(fit.bounds)
    lower22, upper22 = search_bounds(fit.bounds)
    count = len(SCALED_LOSSES)
    box = np.log(np.array(SCALE_BOX))
    lower = np.concatenate([lower22, np.full(count, box[0])])
    upper = np.concatenate([upper22, np.full(count, box[1])])
    start = np.concatenate([to_search(np.array(fit.params.as_vector()), scaled), np.zeros(count)])
    centre = np.concatenate([to_search(np.array(prior.as_vector()), scaled), np.zeros(count)])
    problem = ScaledResiduals(runs, dt, fit.nodes, scaled, fit.criterion)
    penalty = prior_penalty(problem, start, centre, lower, upper)
    before = problem.cost(problem.errors(start[None])[0])
    coords, _, evaluations = polish_one(problem, start, lower, upper, penalty)
    cost = problem.cost(problem.errors(coords[None])[0])
    params = LptnParameters.from_vector(from_search(coords[:problem.width], scaled))
    fitted = replace(fit, params=params, cost=cost, on_bounds=parameters_on_bounds(params, fit.bounds))
    return fitted, LossScales(factors_of(coords[problem.width:]), before, cost, evaluations)
