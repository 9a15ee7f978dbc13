"""The particle swarm's stall stop (bench.thermal.pso.Stall)."""

import numpy as np
import pytest

from bench.thermal.pso import Stall, particle_swarm

LOWER, UPPER = np.full(3, -5.0), np.full(3, 5.0)


def _bowl(positions: np.ndarray) -> np.ndarray:
    return np.sum((positions - 1.0) ** 2, axis=1)


def test_a_stalled_swarm_stops_where_the_full_run_had_stalled():
    full = particle_swarm(_bowl, LOWER, UPPER, swarm_size=12, iterations=200, seed=3)
    stall = Stall(window=5, tolerance=1e-3)
    stopped = particle_swarm(_bowl, LOWER, UPPER, swarm_size=12, iterations=200, seed=3, stall=stall)
    n = stopped.stalled_at
    assert n is not None and stall.window < n < 200
    # the same swarm up to the stop (the stall only reads the history), and the stop is the first stalled iteration
    assert np.array_equal(stopped.history, full.history[:n])
    assert full.history[n - 1 - stall.window] - full.history[n - 1] < stall.tolerance
    assert all(full.history[i - stall.window] - full.history[i] >= stall.tolerance
               for i in range(stall.window, n - 1))
    assert stopped.evaluations == 12 * (n + 1) and full.stalled_at is None and len(full.history) == 200


def test_a_swarm_that_keeps_improving_runs_all_its_iterations():
    result = particle_swarm(_bowl, LOWER, UPPER, swarm_size=12, iterations=30, seed=3, stall=Stall(10, 0.0))
    assert result.stalled_at is None and len(result.history) == 30


def test_the_stall_reads_the_best_cost_over_its_window():
    stall = Stall(window=2, tolerance=0.25)
    assert not stall.reached([5.0, 4.0])                    # too short to tell
    assert not stall.reached([5.0, 4.0, 3.875, 3.75])       # 4 -> 3.75 is the tolerance, not less
    assert stall.reached([5.0, 4.0, 3.875, 3.75, 3.7])      # 3.875 -> 3.7 is less
    with pytest.raises(ValueError):
        Stall(window=0, tolerance=0.01)
