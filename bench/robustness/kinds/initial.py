"""A wrong start: the initial temperatures off by the magnitude in K (either sign), on one node or all four (the
host sends the first measured values; a magnet has no sensor in a vehicle and starts from a guess)."""

from __future__ import annotations

from dataclasses import replace

from bench.robustness.kinds import PerturbationKind, register
from target_sim.artifact import OUTPUTS


class InitialKind(PerturbationKind):
    name = "initial"
    summary = "the initial temperatures off by the magnitude"
    signed = True

    def subjects(self, artifact):
        return ("all", *OUTPUTS)

    def defaults(self, artifact, subject):
        return (-10.0, 10.0)

    def unit(self, artifact, subject):
        return "K"

    def apply(self, lane, artifact, subject, magnitude, rng):
        initial = lane.initial.copy()
        if subject == "all":
            initial += magnitude
        else:
            initial[OUTPUTS.index(subject)] += magnitude
        return replace(lane, initial=initial)


register(InitialKind())
