"""``thermal_bench.dbc`` read once, on first use, into what the codec and the nodes need per message.

Signal names are unique across the DBC (1.5.0): a signal that several messages carry is named `<Message>_<Role>`
there (`Control_Step`, `StateCheckpoint_StateValue`, as `<Message>_CRC` and `<Message>_Counter`). The code knows it
by its role (`Step`, `StateValue`): `SignalLayout.name` is the DBC name without the message's prefix, and
`SignalLayout.dbc_name` the name in the file, for tools that look signals up in it (cantools, the C generator).

Nothing here runs at import: the first call that needs the file loads it (cantools, strict) and checks that it
is the bench's contract; a missing or broken file is one `DbcError` sentence at that call, which the command
line reports like any other bad input.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from types import MappingProxyType
from typing import cast

import cantools
from cantools.database.can import Database
from cantools.database.can import Message as DbcMessage

from dbc.contract import DBC_PATH, EVENT_STEP_MESSAGES, HEARTBEAT_MESSAGE, NODES, REPLY_SIGNALS, FrameError
from dbc.errors import CanLinkError

_FLOAT_FORMATS = {32: ("<f", "<I"), 64: ("<d", "<Q")}


class DbcError(CanLinkError):
    """The DBC file is missing or not the bench's contract; one sentence with what to do."""


@dataclass(frozen=True)
class SignalLayout:
    """One application signal (not CRC, not counter) as the codec packs it."""

    name: str                   # the role the code knows it by: the DBC name without a "<Message>_" prefix
    dbc_name: str               # the name in the DBC, unique across its messages
    start: int
    length: int
    signed: bool
    mask: int
    conversion: object          # cantools' conversion object: scaled <-> raw exactly as cantools does it
    minimum: float
    maximum: float
    tolerance: float            # as cantools' strict encoder, so whatever encodes also validates
    unit: str
    inline: bool                # raw = round((value - offset) / scale), what cantools does for these conversions
    offset: float
    scale: float
    ieee: tuple[str, str] | None  # struct formats (float, bits) of an IEEE float signal (SIG_VALTYPE_)
    choices: Mapping[str, int]  # value-table names -> raw values of an enum signal
    low: float                  # minimum - tolerance: what still encodes and validates
    high: float                 # maximum + tolerance

    def packed(self) -> tuple:
        """The fields the codec's per-frame loops read, as one tuple (unpacked once per signal: fast)."""
        return (self.name, self.start, self.length, self.signed, self.mask, self.conversion, self.low, self.high,
                self.inline, self.offset, self.scale, self.ieee)

    def unpacked(self) -> tuple:
        """The fields the codec's decoding loop reads: name, start, mask, the sign bit (0: unsigned) and what a
        negative raw value takes off, scale and offset (None: ask the conversion), range, IEEE formats."""
        sign = 1 << (self.length - 1) if self.signed else 0
        linear = not self.ieee and _linear(self.conversion, self.scale, self.offset, self.mask)
        return (self.name, self.start, self.mask, sign, 1 << self.length, self.scale if linear else None,
                self.offset, self.conversion, self.low, self.high, self.ieee)


