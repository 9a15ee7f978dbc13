"""`FaultyBus`: the fault layer between the host and the bus, with python-can's `send`/`recv` interface.

The host's session sends through it as through any `can.BusABC`; the lockstep loop tells it which data row (and
which pass of it) the next drive frames belong to (`begin_row`/`end_row`) and whether they are a retransmission
(never faulted). Every frame that actually goes on the bus (altered, duplicated or late as it may be) is handed
to `on_transmit`, so the host's log holds what was on the bus, and every injected fault is recorded as an
`Injection` (kind, row, frame id, the bytes that went out) for the run's summary and the report.

What each kind does to a drive frame is `dbc.mutations.mutate` (the target alters its replies with the same
code): drop (the next frame of the same id, its `witness`, shows a counter jump), duplicate, corrupt (1-3 bit
flips the CRC always catches), stale_counter, wrong_length, unknown_id, out_of_range (MotorTorque or CoolantTemp
at its raw maximum 0x7FFF). The row kinds are the host's own:

* reorder (per row): DriveTemps n goes out before DriveInputs n (a row's DriveCurrents after both).
* delay (per row): the row's frames, and every frame queued behind them, are held for `delay_s` (first-in first-
  out, as a congested gateway would), released by `recv`/`send` calls once due.

A stale_counter the plan puts on a Measurements frame whose previous one the receiver never got intact (lost or
refused: any kind but duplicate) is not injected: its stale counter would be the very one the receiver expects
next, so nothing could detect it. (A row whose Measurements frame is lost is still answered, the filter predicts
only, so the next row's frame follows it directly; a lost drive frame's row is retransmitted in lockstep, never
faulted, before the next row. In real time two drive frames of one id in consecutive rows can meet the same way.)

The frames the host injects on foreign ids come back to it on udp_multicast (multicast loopback): `recv` drops
them, as the session drops its own ids.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import can

from dbc.database import frame_id
from dbc.mutations import FAULTED_HOST_MESSAGES, mutate

from .plan import MEASUREMENT_INDEX, FaultPlan, RowFaults


@dataclass
class Injection:
    """One injected fault. `data` is what went on the bus (hex; None for drop, reorder's DriveTemps for reorder)."""

    kind: str
    row: int
    pass_: int
    frame_id: int | None        # the frame the fault hit (None for process faults)
    sent_id: int | None         # the id it went out on (differs for unknown_id)
    counter: int | None
    data: str | None
    t: float
    witness: str | None = None  # drop: the next frame of the same id that went out (where the loss shows)
    detected: bool = False
    detected_by: str | None = None

    def to_dict(self) -> dict:
        return asdict(self)


class FaultyBus:
    """Wraps a python-can bus; `send` applies the current row's faults, `recv` releases delayed frames."""

    reports_transmissions = True

    def __init__(self, bus: can.BusABC, plan: FaultPlan, *, delay_s: float):
        self.inner = bus
        self.plan = plan
        self.delay_s = delay_s
        self.on_transmit: Callable[[can.Message], None] | None = None
        self.injections: list[Injection] = []
        self.transmitted = 0
        self._new: list[Injection] = []
        self._faults: RowFaults | None = None
        self._row = -1
        self._pass = 0
        self._reorder_held: can.Message | None = None
        self._delay_started = False
        self._held: collections.deque[can.Message] = collections.deque()
        self._hold_until = 0.0
        self._witness: dict[int, Injection] = {}
        # ids whose last frame a fault kept from the receiver (all kinds but duplicate): it still expects the counter
        # before that frame's, so a stale counter on the next frame would be the one it expects, undetectable
        self._behind: set[int] = set()
        self._foreign_ids: set[int] = set()
        # index of each faultable frame in its row (0: DriveInputs, 1: DriveTemps, 2: DriveCurrents, 3: Measurements,
        # 4: DriveVoltages)
        self._drive_index = {frame_id(name): i for i, name in enumerate(FAULTED_HOST_MESSAGES)}

    # ------------------------------------------------------------------ row context (from the lockstep loop)
    def begin_row(self, row: int, pass_: int, *, eligible: bool = True, retransmission: bool = False) -> None:
        self._row, self._pass = row, pass_
        self._faults = self.plan.row_faults(row, pass_) if eligible and not retransmission else None
        self._delay_started = False

    def end_row(self) -> None:
        if self._reorder_held is not None:  # only one drive frame came: nothing to reorder it with
            self._out(self._reorder_held)
            self._reorder_held = None
        self._faults = None

    def take_new_injections(self) -> list[Injection]:
        new, self._new = self._new, []
        return new

    def record(self, kind: str, msg: can.Message | None, *, frame_id: int | None = None, row: int | None = None,
               pass_: int | None = None) -> Injection:
        """Note an injected fault (the frame as it went out, if any) for the summary and the log's marks."""
        data = None if msg is None else bytes(msg.data)
        fid = frame_id if frame_id is not None else (None if msg is None else msg.arbitration_id)
        counter = None if msg is None or len(msg.data) < 2 else msg.data[1] & 0x0F
        injection = Injection(kind, self._row if row is None else row, self._pass if pass_ is None else pass_, fid,
                              None if msg is None else msg.arbitration_id, counter,
                              None if data is None else data.hex(), time.time())
        self.injections.append(injection)
        self._new.append(injection)
        return injection

    # ------------------------------------------------------------------ python-can interface
    def send(self, msg: can.Message, timeout: float | None = None) -> None:  # noqa: ARG002 - BusABC signature
        self._pump()
        faults = self._faults
        index = self._drive_index.get(msg.arbitration_id) if not msg.is_extended_id else None
        if faults is None or index is None:
            self._behind.discard(msg.arbitration_id)
            self._out(msg)
            return
        if faults.row_kind == "delay":
            if not self._delay_started:
                self._delay_started = True
                self._hold_until = max(self._hold_until, time.perf_counter() + self.delay_s)
                self.record("delay", msg)
            self._out(msg)
            return
        if faults.row_kind == "reorder":
            if index == 0 and self._reorder_held is None:
                self._reorder_held = msg
                return
            if index == 1 and self._reorder_held is not None:
                self.record("reorder", msg)
                self._out(msg)
                self._out(self._reorder_held)
                self._reorder_held = None
                return
            self._out(msg)
            return
        kind = faults.frame_kinds[index] if index < len(faults.frame_kinds) else None
        fid = msg.arbitration_id
        if kind == "stale_counter" and fid in self._behind and index >= MEASUREMENT_INDEX:
            kind = None   # it would carry the very counter the receiver expects after the frame it lost
        if kind is None or fid in self._witness:  # a drop's witness goes out intact: it shows the loss
            self._behind.discard(fid)
            self._out(msg)
        else:
            self._inject(kind, msg, index, faults)

    def send_direct(self, msg: can.Message) -> None:
        """Send now, past any fault and any held frame (the bench's own marks)."""
        self._transmit(msg)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        perf = time.perf_counter
        deadline = None if timeout is None else perf() + timeout
        while True:
            self._pump()
            wait = None if deadline is None else max(0.0, deadline - perf())
            if self._held:
                due = max(0.0, self._hold_until - perf())
                wait = due if wait is None else min(wait, due)
            msg = self.inner.recv(wait)
            if msg is not None:
                if not msg.is_extended_id and msg.arbitration_id in self._foreign_ids:
                    continue  # our own injected frame on a foreign id, looped back
                return msg
            if deadline is not None and perf() >= deadline:
                self._pump()
                return None

    def flush_held(self) -> None:
        """Release every held frame now (end of a run)."""
        self._hold_until = 0.0
        self._pump()

    def shutdown(self) -> None:
        self.inner.shutdown()

    def __getattr__(self, name):  # channel_info, state, ... of the wrapped bus
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    # ------------------------------------------------------------------ internals
    def _inject(self, kind: str, msg: can.Message, index: int, faults: RowFaults) -> None:
        sent = mutate(kind, msg, lambda slot: faults.draw(10 * index + slot))
        fid = msg.arbitration_id
        injection = self.record(kind, sent[-1] if sent else None, frame_id=fid)
        injection.counter = msg.data[1] & 0x0F
        if kind != "duplicate":
            self._behind.add(fid)
        if kind == "drop":
            self._witness[fid] = injection
        elif kind == "unknown_id":
            self._foreign_ids.add(sent[0].arbitration_id)
        for frame in sent:
            self._out(frame)

    def _out(self, msg: can.Message) -> None:
        if self._held or time.perf_counter() < self._hold_until:
            self._held.append(msg)
        else:
            self._transmit(msg)

    def _pump(self) -> None:
        if self._held and time.perf_counter() >= self._hold_until:
            while self._held:
                self._transmit(self._held.popleft())

    def _transmit(self, msg: can.Message) -> None:
        msg.timestamp = time.time()
        msg.is_rx = False
        self.inner.send(msg)
        self.transmitted += 1
        if self.on_transmit is not None:
            self.on_transmit(msg)
        waiting = self._witness.pop(msg.arbitration_id, None) if self._witness else None
        if waiting is not None:
            waiting.witness = bytes(msg.data).hex()
