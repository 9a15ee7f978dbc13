"""Encode and validate the frames of the bench's CAN contract, ``thermal_bench.dbc``.

Both nodes import this module: the host encodes drive and control frames with a :class:`FrameCodec` and checks
the replies with a :class:`FrameValidator`; the target does the reverse. Every frame carries an AUTOSAR E2E
profile-2 header: byte 0 is a CRC8H2F (polynomial 0x2F) over bytes 1..7 followed by one data-id byte, and the
low nibble of byte 1 is an alive counter that the sender increments by one (mod 16) per message. The data id of
a message is its ``E2EDataID`` attribute in the DBC (frame id AND 0xFF, unique per message), a simplification of
profile 2's list of 16 data ids.

Only the standard library, python-can and cantools are imported, so the target needs nothing else.
"""

from __future__ import annotations

import math
import numbers
import time
from collections.abc import Mapping
from dataclasses import dataclass
from enum import IntEnum, IntFlag
from functools import cache
from pathlib import Path
from types import MappingProxyType
from typing import Literal, cast, get_args

import can
import cantools
from cantools.autosar import end_to_end
from cantools.database.can import Database
from cantools.database.can import Message as DbcMessage
from cantools.database.errors import EncodeError

DBC_PATH: Path = Path(__file__).with_name("thermal_bench.dbc")
NODES: tuple[str, str] = ("HOST", "TARGET")
COUNTER_MODULO = 16
FRAME_LENGTH = 8

FrameErrorKind = Literal["unknown_id", "wrong_length", "crc", "counter", "out_of_range"]
FRAME_ERROR_KINDS: tuple[FrameErrorKind, ...] = get_args(FrameErrorKind)

SignalValue = int | float


