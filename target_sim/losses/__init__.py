"""Loss models as the target runs them: one module per kind, each found by the name an artifact gives
(`losses.model`), as python-can finds an interface by its name.

A loss model turns the operating point into the five loss inputs of the estimator, `LOSS_OUTPUTS` (copper dc and
ac loss at the copper reference temperature, iron loss, magnet loss, phase current amplitude); the rest of the step
(eqs. 3-8, the sigmoid, the network) is the same for every motor. A kind module owns everything the target needs
of its kind: the fields of the artifact's `losses` section and their shapes and invariants, the float32 evaluator
(`target_sim.model` calls it), its C fragment for the firmware (`bench.firmware.codegen` writes it out), and its
operation counts for the C28x estimate (`target_sim.costs`). What the lab needs of the same kind (the motor file's
section, the float64 model, writing the section) lives in `bench.motor.losses` under the same name; a test checks
that the two registries name the same kinds.

Every module of this package is a kind and registers itself on import (`register`); `LOSS_KINDS` imports them all
on first use. A kind defined elsewhere (a test's) registers the same way.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np

from target_sim.registry import Registry

# the loss model's five outputs, in this order everywhere (artifact tables, the float32 step, the C)
LOSS_OUTPUTS = ("p_dc0", "p_ac0", "p_stator", "p_magnet", "current")
# the values of a data row by the names the artifact gives them: the drive values, then the d/q currents (DBC
# DriveInputs, DriveTemps and DriveCurrents); a row carries the currents only when the loss model reads them
DRIVE_SIGNALS = ("torque_Nm", "speed_rpm", "coolant_C", "ambient_C")
CURRENT_SIGNALS = ("i_d_A", "i_q_A")
# the C names of the operating-point values a loss model may read
C_NAMES = {"torque_Nm": "torque", "speed_rpm": "speed", "i_d_A": "i_d", "i_q_A": "i_q"}
DEFAULT = "maps"   # an artifact of schema version 1 has no losses.model: loss maps were all there was


def reads_currents(names) -> bool:
    """`names` (a loss model's inputs, a data row's values) include a d/q current: the row carries DriveCurrents."""
    return bool(set(names) & set(CURRENT_SIGNALS))


def row_signals(inputs: tuple[str, ...]) -> tuple[str, ...]:
    """The values of a data row for a loss model reading `inputs`: 4, or 6 when it reads a current."""
    unknown = [name for name in inputs if name not in C_NAMES]
    if unknown:
        raise ValueError(f"a loss model reads only {', '.join(C_NAMES)}, not {unknown[0]}")
    return DRIVE_SIGNALS + (CURRENT_SIGNALS if reads_currents(inputs) else ())


def row_of_width(width: int) -> tuple[str, ...]:
    """The values of a data row of `width` values (4, or 6 with the currents), as `dbc.contract.row_signals`."""
    if width not in (len(DRIVE_SIGNALS), len(DRIVE_SIGNALS) + len(CURRENT_SIGNALS)):
        raise ValueError(f"a data row has {len(DRIVE_SIGNALS)} or {len(DRIVE_SIGNALS) + len(CURRENT_SIGNALS)} "
                         f"values, not {width}")
    return (DRIVE_SIGNALS + CURRENT_SIGNALS)[:width]


class Evaluator(Protocol):
    """The float32 (or float64) loss model of one artifact."""

    def lookup(self, *values) -> np.ndarray:
        """LOSS_OUTPUTS at one operating point, from the kind's `inputs` in their order."""


@dataclass(frozen=True)
class CArray:
    """A float array of the generated C from artifact fields (stacked when several)."""

    name: str
    fields: tuple[tuple[str, ...], ...]   # artifact keys of each stacked part (one part: an array of its shape)
    comment: str
    shape: tuple[int, ...] | None = None  # the shape of each part the generator needs (None: any verified one)
    # rows (the last axis) that repeat are stored once: NAME_ROWS[distinct rows][columns] and the uint8/uint16 index
    # NAME_ROW_INDEX[part][row], when that takes less flash than NAME itself (the loss maps are symmetric in torque:
    # half their rows repeat); either way the C reads row r of part k as NAME_ROW(k, r), the same float32 values
    shared_rows: bool = False


class LossKind:
    """One loss model as the target runs it. Subclasses set the class attributes and implement the methods."""

    name: ClassVar[str]
    inputs: ClassVar[tuple[str, ...]]     # the row values the evaluator reads, in its call order
    summary: ClassVar[str]                # a few words for documents (the generated C header says them)
    firmware: ClassVar[bool] = True       # the firmware generator can write it
    # the C fragment: the function `c_function(<inputs>, float out[LOSS_TABLE_COUNT])` defined by `c_code`, and the
    # words node_losses' comment uses for it
    c_function: ClassVar[str]
    c_words: ClassVar[str]
    c_code: ClassVar[str]

    # --- the artifact section
    def fields(self, losses: Mapping[str, Any]) -> list[tuple[str, ...]]:
        """The kind's array fields under `losses` (keys after "losses")."""
        raise NotImplementedError

    def shapes(self, losses: Mapping[str, Any]) -> dict[tuple[str, ...], tuple[int, ...]]:
        """The shape of each non-scalar field (keys after "losses"); scalars need no entry."""
        return {}

    def problem(self, artifact) -> str | None:
        """A sentence on what is wrong with a verified artifact's section beyond shapes (None when nothing)."""
        return None

    # --- the step
    def evaluator(self, artifact, dtype=np.float32) -> Evaluator:
        raise NotImplementedError

    # --- the firmware
    def c_scalars(self, artifact) -> list[tuple[str, tuple[str, ...] | np.float32, str]]:
        """(C name, artifact keys or a float32 value derived as the evaluator derives it, comment) of the scalars
        the C fragment may use."""
        return []

    def c_declarations(self, artifact) -> tuple[list[str], list[CArray]]:
        """#define lines (LOSS_TABLE_COUNT among them) and arrays of the C fragment."""
        return [f"#define LOSS_TABLE_COUNT {len(LOSS_OUTPUTS)} /* [{', '.join(LOSS_OUTPUTS)}] */"], []

    def c_problem(self, artifact) -> str | None:
        """Why the generator cannot write this artifact's section (one sentence), or None."""
        return None

    # --- the C28x estimate (target_sim.costs)
    def ops(self, op: Callable[..., Counter]) -> Counter:
        """Operation counts of one evaluation; `op(multiply=.., add=.., ...)` builds a Counter."""
        raise NotImplementedError

    def coefficient_count(self, artifact) -> int:
        """float32 constants of the section the step reads."""
        raise NotImplementedError


LOSS_KINDS: Registry[LossKind] = Registry("loss model", __name__, first=("maps", "electrical"))


def register(kind: LossKind) -> LossKind:
    """Add a kind (a module of this package calls it on import; a test may for its own kind)."""
    row_signals(kind.inputs)   # ValueError for a value no data row carries
    return LOSS_KINDS.register(kind.name, kind)


def loss_kind(name: str) -> LossKind:
    """The kind called `name` (UnknownKind, one sentence naming the known ones)."""
    return LOSS_KINDS[name]
