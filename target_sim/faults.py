"""Frame faults: what each kind does to a frame, the seeded draws that place them, and the target's reply faults.

Both nodes inject with the same code: the host's `host.faults.FaultyBus` alters its drive frames, and the
target, started with `python -m target_sim --faults reply_drop=0.01,... --fault-seed N`, alters its temperature
replies (`ReplyFaults`), because a bench must also show that nothing corrupted on the way back is ever reported
as a temperature. What each kind does to a frame F with alive counter c (`mutate`):

* drop: F is not sent. The next frame of the same id (its `witness`) carries c+1 after c-1: a counter jump.
* duplicate: F goes out twice, byte for byte; the second copy repeats counter c.
* corrupt: 1 to 3 distinct bits of the 8 bytes are flipped. CRC8H2F has Hamming distance 4 over these 64 bits,
  so the CRC catches every such corruption by construction (checked again for each frame).
* stale_counter: F carries counter c-1 (the previous frame's) with a valid CRC: a sender that did not count.
* wrong_length: F goes out with its first 0..7 bytes only (DLC 0..7).
* unknown_id: F goes out on an id no DBC message has (its id with bit 3 flipped).
* out_of_range: the 16-bit signal at bit 28 (MotorTorque, CoolantTemp, WindingTemp, YokeTemp) carries its
  largest raw value (3276.7 Nm, 3276.7 degC, 605.35 degC: beyond the DBC range) with a valid CRC and counter.

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

from dbc import FRAME_IDS, apply_crc, load_database
from target_sim.fastframes import profile2_crc

FRAME_FAULT_KINDS: tuple[str, ...] = ("drop", "duplicate", "corrupt", "stale_counter", "wrong_length", "unknown_id",
                                      "out_of_range")
REPLY_PREFIX = "reply_"
REPLY_KINDS: tuple[str, ...] = tuple(REPLY_PREFIX + kind for kind in FRAME_FAULT_KINDS)
REPLY_IDS: frozenset[int] = frozenset({FRAME_IDS["Temperatures1"], FRAME_IDS["Temperatures2"]})
UNKNOWN_ID_FLIP = 0x008
OUT_OF_RANGE_START = 28
_MASK = (1 << 64) - 1

Draw = Callable[[int], float]


def _mix(x: int) -> int:
    x = (x + 0x9E3779B97F4A7C15) & _MASK
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _MASK
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _MASK
    return x ^ (x >> 31)


def unit(seed: int, *keys: int) -> float:
    """A uniform number in [0, 1) determined by the seed and the keys (splitmix64 chain): the same faults on the
    same frames whatever the machine's speed."""
    h = _mix(seed & _MASK)
    for key in keys:
        h = _mix(h ^ (key & _MASK))
    return (h >> 11) / float(1 << 53)


def pick(u: float, rates: list[tuple[str, float]]) -> str | None:
    """The kind whose slice of [0, 1) holds u (slices of width rate, in order), or None past the last one."""
    edge = 0.0
    for kind, rate in rates:
        edge += rate
        if u < edge:
            return kind
    return None


def _out_of_range_raw() -> dict[int, int]:
    """Per frame id, the largest raw value of its 16-bit signal at bit 28, when that lies beyond the DBC range."""
    out = {}
    for message in load_database().messages:
        for s in message.signals:
            if s.start != OUT_OF_RANGE_START or s.length != 16 or s.is_float:
                continue
            raw = (1 << 15) - 1 if s.is_signed else (1 << 16) - 1
            if s.maximum is not None and raw * s.scale + s.offset > s.maximum:
                out[message.frame_id] = raw
    return out


OUT_OF_RANGE_RAW = _out_of_range_raw()
_DATA_IDS = {fid: fid & 0xFF for fid in FRAME_IDS.values()}
for _fid in (FRAME_IDS["DriveInputs"], FRAME_IDS["DriveTemps"], *REPLY_IDS):
    assert _fid ^ UNKNOWN_ID_FLIP not in _DATA_IDS, "an unknown-id fault must not land on a DBC id"
    assert _fid in OUT_OF_RANGE_RAW, "every faultable frame has a signal that can be pushed out of range"


