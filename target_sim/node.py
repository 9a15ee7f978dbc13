"""The simulated C2000 target as a CAN node: state machine, frame validation, model steps, replies, heartbeat.

Protocol (the DBC's comments are the contract; this is how the target implements it):

* On start the node is IDLE with its artifact loaded: it sends TargetInfo once, then Status and RxErrors every
  100 ms (the heartbeat), and an extra Status at every state change.
* ResetTemps1/ResetTemps2 (any state) store initial temperatures under their Step. Control RESET with the same
  Step sets the model state from them (x0 = C⁻¹y0), clears the latched fault bits, and goes READY (sending
  TargetInfo and Status); without both frames of that Step it sets RESET_INCOMPLETE and goes IDLE.
  RestoreState (any state) stores one element of a state vector under its Step; Control RESTORE with the same
  Step sets the model state x to the four elements bit for bit (y = C x) and goes READY like RESET; without all
  four it sets RESET_INCOMPLETE and goes IDLE. A host echoes a StateCheckpoint the target sent (below), so a
  restarted target continues exactly where the checkpoint left it.
  Control START (only from READY) goes RUNNING and expects the Step it carries as the first data row.
  Control STOP goes STOPPED and forgets the alive counters it expects (the session is over; the next host
  starts its counters at 0). NOP does nothing.
* A data row is the pair DriveInputs + DriveTemps with the same Step, and for a model with an electrical loss
  model (the artifact's `drive_signals` include the d/q currents) the DriveCurrents of that Step after them: the
  row's messages (`dbc.contract.row_messages`), in this order. A row is used only when all its frames passed
  validation, the node is RUNNING, and its Step is the next one or ahead of it. A model with loss maps validates
  DriveCurrents frames like any other and otherwise ignores them. The row then goes into the InputAccumulator
  (the interval-mean rule of `target_sim.model`); when it completes a model step's interval the engine steps
  once (wall time measured with perf_counter_ns). Every used row is answered with Temperatures1 and
  Temperatures2 (Step = the row's Step, the latest estimate: the reset temperatures before the first model
  step), and every model step with Timing1, Timing2, Timing3 (Step = the row that completed it; the firmware node
  adds Timing4, the step's Cortex-M4 cycles), temperatures first so a host waiting for them is not held up by the
  timing frames; after every CHECKPOINT_EVERY_STEPS-th model step since RESET/RESTORE, four StateCheckpoint frames
  (x after that step). The last used row sent again (a host retransmitting a row whose reply it did not get) is
  answered again with the same temperatures and steps nothing (`repeats`).
* A model with an observer (the artifact's `observer` section, `target_sim.observer.node`): the measurement frames
  of a row (Measurements, and DriveVoltages when its observer computes the flux linkage; sent before its
  DriveInputs) are kept; when the row completes, the observer's raw channels — the VALID values of its channels in
  the kept frames of that Step, and the row's own currents for the flux linkage — are more values of the row,
  averaged over the interval with the drive values (none: NaN, and the model step of an interval with such a row
  makes no update with that measurement; with none valid it predicts only). Every model step is then answered,
  after its Timing frames, with Uncertainty1, Uncertainty2 (each node's 1-sigma; Uncertainty1 with each slot's
  sensor flagged by the innovation gate) and Innovations (each used measurement's innovation in its slot, and
  each slot's reading rejected by the gate this step, DBC 1.8.0). RESET resets the covariance to P0. RESTORE
  sets x bit for bit, and the filter's extra states and covariance from the RestoreObserver frames of that Step
  when all came (bit for bit), else the covariance P0. After each StateCheckpoint the node sends its
  ObserverCheckpoint. A model without an observer validates the observer's frames and ignores them.
* Sequence errors (counted, SEQUENCE fault bit, nothing reaches the model): a drive frame outside RUNNING, a
  DriveTemps without its DriveInputs (a DriveCurrents without its DriveTemps), a row whose frames have different
  Steps, a DriveInputs whose row never completed, a row that goes back (or repeats one before the last: not
  answered), START outside READY. A row ahead of the expected one (rows lost on the bus) is one sequence error;
  the lost rows are left out of their intervals' means, a model step whose interval ended among them runs on the
  rows of it that did arrive (or holds the previous step's inputs if none did, but not an observer's measurement),
  so the model keeps time, and then the row is used. A Measurements frame of another Step than the row it precedes
  is a sequence error too (the row is used, without a measurement).
* Rejected frames (unknown id, wrong length, CRC, signal out of range, alive-counter jump: `dbc.FrameValidator`)
  are counted per kind and set RX_ERROR; they change nothing else. Nothing a frame carries can crash the node:
  an unexpected exception sets INTERNAL and the state FAULT (a RESET recovers).
* This class is the reference implementation (`--engine python`); the firmware engine runs the same rules as
  compiled C in the emulated core (`target_sim.firmware.node_engine.FirmwareNode`, bench/firmware/node.c), and
  the conformance suite (tests/target_sim/test_conformance.py) holds the two to the same bytes.
* Transmitted temperatures outside the DBC range are clamped (SATURATED; NaN or Inf also set NONFINITE), so a
  diverging float32 model (e.g. the `original` realization) is still answered.
* Any other frame the DBC sends to the target (BenchEvent, a bench host's marks of injected faults and gaps;
  DriveCurrents for a model that reads no current; a message added to the DBC that no rule acts on yet) is
  validated like every frame and otherwise ignored.
* Detection journal: with a `journal` callable the node reports every rejected frame and every sequence error
  as one record {"kind": one of RX_ERROR_KINDS, "id", "dlc", "data" (hex), "detail"} naming the frame it judged,
  so a fault-injecting bench can tell which injected frame was caught and why (`host.faults.reconcile`);
  `python -m target_sim --events FILE` appends them to a file that survives a SIGKILL. The counters in RxErrors
  are the same events counted (8 bits, saturating).
"""

