"""The firmware engine: the whole target node (bench/firmware/node.c with the model) in the emulated Cortex-M4F.

    node = FirmwareNode(artifact, "firmware.elf")     # FirmwareError: another core, another model, no node_*
    node.startup_frames(); node.handle(msg) -> frames; node.heartbeat_frames(); node.stats()

The Python side only moves frames: a received frame goes into the MCU's receive mailbox (`node_rx`) and
`node_on_frame` runs, one call per frame (through `Firmware.caller`, which also reads the output's head back with
the stack's guard word); what the firmware queued (`node_out.tx`) goes out as python-can messages, in order
(`node_on_tick` queues the heartbeat); its journal records (`node_out.events`) go to `journal` with the frame
they judged. Every rule of the protocol is the
firmware's; this class has the interface of the Python reference node (`target_sim.node.TargetNode`), so `serve`,
the bench and the conformance tests drive either.

A fault of the emulated core (invalid access, hard fault, endless loop: `FirmwareFault`, one sentence) is the
node's INTERNAL fault: the shell calls `node_internal_fault`, which sets the fault bit and the state FAULT and
queues a Status, so the heartbeat reports it and a RESET recovers. If even that call faults, the shell resets the
core as a watchdog would (RAM re-initialized, `node_init`) and reports the fault from the fresh node.

With `isr_rate_hz` (a timing image: the node and the model with the field-oriented current loop's interrupt,
`target_sim.firmware.motor_control`) the core is an `InterruptedFirmware`: the interrupt preempts every call at
that rate, each call is a job released when the shell's clock (`clock_s`, the bus's time) says the frame arrived,
on the core's timeline at M4_CLOCK_HZ (the idle time between frames skipped, `IDLE_LOOKBACK`), and the shell
writes that release as the CAN controller's time stamp (`node_rx_stamp`, DWT cycles) from which the node times
each step's response (Timing5). The bytes of every other frame are those of the run without the interrupt.

Measured per call: the cycles of `node_on_frame` (the emulator's count) minus those of the model steps in it (the
firmware's DWT reads): frame handling per received frame, and per reply frame for calls that queued replies. A frame of
the XCP command id (dbc/xcp.toml) goes to `node_on_xcp` instead (bench/firmware/xcp.c; a CAN controller's filter
would route it to its own FIFO): its cycles are counted apart (`xcp_cycles`), and so is each DAQ sample (the
firmware's DWT reads around it, `xcp_counters`).
"""

from __future__ import annotations

import os
import struct
import time
from collections import Counter
from collections.abc import Callable
from functools import partial
from types import SimpleNamespace

import can
import numpy as np

from dbc.contract import FIRMWARE_TIMING_MESSAGE, M4_CLOCK_HZ, RX_ERROR_KINDS, FaultBit, TargetState
from dbc.database import frame_id, layout_named
from dbc.xcp import cmd_id as xcp_cmd_id
from target_sim.artifact import ModelArtifact
from target_sim.costs import step_cost
from target_sim.firmware.elf import ElfImage, FirmwareError, memory_from_elf, read_elf
from target_sim.firmware.emulator import Firmware, FirmwareFault
from target_sim.firmware.interrupts import InterruptedFirmware
from target_sim.firmware.motor_control import interrupt_figures, motor_control_core, start_motor_control
from target_sim.firmware.node_protocol import (
    COUNTERS,
    COUNTERS_SIZE,
    EVENT,
    FRAME,
    ID_ERROR,
    ID_EXTENDED,
    ID_FD,
    ID_REMOTE,
    OUTPUT_HEADER,
    TX_OFFSET,
    WHY_CODES,
    Event,
    firmware_refusal,
    output_layout,
    tx_capacity,
)

