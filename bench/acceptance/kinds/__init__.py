"""The kinds of acceptance criterion, one module each; `KINDS` is the registry a criteria file's `kind` names."""

from __future__ import annotations

from bench.acceptance.kinds import (
    bus_load,
    cycles,
    deadline_misses,
    heartbeat_losses,
    max_error,
    missing_replies,
    regression,
    rmse,
)
from bench.acceptance.kinds.base import Criterion, Kind, Subject

KINDS: dict[str, Kind] = {module.KIND.name: module.KIND for module in (
    rmse, max_error, cycles, deadline_misses, missing_replies, heartbeat_losses, bus_load, regression)}

__all__ = ["KINDS", "Criterion", "Kind", "Subject"]
