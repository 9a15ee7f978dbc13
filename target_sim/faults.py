"""The target's reply faults: its temperature replies altered on their way out, each injection journaled.

Started with `python -m target_sim --faults reply_drop=0.01,... --fault-seed N`, the target alters its
Temperatures1/Temperatures2 frames with the frame faults of `dbc.mutations` (the same code the host's fault layer
uses), because a bench must also show that nothing corrupted on the way back is ever reported as a temperature.

Reply faults hit Temperatures1 and Temperatures2, at most one kind per frame with the given probabilities, never
a drop's witness (its counter jump must show the loss) and never a reply the target sends again for a
retransmitted row (so one retransmission always recovers, as the host's retransmissions are never faulted).
Every injection is appended to the target's detection journal (`--events`) as it happens — {"event": "inject",
"kind": "reply_<kind>", "seq", "step", "id", "sent_id", "counter", "data"} — and, for a drop, {"event":
"witness", "seq", "data"} once the witness went out, so a killed target's injections are not lost; the host
matches them with the frames its validator rejected.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping

import can

from dbc.mutations import REPLY_FAULT_KINDS, REPLY_PREFIX, mutate, pick, raw_step, reply_ids, unit


class ReplyFaults:
    """Alters the target's temperature replies on their way out; journals every injection."""

    def __init__(self, rates: Mapping[str, float], seed: int, journal: Callable[[dict], None] | None = None):
        unknown = set(rates) - set(REPLY_FAULT_KINDS)
        if unknown:
            raise ValueError(f"not reply fault kinds: {', '.join(sorted(unknown))}")
        self.rates = [(kind.removeprefix(REPLY_PREFIX), float(rates[kind])) for kind in REPLY_FAULT_KINDS
                      if float(rates.get(kind, 0.0)) > 0]
        self.seed = seed
        self.reply_ids = reply_ids()
        self.journal = journal
        self.sequence = 0                       # reply frames that could have been faulted so far
        self.injected: Counter = Counter()
        self.foreign_ids: set[int] = set()      # ids our unknown_id faults went out on (they loop back to us)
        self._witness: dict[int, int] = {}      # frame id -> seq of the drop whose witness is the next frame

    def apply(self, frames: list[can.Message], *, again: bool = False) -> list[can.Message]:
        """The frames to send instead of `frames` (a reply sent `again` for a retransmitted row is not faulted)."""
        out: list[can.Message] = []
        for msg in frames:
            sent, kind, seq = [msg], None, -1
            # a drop's witness (the next frame of its id) goes out intact: its counter jump is what shows the loss
            fid = msg.arbitration_id
            if fid in self.reply_ids and not again and self.rates and fid not in self._witness:
                seq = self.sequence
                self.sequence += 1
                kind = pick(unit(self.seed, seq, 0), self.rates)
                if kind is not None:
                    sent = mutate(kind, msg, lambda slot, seq=seq: unit(self.seed, seq, 1 + slot))
                    self._record(kind, msg, sent, seq)
            for frame in sent:  # the first frame of an id after a drop of that id is its witness
                waiting = self._witness.pop(frame.arbitration_id, None) if self._witness else None
                if waiting is not None and self.journal is not None:
                    self.journal({"event": "witness", "seq": waiting, "data": bytes(frame.data).hex()})
            if kind == "drop":
                self._witness[msg.arbitration_id] = seq
            out += sent
        return out

    def _record(self, kind: str, original: can.Message, sent: list[can.Message], seq: int) -> None:
        self.injected[kind] += 1
        fid = original.arbitration_id
        shown = sent[-1] if sent else None      # the altered frame (the copy, for duplicate)
        if kind == "unknown_id" and shown is not None:
            self.foreign_ids.add(shown.arbitration_id)
        if self.journal is not None:
            self.journal({"event": "inject", "kind": REPLY_PREFIX + kind, "seq": seq, "step": raw_step(original),
                          "id": fid, "sent_id": None if shown is None else shown.arbitration_id,
                          "counter": original.data[1] & 0x0F,
                          "data": None if shown is None else bytes(shown.data).hex()})


def parse_reply_faults(text: str) -> dict[str, float]:
    """{kind: probability} from 'reply_drop=0.01,reply_corrupt=0.001'; ValueError (one sentence) otherwise."""
    rates: dict[str, float] = {}
    for part in (p.strip() for p in text.split(",") if p.strip()):
        name, sep, value = part.partition("=")
        kind = name.strip().lower().replace("-", "_")
        if not sep or kind not in REPLY_FAULT_KINDS:
            raise ValueError(f"{part!r} is not a reply fault; give KIND=PROBABILITY with KIND one of "
                             f"{', '.join(REPLY_FAULT_KINDS)}")
        try:
            rate = float(value)
        except ValueError:
            raise ValueError(f"{part!r}: {value.strip()!r} is not a probability") from None
        if not 0.0 <= rate <= 1.0:
            raise ValueError(f"{part!r}: the probability must be between 0 and 1")
        rates[kind] = rate
    if sum(rates.values()) > 1.0 + 1e-12:
        raise ValueError(f"the reply fault rates add up to {sum(rates.values()):g}, more than 1")
    return rates
