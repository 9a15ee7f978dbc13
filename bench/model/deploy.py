"""Which model kind `bench identify --kind auto` deploys: one rule on the validation files' figures.

The rule: the kind whose winding + magnet float32 MSE, pooled over all validation files (the sum of the two nodes'
MSEs, as the target runs the model), is the smallest; a kind within `TIE_RELATIVE` of that smallest score ties with
it, and a tie goes to the simpler kind (`CANDIDATES`, simplest first, as the kinds' own flags say). The candidates
share one network fit, so choosing among them costs their validation runs only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from target_sim.kinds import MODEL_KINDS

AUTO = "auto"


def _simplicity(kind: str) -> tuple[bool, bool]:
    """Fitted input nonlinearity last (the sigmoids and refitted loss columns on top of the network), then a
    network rebuilt every step after a fixed linear step (the same 22 fitted parameters, time-varying)."""
    return MODEL_KINDS[kind].input_nonlinearity, not MODEL_KINDS[kind].linear_block


# every model kind, simplest first (lti-lptn, pv-lptn, hammerstein)
CANDIDATES = tuple(sorted(MODEL_KINDS.names(), key=_simplicity))
DEPLOYED_NODES = ("winding", "pm")      # the outputs a model is deployed for
# Scores this close are one score: a difference that small is the float32 estimates' rounding (6e-8 relative per
# value), not evidence for the more complex kind (a chosen margin, not a measured one).
TIE_RELATIVE = 1e-6
RULE = ("the smallest winding + magnet float32 MSE pooled over the validation files; a kind within "
        f"{TIE_RELATIVE:g} (relative) of it ties, and a tie goes to the simpler kind ({', '.join(CANDIDATES)}, "
        "simplest first)")


@dataclass(frozen=True)
class Deployment:
    """The kind the rule chose and the figures it chose on."""

    kind: str
    mse_K2: dict[str, float]        # candidate kind -> its validation score (inf when it diverged)
    tied: tuple[str, ...]           # the more complex kinds that tied with `kind` and lost the tie

    def record(self) -> dict:
        """For --json and the artifacts' provenance (JSON has no inf: a diverged kind's score is null)."""
        return {"deployed_kind": self.kind, "rule": RULE, "tied": list(self.tied),
                "validation_mse_K2": {k: (v if math.isfinite(v) else None) for k, v in self.mse_K2.items()}}

    def sentence(self, path: str) -> str:
        """One sentence: what was deployed where, and why, with the figures."""
        others = ", ".join(f"{k} {_k2(v)}" for k, v in self.mse_K2.items() if k != self.kind)
        tie = f"; it ties with {' and '.join(self.tied)}, and a tie goes to the simpler kind" if self.tied else ""
        return (f"--kind auto deployed {self.kind} to {path}: its winding + magnet float32 MSE on the validation "
                f"files, {_k2(self.mse_K2[self.kind])}, is the smallest ({others}){tie}")


def validation_score(figures: dict) -> float:
    """One kind's score from its validation figures ({float32: {node: {mse, ...}}}): the deployed nodes' float32
    MSE summed, inf when the model diverged (a NaN or an inf estimate is never deployed) or the target would refuse
    its artifact ({"refused": why})."""
    if "refused" in figures:
        return math.inf
    score = math.fsum(figures["float32"][node]["mse"] for node in DEPLOYED_NODES)
    return score if math.isfinite(score) else math.inf


def choose_kind(metrics: dict) -> Deployment:
    """The rule (module docstring) on `metrics` (kind -> validation figures, every one of `CANDIDATES`)."""
    scores = {kind: validation_score(metrics[kind]) for kind in CANDIDATES}
    best = min(scores.values())
    within = [k for k in CANDIDATES if _ties(scores[k], best)]
    return Deployment(within[0], scores, tuple(within[1:]))


def _ties(score: float, best: float) -> bool:
    if math.isinf(best):        # every kind diverged: the simplest is as good as any
        return True
    return score <= best * (1 + TIE_RELATIVE)


def _k2(value: float) -> str:
    return f"{value:.4g} K²" if math.isfinite(value) else "diverged"
