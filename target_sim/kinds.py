"""Model kinds and realizations: what each one is, in one table per family (`target_sim.registry`).

The rest of the tree asks these tables what a kind has (a linear block, an input nonlinearity, a state that is
the temperatures themselves) instead of comparing its name; an unknown name is one sentence naming the known ones.
The DBC's value tables (`dbc.contract.ModelKind`, `Realization`) give each its code on the bus; a test checks that
the tables and the DBC name the same kinds.
"""

from __future__ import annotations

from dataclasses import dataclass

from target_sim.registry import Registry


@dataclass(frozen=True)
class ModelKind:
    """One model kind as the target runs it."""

    name: str
    summary: str
    linear_block: bool          # x <- A x + B u, y = C x from the artifact's linear_block (else rebuilt per step)
    input_nonlinearity: bool    # the sigmoid on the loss inputs (eqs. 28-30)
    realizations: bool          # the linear block may be realized in any coordinates (else only "physical")


@dataclass(frozen=True)
class RealizationKind:
    """One realization of the linear block."""

    name: str
    summary: str
    delta: bool                 # x <- x + Δ·(A x + B ũ) about a reference temperature (else x <- A x + B u)


MODEL_KINDS: Registry[ModelKind] = Registry("model kind")
REALIZATIONS: Registry[RealizationKind] = Registry("realization")

for _kind in (
    ModelKind("lti-lptn", "the LPTN at its operating point, discretized (LTI)", True, False, True),
    ModelKind("pv-lptn", "the parameter-varying LPTN rebuilt every step, forward Euler", False, False, False),
    ModelKind("hammerstein", "sigmoid input nonlinearity + fitted fourth-order linear block", True, True, True),
):
    MODEL_KINDS.register(_kind.name, _kind)

for _realization in (
    RealizationKind("physical", "the network's own coordinates: the states are the node temperatures", False),
    RealizationKind("original", "the balanced block before its coordinates are scaled", False),
    RealizationKind("balanced", "balanced truncation coordinates (equal Gramians)", False),
    RealizationKind("modal", "eigenvector coordinates: A diagonal", False),
    RealizationKind("delta", "delta operator over the balanced coordinates, about a reference temperature", True),
):
    REALIZATIONS.register(_realization.name, _realization)


def model_kind(name: str) -> ModelKind:
    return MODEL_KINDS[name]


def is_delta(kind: str, realization: str) -> bool:
    """The step of this kind and realization is the delta form."""
    return MODEL_KINDS[kind].linear_block and REALIZATIONS[realization].delta