def copy_frame(msg: can.Message, *, arbitration_id: int | None = None, data: bytes | None = None) -> can.Message:
    data = bytes(msg.data) if data is None else data
    return can.Message(timestamp=msg.timestamp, arbitration_id=msg.arbitration_id if arbitration_id is None else
                       arbitration_id, is_extended_id=False, dlc=len(data), data=data, is_rx=False, check=False)


def mutate(kind: str, msg: can.Message, draw: Draw) -> list[can.Message]:
    """The frames that go on the bus instead of `msg` for a fault of `kind` (`draw(slot)`: further uniform
    numbers for bit positions and lengths): none for drop, the frame and its copy for duplicate, else one."""
    data = bytearray(msg.data)
    fid = msg.arbitration_id
    if kind == "drop":
        return []
    if kind == "duplicate":
        return [msg, copy_frame(msg)]
    if kind == "corrupt":
        flips = 1 + int(draw(0) * 3)
        bits: list[int] = []
        slot = 1
        while len(bits) < flips:
            bit = int(draw(slot) * 64)
            slot += 1
            if bit not in bits:
                bits.append(bit)
        for bit in bits:
            data[bit // 8] ^= 1 << (bit % 8)
        # CRC8H2F has Hamming distance 4 over 64 bits: 1..3 flipped bits always break the CRC
        assert data[0] != profile2_crc(bytes(data), _DATA_IDS[fid]), "an undetectable corruption"
        return [copy_frame(msg, data=bytes(data))]
    if kind == "stale_counter":
        data[1] = (data[1] & 0xF0) | ((data[1] - 1) & 0x0F)
        return [copy_frame(msg, data=apply_crc(fid, bytes(data)))]
    if kind == "wrong_length":
        return [copy_frame(msg, data=bytes(data[:int(draw(0) * 8)]))]
    if kind == "unknown_id":
        return [copy_frame(msg, arbitration_id=fid ^ UNKNOWN_ID_FLIP)]
    if kind == "out_of_range":
        word = int.from_bytes(bytes(data), "little")
        word = (word & ~(0xFFFF << OUT_OF_RANGE_START)) | (OUT_OF_RANGE_RAW[fid] << OUT_OF_RANGE_START)
        return [copy_frame(msg, data=apply_crc(fid, word.to_bytes(8, "little")))]
    raise ValueError(f"unknown frame fault kind {kind}")


class ReplyFaults:
    """Alters the target's temperature replies on their way out; journals every injection."""

    def __init__(self, rates: Mapping[str, float], seed: int, journal: Callable[[dict], None] | None = None):
        unknown = set(rates) - set(REPLY_KINDS)
        if unknown:
            raise ValueError(f"not reply fault kinds: {', '.join(sorted(unknown))}")
        self.rates = [(kind.removeprefix(REPLY_PREFIX), float(rates[kind])) for kind in REPLY_KINDS
                      if float(rates.get(kind, 0.0)) > 0]
        self.seed = seed
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
            if msg.arbitration_id in REPLY_IDS and not again and self.rates and msg.arbitration_id not in self._witness:
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
            word = int.from_bytes(bytes(original.data), "little")
            self.journal({"event": "inject", "kind": REPLY_PREFIX + kind, "seq": seq, "step": (word >> 12) & 0xFFFF,
                          "id": fid, "sent_id": None if shown is None else shown.arbitration_id,
                          "counter": original.data[1] & 0x0F,
                          "data": None if shown is None else bytes(shown.data).hex()})


def parse_reply_faults(text: str) -> dict[str, float]:
    """{kind: probability} from 'reply_drop=0.01,reply_corrupt=0.001'; ValueError (one sentence) otherwise."""
    rates: dict[str, float] = {}
    for part in (p.strip() for p in text.split(",") if p.strip()):
        name, sep, value = part.partition("=")
        kind = name.strip().lower().replace("-", "_")
        if not sep or kind not in REPLY_KINDS:
            raise ValueError(f"{part!r} is not a reply fault; give KIND=PROBABILITY with KIND one of "
                             f"{', '.join(REPLY_KINDS)}")
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
