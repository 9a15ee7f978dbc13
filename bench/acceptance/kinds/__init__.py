"""The kinds of acceptance criterion, one module each; `KINDS` is the registry a criteria file's `kind` names (a
`target_sim.registry` table, as the loss models and perturbations are).

Every module of this package is a kind and registers itself on import; `KINDS` loads them on first use, so a new
criterion is one module here (and its test), with no list to edit. What the kinds share is `_base`.
"""

from __future__ import annotations

from bench.acceptance.kinds._base import NODES, Criterion, Kind, Subject, number
from target_sim.registry import Registry

# the order messages list the kinds in; a kind not named here follows them
KINDS: Registry[Kind] = Registry(
    "kind of criterion", __name__,
    first=("rmse", "max_error", "cycles", "deadline_misses", "missing_replies", "heartbeat_losses", "bus_load",
           "regression"))


def register(kind: Kind) -> Kind:
    return KINDS.register(kind.name, kind)


__all__ = ["KINDS", "NODES", "Criterion", "Kind", "Subject", "number", "register"]
