"""Model kinds and realizations: what each one is, in one table per family (`target_sim.registry`).

A model kind is a module of `target_sim.modelkinds` (its artifact sections, float32 step, C and costs; this module
gives its table, `MODEL_KINDS`); a realization is a row of `REALIZATIONS`. The rest of the tree asks these tables
what a kind has (a linear block, an input nonlinearity, a delta step) instead of comparing its name; an unknown name
is one sentence naming the known ones.
The DBC's value tables (`dbc.contract.ModelKind`, `Realization`) give each its code on the bus; a test checks that
the tables and the DBC name the same kinds.
"""

from __future__ import annotations

from dataclasses import dataclass

from target_sim.modelkinds import MODEL_KINDS, ModelKind, model_kind
from target_sim.registry import Registry

__all__ = ["MODEL_KINDS", "REALIZATIONS", "ModelKind", "RealizationKind", "is_delta", "model_kind"]


@dataclass(frozen=True)
class RealizationKind:
    """One realization of the linear block."""

    name: str
    summary: str
    delta: bool                 # x <- x + Δ·(A x + B ũ) about a reference temperature (else x <- A x + B u)


REALIZATIONS: Registry[RealizationKind] = Registry("realization")

for _realization in (
    RealizationKind("physical", "the network's own coordinates: the states are the node temperatures", False),
    RealizationKind("original", "the balanced block before its coordinates are scaled", False),
    RealizationKind("balanced", "balanced truncation coordinates (equal Gramians)", False),
    RealizationKind("modal", "eigenvector coordinates: A diagonal", False),
    RealizationKind("delta", "delta operator over the balanced coordinates, about a reference temperature", True),
):
    REALIZATIONS.register(_realization.name, _realization)


def is_delta(kind: str, realization: str) -> bool:
    """The step of this kind and realization is the delta form."""
    return MODEL_KINDS[kind].linear_block and REALIZATIONS[realization].delta