class DbcError(Exception):
    """The DBC file is missing or not the bench's contract; one sentence with what to do."""


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
    sender, an E2EDataID attribute and its CRC and counter signals."""
    version = str(database.version or "")
    parts = version.split(".")
    if len(parts) != 3 or not all(part.isdigit() for part in parts):
        return f"has no VERSION \"major.minor.patch\" (found {version!r})"
    if not database.messages:
        return "defines no messages (empty or truncated)"
    for message in database.messages:
        names = {signal.name for signal in message.signals}
        attributes = message.dbc.attributes if message.dbc is not None else {}
        if not message.senders:
            return f"gives message {message.name} no sender"
        if "E2EDataID" not in attributes:
            return f"gives message {message.name} no E2EDataID attribute (truncated?)"
        if f"{message.name}_CRC" not in names or f"{message.name}_Counter" not in names:
            return f"gives message {message.name} no {message.name}_CRC and {message.name}_Counter signals"
    return None


class Command(IntEnum):
    """``Control.Command`` (VAL_ table of the DBC)."""

    NOP = 0
    RESET = 1
    START = 2
    STOP = 3
    RESTORE = 4  # set the model state from the RestoreState frames (an echoed StateCheckpoint)


class TargetState(IntEnum):
    """``Status.State`` (VAL_ table of the DBC)."""

    BOOT = 0
    IDLE = 1  # artifact loaded, waiting for a RESET
    READY = 2  # RESET done, waiting for START
    RUNNING = 3
    STOPPED = 4
    FAULT = 5


class ModelKind(IntEnum):
    """``TargetInfo.ModelKind`` (VAL_ table of the DBC)."""

    LTI_LPTN = 0
    PV_LPTN = 1
    HAMMERSTEIN = 2


class Realization(IntEnum):
    """``TargetInfo.Realization`` (VAL_ table of the DBC)."""

    PHYSICAL = 0
    ORIGINAL = 1
    BALANCED = 2
    MODAL = 3


class BenchEvent(IntEnum):
    """``BenchEvent.Event`` (VAL_ table of the DBC): the marks a bench host puts into the bus and its log."""

    FAULT = 0  # a fault was injected
    TARGET_LOST = 1  # heartbeat lost or the target restarted: a gap in the replies begins
    REINIT = 2  # the target is restored from its last StateCheckpoint (the last good estimate): the gap ends
    RETRANSMIT = 3  # a row is sent again after its reply deadline passed


class FaultKind(IntEnum):
    """``BenchEvent.FaultKind`` (VAL_ table of the DBC): the faults a bench host can inject."""

    NONE = 0
    DROP = 1
    DELAY = 2
    DUPLICATE = 3
    REORDER = 4
    CORRUPT = 5
    STALE_COUNTER = 6
    WRONG_LENGTH = 7
    UNKNOWN_ID = 8
    OUT_OF_RANGE = 9
    KILL = 10
    FREEZE = 11


class FaultBit(IntFlag):
    """Bits of ``Status.FaultBits``; the signal comment in the DBC defines each one."""

    NO_ARTIFACT = 1 << 0
    RESET_INCOMPLETE = 1 << 1
    RX_ERROR = 1 << 2
    SEQUENCE = 1 << 3
    OVERRUN = 1 << 4
    NONFINITE = 1 << 5
    SATURATED = 1 << 6
    INTERNAL = 1 << 7


class FrameError(ValueError):
    """A frame that may not be sent or was rejected on receipt; ``kind`` is one of FRAME_ERROR_KINDS."""

    def __init__(self, kind: FrameErrorKind, message: str) -> None:
        if kind not in FRAME_ERROR_KINDS:
            raise ValueError(f"unknown frame error kind {kind!r}")
        super().__init__(message)
        self.kind: FrameErrorKind = kind
        self.message = message


@dataclass(frozen=True)
class DecodedFrame:
    """A frame that passed validation; ``signals`` holds scaled values without the CRC and counter signals."""

    name: str
    frame_id: int
    signals: dict[str, SignalValue]
    counter: int
    timestamp: float


@dataclass(frozen=True)
class _Spec:
    message: DbcMessage
    sender: str
    data_id: int
    crc_signal: str
    counter_signal: str
    # (name, minimum, maximum, tolerance, unit) of every application signal
    limits: tuple[tuple[str, float, float, float, str], ...]
    # value-table names of enum signals: signal -> {name: raw value}
    choices: Mapping[str, Mapping[str, int]]

    @property
    def label(self) -> str:
        return f"frame 0x{self.message.frame_id:03X} ({self.message.name})"


def _build_specs() -> dict[int, _Spec]:
    specs: dict[int, _Spec] = {}
    for message in load_database().messages:
        crc_signal, counter_signal = f"{message.name}_CRC", f"{message.name}_Counter"
        limits = tuple(
            (
                s.name,
                -math.inf if s.minimum is None else float(s.minimum),
                math.inf if s.maximum is None else float(s.maximum),
                # Same tolerance as cantools' strict encoder, so whatever encodes also validates.
                abs(s.conversion.scale) * 1e-6,
                s.unit or "",
            )
            for s in message.signals
            if s.name not in (crc_signal, counter_signal)
        )
        specs[message.frame_id] = _Spec(
            message=message,
            sender=message.senders[0],
            data_id=int(message.dbc.attributes["E2EDataID"].value),
            crc_signal=crc_signal,
            counter_signal=counter_signal,
            limits=limits,
            choices={
                s.name: {str(text): int(raw) for raw, text in s.choices.items()} for s in message.signals if s.choices
            },
        )
    return specs


_SPECS: dict[int, _Spec] = _build_specs()
_SPECS_BY_NAME: dict[str, _Spec] = {spec.message.name: spec for spec in _SPECS.values()}

DBC_VERSION: str = str(load_database().version)
DBC_VERSION_INFO: tuple[int, int, int] = cast(
    "tuple[int, int, int]", tuple(int(part) for part in DBC_VERSION.split("."))
)
FRAME_IDS: Mapping[str, int] = MappingProxyType({name: s.message.frame_id for name, s in _SPECS_BY_NAME.items()})
E2E_DATA_IDS: Mapping[int, int] = MappingProxyType({fid: s.data_id for fid, s in _SPECS.items()})
HOST_FRAME_IDS: frozenset[int] = frozenset(fid for fid, s in _SPECS.items() if s.sender == "HOST")
TARGET_FRAME_IDS: frozenset[int] = frozenset(fid for fid, s in _SPECS.items() if s.sender == "TARGET")


def frame_id(name: str) -> int:
    """The frame id of the message ``name``; FrameError("unknown_id") if the DBC has no such message."""
    return _spec_by_name(name).message.frame_id


def model_id_from_sha256(hexdigest: str) -> int:
    """``Status.ModelId`` for an artifact: its sha256's first 8 hex digits as an unsigned 32-bit integer."""
    return int(hexdigest[:8], 16)


