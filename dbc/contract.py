"""The facts of the bench's CAN contract that code needs by name, each defined once (no file is read here).

The DBC (`thermal_bench.dbc`) is the contract; what it states about ids, layouts, ranges, cycle times and
E2E data ids is read from it (`dbc.database`). This module holds what both nodes must agree on beyond the
file's syntax: the enums of its value tables (a test checks them against the DBC), the arithmetic of Step
and alive counters, which messages make a reply and in which order the temperatures are carried, the
RxErrors counters, and the heartbeat timeout a receiver applies.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from enum import IntEnum, IntFlag
from pathlib import Path
from types import MappingProxyType
from typing import Literal, get_args

from dbc.errors import CanLinkError

DBC_PATH: Path = Path(__file__).with_name("thermal_bench.dbc")
NODES: tuple[str, str] = ("HOST", "TARGET")
FRAME_LENGTH = 8                 # classic CAN, every message DLC 8
COUNTER_MODULO = 16              # 4-bit alive counter in the low nibble of byte 1
STEP_MODULO = 1 << 16            # `Step` is 16 bits: the data row number modulo 65536
HEARTBEAT_MESSAGE = "Status"     # its GenMsgCycleTime in the DBC is the heartbeat period
HEARTBEAT_TIMEOUT_S = 0.5        # five heartbeat periods without a Status: the target is lost
# how long a host waits for a row's replies by default (--reply-timeout): a round trip is about 0.1 ms, with rare
# 4-10 ms outliers on udp_multicast, so tens of ms
DEFAULT_REPLY_TIMEOUT_S = 0.05
# the bench's drive data rate (5 Hz): one data row per period, the DBC's GenMsgCycleTime of the row messages
DRIVE_SAMPLE_PERIOD_S = 0.2

FrameErrorKind = Literal["unknown_id", "wrong_length", "crc", "counter", "out_of_range"]
FRAME_ERROR_KINDS: tuple[FrameErrorKind, ...] = get_args(FrameErrorKind)
# What the target counts: every frame error kind, and sequence errors (frames valid on their own, out of order)
RX_ERROR_KINDS: tuple[str, ...] = (*FRAME_ERROR_KINDS, "sequence")
# RxErrors signal of each counted kind
RX_ERROR_SIGNALS: Mapping[str, str] = MappingProxyType({
    "unknown_id": "UnknownId", "wrong_length": "WrongLength", "crc": "CrcError", "counter": "CounterError",
    "out_of_range": "OutOfRange", "sequence": "SequenceError"})

# Temperatures travel in the state order of the model: x = [yoke, winding, tooth, magnet]
TEMPERATURE_NODES: tuple[str, str, str, str] = ("yoke", "winding", "tooth", "magnet")
STATE_SIZE = len(TEMPERATURE_NODES)
# message -> ((signal, index into the temperature order), ...) for the reply and for the RESET's initial values
REPLY_SIGNALS: Mapping[str, tuple[tuple[str, int], ...]] = MappingProxyType({
    "Temperatures1": (("WindingTemp", 1), ("MagnetTemp", 3)),
    "Temperatures2": (("YokeTemp", 0), ("ToothTemp", 2))})
RESET_SIGNALS: Mapping[str, tuple[tuple[str, int], ...]] = MappingProxyType({
    "ResetTemps1": (("WindingTempInit", 1), ("MagnetTempInit", 3)),
    "ResetTemps2": (("YokeTempInit", 0), ("ToothTempInit", 2))})
REPLY_MESSAGES: tuple[str, ...] = tuple(REPLY_SIGNALS)
# a row is answered when both reply messages are in: one bit per message, all bits set
REPLY_BIT: Mapping[str, int] = MappingProxyType({name: 1 << i for i, name in enumerate(REPLY_MESSAGES)})
REPLY_COMPLETE = (1 << len(REPLY_MESSAGES)) - 1
# the drive values of a data row, in the order the host reads them from a dataset: torque, speed, coolant, ambient
DRIVE_SIGNALS: tuple[tuple[str, str], ...] = (("DriveInputs", "MotorTorque"), ("DriveInputs", "MotorSpeed"),
                                              ("DriveTemps", "CoolantTemp"), ("DriveTemps", "AmbientTemp"))
# and after them, when the drive data has them (DBC 1.4.0), the d/q stator currents: a model with an electrical
# loss model needs them (the artifact's drive_signals), one with loss maps ignores them
CURRENT_SIGNALS: tuple[tuple[str, str], ...] = (("DriveCurrents", "CurrentD"), ("DriveCurrents", "CurrentQ"))
CURRENT_MESSAGE = "DriveCurrents"
# The observer's frames (DBC 1.6.0). The host sends a row's Measurements right before its DriveInputs: one slot per
# kind of measurement, a value and its status. A target with an observer answers every model step with each node's
# 1-sigma (Uncertainty1/2, in the temperature order as the replies) and the innovation of each slot its update used
# (Innovations).
MEASUREMENT_MESSAGE = "Measurements"
MEASUREMENT_SLOTS: tuple[str, ...] = ("sensor", "flux")
# DBC 1.7.0: the row's d/q stator voltages (DriveVoltages, one status for both), sent after its Measurements and
# before its DriveInputs, for a target whose observer computes the flux linkage itself (with the row's DriveCurrents
# and MotorSpeed, and its own winding estimate).
VOLTAGE_MESSAGE = "DriveVoltages"
MEASUREMENT_MESSAGES: tuple[str, ...] = (MEASUREMENT_MESSAGE, VOLTAGE_MESSAGE)   # sent in this order
# The host's measurement channels: what it sends per row beside the drive values for an observer, channel ->
# (message, value signal, status signal). Its measurement matrix has one column per channel in this order (NaN:
# absent): the first two (the Measurements slots), or all four when the observer reads the voltages
# (`measurement_messages`).
MEASUREMENT_CHANNELS: Mapping[str, tuple[str, str, str]] = MappingProxyType({
    "sensor": (MEASUREMENT_MESSAGE, "SensorTemp", "SensorStatus"),
    "flux": (MEASUREMENT_MESSAGE, "FluxMagnetTemp", "FluxMagnetStatus"),
    "u_d": (VOLTAGE_MESSAGE, "VoltageD", "VoltageStatus"),
    "u_q": (VOLTAGE_MESSAGE, "VoltageQ", "VoltageStatus")})
CHANNEL_NAMES: tuple[str, ...] = tuple(MEASUREMENT_CHANNELS)
# the row's own values an observer reads as raw channels (the flux linkage's speed and currents): name -> index in a
# row of 6 values (DRIVE_SIGNALS + CURRENT_SIGNALS)
ROW_CHANNELS: Mapping[str, int] = MappingProxyType({"speed": 1, "i_d": 4, "i_q": 5})
# slot -> (value signal, status signal) of Measurements, (innovation signal, used flag) of Innovations
MEASUREMENT_SIGNALS: Mapping[str, tuple[str, str]] = MappingProxyType({
    slot: MEASUREMENT_CHANNELS[slot][1:] for slot in MEASUREMENT_SLOTS})
INNOVATION_MESSAGE = "Innovations"
INNOVATION_SIGNALS: Mapping[str, tuple[str, str]] = MappingProxyType({
    "sensor": ("SensorInnovation", "SensorUsed"), "flux": ("FluxMagnetInnovation", "FluxMagnetUsed")})
# DBC 1.8.0: the observer's innovation gate, per slot: its reading rejected this step (in Innovations, beside Used)
# and its sensor flagged (latched until RESET or RESTORE; in Uncertainty1's free bits)
REJECTED_SIGNALS: Mapping[str, str] = MappingProxyType({"sensor": "SensorRejected", "flux": "FluxMagnetRejected"})
FLAG_MESSAGE = "Uncertainty1"
FLAGGED_SIGNALS: Mapping[str, str] = MappingProxyType({"sensor": "SensorFlagged", "flux": "FluxMagnetFlagged"})
SIGMA_SIGNALS: Mapping[str, tuple[tuple[str, int], ...]] = MappingProxyType({
    "Uncertainty1": (("WindingSigma", 1), ("MagnetSigma", 3)),
    "Uncertainty2": (("YokeSigma", 0), ("ToothSigma", 2))})
OBSERVER_MESSAGES: tuple[str, ...] = (*SIGMA_SIGNALS, INNOVATION_MESSAGE)   # per model step, in this order
# messages whose Step names the row of a command or an event (the DBC's comments say which); in every other message
# that carries a Step, it is the data row the frame belongs to (a row's own frames, the replies, timing, checkpoints)
EVENT_STEP_MESSAGES: tuple[str, ...] = ("Control", "ResetTemps1", "ResetTemps2", "RestoreState", "BenchEvent")


def row_signals(width: int) -> tuple[tuple[str, str], ...]:
    """(message, signal) of each value of a data row of `width` values: the 4 drive values, or 6 with the currents."""
    if width == len(DRIVE_SIGNALS):
        return DRIVE_SIGNALS
    if width == len(DRIVE_SIGNALS) + len(CURRENT_SIGNALS):
        return DRIVE_SIGNALS + CURRENT_SIGNALS
    raise ValueError(f"a data row has {len(DRIVE_SIGNALS)} or {len(DRIVE_SIGNALS) + len(CURRENT_SIGNALS)} values, "
                     f"not {width}")


def row_messages(width: int) -> tuple[str, ...]:
    """The messages of a data row of `width` values, in the order they are sent (and must arrive): DriveInputs,
    DriveTemps, then DriveCurrents with the currents."""
    return tuple(dict.fromkeys(message for message, _ in row_signals(width)))
# The firmware engine's timing frame: Cortex-M4F cycles the emulated core counted for a model step, and their time
# at M4_CLOCK_HZ (90 MHz, the clock of the paper's C28x F28069M, so the two µs figures compare cycle for cycle).
# Sent only by a target that runs the compiled firmware; Timing2 carries the C28x estimate beside it.
FIRMWARE_TIMING_MESSAGE = "Timing4"
M4_CLOCK_HZ = 90_000_000
# The firmware target with the motor-control interrupt beside the estimator (bench run --engine firmware
# --isr-rate): the model step's response time (reception -> result) and the interrupt's CPU load, after Timing4.
RESPONSE_TIMING_MESSAGE = "Timing5"
# DBC 1.7.0: a target with an observer sends its filter's checkpoint (extra states, covariance; the order is the
# filter's, `target_sim.observer.Float32Observer.checkpoint`) right after a StateCheckpoint, one element per frame
# named by its Index and the Step mod CHECKPOINT_STEP_LOW_MODULO; a host echoes it in RestoreObserver before RESTORE.
OBSERVER_CHECKPOINT_MESSAGE = "ObserverCheckpoint"
RESTORE_OBSERVER_MESSAGE = "RestoreObserver"
CHECKPOINT_STEP_LOW_MODULO = 1 << 12
CHECKPOINT_EVERY_STEPS = 20   # model steps between two StateCheckpoints (10 s at Δt 0.5 s): the most a restored
                              # target has to re-run, at 4 frames per checkpoint


def step_of(row: int) -> int:
    """The Step signal that carries data row `row`."""
    return row % STEP_MODULO


def nearest_row(step: int, reference: int) -> int:
    """The row whose Step is `step` nearest to row `reference` (a Step names a row only up to 65536)."""
    delta = (step - reference) % STEP_MODULO
    if delta >= STEP_MODULO // 2:
        delta -= STEP_MODULO
    return reference + delta


def latest_row(step: int, last_sent: int) -> int:
    """The most recent row up to `last_sent` whose Step is `step`."""
    return last_sent - ((last_sent - step) % STEP_MODULO)


def split_temperatures(values: Sequence[float],
                       layout: Mapping[str, tuple[tuple[str, int], ...]] = REPLY_SIGNALS) -> dict[str, dict]:
    """[yoke, winding, tooth, magnet] as {message: {signal: value}} of `layout` (REPLY_SIGNALS or RESET_SIGNALS)."""
    return {message: {signal: values[index] for signal, index in signals} for message, signals in layout.items()}


def place_temperatures(message: str, signals: Mapping[str, float], out,
                       layout: Mapping[str, tuple[tuple[str, int], ...]] = REPLY_SIGNALS) -> int:
    """Write the temperatures `message` carries into `out` (indexed in the temperature order); its reply bit."""
    for signal, index in layout[message]:
        out[index] = signals[signal]
    return REPLY_BIT.get(message, 0)


def join_temperatures(frames: Mapping[str, Mapping[str, float]],
                      layout: Mapping[str, tuple[tuple[str, int], ...]] = RESET_SIGNALS) -> list[float]:
    """[yoke, winding, tooth, magnet] from the signals of every message of `layout`."""
    out = [0.0] * STATE_SIZE
    for message in layout:
        place_temperatures(message, frames[message], out, layout)
    return out


def measurement_messages(width: int) -> tuple[str, ...]:
    """The measurement frames of a row whose measurement matrix has `width` columns, in the order they are sent
    (right before the row's DriveInputs): Measurements, then DriveVoltages when the matrix has the voltages."""
    channels = CHANNEL_NAMES[:width]
    if width not in (len(MEASUREMENT_SLOTS), len(CHANNEL_NAMES)):
        raise ValueError(f"a measurement row has {len(MEASUREMENT_SLOTS)} or {len(CHANNEL_NAMES)} values, not {width}")
    return tuple(dict.fromkeys(MEASUREMENT_CHANNELS[c][0] for c in channels))


def channel_values(message: str, signals: Mapping[str, float]) -> dict[str, float]:
    """A measurement frame's values by channel, NaN for a channel whose status is not VALID."""
    return {channel: float(signals[value]) if int(signals[status]) == MeasurementStatus.VALID else float("nan")
            for channel, (name, value, status) in MEASUREMENT_CHANNELS.items() if name == message}


class FrameError(CanLinkError, ValueError):
    """A frame that may not be sent or was rejected on receipt; ``kind`` is one of FRAME_ERROR_KINDS."""

    def __init__(self, kind: FrameErrorKind, message: str) -> None:
        if kind not in FRAME_ERROR_KINDS:
            raise ValueError(f"unknown frame error kind {kind!r}")
        super().__init__(message)
        self.kind: FrameErrorKind = kind
        self.message = message


def model_id_from_sha256(hexdigest: str) -> int:
    """``Status.ModelId`` for an artifact: its sha256's first 8 hex digits as an unsigned 32-bit integer."""
    return int(hexdigest[:8], 16)


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

    @property
    def label(self) -> str:
        """The artifact's spelling, e.g. "lti-lptn"."""
        return self.name.lower().replace("_", "-")

    @classmethod
    def of(cls, label: str) -> ModelKind:
        return cls[label.upper().replace("-", "_")]


class Realization(IntEnum):
    """``TargetInfo.Realization`` (VAL_ table of the DBC)."""

    PHYSICAL = 0
    ORIGINAL = 1
    BALANCED = 2
    MODAL = 3
    DELTA = 4

    @property
    def label(self) -> str:
        return self.name.lower()


class MeasurementStatus(IntEnum):
    """``Measurements.SensorStatus`` / ``FluxMagnetStatus``, ``DriveVoltages.VoltageStatus`` (VAL_ tables of the
    DBC): only a VALID value is used."""

    ABSENT = 0    # no reading in this row
    VALID = 1
    INVALID = 2   # a reading its source flags as unusable (e.g. the flux linkage below its speed)


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


def target_info(signals: Mapping[str, float]) -> dict[str, object]:
    """A TargetInfo frame's signals as the host and the log analysis report them."""
    return {"model_kind": ModelKind(int(signals["ModelKind"])).label,
            "realization": Realization(int(signals["Realization"])).label,
            "dt_s": float(signals["ModelDt"]), "flash_bytes": int(signals["FlashBytes"]),
            "ram_bytes": int(signals["RamBytes"])}


def rx_error_counts(signals: Mapping[str, float]) -> dict[str, int]:
    """An RxErrors frame's counters by error kind."""
    kind_of = {signal: kind for kind, signal in RX_ERROR_SIGNALS.items()}
    return {kind_of.get(signal, signal): int(value) for signal, value in signals.items()}