def _linear(conversion, scale, offset, mask: int) -> bool:
    """cantools' scaled value of this conversion (without choices) is `raw * scale + offset`, type and all (an
    identity's int 1 and 0 keep an int an int): checked on raw values across the signal's range."""
    for raw in (0, 1, 2, 3, mask // 2, mask, -(mask // 2), -1):
        value, inline = conversion.raw_to_scaled(raw, False), raw * scale + offset
        if type(value) is not type(inline) or value != inline:
            return False
    return True


@dataclass(frozen=True)
class MessageLayout:
    """One message of the contract: id, sender, E2E data id, its application signals, cycle time."""

    name: str
    frame_id: int
    sender: str
    data_id: int
    signals: tuple[SignalLayout, ...]
    cycle_time_ms: int
    message: DbcMessage
    packed: tuple[tuple, ...]   # SignalLayout.packed() of every signal, in order
    unpacked: tuple[tuple, ...]  # SignalLayout.unpacked() of every signal, in order

    @property
    def label(self) -> str:
        return f"frame 0x{self.frame_id:03X} ({self.name})"

    @property
    def signal_names(self) -> frozenset[str]:
        return frozenset(s.name for s in self.signals)

    def signal(self, name: str) -> SignalLayout:
        return next(s for s in self.signals if s.name == name)


@dataclass(frozen=True)
class Contract:
    """The DBC as the codec sees it."""

    database: Database
    version: str
    by_id: Mapping[int, MessageLayout]
    by_name: Mapping[str, MessageLayout]

    @property
    def version_info(self) -> tuple[int, int, int]:
        return cast("tuple[int, int, int]", tuple(int(part) for part in self.version.split(".")))

    def frame_ids(self, sender: str | None = None) -> frozenset[int]:
        return frozenset(fid for fid, m in self.by_id.items() if sender is None or m.sender == sender)


@cache
def load_database() -> Database:
    """The DBC, loaded once with cantools' strict checks (shared between callers: do not modify it).

    DbcError (one sentence) when the file is missing, unreadable, not a DBC, or lacks what the codec needs.
    """
    path = Path(DBC_PATH)
    fix = "reinstall the package or restore dbc/thermal_bench.dbc from the repository"
    try:
        database = cast(Database, cantools.database.load_file(path, database_format="dbc", strict=True))
    except FileNotFoundError:
        raise DbcError(f"the CAN contract {path} does not exist; {fix}") from None
    except OSError as exc:
        raise DbcError(f"the CAN contract {path} cannot be read ({exc.strerror or exc}); {fix}") from None
    except Exception as exc:  # noqa: BLE001 - cantools raises parse, value and unicode errors of many kinds
        reason = " ".join(str(exc).split())[:120] or exc.__class__.__name__
        raise DbcError(f"the CAN contract {path} is not a valid DBC ({reason}); {fix}") from None
    problem = _contract_problem(database)
    if problem:
        raise DbcError(f"the CAN contract {path} {problem}; {fix}")
    return database


def _contract_problem(database: Database) -> str | None:
    """What the codec needs from the DBC and this one lacks (None if nothing): a version, and per message one
    sender of the two nodes, an E2EDataID attribute, its CRC and counter signals, and signals it can pack."""
    version = str(database.version or "")
    parts = version.split(".")
    if len(parts) != 3 or not all(part.isdigit() for part in parts):
        return f"has no VERSION \"major.minor.patch\" (found {version!r})"
    if not database.messages:
        return "defines no messages (empty or truncated)"
    for message in database.messages:
        names = {signal.name for signal in message.signals}
        attributes = message.dbc.attributes if message.dbc is not None else {}
        if not message.senders or message.senders[0] not in NODES:
            return f"gives message {message.name} no sender of {' or '.join(NODES)}"
        if "E2EDataID" not in attributes:
            return f"gives message {message.name} no E2EDataID attribute (truncated?)"
        if f"{message.name}_CRC" not in names or f"{message.name}_Counter" not in names:
            return f"gives message {message.name} no {message.name}_CRC and {message.name}_Counter signals"
        for s in message.signals:
            if s.byte_order != "little_endian" or (s.conversion.is_float and s.length not in _FLOAT_FORMATS):
                return f"gives signal {message.name}.{s.name} a layout the codec does not pack (Intel integer " \
                       "or IEEE float only)"
    return None


def role_name(message: str, signal: str) -> str:
    """The name the code knows DBC signal `signal` of `message` by: `Control_Step` -> `Step`."""
    prefix = f"{message}_"
    return signal[len(prefix):] if signal.startswith(prefix) else signal


def _signal_layout(message: str, s) -> SignalLayout:
    minimum = -math.inf if s.minimum is None else float(s.minimum)
    maximum = math.inf if s.maximum is None else float(s.maximum)
    tolerance = abs(s.conversion.scale) * 1e-6
    return SignalLayout(
        name=role_name(message, s.name), dbc_name=s.name, start=s.start, length=s.length, signed=s.is_signed,
        mask=(1 << s.length) - 1,
        conversion=s.conversion,
        minimum=minimum, maximum=maximum, tolerance=tolerance, low=minimum - tolerance, high=maximum + tolerance,
        unit=s.unit or "",
        inline=type(s.conversion).__name__ in ("IdentityConversion", "LinearConversion", "NamedSignalConversion"),
        offset=s.conversion.offset, scale=s.conversion.scale,
        ieee=_FLOAT_FORMATS[s.length] if s.conversion.is_float else None,
        choices=MappingProxyType({str(text): int(raw) for raw, text in (s.choices or {}).items()}))


@cache
def contract() -> Contract:
    """The loaded contract (first call reads the DBC; DbcError if it is broken)."""
    database = load_database()
    layouts = []
    for message in database.messages:
        attributes = message.dbc.attributes
        cycle = attributes.get("GenMsgCycleTime")
        signals = tuple(_signal_layout(message.name, s) for s in message.signals
                        if s.name not in (f"{message.name}_CRC", f"{message.name}_Counter"))
        layouts.append(MessageLayout(
            name=message.name, frame_id=message.frame_id, sender=message.senders[0],
            data_id=int(attributes["E2EDataID"].value), signals=signals,
            cycle_time_ms=int(cycle.value) if cycle is not None else 0, message=message,
            packed=tuple(signal.packed() for signal in signals),
            unpacked=tuple(signal.unpacked() for signal in signals)))
    return Contract(database=database, version=str(database.version),
                    by_id=MappingProxyType({m.frame_id: m for m in layouts}),
                    by_name=MappingProxyType({m.name: m for m in layouts}))


def frame_id(name: str) -> int:
    """The frame id of message `name`; FrameError("unknown_id") if the DBC has no such message."""
    return layout_named(name).frame_id


def layout_named(name: str) -> MessageLayout:
    """Message `name`'s layout; FrameError("unknown_id") if the DBC has no such message."""
    layout = contract().by_name.get(name)
    if layout is None:
        raise FrameError("unknown_id", f"{DBC_PATH.name} has no message named {name!r}.")
    return layout


def frame_ids() -> Mapping[str, int]:
    """Every message's frame id by name."""
    return MappingProxyType({name: m.frame_id for name, m in contract().by_name.items()})


@cache
def host_frame_ids() -> frozenset[int]:
    """The ids the HOST node sends."""
    return contract().frame_ids("HOST")


@cache
def target_frame_ids() -> frozenset[int]:
    """The ids the TARGET node sends."""
    return contract().frame_ids("TARGET")


def dbc_version() -> str:
    return contract().version


def dbc_version_info() -> tuple[int, int, int]:
    return contract().version_info


def e2e_data_id(fid: int) -> int:
    return contract().by_id[fid].data_id


def signal_ranges(name: str) -> dict[str, tuple[float, float]]:
    """(minimum, maximum) of every application signal of message `name`, e.g. for a sender to saturate."""
    return {s.name: (s.minimum, s.maximum) for s in layout_named(name).signals}


def temperature_range() -> tuple[float, float]:
    """What a reply's temperature signal can carry (they share one range, a test checks it); the target clamps
    to it and the analysis leaves values beyond it out of the comparisons."""
    message, signals = next(iter(REPLY_SIGNALS.items()))
    return signal_ranges(message)[signals[0][0]]


def row_step_messages() -> tuple[str, ...]:
    """The messages whose Step is the data row they belong to: every message with a Step but the command and event
    messages (`dbc.contract.EVENT_STEP_MESSAGES`), in frame-id order."""
    return tuple(m.name for _, m in sorted(contract().by_id.items())
                 if "Step" in m.signal_names and m.name not in EVENT_STEP_MESSAGES)


def heartbeat_period_s() -> float:
    """The heartbeat period: the cycle time the DBC gives the Status message."""
    return contract().by_name[HEARTBEAT_MESSAGE].cycle_time_ms / 1000.0
