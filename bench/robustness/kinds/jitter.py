"""Δt jitter: every model step lasts Δt·(1 + ε), ε normal with standard deviation σ (the magnitude, a fraction of
Δt), while the model still integrates as if it were Δt. The step boundaries accumulate the jitter, so the samples
each step averages and the time its output refers to are those of the jittered clock."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from bench.robustness.kinds import PerturbationKind, register


class JitterKind(PerturbationKind):
    name = "jitter"
    summary = "each step Δt·(1 + ε), ε of standard deviation σ, the model assuming Δt"
    random = True

    def subjects(self, artifact):
        return ("dt",)

    def defaults(self, artifact, subject):
        return (0.02, 0.1)

    def unit(self, artifact, subject):
        return "fraction of Δt"

    def problem(self, magnitude):
        return None if 0 <= magnitude <= 0.3 else "must be a fraction of Δt from 0 to 0.3"

    def apply(self, lane, artifact, subject, magnitude, rng):
        steps = int(len(lane.drive) * lane.sample_period_s / lane.dt) + 2
        lengths = lane.dt * np.clip(1.0 + rng.normal(0.0, magnitude, steps), 0.05, None)   # a step has a length
        return replace(lane, boundaries_s=np.concatenate([[0.0], np.cumsum(lengths)]))


register(JitterKind())
