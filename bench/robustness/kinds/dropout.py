"""Dropped samples on one input: each sample lost with probability p (the magnitude). A drive channel's receiver
holds the last value it got (a lost CAN frame leaves the signal's buffer as it was); an observer's measurement
channel flags the reading absent (NaN: the observer predicts only, as the target does without a fresh reading)."""

from __future__ import annotations

import numpy as np

from bench.robustness.channels import channel_index
from bench.robustness.kinds import InputKind, register


class DropoutKind(InputKind):
    name = "dropout"
    summary = "each sample lost with probability p: a drive signal's last value held, a measurement absent"
    random = True

    def defaults(self, artifact, subject):
        return (0.05, 0.3)

    def unit(self, artifact, subject):
        return "probability"

    def problem(self, magnitude):
        return None if 0 <= magnitude < 1 else "must be a probability from 0 up to (not including) 1"

    def apply(self, lane, artifact, subject, magnitude, rng):
        index = channel_index(artifact, subject)
        values = lane.drive[:, index]
        lost = self.lost(len(values), magnitude, rng)
        if self.channel(artifact, subject).measured:
            return lane.with_column(index, np.where(lost, np.nan, values))
        kept = np.where(lost, 0, np.arange(len(values)))
        return lane.with_column(index, values[np.maximum.accumulate(kept)])   # the last received sample

    @staticmethod
    def lost(rows: int, magnitude: float, rng: np.random.Generator) -> np.ndarray:
        lost = rng.random(rows) < magnitude
        lost[0] = False                                   # the first sample is the one the model starts from
        return lost


register(DropoutKind())