def apply_crc(frame_id: int, payload: bytes) -> bytes:
    """``payload`` (8 bytes) with byte 0 replaced by its E2E profile-2 CRC for message ``frame_id``."""
    spec = _SPECS.get(frame_id)
    if spec is None:
        raise FrameError("unknown_id", f"frame 0x{frame_id:X} is not in {DBC_PATH.name}.")
    sealed = end_to_end.apply_profile2_crc(bytes(payload), spec.data_id)
    assert sealed is not None  # only None for payloads shorter than 2 bytes
    return bytes(sealed)


def _spec_by_name(name: str) -> _Spec:
    spec = _SPECS_BY_NAME.get(name)
    if spec is None:
        raise FrameError("unknown_id", f"{DBC_PATH.name} has no message named {name!r}.")
    return spec


def _check_node(node: str) -> str:
    if node not in NODES:
        raise ValueError(f"node {node!r} is not one of {', '.join(NODES)} in {DBC_PATH.name}.")
    return node


def _format_value(value: float, unit: str) -> str:
    return f"{value:.10g} {unit}".rstrip()


def _format_range(minimum: float, maximum: float, unit: str) -> str:
    return f"{minimum:.10g} to {maximum:.10g} {unit}".rstrip()


def signal_ranges(name: str) -> dict[str, tuple[float, float]]:
    """(minimum, maximum) of every application signal of message ``name``, e.g. for a sender to saturate."""
    return {signal: (minimum, maximum) for signal, minimum, maximum, *_ in _spec_by_name(name).limits}


class FrameCodec:
    """Encodes the messages one node sends, filling in alive counter and CRC (one instance per sending node)."""

    def __init__(self, sender: str) -> None:
        self.sender = _check_node(sender)
        self._next_counter: dict[int, int] = {}

    def reset_counters(self) -> None:
        """Restart every alive counter at 0 (receivers accept the first frame after their own reset only)."""
        self._next_counter.clear()

    def encode(
        self, name: str, signals: Mapping[str, SignalValue | str], *, timestamp: float | None = None
    ) -> can.Message:
        """A classic 11-bit, DLC-8 frame of message ``name`` with the given application signals.

        ``signals`` holds every signal of the message except ``<name>_CRC`` and ``<name>_Counter``, in physical
        units; enum signals also take their value-table names. Values outside the DBC range raise
        FrameError("out_of_range") instead of wrapping, and a refused frame does not use up a counter value.
        """
        spec = _spec_by_name(name)
        if spec.sender != self.sender:
            raise FrameError("unknown_id", f"message {name} is sent by {spec.sender}, not by {self.sender}.")
        expected = {limit[0] for limit in spec.limits}
        given = set(signals)
        if given != expected:
            missing, unknown = sorted(expected - given), sorted(given - expected)
            raise ValueError(
                f"message {name} needs exactly the signals {sorted(expected)}"
                + (f"; missing {missing}" if missing else "")
                + (f"; unknown {unknown}" if unknown else "")
                + "."
            )
        data: dict[str, SignalValue] = {}
        for signal, minimum, maximum, tolerance, unit in spec.limits:
            value = signals[signal]
            if isinstance(value, str):
                names = spec.choices.get(signal, {})
                if value not in names:
                    raise FrameError(
                        "out_of_range",
                        f"signal {signal} of message {name} has no value named {value!r}"
                        + (f"; use one of {', '.join(names)}." if names else "; give a number."),
                    )
                value = names[value]
            # cantools takes only int, float and str: numpy scalars (np.float32 is no float) become Python ones
            number = int(value) if isinstance(value, numbers.Integral) else float(value)
            data[signal] = number
            if not math.isfinite(number) or not minimum - tolerance <= number <= maximum + tolerance:
                raise FrameError(
                    "out_of_range",
                    f"signal {signal} of message {name} cannot carry {_format_value(float(number), unit)}, "
                    f"its range is {_format_range(minimum, maximum, unit)}.",
                )

        counter = self._next_counter.get(spec.message.frame_id, 0)
        data.update({spec.crc_signal: 0, spec.counter_signal: counter})
        try:
            payload = spec.message.encode(data, scaling=True, padding=False, strict=True)
        except EncodeError as error:
            raise FrameError("out_of_range", f"message {name} cannot be encoded: {error}") from None
        sealed = end_to_end.apply_profile2_crc(payload, spec.data_id)
        assert sealed is not None
        self._next_counter[spec.message.frame_id] = (counter + 1) % COUNTER_MODULO
        return can.Message(
            timestamp=time.time() if timestamp is None else timestamp,
            arbitration_id=spec.message.frame_id,
            is_extended_id=False,
            dlc=FRAME_LENGTH,
            data=bytes(sealed),
            check=True,
        )


