"""Σ w log MSE: Gaussian maximum likelihood with an unknown variance per node (the paper's criterion)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Likelihood:
    name: str = "likelihood"
    description: str = ("weighted sum of log MSE over the measured nodes: Gaussian maximum likelihood with unknown "
                        "variances")

    def cost(self, mse: np.ndarray, weights: np.ndarray) -> np.ndarray:
        from bench.thermal import portable  # numba: imported by a cost, not by the criteria's names

        with np.errstate(divide="ignore", invalid="ignore"):
            return np.sum(weights * portable.log_array(mse), axis=-1)

    def exact_cost(self, mse: np.ndarray, weights: np.ndarray) -> float:
        from bench.thermal import portable  # numba: imported by a cost, not by the criteria's names

        logs = (float(portable.log_array(np.array([m]))[0]) for m in mse)
        return math.fsum(float(w) * log for w, log in zip(weights, logs, strict=True))

    def variances(self, mse: np.ndarray, weights: np.ndarray) -> np.ndarray:
        return mse


LIKELIHOOD = Likelihood()
