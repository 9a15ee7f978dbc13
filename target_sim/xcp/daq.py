"""Synchronous data acquisition: dynamic DAQ lists (FREE_DAQ, ALLOC_DAQ, ALLOC_ODT, ALLOC_ODT_ENTRY, SET_DAQ_PTR,
WRITE_DAQ, SET_DAQ_LIST_MODE, START_STOP_DAQ_LIST, START_STOP_SYNCH) sampled on an event.

Two event channels: EVENT_MODEL_STEP (0), after every model step, once the step's reply frames are queued, and
EVENT_HEARTBEAT (1), a time event on the node's heartbeat tick (the DBC's Status period, 100 ms). A running
list sends, every `prescaler`-th event, one DAQ packet per ODT: its packet identifier (absolute ODT number: the list's
first PID plus the ODT's index) and its entries' bytes read at that moment, so one packet holds values of one step.
The configuration follows the standard's order (FREE_DAQ, then ALLOC_DAQ, then ALLOC_ODT per list, then
ALLOC_ODT_ENTRY per ODT; ERR_SEQUENCE otherwise) within the RAM budget of the C node's fixed tables
(bench/firmware/xcp.c): MAX_DAQ_LISTS lists, MAX_ODTS ODTs and MAX_ODT_ENTRIES entries over all lists
(ERR_MEMORY_OVERFLOW beyond them), at most ODT_PAYLOAD entries in one ODT (ERR_OUT_OF_RANGE: each entry is a byte at
least, so no more can ever be written); an ODT's entries must fit one CAN frame after the PID (7 bytes;
ERR_DAQ_CONFIG), and every entry must read mapped bytes (ERR_ACCESS_DENIED at WRITE_DAQ). Both engines answer
alike, so these limits are the slave's, not the Python node's."""

from __future__ import annotations

from dataclasses import dataclass, field

from target_sim.errors import TargetError
from target_sim.xcp.codes import (
    LIST_RUNNING,
    LIST_SELECTED,
    MAX_DTO,
    MODE_DIRECTION_STIM,
    MODE_PID_OFF,
    MODE_TIMESTAMP,
    Err,
)
from target_sim.xcp.memory import AccessRefused, AddressSpace

EVENT_MODEL_STEP = 0
EVENT_HEARTBEAT = 1
EVENTS = {EVENT_MODEL_STEP: "model step", EVENT_HEARTBEAT: "heartbeat"}
MAX_ODT_ENTRIES = 64          # the RAM budget of the DAQ tables (entries over all lists)
MAX_DAQ_LISTS = 16            # ... lists
MAX_ODTS = 16                 # ... ODTs over all lists (each a DAQ packet per event: the C node's queue)
MAX_PID = 0xFB                # 0xFC..0xFF are the slave's RES/ERR/EV/SERV packets
# the DAQ packets one call of the node (a row's reply, a heartbeat) carries at most: the C node's queue, one per ODT
# of the tables, so one event's packets always fit; a row that runs several model steps (after lost rows) may sample
# more, and both engines drop those past the queue and count them (XcpSlave.queued)
DAQ_QUEUE = min(MAX_ODTS, MAX_PID + 1)
ODT_PAYLOAD = MAX_DTO - 1     # bytes of an ODT after its packet identifier (and so its most entries)


class DaqError(TargetError):
    def __init__(self, code: Err, why: str):
        super().__init__(why)
        self.code = code


@dataclass
class DaqList:
    odts: list[list[tuple[int, int, list]]]          # per ODT: (address, size, resolved pieces) per entry
    capacity: list[int]                              # entries allocated per ODT
    event: int = EVENT_MODEL_STEP
    prescaler: int = 1
    mode: int = 0
    selected: bool = False
    running: bool = False
    first_pid: int = 0
    countdown: int = 0