ENTRY_POINTS = ("node_init", "node_on_frame", "node_on_xcp", "node_on_tick", "node_internal_fault")
BUFFERS = ("node_rx", "node_out", "node_counters", "fw_model_id")
XCP_COUNTERS = struct.Struct("<7I")      # xcp.c's struct xcp_counters
_MASK32 = 0xFFFF_FFFF
_STATES = {int(state): state for state in TargetState}   # the enum by value without its call's cost per frame
PREFETCH_FRAMES = 8      # frames read with the output's header (a row's replies: 2 temperatures, 4 timing frames)
PREFETCH_SPAN = TX_OFFSET + PREFETCH_FRAMES * FRAME.size
_XCP_SAMPLES = struct.Struct("<2I")     # xcp_counters' DAQ samples and their cycles (its last two words)
_XCP_SAMPLES_OFFSET = XCP_COUNTERS.size - _XCP_SAMPLES.size


def _ms(seconds: float) -> int:
    return int(seconds * 1000.0) & _MASK32


def cycle_figures(cycles: Counter[int]) -> dict[str, int | None]:
    """p50 (the lower median) and max of counted cycles (None before the first)."""
    if not cycles:
        return {"p50": None, "max": None}
    values = sorted(cycles)
    seen, half = 0, (sum(cycles.values()) + 1) // 2
    for value in values:
        seen += cycles[value]
        if seen >= half:
            return {"p50": value, "max": values[-1]}
    return {"p50": values[-1], "max": values[-1]}


