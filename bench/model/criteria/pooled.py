"""log Σ w MSE: one variance for every node, so the nodes weigh by their errors in K², not by their relative fit.

Why beside the likelihood: the scale-free likelihood counts halving a 1 K² error as much as halving a 10 K² one,
and on the motor suite it preferred a network that traded a large winding error for a small magnet one (outrunner,
--prior auto: training MSE winding / magnet / yoke / tooth 11.1 / 1.7 / 3.0 / 2.7 K², likelihood 4.00, against the
designer prior's 4.6 / 6.7 / 1.1 / 4.5, 4.24; pooled 2.75 against 2.65). The log keeps the swarm's stall tolerance a
relative one."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Pooled:
    name: str = "pooled"
    description: str = "log of the weighted sum of MSE over the measured nodes: one common error variance"

    def cost(self, mse: np.ndarray, weights: np.ndarray) -> np.ndarray:
        from bench.thermal import portable  # numba: imported by a cost, not by the criteria's names

        with np.errstate(divide="ignore", invalid="ignore"):
            return portable.log_array(np.sum(weights * mse, axis=-1))

    def exact_cost(self, mse: np.ndarray, weights: np.ndarray) -> float:
        from bench.thermal import portable  # numba: imported by a cost, not by the criteria's names

        return float(portable.log_array(np.array([math.fsum(weights * mse)]))[0])

    def variances(self, mse: np.ndarray, weights: np.ndarray) -> np.ndarray:
        return np.full(mse.shape, math.fsum(weights * mse))


POOLED = Pooled()
