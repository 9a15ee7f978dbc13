"""A slow drift on one input: an offset growing linearly from 0 at the first sample at `magnitude` per hour
(either sign), a sensor ageing or warming up over the run."""

from __future__ import annotations

import numpy as np

from bench.robustness.kinds import InputKind, register


class DriftKind(InputKind):
    name = "drift"
    summary = "an offset growing linearly at the magnitude per hour"
    signed = True
    relative_defaults = (-0.01, 0.01)          # per hour: 6.4 Nm/h, 90 rpm/h
    temperature_defaults = (-1.0, 1.0)         # K per hour

    def unit(self, artifact, subject):
        return f"{super().unit(artifact, subject)}/h"

    def perturb(self, values, magnitude, rng, sample_period_s):
        hours = np.arange(len(values)) * sample_period_s / 3600.0
        return values + magnitude * hours


register(DriftKind())
