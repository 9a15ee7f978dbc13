"""Which rows of a log the bench's figures are over: one rule, in one place.

A row that any check flagged as not the target's own answer is left out of every figure (the RMSE, max |CAN −
clean run|, the round trip, the plots, a replay's comparison) and counted beside them, by reason:

* `contested`: the row got a second reply with other temperatures (`bench.analysis.logdecode`);
* `replayed`: a reply frame the host's counter check rejected carried other temperatures for the row than the
  answer that was used (`logdecode`): the row had two answers;
* `restored_not_from_target`: the row's answer came from a segment whose RESTORE was not the target's own
  checkpoint (a forged or contested StateCheckpoint/ObserverCheckpoint, `logdecode`): its estimate starts from a
  state the target never had;
* `off_reference`: the reply differs from what the target's own code answers, the float32 reference restarted as
  the target was (or the target's twin, when rows were lost on the bus), by more than the 0.005 °C quantization,
  where that reference is inside the DBC range: another run's reply or a forged value that carries valid counters
  and CRC, or a target that computes something else. The check's own figure (max |CAN − float32|) is over every
  reply: it is what flags them.

`kept_rows` is that rule; `canmetrics.compute` applies it to every log (`bench run`, `bench host`, `bench analyze`,
`bench compare` and the campaign's runs all go through it), `bench replay` to both of its logs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.analysis.logdecode import BusRecord
from bench.analysis.results import FigureRows
from dbc.database import temperature_range

CONTESTED = "contested"
REPLAYED = "replayed"
RESTORED = "restored_not_from_target"
OFF_REFERENCE = "off_reference"


def restored_not_from_target(record: BusRecord) -> np.ndarray:
    """(rows,) the rows whose answer came from a segment restored not from the target's own checkpoint."""
    out = np.zeros(record.rows, dtype=bool)
    owner = record.owner if len(record.owner) == record.rows else np.full(record.rows, -1)
    for index, segment in enumerate(record.segments):
        if segment.checkpoint is not None:
            out |= owner == index
    return out


@dataclass
class RowSelection:
    """The rows the figures are over (`kept`, per data row) and how many were left out, by reason."""

    kept: np.ndarray
    counts: FigureRows

    def values(self, temps: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """`temps` (per data row, or per entry of `rows` when given) with NaN where the row is not kept."""
        kept = self.kept if rows is None else self.kept[rows]
        return np.where(kept[:, None], temps, np.nan)


def kept_rows(record: BusRecord, reference: np.ndarray | None = None, *, tolerance: float) -> RowSelection:
    """The rule: a row is kept when it was answered and no check flagged its answer. `reference` (rows, 4) is what
    the target's own code answers after each row (NaN: not known); without it only the log's own checks flag.
    A row flagged for several reasons counts under the first of contested, replayed, restored_not_from_target,
    off_reference."""
    answered = record.answered
    flags = {CONTESTED: record.contested, REPLAYED: record.replayed & answered,
             RESTORED: answered & restored_not_from_target(record)}
    if reference is not None:
        low, high = temperature_range()
        with np.errstate(invalid="ignore"):
            judged = (reference >= low) & (reference <= high)      # a clamped value is the target's, not judged
            off = np.abs(record.temps - reference) > tolerance
        flags[OFF_REFERENCE] = answered & (off & judged).any(axis=1)
    taken = np.zeros(record.rows, dtype=bool)
    excluded: dict[str, int] = {}
    for reason, flagged in flags.items():
        new = flagged[: record.rows] & ~taken
        if new.any():
            excluded[reason] = int(np.count_nonzero(new))
        taken |= new
    kept = answered & ~taken
    counts = FigureRows(rows=record.rows, kept=int(np.count_nonzero(kept)),
                        without_reply=int(np.count_nonzero(~answered & ~taken)), excluded=excluded)
    return RowSelection(kept, counts)