def _check_frame(msg: can.Message, accepted: frozenset[int] | None) -> tuple[_Spec, dict[str, SignalValue], int]:
    """Stateless checks in contract order: id, length, CRC, ranges. Returns (spec, signals, counter)."""
    fid = msg.arbitration_id
    if msg.is_error_frame:
        raise FrameError("unknown_id", "an error frame is not a frame of the contract.")
    if msg.is_remote_frame:
        raise FrameError("unknown_id", f"remote frame 0x{fid:X} is not a frame of the contract.")
    if msg.is_extended_id:
        raise FrameError("unknown_id", f"extended frame 0x{fid:08X} is not a frame of the contract.")
    if msg.is_fd:
        raise FrameError("unknown_id", f"CAN FD frame 0x{fid:03X} is not a frame of the classic-CAN contract.")
    spec = _SPECS.get(fid)
    if spec is None:
        raise FrameError("unknown_id", f"frame 0x{fid:03X} is not in {DBC_PATH.name}.")
    if accepted is not None and fid not in accepted:
        raise FrameError("unknown_id", f"{spec.label} is sent by {spec.sender} and not received here.")
    if msg.dlc != FRAME_LENGTH or len(msg.data) != FRAME_LENGTH:
        raise FrameError("wrong_length", f"{spec.label} has {len(msg.data)} data bytes (DLC {msg.dlc}) instead of 8.")
    payload = bytes(msg.data)
    expected_crc = end_to_end.compute_profile2_crc(payload, spec.data_id)
    if payload[0] != expected_crc:
        raise FrameError("crc", f"{spec.label} has CRC 0x{payload[0]:02X} instead of 0x{expected_crc:02X}.")
    decoded = spec.message.decode(payload, decode_choices=False, scaling=True)
    for signal, minimum, maximum, tolerance, unit in spec.limits:
        value = float(cast(SignalValue, decoded[signal]))
        if not minimum - tolerance <= value <= maximum + tolerance:
            raise FrameError(
                "out_of_range",
                f"{spec.label} carries {signal} = {_format_value(value, unit)}, "
                f"outside its range {_format_range(minimum, maximum, unit)}.",
            )
    signals = {signal: cast(SignalValue, decoded[signal]) for signal, *_ in spec.limits}
    return spec, signals, payload[1] & 0x0F


def decode_any(msg: can.Message) -> DecodedFrame:
    """Decode any frame of the contract without counter state (for logs): checks id, length, CRC and ranges."""
    spec, signals, counter = _check_frame(msg, None)
    return DecodedFrame(spec.message.name, spec.message.frame_id, signals, counter, msg.timestamp)


class FrameValidator:
    """Checks received frames against the contract (one stateful instance per receiving node).

    Checks run in this order: id (extended, remote, error and FD frames are unknown too), DLC, CRC, signal
    ranges, alive counter. A rejected frame changes no state, so it counts as lost; the only exception is a
    counter error, after which the expected counter resynchronizes to the received one, so that one lost frame
    costs one error and not one per following frame.
    """

    def __init__(self, receiver: str | None = None) -> None:
        """``receiver`` ("HOST"/"TARGET") accepts only frames the other node sends; None accepts all frames."""
        self.receiver = None if receiver is None else _check_node(receiver)
        self._accepted: frozenset[int] | None = (
            None if receiver is None else frozenset(fid for fid, s in _SPECS.items() if s.sender != receiver)
        )
        self._last_counter: dict[int, int] = {}

    def reset_counters(self) -> None:
        """Forget every message's last counter: the next frame of each message is accepted with any counter."""
        self._last_counter.clear()

    def validate(self, msg: can.Message) -> DecodedFrame:
        """The decoded frame, or FrameError(kind, one-sentence message) if it must be rejected."""
        spec, signals, counter = _check_frame(msg, self._accepted)
        fid = spec.message.frame_id
        last = self._last_counter.get(fid)
        self._last_counter[fid] = counter
        if last is not None and counter != (last + 1) % COUNTER_MODULO:
            if counter == last:
                detail = f"repeats alive counter {counter}"
            else:
                detail = f"has alive counter {counter} after {last}, {(counter - last - 1) % 16} frame(s) lost"
            raise FrameError("counter", f"{spec.label} {detail}.")
        return DecodedFrame(spec.message.name, fid, signals, counter, msg.timestamp)
