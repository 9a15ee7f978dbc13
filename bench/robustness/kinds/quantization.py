"""Quantization of one input: every sample rounded to a multiple of the step (the magnitude), as a coarse ADC or
a CAN signal's resolution gives it."""

from __future__ import annotations

import numpy as np

from bench.robustness.kinds import InputKind, register


class QuantizationKind(InputKind):
    name = "quantization"
    summary = "every sample rounded to a multiple of the step"
    relative_defaults = (0.002, 0.01)          # 1.3 and 6.4 Nm, 18 and 90 rpm
    temperature_defaults = (0.5, 1.0)          # K: an 8-bit temperature signal

    def problem(self, magnitude):
        return None if magnitude > 0 else "must be a positive step"

    def perturb(self, values, magnitude, rng, sample_period_s):
        return np.round(values / magnitude) * magnitude


register(QuantizationKind())
