"""What to inject: fault kinds, rates, counts and the seed, as given on the command line.

    --fault drop=0.01 --fault corrupt=0.001 --fault kill=1     (repeatable)
    --faults drop=0.01,corrupt=0.001,kill=1                     (the same, compact)
    --fault-seed N                                              (default 0: the same faults on every run)

Bus faults hit the host's data-row frames (DriveInputs, DriveTemps, DriveCurrents when the rows carry the d/q
currents, and Measurements for a model with an observer) on their way to the target; control frames
(ResetTemps, Control) and the bench's own BenchEvent marks are never faulted. Their values are probabilities:

* per drive frame: `drop`, `duplicate`, `corrupt`, `stale_counter`, `wrong_length`, `unknown_id`,
  `out_of_range` (at most one of them per frame; their rates add up to at most 1);
* per data row: `reorder` (DriveTemps goes out before DriveInputs) and `delay` (the row's frames, and everything
  queued behind them, are held for 1.5 x the reply timeout).

Reply faults (`reply_drop`, `reply_duplicate`, `reply_corrupt`, `reply_stale_counter`, `reply_wrong_length`,
`reply_unknown_id`, `reply_out_of_range`) are probabilities per temperature reply frame (Temperatures1/2); the
target injects them (`python -m target_sim --faults`, started so by `bench run`) and the host's validator
detects them. They are not marked in the log (the host learns of them only by detecting them).

Process faults are counts over the run: `kill` (SIGKILL the target, the bench restarts it) and `freeze` (SIGSTOP
for twice the heartbeat timeout, then SIGCONT), at rows drawn from the middle 80 % of the run. They need the
bench runner, which owns the target process (`bench run`), not `python -m host`.
Names may use `-` or `_`; `kill-target`, `freeze-target` and `stale` are accepted too.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from dbc.contract import FaultKind
from dbc.mutations import FRAME_FAULT_KINDS, REPLY_FAULT_KINDS
from host.errors import HostError

REPLY_KINDS: tuple[str, ...] = REPLY_FAULT_KINDS

# The host's kinds, in the order of the DBC's FaultKind value table (BenchEvent.FaultKind: marked in the log),
# then the target's reply kinds.
MARKED_KINDS: tuple[str, ...] = tuple(k.name.lower() for k in FaultKind if k != FaultKind.NONE)
KINDS: tuple[str, ...] = MARKED_KINDS + REPLY_KINDS
FRAME_KINDS: tuple[str, ...] = FRAME_FAULT_KINDS
ROW_KINDS: tuple[str, ...] = ("reorder", "delay")
PROCESS_KINDS: tuple[str, ...] = ("kill", "freeze")
BUS_KINDS: tuple[str, ...] = FRAME_KINDS + ROW_KINDS
TARGET_DETECTED: frozenset[str] = frozenset(FRAME_KINDS) | {"reorder"}   # seen in the target's journal
HOST_DETECTED: frozenset[str] = frozenset({"delay", "kill", "freeze", *REPLY_KINDS})  # seen by the host itself
ALIASES = {"kill_target": "kill", "freeze_target": "freeze", "stale": "stale_counter", "corruption": "corrupt",
           "duplicate_frame": "duplicate", "wrong_id": "unknown_id"}

assert set(KINDS) == set(BUS_KINDS) | set(PROCESS_KINDS) | set(REPLY_KINDS)
assert set(MARKED_KINDS) == set(BUS_KINDS) | set(PROCESS_KINDS)
assert set(KINDS) == TARGET_DETECTED | HOST_DETECTED


class FaultSpecError(HostError, ValueError):
    """A fault option that cannot be used; one sentence naming it and the fix."""


def canonical_kind(name: str) -> str:
    """'kill-target' -> 'kill', 'Stale-Counter' -> 'stale_counter'; FaultSpecError for an unknown kind."""
    key = name.strip().lower().replace("-", "_")
    key = ALIASES.get(key, key)
    if key not in KINDS:
        raise FaultSpecError(f"unknown fault kind {name.strip()!r}; use one of {', '.join(KINDS)}")
    return key


@dataclass(frozen=True)
class FaultSpec:
    """Rates of the bus faults, counts of the process faults, and the seed of every random choice."""

    rates: Mapping[str, float] = field(default_factory=dict)
    counts: Mapping[str, int] = field(default_factory=dict)
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "rates", MappingProxyType(dict(self.rates)))
        object.__setattr__(self, "counts", MappingProxyType(dict(self.counts)))

    @property
    def active(self) -> bool:
        return any(v > 0 for v in self.rates.values()) or any(v > 0 for v in self.counts.values())

    @property
    def process_faults(self) -> int:
        return sum(self.counts.values())

    def reply_rates(self) -> dict[str, float]:
        """The target's part: rates of the reply kinds asked for."""
        return {k: v for k, v in self.rates.items() if k in REPLY_KINDS and v > 0}

    def reply_argv(self) -> list[str]:
        """`python -m target_sim` options that make the target inject this spec's reply faults (none: [])."""
        rates = self.reply_rates()
        if not rates:
            return []
        return ["--faults", ",".join(f"{k}={v!r}" for k, v in rates.items()), "--fault-seed", str(self.seed)]

    def kinds(self) -> list[str]:
        """The kinds asked for (rate or count above 0), in DBC order."""
        return [k for k in KINDS if self.rates.get(k, 0) > 0 or self.counts.get(k, 0) > 0]

    def describe(self) -> str:
        parts = [f"{k}={self.rates[k]:g}" if k in self.rates else f"{k}={self.counts[k]}" for k in self.kinds()]
        return (", ".join(parts) or "none") + f" (seed {self.seed})"

    def to_dict(self) -> dict:
        return {"rates": {k: v for k, v in self.rates.items() if v > 0},
                "counts": {k: v for k, v in self.counts.items() if v > 0}, "seed": self.seed}


