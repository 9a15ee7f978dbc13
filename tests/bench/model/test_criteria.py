"""The network fit's criteria (bench.model.criteria): each cost's own gradient is what a polish round's weighted
least squares minimizes at its start (Σ w ‖r‖² / (N σ²), σ² the criterion's variances), and the pooled cost weighs
the nodes by their errors in K², the likelihood by their relative fit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.model.criteria import CRITERIA, DEFAULT_CRITERION

WEIGHTS = np.array([1.0, 1.0, 0.5, 0.5])


@pytest.mark.parametrize("name", list(CRITERIA))
def test_a_polish_round_has_the_criterions_gradient(name):
    """d cost / d MSE_n = w_n / σ_n² for every node: the round's least squares descends the criterion itself."""
    criterion = CRITERIA[name]
    mse = np.array([11.14, 1.74, 2.97, 2.69])
    step = 1e-7
    numeric = [(criterion.exact_cost(mse + step * np.eye(4)[n], WEIGHTS) - criterion.exact_cost(mse, WEIGHTS)) / step
               for n in range(4)]
    assert numeric == pytest.approx(WEIGHTS / criterion.variances(mse, WEIGHTS), rel=1e-5)


@pytest.mark.parametrize("name", list(CRITERIA))
def test_the_batch_cost_is_the_exact_cost(name):
    criterion = CRITERIA[name]
    mse = np.array([[11.14, 1.74, 2.97, 2.69], [4.61, 6.69, 1.14, 4.46]])
    assert criterion.cost(mse, WEIGHTS) == pytest.approx([criterion.exact_cost(m, WEIGHTS) for m in mse], rel=1e-14)


def test_pooled_prefers_the_balanced_network_the_likelihood_does_not():
    """The suite's outrunner from --prior auto (training MSE winding, magnet, yoke, tooth, K²): a large winding
    error traded for a small magnet one. The likelihood prefers the traded network (4.00 against 4.24); the pooled
    cost prefers the one without a large error (2.65 against 2.75)."""
    traded, balanced = np.array([11.14, 1.74, 2.97, 2.69]), np.array([4.61, 6.69, 1.14, 4.46])
    likelihood, pooled = CRITERIA[DEFAULT_CRITERION], CRITERIA["pooled"]
    assert likelihood.exact_cost(traded, WEIGHTS) < likelihood.exact_cost(balanced, WEIGHTS) - 0.2
    assert pooled.exact_cost(balanced, WEIGHTS) < pooled.exact_cost(traded, WEIGHTS) - 0.1
    assert pooled.exact_cost(balanced, WEIGHTS) == pytest.approx(math.log(4.61 + 6.69 + 0.5 * (1.14 + 4.46)))
