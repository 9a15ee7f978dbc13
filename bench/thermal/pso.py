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


def particle_swarm(cost: Callable[[np.ndarray], np.ndarray], lower: np.ndarray, upper: np.ndarray, *,
                   swarm_size: int = 220, iterations: int = 100, seed: int = 0,
                   initial: np.ndarray | None = None,
                   on_iteration: Callable[[int, float], None] | None = None) -> SwarmResult:
    """Minimize `cost` inside the box [lower, upper]. `initial`, if given, is one of the starting particles."""
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
    return SwarmResult(best_pos[g].copy(), float(best_cost[g]), np.array(history), swarm_size * (iterations + 1),
                       best_pos, best_cost)


def _finite(costs) -> np.ndarray:
    """A candidate whose simulation blew up is simply the worst, not an error."""
    costs = np.asarray(costs, dtype=float)
    return np.where(np.isfinite(costs), costs, np.inf)