def parse_faults(items: Iterable[str], seed: int = 0) -> FaultSpec:
    """FaultSpec from 'kind=value' items (each may hold several, comma-separated)."""
    rates: dict[str, float] = {}
    counts: dict[str, int] = {}
    for item in items:
        for part in (p for p in str(item).split(",") if p.strip()):
            name, sep, text = part.partition("=")
            if not sep:
                raise FaultSpecError(f"fault {part.strip()!r} needs a value, e.g. drop=0.01 or kill=1")
            kind = canonical_kind(name)
            if kind in rates or kind in counts:
                raise FaultSpecError(f"fault kind {kind} is given twice; give it once")
            text = text.strip()
            if kind in PROCESS_KINDS:
                try:
                    number = int(text)
                except ValueError:
                    raise FaultSpecError(f"{kind}={text} must be a whole number of {kind}s, e.g. {kind}=1") from None
                if number < 0:
                    raise FaultSpecError(f"{kind}={text} must not be negative")
                counts[kind] = number
            else:
                try:
                    rate = float(text)
                except ValueError:
                    raise FaultSpecError(f"{kind}={text} is not a number; give a probability, e.g. {kind}=0.01")\
                        from None
                if not math.isfinite(rate) or not 0.0 <= rate <= 1.0:
                    raise FaultSpecError(f"{kind}={text} must be a probability between 0 and 1")
                rates[kind] = rate
    for group, label in ((FRAME_KINDS, "per-frame"), (ROW_KINDS, "per-row"), (REPLY_KINDS, "per-reply-frame")):
        total = sum(rates.get(k, 0.0) for k in group)
        if total > 1.0 + 1e-12:
            raise FaultSpecError(f"the {label} fault rates ({', '.join(k for k in group if k in rates)}) add up to "
                                 f"{total:g}, more than 1")
    if not isinstance(seed, int) or isinstance(seed, bool):
        raise FaultSpecError(f"the fault seed {seed!r} must be a whole number")
    return FaultSpec(rates, counts, seed)


def spec_from_args(args) -> FaultSpec | None:
    """The FaultSpec the options give (--fault, --faults, --fault-seed: `bench.run.request`), or None without any
    fault option; FaultSpecError for a bad one."""
    items = list(getattr(args, "fault", []) or []) + list(getattr(args, "faults", []) or [])
    if not items:
        return None
    spec = parse_faults(items, seed=getattr(args, "fault_seed", 0))
    return spec if spec.active else None
