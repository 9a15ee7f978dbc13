"""Model kinds as the target runs them: one module per kind, each found by the name an artifact gives
(`model_kind`), as the loss models are (`target_sim.losses`).

Every kind shares the front of a model step: the loss model, the copper correction and the stator split (eqs. 3-8,
`target_sim.model.Float32Estimator.node_losses`), from the artifact's common sections (`lptn`, `losses`). A kind
module owns the rest: its artifact sections (array fields, shapes, the stability check; `target_sim.artifact`
asks), its part of the float32 step (how the state is reset, stepped and read out; `target_sim.model` calls it),
its C fragments (functions, step/reset/restore, constants and arrays; `bench.firmware.codegen` writes them out)
and its C28x operation and coefficient counts (`target_sim.costs`). A realization stays a row of
`target_sim.kinds.REALIZATIONS` that a kind asks (`delta`). The flags (`linear_block`, `input_nonlinearity`,
`realizations`) say what the lab builds for a kind (`bench.model`).

Every module of this package is a kind, named as its module with "-" for "_" (`lti_lptn`: "lti-lptn"), and
registers itself on import (`register`); `MODEL_KINDS` imports them all on first use.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from typing import Any, ClassVar, Protocol

import numpy as np

from target_sim.losses import CArray
from target_sim.registry import Registry

__all__ = ["MODEL_KINDS", "CArray", "ModelKind", "StepPart", "model_kind", "pole_text", "register"]


class StepPart(Protocol):
    """A kind's part of one artifact's float32 step: the state x after the node losses are known."""

    def reset(self, y: np.ndarray) -> np.ndarray:
        """The state x that starts from the temperatures y [yoke, winding, tooth, magnet] (C: fw_reset)."""

    def output(self, x: np.ndarray) -> np.ndarray:
        """The temperatures y of the state x (C: the end of fw_step, fw_restore)."""

    def step(self, x: np.ndarray, losses: np.ndarray, speed, coolant, ambient) -> np.ndarray:
        """The next state from x, the node losses [P_y, P_w, P_t, P_m] and the interval means (C: fw_step)."""


class ModelKind:
    """One model kind as the target runs it. Subclasses set the class attributes and implement the methods."""

    name: ClassVar[str]
    summary: ClassVar[str]
    linear_block: ClassVar[bool]          # x <- A x + B u, y = C x from the artifact's linear_block
    input_nonlinearity: ClassVar[bool]    # the sigmoid on the loss inputs (eqs. 28-30)
    realizations: ClassVar[bool]          # the linear block may be realized in any coordinates (else "physical")

    # --- the artifact sections (besides the common lptn and losses)
    def fields(self, content: Mapping[str, Any]) -> list[tuple[str, ...]]:
        """The kind's array fields (full keys) in a content whose realization is known."""
        return []

    def shapes(self, content: Mapping[str, Any]) -> dict[tuple[str, ...], tuple[int, ...]]:
        """The shape of each non-scalar field of `fields` (full keys); scalars need no entry."""
        return {}

    def instability(self, artifact) -> str | None:
        """The sentence (fix included) that refuses a verified artifact whose step grows without bound, or None."""
        return None

    # --- the step
    def part(self, artifact, estimator) -> StepPart:
        """The kind's part of `estimator`'s step (a `target_sim.model.Float32Estimator` of `artifact`)."""
        raise NotImplementedError

    # --- the firmware
    def c_functions(self, artifact) -> list[str]:
        """The C functions fw_step calls besides dot and node_losses, in the order they are written."""
        return []

    def c_step(self, artifact) -> str:
        """fw_step, fw_reset and fw_restore, for a row of 4 inputs whose loss model takes torque and speed
        (`bench.firmware.codegen` adapts the row and the call of node_losses)."""
        raise NotImplementedError

    def c_scalars(self, artifact) -> list[tuple[str, tuple[str, ...] | np.float32, str]]:
        """(C name, artifact keys or a float32 value, comment) of the kind's own scalars."""
        return []

    def c_arrays(self, artifact) -> list[CArray]:
        """The kind's arrays of the generated C."""
        return []

    # --- the C28x estimate (target_sim.costs)
    def ops(self, artifact) -> dict[str, Counter]:
        """Operation counts of the kind's part of one step, by block ("sigmoid", "sources", "linear", ...)."""
        raise NotImplementedError

    def coefficient_count(self, artifact) -> int:
        """float32 constants of the kind's part of the step."""
        return 0

    def work_floats(self, artifact) -> int:
        """Work buffers (floats) the kind's part needs besides the common ones."""
        return 0


def pole_text(z: complex) -> str:
    """A pole for a message: 1.0005, or 0.99+0.05j."""
    z = complex(z)
    if not np.isfinite(z.real) or not np.isfinite(z.imag):
        return "inf"
    if abs(z.imag) <= 1e-12 * max(1.0, abs(z.real)):
        return f"{z.real:.6g}"
    return f"{z.real:.6g}{z.imag:+.6g}j"


MODEL_KINDS: Registry[ModelKind] = Registry("model kind", __name__, first=("lti-lptn", "pv-lptn", "hammerstein"))


def register(kind: ModelKind) -> ModelKind:
    """Add a kind (a module of this package calls it on import; a test may for its own kind)."""
    return MODEL_KINDS.register(kind.name, kind)


def model_kind(name: str) -> ModelKind:
    """The kind called `name` (UnknownKind, one sentence naming the known ones)."""
    return MODEL_KINDS[name]
