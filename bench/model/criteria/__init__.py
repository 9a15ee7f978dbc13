"""The network fit's criteria: how the swarm, the polish and the loss scales weigh the measured nodes' errors.

    CRITERIA[name].cost(mse, weights)       # (P, nodes) MSEs -> (P,) costs, lower is better
    CRITERIA[name].exact_cost(mse, weights) # (nodes,) MSEs of one model -> its cost, exactly summed (math.fsum)
    CRITERIA[name].variances(mse, weights)  # (nodes,) MSEs -> the variances a polish round divides by

One module per kind: `likelihood` (Σ w log MSE, the default: scale-free, every node by its relative fit) and
`pooled` (log Σ w MSE: every node by its error in K², so a large error weighs more than a small one halved). A
criterion's variances make one round of the polish's least squares (Σ w ‖r‖² / (N σ²)) have the criterion's
gradient at its start (bench.model.polish).

The package imports nothing heavy (the criteria import bench.thermal.portable, and with it numba, when they compute
a cost): `bench identify` takes its --network-cost choices and default from here when it builds its parser.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from bench.model.criteria.likelihood import LIKELIHOOD
from bench.model.criteria.pooled import POOLED


class NetworkCriterion(Protocol):
    name: str
    description: str

    def cost(self, mse: np.ndarray, weights: np.ndarray) -> np.ndarray: ...

    def exact_cost(self, mse: np.ndarray, weights: np.ndarray) -> float: ...

    def variances(self, mse: np.ndarray, weights: np.ndarray) -> np.ndarray: ...


CRITERIA: dict[str, NetworkCriterion] = {c.name: c for c in (LIKELIHOOD, POOLED)}
DEFAULT_CRITERION = LIKELIHOOD.name
