"""The input search of bench/firmware/adversarial.py: it climbs to a known maximum, is reproducible by its seed, and
counts its evaluations; its scenarios map the unit cube into the bus's ranges."""

from __future__ import annotations

import numpy as np
import pytest

from bench.firmware.adversarial import maximize


def _peak(point: np.ndarray) -> int:
    """A cycle count with one narrow peak (1000 at (0.8, 0.2, 0.6)) and plateaus of equal counts around it."""
    distance = float(np.abs(point - np.array([0.8, 0.2, 0.6])).sum())
    return int(1000 - 40 * round(distance * 10))


def test_the_search_climbs_to_the_peak_and_repeats_itself_by_its_seed():
    calls = []

    def counted(point):
        calls.append(point)
        return _peak(point)

    found = maximize(counted, 3, evaluations=300, seed=4)
    assert found.evaluations == len(calls) == 300
    assert found.cycles == max(_peak(p) for p in calls) and found.cycles >= 960
    assert maximize(_peak, 3, evaluations=300, seed=4).cycles == found.cycles
    assert np.all((found.point >= 0) & (found.point <= 1))


def test_a_start_is_evaluated_first_and_an_empty_budget_is_refused():
    found = maximize(_peak, 3, evaluations=1, starts=[np.array([0.8, 0.2, 0.6])])
    assert found.cycles == 1000 and found.evaluations == 1
    with pytest.raises(ValueError):
        maximize(_peak, 3, evaluations=0)