from __future__ import annotations

import gc
import math
import os
import sys
import time
from collections.abc import Callable, Iterable

import can
import numpy as np

from dbc.codec import FrameCodec, FrameValidator, decode_any
from dbc.contract import (
    CHANNEL_NAMES,
    CHECKPOINT_EVERY_STEPS,
    CHECKPOINT_STEP_LOW_MODULO,
    INNOVATION_MESSAGE,
    OBSERVER_CHECKPOINT_MESSAGE,
    OBSERVER_MESSAGES,
    REPLY_SIGNALS,
    RESET_SIGNALS,
    RESTORE_OBSERVER_MESSAGE,
    RX_ERROR_KINDS,
    RX_ERROR_SIGNALS,
    STATE_SIZE,
    STEP_MODULO,
    Command,
    FaultBit,
    FrameError,
    ModelKind,
    Realization,
    TargetState,
    channel_values,
    join_temperatures,
    row_messages,
    row_signals,
)
from dbc.database import dbc_version_info, frame_id, signal_ranges, target_frame_ids, temperature_range
from dbc.database import heartbeat_period_s as heartbeat_period_s_of_dbc
from dbc.loopback_filter import drop_own_frames
from dbc.transport import IN_USE_LISTEN_S, OwnFrameFilter, SpinPolicy, first_heard
from dbc.xcp import cmd_id as xcp_cmd_id
from dbc.xcp import res_id as xcp_res_id
from target_sim.artifact import ModelArtifact
from target_sim.costs import memory_estimate, step_cost
from target_sim.faults import ReplyFaults
from target_sim.model import Float32Estimator, InputAccumulator
from target_sim.observer import has_observer
from target_sim.observer.node import NodeObserver, observer_signals
from target_sim.xcp import node_slave
from target_sim.xcp.codes import PID_ERR, Err
from target_sim.xcp.daq import EVENT_HEARTBEAT, EVENT_MODEL_STEP

SPIN_S = float(os.environ.get("TARGET_SIM_SPIN_S", "0.0003"))  # busy-poll before blocking (0 disables)


def _clamp(value: float, limits: tuple[float, float]) -> float:
    return min(max(value, limits[0]), limits[1])


