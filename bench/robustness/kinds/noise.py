"""White noise on one input: every sample plus a normal draw of standard deviation σ (the magnitude)."""

from __future__ import annotations

from bench.robustness.kinds import InputKind, register


class NoiseKind(InputKind):
    name = "noise"
    summary = "white noise of standard deviation σ on every sample"
    random = True
    relative_defaults = (0.005, 0.02)          # 3 and 13 Nm on a 640 Nm drive, 45 and 180 rpm at 9000 rpm
    temperature_defaults = (0.2, 1.0)          # K: a thermistor channel's noise, and a bad one's

    def perturb(self, values, magnitude, rng, sample_period_s):
        return values + rng.normal(0.0, magnitude, len(values))


register(NoiseKind())
