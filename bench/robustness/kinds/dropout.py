"""Dropped samples on one input: each sample lost with probability p (the magnitude), the receiver holding the
last value it got (a lost CAN frame leaves the signal's buffer as it was)."""

from __future__ import annotations

import numpy as np

from bench.robustness.kinds import InputKind, register


class DropoutKind(InputKind):
    name = "dropout"
    summary = "each sample lost with probability p, the last received value held"
    random = True

    def defaults(self, artifact, subject):
        return (0.05, 0.3)

    def unit(self, artifact, subject):
        return "probability"

    def problem(self, magnitude):
        return None if 0 <= magnitude < 1 else "must be a probability from 0 up to (not including) 1"

    def perturb(self, values, magnitude, rng, sample_period_s):
        lost = rng.random(len(values)) < magnitude
        lost[0] = False                                   # the first sample is the one the model starts from
        kept = np.where(lost, 0, np.arange(len(values)))
        return values[np.maximum.accumulate(kept)]        # the last received sample at every row


register(DropoutKind())
