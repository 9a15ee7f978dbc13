"""Perturbation kinds: one module per kind, each found by its name (`PERTURBATIONS`, a `target_sim.registry`
table as the loss models and model kinds are).

A kind names its subjects for a model (the input channels, the parameter groups, the nodes), its default
magnitudes per subject (sensible for a traction drive; a spec overrides them), the unit of a magnitude, and what it
does: to a lane (`apply`: the drive rows, the initial temperatures or the step clock of one trajectory) or to the
model (`model`: the artifact with its parameters off). `random` kinds draw from a seed (one lane per Monte Carlo
seed); the others are deterministic and run one lane.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from bench.robustness.channels import Channel, channel_index, input_channels
from target_sim.artifact import ModelArtifact
from target_sim.registry import Registry

__all__ = ["PERTURBATIONS", "InputKind", "Lane", "PerturbationKind", "register"]


@dataclass(frozen=True)
class Lane:
    """One trajectory's inputs: the drive rows (rows, width) in the data's units, the initial temperatures
    [yoke, winding, tooth, magnet], and the step boundaries in s (None: the target's exact clock)."""

    drive: np.ndarray
    initial: np.ndarray
    sample_period_s: float
    dt: float
    boundaries_s: np.ndarray | None = None

    def with_column(self, index: int, values: np.ndarray) -> Lane:
        drive = self.drive.copy()
        drive[:, index] = values
        return replace(self, drive=drive)


class PerturbationKind:
    """One kind of perturbation. Subclasses set the class attributes and implement `subjects`, `defaults`, `unit`
    and `apply` or `model`."""

    name: ClassVar[str]
    summary: ClassVar[str]
    random: ClassVar[bool] = False      # draws from a seed: Monte Carlo lanes
    signed: ClassVar[bool] = False      # a magnitude may be negative (a bias, an error of either sign)

    def subjects(self, artifact: ModelArtifact) -> tuple[str, ...]:
        raise NotImplementedError

    def defaults(self, artifact: ModelArtifact, subject: str) -> tuple[float, ...]:
        raise NotImplementedError

    def unit(self, artifact: ModelArtifact, subject: str) -> str:
        raise NotImplementedError

    def problem(self, magnitude: float) -> str | None:
        """Why `magnitude` is no magnitude of this kind (a clause for a sentence), or None."""
        if not self.signed and magnitude < 0:
            return "must not be negative"
        return None

    def apply(self, lane: Lane, artifact: ModelArtifact, subject: str, magnitude: float,
              rng: np.random.Generator) -> Lane:
        """The lane perturbed (the default: unchanged, for a kind that acts on the model)."""
        return lane

    def model(self, artifact: ModelArtifact, subject: str, magnitude: float) -> ModelArtifact:
        """The model perturbed (the default: unchanged, for a kind that acts on a lane)."""
        return artifact


class InputKind(PerturbationKind):
    """A perturbation of one input channel's samples; `defaults` scale with the channel's full scale."""

    relative_defaults: ClassVar[tuple[float, ...]]   # fractions of the channel's full scale
    temperature_defaults: ClassVar[tuple[float, ...]]  # K, for a temperature channel (coolant, ambient)

    def subjects(self, artifact: ModelArtifact) -> tuple[str, ...]:
        return tuple(c.name for c in input_channels(artifact))

    def channel(self, artifact: ModelArtifact, subject: str) -> Channel:
        return next(c for c in input_channels(artifact) if c.name == subject)

    def defaults(self, artifact: ModelArtifact, subject: str) -> tuple[float, ...]:
        channel = self.channel(artifact, subject)
        if channel.unit == "K":
            return self.temperature_defaults
        return tuple(float(np.format_float_positional(f * channel.full_scale, 3, fractional=False))
                     for f in self.relative_defaults)

    def unit(self, artifact: ModelArtifact, subject: str) -> str:
        return self.channel(artifact, subject).unit

    def apply(self, lane: Lane, artifact: ModelArtifact, subject: str, magnitude: float,
              rng: np.random.Generator) -> Lane:
        index = channel_index(artifact, subject)
        return lane.with_column(index, self.perturb(lane.drive[:, index], magnitude, rng, lane.sample_period_s))

    def perturb(self, values: np.ndarray, magnitude: float, rng: np.random.Generator,
                sample_period_s: float) -> np.ndarray:
        raise NotImplementedError


PERTURBATIONS: Registry[PerturbationKind] = Registry(
    "perturbation", __name__,
    first=("noise", "bias", "drift", "quantization", "dropout", "parameter", "initial", "jitter"))


def register(kind: PerturbationKind) -> PerturbationKind:
    return PERTURBATIONS.register(kind.name, kind)