class FirmwareNode:
    """The target node as compiled firmware in the emulated Cortex-M4F (see the module docstring)."""

    engine = "firmware"

    def __init__(self, artifact: ModelArtifact, elf: str | os.PathLike | bytes | ElfImage, *,
                 clock_s: Callable[[], float] = time.monotonic, journal: Callable[[dict], None] | None = None,
                 core: Callable[[ElfImage], Firmware] = Firmware, isr_rate_hz: float = 0.0, isr_seed: int = 0):
        refusal = firmware_refusal(artifact)   # before the ELF is read: a loss model the firmware has not
        if refusal is not None:
            raise FirmwareError(refusal)
        image = elf if isinstance(elf, ElfImage) else read_elf(elf)
        self.artifact = artifact
        self.journal = journal
        self.clock_s = clock_s
        self.name = image.name
        if isr_rate_hz:
            core = partial(motor_control_core, rate_hz=isr_rate_hz)
        self.isr_rate_hz = isr_rate_hz
        self.fw = fw = core(image)      # `core`: e.g. an interrupted core (bench firmware timing)
        missing = [name for name in (*ENTRY_POINTS, *BUFFERS) if name not in fw.symbols]
        if missing:
            raise FirmwareError(f"{image.name} has no {', '.join(missing)}: it is not a node firmware of "
                                "'bench firmware build'; rebuild it")
        self._events_offset, output_size = output_layout(tx_capacity(artifact))
        layout = {"node_out": output_size, "node_counters": COUNTERS_SIZE, "node_rx": FRAME.size}
        wrong = [f"{name} is {fw.symbols[name].size} bytes, not {size}" for name, size in layout.items()
                 if fw.symbols[name].size != size]
        if wrong:
            raise FirmwareError(f"{image.name} has another node layout than this bench ({'; '.join(wrong)}); "
                                "rebuild it with 'bench firmware build'")
        model_id = int.from_bytes(fw.read_bytes(fw.address("fw_model_id"), 4), "little")
        if model_id != artifact.model_id:
            raise FirmwareError(f"{image.name} is the firmware of model {model_id:08x}, not of the artifact's model "
                                f"{artifact.model_id:08x}; build it from this artifact with 'bench firmware build'")
        self.cost = step_cost(artifact)      # the C28x estimate the firmware's Timing2/3 carry
        memory = memory_from_elf(image)
        self.memory_figures = memory
        self._rx, self._out, self._counters = (fw.address(name) for name in BUFFERS[:3])
        self._rx_data = self._rx + 8
        timing4 = layout_named(FIRMWARE_TIMING_MESSAGE).signal("M4Cycles")
        self._timing4 = (frame_id(FIRMWARE_TIMING_MESSAGE), timing4.start, timing4.mask)
        self.m4_cycles: Counter[int] = Counter()      # per model step (Timing4), value -> steps
        self.frame_cycles: Counter[int] = Counter()   # per received frame, model steps excluded
        self.reply_cycles: Counter[int] = Counter()   # per reply frame of calls that queued replies
        self.xcp_cycles: Counter[int] = Counter()     # per XCP command (node_on_frame's whole call)
        self.xcp_sample_cycles: Counter[int] = Counter()   # per DAQ sample (the mean of a call's samples)
        self._xcp = fw.symbols["xcp_counters"].address if "xcp_counters" in fw.symbols else None
        self._xcp_before_out = self._xcp is not None and self._xcp + XCP_COUNTERS.size == self._out
        self._xcp_last = (0, 0)
        self._xcp_id = xcp_cmd_id()
        self._is_xcp = False
        self.answered_again = False
        self.state = TargetState.BOOT
        self.faults = 0
        self._next_beat_ms = 0
        self._t0 = clock_s()
        # the per-frame entry points prepared once (`Firmware.caller`: None on a core that must take `call`)
        # (each returns the output's head, `_collect`'s read)
        head = (self._xcp, XCP_COUNTERS.size + PREFETCH_SPAN) if self._xcp_before_out else (self._out, PREFETCH_SPAN)
        self._callers = {name: call for name, ints in (("node_on_frame", 3), ("node_on_xcp", 2), ("node_on_tick", 1))
                         if (call := fw.caller(name, ints, head)) is not None}
        self._startup = self._run("node_init", 0)
        self._stamp = fw.symbols["node_rx_stamp"].address if "node_rx_stamp" in fw.symbols else None
        if isr_rate_hz:                 # interrupts on after the node's start, as a main() enables them
            start_motor_control(fw, rate_hz=isr_rate_hz, seed=isr_seed)
            self._origin = fw.now       # the core's timeline at the shell's clock _t0 + the node's start

    def _release(self) -> None:
        """The next call is released when the shell's clock says (see the module docstring)."""
        if self.isr_rate_hz:
            self.fw.release_at(self._origin + int((self.clock_s() - self._t0) * M4_CLOCK_HZ))

    # ------------------------------------------------------------------ calls into the firmware
    def _run(self, function: str, *args: int) -> list[can.Message]:
        """Call an entry point; its queued frames as messages (journal records handed on)."""
        fw = self.fw
        try:
            if self.isr_rate_hz and function != "node_init":
                self._release()
            if self._stamp is not None:          # the reception's time stamp: the release, or now
                stamp = fw.cyccnt_at(fw.job_release) if isinstance(fw, InterruptedFirmware) else fw.cyccnt()
                fw.write_bytes(self._stamp, stamp.to_bytes(4, "little"))
            call = self._callers.get(function)
            if call is not None:
                head = call(*args)
            else:
                head = None
                fw.call(function, *args)
        except FirmwareFault as fault:
            return self._core_faulted(fault)
        return self._collect(function in ("node_on_frame", "node_on_xcp"), fw.last.cycles, head)

    def _collect(self, on_frame: bool, cycles: int | None, head: bytes | None = None) -> list[can.Message]:
        read = self.fw.read_bytes
        # the header and the first frames in one read (one call into the emulator less a reply), and the XCP
        # slave's counters with them where the firmware placed them right before its output (the usual layout);
        # unpacked in place (offsets into the one buffer, no slices of it). `head`: that read, made by the call
        if self._xcp_before_out:
            head, base = head or read(self._xcp, XCP_COUNTERS.size + PREFETCH_SPAN), XCP_COUNTERS.size
            self._xcp_samples(_XCP_SAMPLES.unpack_from(head, _XCP_SAMPLES_OFFSET))
        else:
            head, base = head or read(self._out, PREFETCH_SPAN), 0
        tx_count, event_count, state, faults, again, _, _, _, step_cycles, next_beat_ms = \
            OUTPUT_HEADER.unpack_from(head, base)
        self.state = _STATES.get(state) or TargetState(state)   # (an unknown value raises, as the call does)
        self.faults = faults
        self.answered_again = bool(again)
        self._next_beat_ms = next_beat_ms
        frames: list[can.Message] = []
        if tx_count:
            if tx_count <= PREFETCH_FRAMES:
                start = base + TX_OFFSET
                raw = head[start:start + tx_count * FRAME.size]
            else:
                raw = read(self._out + TX_OFFSET, tx_count * FRAME.size)
            now = time.time()
            timing4, start, mask = self._timing4
            append = frames.append
            for fid, dlc, data in FRAME.iter_unpack(raw):
                if fid == timing4:
                    self.m4_cycles[(int.from_bytes(data, "little") >> start) & mask] += 1
                append(can.Message(timestamp=now, arbitration_id=fid, is_extended_id=False, dlc=dlc,
                                   data=data[:dlc], check=False))
        if event_count and self.journal is not None and self._msg is not None:
            raw = read(self._out + self._events_offset, event_count * EVENT.size)
            msg = self._msg
            for index in range(event_count):
                event = Event.unpack(raw[index * EVENT.size:(index + 1) * EVENT.size])
                self.journal({"kind": event.kind, "id": msg.arbitration_id, "dlc": msg.dlc,
                              "data": bytes(msg.data).hex(), "detail": event.sentence})
        if self._xcp is not None and not self._xcp_before_out:
            self._xcp_samples(self._xcp_counters()[5:7])
        if on_frame and cycles is not None and self._is_xcp:
            self.xcp_cycles[cycles] += 1
        elif on_frame and cycles is not None:
            handling = max(cycles - step_cycles, 0)
            self.frame_cycles[handling] += 1
            if frames:
                self.reply_cycles[handling // len(frames)] += 1
        return frames

    def _xcp_counters(self) -> tuple[int, ...]:
        return XCP_COUNTERS.unpack(self.fw.read_bytes(self._xcp, XCP_COUNTERS.size))

    def _xcp_samples(self, counters: tuple[int, ...]) -> None:
        """The DAQ samples of the last call (from the slave's sample count and cycles after it): their mean
        cycles, once per sample."""
        samples, cycles = counters
        new, spent = samples - self._xcp_last[0], (cycles - self._xcp_last[1]) & _MASK32
        if new > 0:
            self.xcp_sample_cycles[spent // new] += new
        self._xcp_last = (samples, cycles)

    def xcp_stats(self) -> dict:
        """The XCP slave's counters and cycles (the Python slave's `stats` has times where these have cycles)."""
        if self._xcp is None:
            return {}
        commands, errors, ignored, packets, calibrations, _, _ = self._xcp_counters()
        return {"commands": commands, "errors": errors, "ignored": ignored, "daq_packets": packets,
                "calibrations": calibrations, "handler_cycles": cycle_figures(self.xcp_cycles),
                "daq_sample_cycles": cycle_figures(self.xcp_sample_cycles)}

    def _core_faulted(self, fault: FirmwareFault) -> list[can.Message]:
        """The node's INTERNAL fault (see the module docstring); the fault's sentence is the last error."""
        self.fault_message = str(fault)
        try:
            self.fw.call("node_internal_fault", WHY_CODES["CORE_FAULT"])
            return self._collect(False, None)
        except FirmwareFault:
            pass
        self.fw.reset()                 # the watchdog: RAM as at power-on, then the node starts again
        frames: list[can.Message] = []
        try:
            self.fw.call("node_init", _ms(self.clock_s() - self._t0))
            frames = self._collect(False, None)
            self.fw.call("node_internal_fault", WHY_CODES["CORE_FAULT"])
            frames += self._collect(False, None)
        except FirmwareFault as again:   # the image cannot even start: report FAULT from here, nothing to send
            self.fault_message = str(again)
            self.state = TargetState.FAULT
            self.faults |= int(FaultBit.INTERNAL)
        return frames

    # ------------------------------------------------------------------ TargetNode's interface
    fault_message = ""
    _stamp: int | None = None
    _msg: can.Message | None = None
    _scratch: int | None = None

    def startup_frames(self) -> list[can.Message]:
        """What node_init queued: TargetInfo, Status, RxErrors."""
        frames, self._startup = self._startup, []
        return frames

    def handle(self, msg: can.Message) -> list[can.Message]:
        """Put one received frame into the mailbox, run node_on_frame, return what the firmware queued."""
        fid = msg.arbitration_id & 0x1FFF_FFFF
        if msg.is_extended_id:
            fid |= ID_EXTENDED
        if msg.is_remote_frame:
            fid |= ID_REMOTE
        if msg.is_error_frame:
            fid |= ID_ERROR
        if msg.is_fd:
            fid |= ID_FD
        # (the "8s" field pads the data with zeros to 8 bytes, or cuts it there)
        self.fw.write_bytes(self._rx, FRAME.pack(fid, msg.dlc, bytes(msg.data)))
        self._msg = msg
        self._is_xcp = (fid & ~ID_FD) == self._xcp_id       # the Python node's rule: any 11-bit data frame
        try:
            if self._is_xcp:
                return self._run("node_on_xcp", msg.dlc & _MASK32, self._rx_data)
            return self._run("node_on_frame", fid, msg.dlc & _MASK32, self._rx_data)
        finally:
            self._msg = None
            self._is_xcp = False

    def heartbeat_frames(self) -> list[can.Message]:
        """A heartbeat now: node_on_tick at the firmware's own next heartbeat time (serve() keeps the period)."""
        return self._run("node_on_tick", self._next_beat_ms)

    # ------------------------------------------------------------------ what the bench reads
    def _floats(self, function: str) -> np.ndarray:
        """fw_state / fw_output into a scratch buffer (not the node's RAM), bit for bit."""
        if self._scratch is None:
            self._scratch = self.fw.alloc_f32(4)
        self.fw.call(function, self._scratch)
        return self.fw.read_f32(self._scratch, 4)

    @property
    def x(self) -> np.ndarray:
        """The model's state vector (fw_state)."""
        return self._floats("fw_state")

    @property
    def estimate(self) -> np.ndarray:
        """The latest outputs (fw_output): what the next temperature replies carry."""
        return self._floats("fw_output")

    @property
    def memory(self) -> SimpleNamespace:
        """What TargetInfo reports: flash and RAM of the ELF."""
        return SimpleNamespace(flash_bytes=self.memory_figures["flash_bytes"],
                               ram_bytes=self.memory_figures["ram_bytes"])

    def rx_error_frames(self) -> list[can.Message]:
        """The RxErrors frame of a heartbeat (the firmware sends it only with Status)."""
        rx_errors = frame_id("RxErrors")
        return [frame for frame in self.heartbeat_frames() if frame.arbitration_id == rx_errors]

    def __getattr__(self, name: str):
        if name in ("frames_received", "rows_used", "repeats", "model_steps", "overruns"):
            return self.counters()[name]
        raise AttributeError(name)

    def counters(self) -> dict:
        values = COUNTERS.unpack(self.fw.read_bytes(self._counters, COUNTERS.size))
        raw_last = self.fw.read_bytes(self._counters + COUNTERS.size, EVENT.size)
        last_error = ""
        if raw_last[0]:                  # kind 0: no error yet
            last = Event.unpack(raw_last)
            last_error = self.fault_message if last.why == "CORE_FAULT" and self.fault_message else last.sentence
        return {"errors": dict(zip(RX_ERROR_KINDS, values[:6], strict=True)), "frames_received": values[6],
                "rows_used": values[7], "repeats": values[8], "model_steps": values[9], "overruns": values[10],
                "last_error": last_error}

    @property
    def errors(self) -> dict[str, int]:
        return self.counters()["errors"]

    @property
    def last_error(self) -> str:
        return self.counters()["last_error"]

    def stats(self) -> dict:
        counters = self.counters()
        header = OUTPUT_HEADER.unpack(self.fw.read_bytes(self._out, OUTPUT_HEADER.size))
        return {"state": self.state.name, "faults": int(self.faults), **counters,
                "model_id": self.artifact.model_id, "engine": self.engine, "est_cycles": self.cost.cycles,
                "m4_cycles": cycle_figures(self.m4_cycles), "frame_cycles": cycle_figures(self.frame_cycles),
                "reply_cycles": cycle_figures(self.reply_cycles), "tx_dropped": header[5],
                "events_dropped": header[6], "flash_bytes": self.memory_figures["flash_bytes"],
                "ram_bytes": self.memory_figures["ram_bytes"], "memory": "measured from the firmware ELF",
                "stack_used_bytes": self.fw.stack_used(), "xcp": self.xcp_stats(),
                **({"isr": interrupt_figures(self.fw)} if isinstance(self.fw, InterruptedFirmware) else {})}