class RowAccumulator(InputAccumulator):
    """The interval-mean rule (`InputAccumulator`), plus what to do with rows lost on the bus (see the module
    docstring)."""

    def __init__(self, sample_period_s: float, dt_s: float, width: int = 4, measured: int = 0):
        super().__init__(sample_period_s, dt_s, width)
        self.last_inputs: np.ndarray | None = None
        self.measured = measured   # the last values are an observer's raw channels: never held over a step

    def add(self, row: int, sample) -> np.ndarray | None:
        """Add row `row`; the inputs of its model step if this row completes the interval."""
        mean = super().add(row, sample)
        if mean is not None:
            self.last_inputs = mean
        return mean

    def skip(self, first: int, stop: int) -> list[np.ndarray]:
        """Rows first..stop-1 were lost: the inputs of each model step whose interval ended among them."""
        inputs = []
        for row in range(first, stop):
            if not self.ends_interval(row):
                continue
            mean = self.mean()                # the rows of the interval that did arrive
            if mean is not None:
                self.last_inputs = mean
            elif self.last_inputs is not None:
                mean = self.last_inputs.copy()  # none did: hold the previous step's inputs
                if self.measured:
                    mean[-self.measured:] = np.float32(np.nan)   # but not its measurements: it predicts only
            else:
                continue  # nothing ever arrived: no inputs to step on
            inputs.append(mean)
        return inputs

    def reset(self) -> None:
        self.clear()
        self.last_inputs = None