@dataclass
class Daq:
    memory: AddressSpace
    lists: list[DaqList] = field(default_factory=list)
    pointer: tuple[int, int, int] | None = None
    allocated_entries: int = 0
    stage: str = "free"        # free -> daq -> odt -> entry: the allocation order
    packets: int = 0

    # ------------------------------------------------------------------ configuration
    def free(self) -> None:
        self.lists, self.pointer, self.allocated_entries, self.stage = [], None, 0, "daq"

    def alloc_daq(self, count: int) -> None:
        if self.stage != "daq" or self.lists:
            raise DaqError(Err.SEQUENCE, "ALLOC_DAQ needs a FREE_DAQ before it")
        if count > MAX_DAQ_LISTS:
            raise DaqError(Err.MEMORY_OVERFLOW, f"more than {MAX_DAQ_LISTS} DAQ lists (the DAQ RAM budget)")
        self.lists = [DaqList(odts=[], capacity=[]) for _ in range(count)]
        self.stage = "odt"

    def alloc_odt(self, daq: int, count: int) -> None:
        if self.stage != "odt":
            raise DaqError(Err.SEQUENCE, "ALLOC_ODT comes after ALLOC_DAQ and before ALLOC_ODT_ENTRY")
        daq_list = self._list(daq)
        if sum(len(d.odts) for d in self.lists) + count > min(MAX_ODTS, MAX_PID + 1):
            raise DaqError(Err.MEMORY_OVERFLOW, f"more than {MAX_ODTS} ODTs (the DAQ RAM budget)")
        daq_list.odts = [[] for _ in range(count)]
        daq_list.capacity = [0] * count
        first = 0
        for d in self.lists:
            d.first_pid = first
            first += len(d.odts)

    def alloc_odt_entry(self, daq: int, odt: int, count: int) -> None:
        if self.stage not in ("odt", "entry"):
            raise DaqError(Err.SEQUENCE, "ALLOC_ODT_ENTRY needs ALLOC_ODT before it")
        daq_list = self._list(daq)
        if not 0 <= odt < len(daq_list.odts):
            raise DaqError(Err.OUT_OF_RANGE, f"DAQ list {daq} has no ODT {odt}")
        if count > ODT_PAYLOAD:
            raise DaqError(Err.OUT_OF_RANGE, f"{count} entries in one ODT: at most {ODT_PAYLOAD} fit its packet")
        if self.allocated_entries - daq_list.capacity[odt] + count > MAX_ODT_ENTRIES:
            raise DaqError(Err.MEMORY_OVERFLOW, f"more than {MAX_ODT_ENTRIES} ODT entries (the DAQ RAM budget)")
        self.allocated_entries += count - daq_list.capacity[odt]
        daq_list.capacity[odt] = count
        self.stage = "entry"

    def set_pointer(self, daq: int, odt: int, entry: int) -> None:
        daq_list = self._list(daq)
        if not 0 <= odt < len(daq_list.odts) or not 0 <= entry < daq_list.capacity[odt]:
            raise DaqError(Err.OUT_OF_RANGE, f"DAQ list {daq} has no ODT {odt} entry {entry}")
        if daq_list.running:
            raise DaqError(Err.DAQ_ACTIVE, f"DAQ list {daq} is running")
        self.pointer = (daq, odt, entry)

    def write_entry(self, size: int, address: int) -> None:
        if self.pointer is None:
            raise DaqError(Err.SEQUENCE, "WRITE_DAQ needs SET_DAQ_PTR before it")
        daq, odt, entry = self.pointer
        entries = self.lists[daq].odts[odt]
        if entry >= self.lists[daq].capacity[odt]:
            raise DaqError(Err.OUT_OF_RANGE, "WRITE_DAQ past the ODT's allocated entries")
        others = sum(s for i, (_, s, _) in enumerate(entries) if i != entry)
        if not 1 <= size or others + size > ODT_PAYLOAD:
            raise DaqError(Err.DAQ_CONFIG, f"ODT {odt} of DAQ list {daq} would carry {others + size} bytes; "
                                           f"at most {ODT_PAYLOAD} fit one CAN frame")
        try:
            pieces = self.memory.locate(address, size)
        except AccessRefused as exc:
            raise DaqError(exc.code, str(exc)) from None
        record = (address, size, pieces)
        if entry < len(entries):
            entries[entry] = record
        else:
            entries.extend([(0, 0, [])] * (entry - len(entries)))
            entries.append(record)
        self.pointer = (daq, odt, entry + 1)       # WRITE_DAQ post-increments the pointer

    def set_mode(self, daq: int, mode: int, event: int, prescaler: int) -> None:
        daq_list = self._list(daq)
        if mode & (MODE_DIRECTION_STIM | MODE_TIMESTAMP | MODE_PID_OFF):
            raise DaqError(Err.MODE_NOT_VALID, f"mode 0x{mode:02X}: no STIM, time stamp or PID_OFF here")
        if event not in EVENTS:
            raise DaqError(Err.OUT_OF_RANGE, f"event channel {event} does not exist")
        if prescaler < 1:
            raise DaqError(Err.OUT_OF_RANGE, "prescaler 0")
        daq_list.mode, daq_list.event, daq_list.prescaler = mode, event, prescaler

    def start_stop_list(self, mode: int, daq: int) -> int:
        """START_STOP_DAQ_LIST: 0 stop, 1 start, 2 select; returns the list's first PID."""
        daq_list = self._list(daq)
        if mode not in (0, 1, 2):
            raise DaqError(Err.MODE_NOT_VALID, f"START_STOP_DAQ_LIST mode {mode}")
        if mode == 1 and not self._complete(daq_list):
            raise DaqError(Err.DAQ_CONFIG, f"DAQ list {daq} has an ODT entry never written")
        if mode == 0:
            daq_list.running = False
        elif mode == 1:
            daq_list.running, daq_list.countdown = True, 0
        else:
            daq_list.selected = True
        return daq_list.first_pid

    def start_stop_synch(self, mode: int) -> None:
        """START_STOP_SYNCH: 0 stop all, 1 start the selected, 2 stop the selected (selection cleared)."""
        if mode not in (0, 1, 2):
            raise DaqError(Err.MODE_NOT_VALID, f"START_STOP_SYNCH mode {mode}")
        if mode == 1 and not all(self._complete(d) for d in self.lists if d.selected):
            raise DaqError(Err.DAQ_CONFIG, "a selected DAQ list has an ODT entry never written")
        for d in self.lists:
            if mode == 0:
                d.running = False
            elif d.selected:
                d.running, d.countdown = mode == 1, 0
            if mode != 0:
                d.selected = False

    def stop_all(self) -> None:
        for d in self.lists:
            d.running = d.selected = False

    @property
    def running(self) -> bool:
        return any(d.running for d in self.lists)

    def list_mode(self, daq: int) -> int:
        d = self._list(daq)
        return d.mode | (LIST_SELECTED if d.selected else 0) | (LIST_RUNNING if d.running else 0)

    def _list(self, daq: int) -> DaqList:
        if not 0 <= daq < len(self.lists):
            raise DaqError(Err.OUT_OF_RANGE, f"DAQ list {daq} does not exist ({len(self.lists)} allocated)")
        return self.lists[daq]

    @staticmethod
    def _complete(daq_list: DaqList) -> bool:
        return all(len(entries) == cap and all(size for _, size, _ in entries)
                   for entries, cap in zip(daq_list.odts, daq_list.capacity, strict=True))

    # ------------------------------------------------------------------ sampling
    def sample(self, event: int) -> list[bytes]:
        """The DAQ packets of `event` (each running list of that event whose prescaler is due)."""
        out: list[bytes] = []
        text = self.memory.text[1] if self.memory.text is not None else b""
        for d in self.lists:
            if not d.running or d.event != event:
                continue
            if d.countdown:
                d.countdown -= 1
                continue
            d.countdown = d.prescaler - 1
            cache: dict[int, bytes] = {}
            for k, entries in enumerate(d.odts):
                packet = bytearray((d.first_pid + k,))
                for _, _, pieces in entries:
                    for cell, start, n in pieces:
                        if cell is None:
                            packet += text[start: start + n]
                            continue
                        raw = cache.get(cell.address)
                        if raw is None:
                            raw = cache[cell.address] = cell.bytes()
                        packet += raw[start: start + n]
                out.append(bytes(packet))
        self.packets += len(out)
        return out
