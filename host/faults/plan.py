"""Where the faults go: a deterministic function of (seed, row, pass), independent of timing.

Every random choice is a hash of the seed, the data row, the pass (how many times that row has been started:
0 the first time, 1 after a re-initialization re-sends it, ...) and a slot number, mapped to [0, 1)
(splitmix64). So the same seed puts the same faults on the same rows whatever the machine's speed, and a row
re-sent after a recovery draws anew. Retransmissions of a row (after its reply deadline) are never faulted.

Eligible rows: every row except the first row of each session (after START, also after a re-initialization):
the target's validator may have no alive counter for a drive frame yet (it started fresh), and a lost first frame
then could not show as a counter jump. A row that gets a process fault gets no bus fault.

Per eligible row: first `reorder` or `delay` with their per-row rates (at most one); otherwise, per drive frame,
at most one of the per-frame kinds with their per-frame rates (DriveInputs, DriveTemps, and DriveCurrents when the
rows carry the currents: a third draw that leaves the first two, and so the faults of a run without currents,
unchanged; and the Measurements frame of a model with an observer: a fourth draw, which leaves the others unchanged
too). The last row's Measurements frame is never faulted: its row is answered (the filter predicts only), nothing
is sent after it, so a lost one would have no next frame of its id to show the alive-counter jump.
"""

from __future__ import annotations

import random
from dataclasses import dataclass

from dbc.contract import MEASUREMENT_MESSAGE
from dbc.mutations import FAULTED_HOST_MESSAGES, pick, unit
from host.faults.spec import FRAME_KINDS, PROCESS_KINDS, ROW_KINDS, FaultSpec, FaultSpecError

# the place of the first measurement frame (Measurements; DriveVoltages after it) in RowFaults.frame_kinds
MEASUREMENT_INDEX = FAULTED_HOST_MESSAGES.index(MEASUREMENT_MESSAGE)
PROCESS_MIN_SPACING = 5        # rows between two process faults
PROCESS_WINDOW = (0.1, 0.9)    # process faults fall in this part of the run


@dataclass(frozen=True)
class RowFaults:
    """The faults of one pass of one row: a row-level kind, or a kind (or None) per drive frame."""

    row: int
    pass_: int
    seed: int
    row_kind: str | None
    frame_kinds: tuple[str | None, ...]   # DriveInputs, DriveTemps (, DriveCurrents (, Measurements, DriveVoltages))

    def draw(self, slot: int) -> float:
        """A further uniform number for this row and pass (bit positions, lengths, ...)."""
        return unit(self.seed, self.row, self.pass_, 100 + slot)

    @property
    def any(self) -> bool:
        return self.row_kind is not None or any(k is not None for k in self.frame_kinds)


class FaultPlan:
    """The faults of one run over `rows` data rows."""

    def __init__(self, spec: FaultSpec, rows: int, frames_per_row: int = 2, measurements: int = 0):
        self.spec = spec
        self.rows = rows
        self.frames_per_row = frames_per_row   # the drive frames of a row: 2, or 3 with DriveCurrents
        # measurement frames per row (1: Measurements, 2: and DriveVoltages; from index MEASUREMENT_INDEX on)
        self.measurements = int(measurements)
        self._frame = [(k, spec.rates.get(k, 0.0)) for k in FRAME_KINDS if spec.rates.get(k, 0.0) > 0]
        self._row = [(k, spec.rates.get(k, 0.0)) for k in ROW_KINDS if spec.rates.get(k, 0.0) > 0]
        self.process_rows = self._process_rows()

    def _process_rows(self) -> dict[int, str]:
        kinds = [k for k in PROCESS_KINDS for _ in range(self.spec.counts.get(k, 0))]
        if not kinds:
            return {}
        low = max(2, int(self.rows * PROCESS_WINDOW[0]))
        high = int(self.rows * PROCESS_WINDOW[1])
        slots = (high - low) // PROCESS_MIN_SPACING
        if slots < len(kinds):
            raise FaultSpecError(f"{len(kinds)} process fault(s) need at least "
                                 f"{int((len(kinds) * PROCESS_MIN_SPACING + 2) / 0.8) + 1} rows; replay more rows or "
                                 "ask for fewer kills/freezes")
        rng = random.Random(self.spec.seed)
        chosen = sorted(rng.sample(range(slots), len(kinds)))
        rng.shuffle(kinds)
        return {low + slot * PROCESS_MIN_SPACING + rng.randrange(PROCESS_MIN_SPACING): kind
                for slot, kind in zip(chosen, kinds, strict=True)}

    def process_fault(self, row: int, pass_: int) -> str | None:
        """'kill' or 'freeze' before the first pass of this row, else None."""
        return self.process_rows.get(row) if pass_ == 0 else None

    def row_faults(self, row: int, pass_: int) -> RowFaults | None:
        """The bus faults of this pass of this (eligible) row, or None."""
        seed = self.spec.seed
        if self._row:
            kind = pick(unit(seed, row, pass_, 0), self._row)
            if kind is not None:
                return RowFaults(row, pass_, seed, kind, (None,) * self.frames_per_row)
        if not self._frame:
            return None
        kinds = tuple(pick(unit(seed, row, pass_, 1 + index), self._frame) for index in range(self.frames_per_row))
        if self.measurements:
            kinds += (None,) * (MEASUREMENT_INDEX - len(kinds))
            last = row == self.rows - 1
            kinds += tuple(None if last else pick(unit(seed, row, pass_, 1 + index), self._frame)
                           for index in range(MEASUREMENT_INDEX, MEASUREMENT_INDEX + self.measurements))
        if all(kind is None for kind in kinds):
            return None
        return RowFaults(row, pass_, seed, None, kinds)
