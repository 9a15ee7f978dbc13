"""Parameter error: one group of the model's parameters off by ±x % (each thermal capacitance, each thermal
resistance path, the stator loss split, each loss-model coefficient group; `bench.robustness.models`)."""

from __future__ import annotations

from bench.robustness.kinds import PerturbationKind, register
from bench.robustness.models import parameter_subjects, perturbed_model


class ParameterKind(PerturbationKind):
    name = "parameter"
    summary = "a parameter group of the model off by the magnitude in %"
    signed = True

    def subjects(self, artifact):
        return parameter_subjects(artifact)

    def defaults(self, artifact, subject):
        return (-10.0, 10.0)

    def unit(self, artifact, subject):
        return "%"

    def problem(self, magnitude):
        return None if magnitude > -100 else "must be above -100 % (a parameter stays positive)"

    def model(self, artifact, subject, magnitude):
        return perturbed_model(artifact, subject, magnitude)


register(ParameterKind())