class TargetNode:
    """The target's behaviour on the bus, without the bus: `handle(frame)` returns the frames to send."""

    engine = "python"

    def __init__(self, artifact: ModelArtifact, *, clock_ns: Callable[[], int] = time.perf_counter_ns,
                 journal: Callable[[dict], None] | None = None, xcp_elf: str | os.PathLike | None = None):
        self.artifact = artifact
        self.journal = journal
        self._msg: can.Message | None = None
        # with an observer section the model steps through the filter (`target_sim.observer.node`); x, y and the
        # checkpoints are its estimator's
        self.observer = NodeObserver(artifact) if has_observer(artifact) else None
        self.model = self.observer.model if self.observer is not None else Float32Estimator(artifact)
        # the compiled step where it covers the model (`target_sim.compiled`, bit for bit the numpy step), else numpy;
        # numba loads only here, with the first node of a process
        from target_sim.compiled import compiled_step

        self.model_step = (compiled_step(self.model) if self.observer is None else None) or self.model.step
        self.cost = step_cost(artifact)
        self.memory = memory_estimate(artifact, self.cost)
        self.dt_ns = int(round(artifact.dt * 1e9))
        self.clock_ns = clock_ns
        self.codec = FrameCodec("TARGET")
        self.validator = FrameValidator("TARGET")
        self.state = TargetState.IDLE
        self.faults = FaultBit(0)
        self.errors = dict.fromkeys(RX_ERROR_KINDS, 0)
        self.last_error = ""
        width = len(artifact.drive_signals)    # 4 drive values, 6 with the d/q currents
        # an observer's raw channels are more values of the row, averaged over the interval with the drive values
        channels = self.observer.channels if self.observer is not None else 0
        self.accumulator = RowAccumulator(artifact.data_sample_period, artifact.dt, width + channels,
                                          measured=channels)
        # message -> (Step, {channel: value}) of the last measurement frame of each kind the observer reads
        self._measurement: dict[str, tuple[int, dict[str, float]]] = {}
        self._observer_restore: dict[int, dict] = {}    # RestoreObserver elements by Index
        self.row_messages = row_messages(width)    # DriveInputs, DriveTemps (, DriveCurrents): a row, in order
        self._row_index = {name: index for index, name in enumerate(self.row_messages)}
        self._row_signals = row_signals(width)
        self._reset_frames: dict[str, dict] = {}
        self._restore_frames: dict[int, dict] = {}
        self.last_reply_row: int | None = None
        self.repeats = 0
        self.answered_again = False    # the last handle() answered a row again (a retransmission)
        self._rest: Callable[[], list[can.Message]] | None = None   # the rest of the frame's replies (handle_split)
        self._pending: list[dict] = []     # the frames of the row being received, in row order
        self.next_row: int | None = None
        self.rows_used = 0
        self.model_steps = 0
        self.overruns = 0
        self.frames_received = 0
        self.estimate = np.zeros(STATE_SIZE, dtype=np.float32)
        self._version = dbc_version_info()
        self._temp_limits = temperature_range()
        self._state_limits = signal_ranges("StateCheckpoint")["StateValue"]
        self._timing1_limits = signal_ranges("Timing1")["StepTimeMeasured"]
        timing2, timing3 = signal_ranges("Timing2"), signal_ranges("Timing3")
        self._timing2 = {"EstCycles": _clamp(self.cost.cycles, timing2["EstCycles"]),
                         "EstExecTime": _clamp(round(self.cost.exec_time_us, 1), timing2["EstExecTime"])}
        self._timing3 = {"CpuLoad": _clamp(round(self.cost.cpu_load_percent(artifact.dt), 4), timing3["CpuLoad"])}
        self._sigma_limits = signal_ranges("Uncertainty1")["WindingSigma"]
        self._innovation_limits = signal_ranges(INNOVATION_MESSAGE)["SensorInnovation"]
        # the XCP slave (`target_sim.xcp`): its cells at the addresses of the firmware ELF `xcp_elf` when given
        self.xcp = node_slave(self, xcp_elf)
        self.xcp_cmd_id, self.xcp_res_id = xcp_cmd_id(), xcp_res_id()

    # ------------------------------------------------------------------ frames the node sends
    def _encode(self, name: str, signals: dict) -> list[can.Message]:
        try:
            return [self.codec.encode(name, signals)]
        except (FrameError, ValueError) as exc:  # a value the DBC cannot carry: should not happen, never fatal
            self.faults |= FaultBit.INTERNAL
            self.last_error = f"cannot send {name}: {exc}"
            return []

    def status_frames(self) -> list[can.Message]:
        return self._encode("Status", {
            "State": int(self.state), "FaultBits": int(self.faults), "ModelId": self.artifact.model_id,
            "DbcVersionMajor": self._version[0], "DbcVersionMinor": self._version[1]})

    def rx_error_frames(self) -> list[can.Message]:
        return self._encode("RxErrors", {signal: min(self.errors[kind], 255)
                                         for kind, signal in RX_ERROR_SIGNALS.items()})

    def target_info_frames(self) -> list[can.Message]:
        limits = signal_ranges("TargetInfo")
        return self._encode("TargetInfo", {
            "ModelKind": int(ModelKind.of(self.artifact.kind)),
            "Realization": int(Realization[self.artifact.realization.upper()]),
            "ModelDt": _clamp(round(self.artifact.dt, 1), limits["ModelDt"]),
            "FlashBytes": _clamp(self.memory.flash_bytes, limits["FlashBytes"]),
            "RamBytes": _clamp(self.memory.ram_bytes, limits["RamBytes"])})

    def startup_frames(self) -> list[can.Message]:
        return self.target_info_frames() + self.status_frames() + self.rx_error_frames()

    def heartbeat_frames(self) -> list[can.Message]:
        """Status and RxErrors, then the DAQ packets of the XCP time event (the heartbeat tick)."""
        return self.status_frames() + self.rx_error_frames() + self._xcp_packets(self.xcp.event(EVENT_HEARTBEAT))

    def _temperature_frames(self, step: int) -> list[can.Message]:
        values = []
        limits = self._temp_limits
        for value in self.estimate.tolist():
            if not math.isfinite(value):
                self.faults |= FaultBit.NONFINITE | FaultBit.SATURATED
                value = limits[1] if value > 0 or math.isnan(value) else limits[0]
            elif not limits[0] <= value <= limits[1]:
                self.faults |= FaultBit.SATURATED
                value = _clamp(value, limits)
            values.append(value)
        out = []
        for name, signals in REPLY_SIGNALS.items():   # split_temperatures, straight into each frame's signals
            frame_signals = {"Step": step}
            for signal, index in signals:
                frame_signals[signal] = values[index]
            out += self._encode(name, frame_signals)
        return out

    def _timing_frames(self, step: int, elapsed_ns: int) -> list[can.Message]:
        measured = _clamp(round(elapsed_ns / 1000.0, 1), self._timing1_limits)
        return (self._encode("Timing1", {"Step": step, "StepTimeMeasured": measured,
                                         "Overruns": min(self.overruns, 255)})
                + self._encode("Timing2", {"Step": step, **self._timing2})
                + self._encode("Timing3", {"Step": step, **self._timing3}))

    def _observer_frames(self, step: int) -> list[can.Message]:
        """Uncertainty1, Uncertainty2 and Innovations after a model step of the observer."""
        observer = self.observer
        signals = observer_signals(observer.sigma(), observer.innovations(), self._sigma_limits,
                                   self._innovation_limits, observer.gate_status())
        return [frame for name in OBSERVER_MESSAGES for frame in self._encode(name, {"Step": step, **signals[name]})]

    # ------------------------------------------------------------------ receiving
    def _set_state(self, state: TargetState) -> list[can.Message]:
        changed = state != self.state
        self.state = state
        return self.status_frames() if changed else []

    def _sequence_error(self, why: str) -> list[can.Message]:
        self.errors["sequence"] += 1
        self.faults |= FaultBit.SEQUENCE
        self.last_error = why
        self._record("sequence", why)
        return []

    def _record(self, kind: str, detail: str) -> None:
        """One journal record about the frame being handled (no-op without a journal)."""
        if self.journal is None or self._msg is None:
            return
        msg = self._msg
        self.journal({"kind": kind, "id": msg.arbitration_id, "dlc": msg.dlc, "data": bytes(msg.data).hex(),
                      "detail": detail})

    def _xcp_packets(self, packets: Iterable[bytes]) -> list[can.Message]:
        return [can.Message(arbitration_id=self.xcp_res_id, is_extended_id=False, data=packet) for packet in packets]

    def _xcp_command(self, msg: can.Message) -> list[can.Message]:
        """An XCP command (`target_sim.xcp`): its reply, never a frame error of the contract, never a model step."""
        try:
            reply = self.xcp.command(bytes(msg.data))
        except Exception as exc:  # noqa: BLE001 - a calibration master must not end the node
            self.last_error = f"internal error on an XCP command {bytes(msg.data).hex()}: {exc!r}"
            reply = bytes((PID_ERR, Err.GENERIC))
        return self._xcp_packets(() if reply is None else (reply,))

    def handle(self, msg: can.Message) -> list[can.Message]:
        """Validate one received frame, act on it, and return the frames to send in reply (maybe none)."""
        frames, rest = self.handle_split(msg)
        return frames if rest is None else frames + rest()

    def handle_split(self, msg: can.Message) -> tuple[list[can.Message], Callable[[], list[can.Message]] | None]:
        """`handle` in two parts: the frames to send first, and what builds the rest once they are out (None: no
        rest). A row's temperature replies come first; its model step's Timing, observer, checkpoint and DAQ frames
        are encoded only after them, so a host waiting for the temperatures does not wait for that (`serve`)."""
        self._rest = None
        frames = self._handle(msg)
        rest, self._rest = self._rest, None
        if rest is None:
            return frames, None

        def finish() -> list[can.Message]:
            try:
                return rest()
            except Exception as exc:  # noqa: BLE001 - as in `_handle`: the node survives, in FAULT
                self.faults |= FaultBit.INTERNAL
                self.last_error = f"internal error after a row's replies: {exc!r}"
                return self._set_state(TargetState.FAULT)
        return frames, finish

    def _handle(self, msg: can.Message) -> list[can.Message]:
        if msg.arbitration_id == self.xcp_cmd_id and not msg.is_extended_id and not msg.is_remote_frame:
            self.answered_again = False
            return self._xcp_command(msg)
        self.frames_received += 1
        self._msg = msg
        self.answered_again = False
        try:
            frame = self.validator.validate(msg)
        except FrameError as exc:
            self.errors[exc.kind] += 1
            self.faults |= FaultBit.RX_ERROR
            self.last_error = exc.message
            self._record(exc.kind, exc.message)
            return []
        except Exception as exc:  # noqa: BLE001 - a frame the codec cannot even judge must not end the node
            self.faults |= FaultBit.INTERNAL | FaultBit.RX_ERROR
            self.last_error = f"frame 0x{msg.arbitration_id:X} could not be validated: {exc!r}"
            return []
        try:
            return self._dispatch(frame.name, frame.signals)
        except Exception as exc:  # noqa: BLE001 - the node must survive anything a frame causes
            self.faults |= FaultBit.INTERNAL
            self.last_error = f"internal error on {frame.name}: {exc!r}"
            return self._set_state(TargetState.FAULT)

    def _dispatch(self, name: str, signals: dict) -> list[can.Message]:
        index = self._row_index.get(name)
        if index is not None:
            return self._row_frame(name, index, signals)
        if name in RESET_SIGNALS:
            self._reset_frames[name] = signals
            return []
        if name == "RestoreState":
            self._restore_frames[int(signals["StateIndex"])] = signals
            return []
        if name == "Control":
            return self._control(Command(int(signals["Command"])), int(signals["Step"]))
        if self.observer is not None and name in self.observer.messages:
            self._measurement[name] = (int(signals["Step"]), channel_values(name, signals))
            return []
        if name == RESTORE_OBSERVER_MESSAGE:
            self._observer_restore[int(signals["Index"])] = signals
            return []
        return []  # a frame of the contract no rule acts on (BenchEvent, unread DriveCurrents, ...): validated only

    def _row_frame(self, name: str, index: int, signals: dict) -> list[can.Message]:
        """One frame of a data row, the `index`-th of the row's messages: the row is used when its last one comes
        after all the others, in order and of the same Step."""
        pending, row = self._pending, self.row_messages
        first = row[0]
        if index == 0:
            out = []
            if pending:
                out = self._sequence_error(f"{first} of step {pending[0]['Step']} had no {row[len(pending)]}")
            self._pending = [signals]
            return out
        if len(pending) != index:
            self._pending = []
            if len(pending) < index:
                return self._sequence_error(f"{name} of step {signals['Step']} without its {row[len(pending)]}")
            return self._sequence_error(f"{first} of step {pending[0]['Step']} had no {row[len(pending)]}")
        if pending[0]["Step"] != signals["Step"]:
            self._pending = []
            return self._sequence_error(f"{first} step {pending[0]['Step']} paired with {name} step "
                                        f"{signals['Step']}")
        if index + 1 < len(row):
            pending.append(signals)
            return []
        self._pending = []
        frames = dict(zip(row, (*pending, signals), strict=True))
        sample = tuple([frames[message][signal] for message, signal in self._row_signals])
        if self.observer is not None:
            sample += self.observer.raw(sample, self._measured(int(signals["Step"])))
        return self._row(int(signals["Step"]), sample)

    def _measured(self, step: int) -> list[float]:
        """The host's measurement channels for the row of `step` (NaN: none): the VALID values of the measurement
        frames of that Step that came before the row. A measurement frame of another Step is a sequence error; a
        row without one (lost, refused, not sent) has none of its channels."""
        pending, self._measurement = self._measurement, {}
        out = [float("nan")] * len(CHANNEL_NAMES)
        for message, (at, values) in pending.items():
            if at != step:
                self._sequence_error(f"{message} of step {at} before the row of step {step}")
                continue
            for channel, value in values.items():
                out[CHANNEL_NAMES.index(channel)] = value
        return out

    def _control(self, command: Command, step: int) -> list[can.Message]:
        if command == Command.RESET:
            frames, self._reset_frames = self._reset_frames, {}
            if len(frames) != len(RESET_SIGNALS) or any(f["Step"] != step for f in frames.values()):
                return self._incomplete(f"RESET of step {step} without {' and '.join(RESET_SIGNALS)} of that step")
            (self.observer or self.model).reset(join_temperatures(frames, RESET_SIGNALS))
            return self._ready()
        if command == Command.RESTORE:
            elements, self._restore_frames = self._restore_frames, {}
            state = [elements[i]["StateValue"] for i in range(STATE_SIZE)
                     if i in elements and elements[i]["Step"] == step]
            if len(state) != STATE_SIZE:
                return self._incomplete(f"RESTORE of step {step} without the {STATE_SIZE} RestoreState elements "
                                        "of that step")
            if self.observer is not None:
                self.observer.restore(state, self._restored_checkpoint(step))
            else:
                self.model.restore(state)
            return self._ready()
        if command == Command.START:
            if self.state != TargetState.READY:
                return self._sequence_error(f"START in state {self.state.name} (needs READY after a RESET)")
            self.next_row = step
            return self._set_state(TargetState.RUNNING)
        if command == Command.STOP:
            self.validator.reset_counters()
            self._pending = []
            self._measurement = {}
            return self._set_state(TargetState.STOPPED)
        return []

    def _restored_checkpoint(self, step: int) -> dict[int, float]:
        """The RestoreObserver elements {Index: value} of the RESTORE's Step (the observer uses them only when every
        element came; else its covariance starts again at P0)."""
        elements, self._observer_restore = self._observer_restore, {}
        low = step % CHECKPOINT_STEP_LOW_MODULO
        return {i: f["Value"] for i, f in elements.items() if f["StepLow"] == low}

    def _incomplete(self, why: str) -> list[can.Message]:
        """A RESET or RESTORE without its data: nothing of the model changes, the node waits in IDLE."""
        self.faults |= FaultBit.RESET_INCOMPLETE
        self.last_error = why
        return self._set_state(TargetState.IDLE)

    def _ready(self) -> list[can.Message]:
        """After the model state was set (RESET or RESTORE): a fresh interval, counters and latched faults."""
        self.estimate = self.model.y.copy()
        self.accumulator.reset()
        self._pending = []
        self._measurement = {}
        self.next_row = None
        self.last_reply_row = None
        self.rows_used = self.model_steps = self.overruns = 0
        self.faults &= FaultBit.NO_ARTIFACT
        self.state = TargetState.READY
        return self.target_info_frames() + self.status_frames()

    def _checkpoint_frames(self, step: int) -> list[can.Message]:
        """The model state x after this row's model step, one frame per element; none if x cannot be carried
        (a diverging model: the host then re-initializes from an older checkpoint)."""
        state = self.model.x.tolist()
        if len(state) != STATE_SIZE or not all(self._state_limits[0] <= v <= self._state_limits[1] for v in state):
            return []
        frames = [frame for index, value in enumerate(state)
                  for frame in self._encode("StateCheckpoint", {"Step": step, "StateIndex": index,
                                                                "StateValue": value})]
        return frames + self._observer_checkpoint_frames(step)

    def _observer_checkpoint_frames(self, step: int) -> list[can.Message]:
        """The observer's checkpoint after the StateCheckpoint of the same row, one frame per element; none
        without an observer or when an element cannot be carried (a restore then starts P at P0)."""
        if self.observer is None:
            return []
        values = self.observer.checkpoint().tolist()
        if not all(self._state_limits[0] <= v <= self._state_limits[1] for v in values):
            return []
        low = step % CHECKPOINT_STEP_LOW_MODULO
        return [frame for index, value in enumerate(values)
                for frame in self._encode(OBSERVER_CHECKPOINT_MESSAGE, {"Index": index, "StepLow": low,
                                                                        "Value": value})]

    def _row(self, step: int, sample) -> list[can.Message]:
        if self.state != TargetState.RUNNING or self.next_row is None:
            return self._sequence_error(f"drive frames of step {step} in state {self.state.name}")
        ahead = (step - self.next_row) % STEP_MODULO
        if self.last_reply_row is not None and step == self.last_reply_row % STEP_MODULO:
            # the host sent the last row again (its reply did not reach it): answer again, step nothing
            self.repeats += 1
            self.answered_again = True
            return self._temperature_frames(step)
        if ahead >= STEP_MODULO // 2:
            return self._sequence_error(f"step {step} repeats or goes back (expected {self.next_row % STEP_MODULO})")
        out: list[can.Message] = []
        row = self.next_row + ahead
        inputs = []
        if ahead:
            self._sequence_error(f"steps {self.next_row % STEP_MODULO}..{(row - 1) % STEP_MODULO} never arrived")
            inputs = self.accumulator.skip(self.next_row, row)
        self.next_row = row + 1
        self.rows_used += 1
        mean = self.accumulator.add(row, sample)
        if mean is not None:
            inputs.append(mean)
        timing = []
        observer = self.observer
        step_model = self.model_step if observer is None else (lambda *values: observer.step(values))
        observed = []
        daq: list[bytes] = []
        for step_inputs in inputs:
            started = self.clock_ns()
            self.estimate = step_model(*step_inputs)
            elapsed = self.clock_ns() - started
            if observer is not None:
                observed.append(self._observer_frames(step))
            self.model_steps += 1
            if elapsed > self.dt_ns:
                self.overruns += 1
                self.faults |= FaultBit.OVERRUN
            timing.append(elapsed)
            daq += self.xcp.event(EVENT_MODEL_STEP)     # sampled right after its step, sent after its replies
        out += self._temperature_frames(step)
        self.last_reply_row = row
        checkpoint = bool(timing) and self.model_steps % CHECKPOINT_EVERY_STEPS == 0

        def rest() -> list[can.Message]:   # after the temperatures (`handle_split`)
            frames = []
            for index, elapsed in enumerate(timing):
                frames += self._timing_frames(step, elapsed)
                if observed:
                    frames += observed[index]
            if checkpoint:
                frames += self._checkpoint_frames(step)
            return frames + self._xcp_packets(self.xcp.queued(daq))

        self._rest = rest
        return out

    # ------------------------------------------------------------------ reporting
    def stats(self) -> dict:
        return {"state": self.state.name, "faults": [bit.name for bit in FaultBit if bit & self.faults],
                "errors": dict(self.errors), "frames_received": self.frames_received, "rows_used": self.rows_used,
                "repeats": self.repeats,
                "model_steps": self.model_steps, "overruns": self.overruns, "last_error": self.last_error,
                "model_id": self.artifact.model_id, "engine": self.engine, "est_cycles": self.cost.cycles,
                "m4_cycles": None, "flash_bytes": self.memory.flash_bytes, "ram_bytes": self.memory.ram_bytes,
                "memory": "C28x estimate", "xcp": self.xcp.stats()}


