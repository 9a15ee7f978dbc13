"""The Hammerstein model: a per-input sigmoid on the node losses (eqs. 28-30), then a fitted fourth-order linear
block run as the LTI LPTN's (`lti_lptn`: the same sections, step, C and counts). The artifact's
`input_nonlinearity` holds six vectors over [P_y, P_w, P_t, P_m] (`SIGMOID_KEYS`): u = P/scale,
S(u) = gain·σ(weight·u + bias) + linear·u + offset, times scale (MATLAB's sigmoidnet also has the linear term and
the offset)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from typing import Any

import numpy as np

from target_sim import costs
from target_sim.fmath import lanes
from target_sim.modelkinds import CArray, register
from target_sim.modelkinds.lti_lptn import LinearBlockPart, LtiLptnKind

SIGMOID_KEYS = ("scale_W", "weight", "bias", "gain", "linear", "offset")


class HammersteinPart(LinearBlockPart):
    """The linear block behind the sigmoid."""

    def __init__(self, artifact, estimator):
        super().__init__(artifact, estimator)
        self.sigmoid = {k: artifact.array("input_nonlinearity", k, dtype=estimator.f) for k in SIGMOID_KEYS}

    def input_nonlinearity(self, losses: np.ndarray) -> np.ndarray:
        """S(u)·scale per loss input, u = P/scale, S(u) = (gain/(1 + exp(-(w·u + b))) + lin·u) + off
        (eqs. 28-30; C: input_nonlinearity)."""
        est = self.est
        s = {k: lanes(v, losses[0]) for k, v in self.sigmoid.items()}   # lanes of trajectories: (4, L)
        u = losses / s["scale_W"]
        z = s["weight"] * u + s["bias"]
        out = (s["gain"] / (est.one + est.exp(-z)) + s["linear"] * u) + s["offset"]
        return out * s["scale_W"]

    def step(self, x: np.ndarray, losses: np.ndarray, speed, coolant, ambient) -> np.ndarray:
        return super().step(x, self.input_nonlinearity(losses), speed, coolant, ambient)


_SIGMOID_C = """\
/* Float32Estimator.input_nonlinearity (eqs. 28-30): per loss input, u = P/scale,
 * S(u) = (gain / (1 + exp(-(w u + b))) + lin u) + off, times scale */
static void input_nonlinearity(float losses[4])
{
    int k;
    for (k = 0; k < 4; k++) {
        const float u = losses[k] / SIG_SCALE[k];
        const float z = SIG_WEIGHT[k] * u + SIG_BIAS[k];
        const float out = (SIG_GAIN[k] / (1.0f + fw_exp(-z)) + SIG_LINEAR[k] * u) + SIG_OFFSET[k];
        losses[k] = out * SIG_SCALE[k];
    }
}
"""


def sigmoid_ops() -> Counter:
    """S(u) = gain·σ(w·u + b) + lin·u + off on u = P/scale, times scale, for the four loss inputs."""
    per_input = costs.op_counts(divide=2, multiply=3, add=4, exp=1, load_store=7)
    return Counter({k: 4 * v for k, v in per_input.items()}) + costs.op_counts(call=1)


class HammersteinKind(LtiLptnKind):
    name = "hammerstein"
    summary = "sigmoid input nonlinearity + fitted fourth-order linear block"
    input_nonlinearity = True
    c_nonlinearity = "    input_nonlinearity(u);\n"

    def fields(self, content: Mapping[str, Any]) -> list[tuple[str, ...]]:
        return super().fields(content) + [("input_nonlinearity", k) for k in SIGMOID_KEYS]

    def shapes(self, content: Mapping[str, Any]) -> dict[tuple[str, ...], tuple[int, ...]]:
        return {**super().shapes(content), **{("input_nonlinearity", k): (4,) for k in SIGMOID_KEYS}}

    def part(self, artifact, estimator) -> HammersteinPart:
        return HammersteinPart(artifact, estimator)

    def c_functions(self, artifact) -> list[str]:
        return [_SIGMOID_C, *super().c_functions(artifact)]

    def c_arrays(self, artifact) -> list[CArray]:
        sigmoid = [CArray("SIG_" + k.split("_")[0].upper(), (("input_nonlinearity", k),),
                          f"input_nonlinearity.{k} [P_y, P_w, P_t, P_m]", (4,)) for k in SIGMOID_KEYS]
        return sigmoid + super().c_arrays(artifact)

    def ops(self, artifact) -> dict[str, Counter]:
        return {"sigmoid": sigmoid_ops(), **super().ops(artifact)}

    def coefficient_count(self, artifact) -> int:
        return super().coefficient_count(artifact) + len(SIGMOID_KEYS) * 4


register(HammersteinKind())
