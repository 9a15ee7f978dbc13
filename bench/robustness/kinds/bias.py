"""A constant bias on one input: every sample plus the magnitude (either sign)."""

from __future__ import annotations

from bench.robustness.kinds import InputKind, register


class BiasKind(InputKind):
    name = "bias"
    summary = "a constant offset on every sample"
    signed = True
    relative_defaults = (-0.02, 0.02)          # ±13 Nm, ±180 rpm: a torque estimate's and a resolver's offset
    temperature_defaults = (-2.0, 2.0)         # K: a coolant sensor's tolerance

    def perturb(self, values, magnitude, rng, sample_period_s):
        return values + magnitude


register(BiasKind())
