"""Particle swarm optimization (global-best, constriction coefficients of Clerc and Kennedy 2002).

The cost function gets the whole swarm at once, (particles, dims) -> (particles,), so it can evaluate the
candidates vectorized or in parallel instead of one by one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

INERTIA = 0.7298
ACCELERATION = 1.49618


@dataclass(frozen=True)
class SwarmResult:
    best: np.ndarray              # best position found
    best_cost: float
    history: np.ndarray           # best cost after each iteration
    evaluations: int
    personal_bests: np.ndarray    # (swarm, dims) each particle's best position, for a local polish to start from
    personal_costs: np.ndarray    # (swarm,) their costs
    stalled_at: int | None = None   # the iterations run when the swarm stopped for a stall (`Stall`), if it did


@dataclass(frozen=True)
class Stall:
    """Stop the swarm once its best cost has fallen by less than `tolerance` over the last `window` iterations.

    For a swarm that a local polish follows (bench.model.polish): the swarm's job is then the basin, not its
    bottom; a swarm that gains less than the tolerance in `window` iterations (window × swarm simulations) gains
    less than one LM step of the polish does for a few dozen. Checked after `window` iterations at the earliest;
    deterministic, since it reads only the best-cost history."""

    window: int
    tolerance: float

    def __post_init__(self):
        if self.window < 1 or not self.tolerance >= 0:
            raise ValueError("a stall needs a window of at least one iteration and a tolerance of zero or more")

    def reached(self, history: list[float]) -> bool:
        return len(history) > self.window and history[-1 - self.window] - history[-1] < self.tolerance


def particle_swarm(cost: Callable[[np.ndarray], np.ndarray], lower: np.ndarray, upper: np.ndarray, *,
                   swarm_size: int = 220, iterations: int = 100, seed: int = 0,
                   initial: np.ndarray | None = None, stall: Stall | None = None,
                   on_iteration: Callable[[int, float], None] | None = None) -> SwarmResult:
    """Minimize `cost` inside the box [lower, upper]. `initial`, if given, is one of the starting particles; with a
    `stall` the swarm stops before `iterations` once its best cost stalls."""
    rng = np.random.default_rng(seed)
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    span = upper - lower
    pos = lower + rng.random((swarm_size, lower.size)) * span
    if initial is not None:
        pos[0] = np.clip(initial, lower, upper)
    vel = (rng.random(pos.shape) - 0.5) * span * 0.2
    costs = _finite(cost(pos))
    best_pos, best_cost = pos.copy(), costs.copy()
    g = int(np.argmin(best_cost))
    history = []
    stalled_at = None
    for it in range(iterations):
        r1, r2 = rng.random(pos.shape), rng.random(pos.shape)
        vel = INERTIA * vel + ACCELERATION * r1 * (best_pos - pos) + ACCELERATION * r2 * (best_pos[g] - pos)
        vel = np.clip(vel, -span * 0.5, span * 0.5)
        pos = pos + vel
        out = (pos < lower) | (pos > upper)       # reflect at the walls and stop the outward motion
        pos = np.clip(pos, lower, upper)
        vel[out] = 0.0
        costs = _finite(cost(pos))
        improved = costs < best_cost
        best_pos[improved], best_cost[improved] = pos[improved], costs[improved]
        g = int(np.argmin(best_cost))
        history.append(float(best_cost[g]))
        if on_iteration is not None:
            on_iteration(it, history[-1])
        if stall is not None and stall.reached(history):
            stalled_at = len(history)
            break
    return SwarmResult(best_pos[g].copy(), float(best_cost[g]), np.array(history), swarm_size * (len(history) + 1),
                       best_pos, best_cost, stalled_at)


def _finite(costs) -> np.ndarray:
    """A candidate whose simulation blew up is simply the worst, not an error."""
    costs = np.asarray(costs, dtype=float)
    return np.where(np.isfinite(costs), costs, np.inf)