def target_on_channel(bus: can.BusABC, listen_s: float = IN_USE_LISTEN_S) -> tuple[int, int | None] | None:
    """(frame id, model id) of a target already sending on `bus` — the model id from its heartbeat, None when
    only another of its frames was heard — or None when none is heard within `listen_s`."""
    status_id = frame_id("Status")
    heard = first_heard(bus, target_frame_ids(), listen_s, prefer=status_id)  # a heartbeat names the model
    if heard is None:
        return None
    if heard.arbitration_id != status_id:   # a target is there: wait one heartbeat period for it to name its model
        heard = first_heard(bus, {status_id}, heartbeat_period_s_of_dbc() + listen_s) or heard
    try:
        model_id = int(decode_any(heard).signals["ModelId"]) if heard.arbitration_id == status_id else None
    except FrameError:
        model_id = None
    return heard.arbitration_id, model_id


def serve(node: TargetNode, bus: can.BusABC, should_stop: Callable[[], bool],
          heartbeat_period_s: float | None = None, on_error: Callable[[str], None] | None = None,
          spin_s: float | None = None, reply_faults: ReplyFaults | None = None) -> None:
    """Run the node on a bus until `should_stop()`: receive, handle, reply; heartbeat every period.

    With `reply_faults` the replies go out through the fault layer (`target_sim.faults`); the heartbeat period
    is the DBC's unless given."""
    heartbeat_period_s = heartbeat_period_s or heartbeat_period_s_of_dbc()
    own = OwnFrameFilter(target_frame_ids() | {xcp_res_id()})   # the XCP slave's packets loop back too
    drop_own_frames(bus, own.own_ids)   # udp_multicast: the kernel drops the copies before they wake us (Linux)
    foreign = reply_faults.foreign_ids if reply_faults is not None else set()
    send_failures = 0

    def send(frames: Iterable[can.Message]) -> None:
        nonlocal send_failures
        for frame in frames:
            try:
                bus.send(frame)
            except can.CanError as exc:
                send_failures += 1
                if on_error is not None and send_failures in (1, 10, 100, 1000):
                    on_error(f"sending 0x{frame.arbitration_id:03X} failed ({exc}); {send_failures} so far")

    monotonic = time.monotonic
    gc.freeze()  # everything loaded so far is permanent: keep it out of the collector's scans
    send(node.startup_frames())
    next_beat = monotonic() + heartbeat_period_s
    perf = time.perf_counter
    spin = SpinPolicy(SPIN_S if spin_s is None else spin_s)
    split = getattr(node, "handle_split", None)   # the Python node: a row's temperatures out before the rest
    faulted = node.state == TargetState.FAULT
    while not should_stop():
        # what already waits first; then poll briefly before sleeping (`SpinPolicy`: in lockstep the next frame is
        # usually microseconds away, and waking a sleeping process costs more than the poll, unless the machine
        # is loaded)
        msg = bus.recv(0.0)
        if msg is None:
            started = perf()
            until = started + spin.budget()
            while msg is None and perf() < until:
                msg = bus.recv(0.0)
            blocked = msg is None
            if blocked:
                msg = bus.recv(max(0.0, next_beat - monotonic()))
            if msg is not None:
                spin.waited(perf() - started, blocked=blocked)
        if msg is not None and not own.is_own(msg):
            if foreign and not msg.is_extended_id and msg.arbitration_id in foreign:
                continue  # our own reply fault on a foreign id, looped back
            replies, rest = split(msg) if split is not None else (node.handle(msg), None)
            if reply_faults is not None:
                replies = reply_faults.apply(replies, again=node.answered_again)
            send(replies)
            if rest is not None:     # a row's timing, checkpoint and DAQ frames: after its temperatures went out
                more = rest()
                send(more if reply_faults is None else reply_faults.apply(more, again=node.answered_again))
            if node.state == TargetState.FAULT and not faulted and on_error is not None:
                on_error(f"internal fault, state FAULT until a RESET: {node.last_error}")
            faulted = node.state == TargetState.FAULT
        now = monotonic()
        if now >= next_beat:
            send(node.heartbeat_frames())
            next_beat += heartbeat_period_s
            if next_beat <= now:
                next_beat = now + heartbeat_period_s


def log_error(message: str) -> None:
    print(f"target_sim: {message}", file=sys.stderr, flush=True)
