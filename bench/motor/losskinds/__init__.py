"""Loss models as the lab knows them: one module per kind, under the name the target's twin has
(`target_sim.losses`): the motor file's `[losses]` section (its keys, their checks), the float64 model the
identification evaluates (`evaluate_columns`), the artifact's `losses` section written from it and read back, and
the coefficient groups a robustness study perturbs (`robustness_groups`, plain data `bench.robustness` reads).

Every module of this package is a kind and registers itself on import; `LAB_LOSS_KINDS` loads them on first use.
A test checks that this table and the target's name the same kinds.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

from bench.motor.check import Checker
from target_sim.registry import Registry

# keys of the motor file's [losses] table every kind has
COMMON_KEYS = ("kind", "copper_reference_C", "copper_alpha_per_K")


class LabLossKind:
    """One loss model as the lab knows it. Subclasses set the class attributes and implement the methods."""

    name: ClassVar[str]
    keys: ClassVar[tuple[str, ...]]        # the motor file's [losses] keys besides COMMON_KEYS
    summary: ClassVar[str]                 # a few words for reports ("loss maps over torque and speed")
    # its coefficient groups a robustness study perturbs (`bench robustness`, the `parameter` kind): group name ->
    # the entries under the artifact's `losses` the group scales together, each a key path (("tables", "p_dc0"))
    robustness_groups: ClassVar[Mapping[str, tuple[tuple[str, ...], ...]]]

    def from_motor_file(self, check: Checker, losses: Mapping[str, Any], *, motor_path: Path | None,
                        pole_pairs: int, current_max_A: float) -> tuple[Any, str | None]:
        """The float64 model of the [losses] table and the sha256 of any file it read (None when none)."""
        raise NotImplementedError

    def artifact_section(self, model, encode) -> dict[str, Any]:
        """The kind's fields of the artifact's `losses` (each array through `encode`)."""
        raise NotImplementedError

    def from_artifact(self, artifact, current_max_A: float):
        """The float64 model of an artifact's `losses` section."""
        raise NotImplementedError

    def describe(self, model) -> dict[str, Any]:
        """What `bench motor check --json` shows of the model."""
        return {}

    def scaled(self, model, factors: Mapping[str, float]):
        """The model with loss inputs multiplied: `factors` maps a loss input (p_stator, p_magnet: `MAP_TABLES`
        names) to its factor (bench.model.loss_scales)."""
        raise NotImplementedError


LAB_LOSS_KINDS: Registry[LabLossKind] = Registry("loss model", __name__, first=("maps", "electrical"))


def register(kind: LabLossKind) -> LabLossKind:
    return LAB_LOSS_KINDS.register(kind.name, kind)
