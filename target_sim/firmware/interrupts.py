"""A periodic interrupt preempting the firmware in the emulated core, with the Cortex-M4 exception model's costs.

    fw = InterruptedFirmware.load("timing.elf", irq=18, period_cycles=9000)   # the IRQ's handler from the vectors
    fw.call("foc_init", 10000.0)           # setup runs unpreempted: interrupts are enabled by `start_interrupts`
    fw.start_interrupts(at=0)
    fw.release_at(t); fw.call("node_on_frame", ...)       # a background job released at cycle t
    fw.jobs[-1].response, fw.isr_events                    # release -> result; every interrupt taken

The core has one timeline, `now`, in cycles since `start_interrupts`: the background's counted cycles, the
handler's, the exception overheads and the idle time between jobs. Releases of the interrupt are at
`phase + k * period_cycles`. A job (a `call`) starts at its release or when the core is free; while it runs, every
release the clock passes preempts it: the block hook sees the release at the first basic-block boundary at or
after it, saves the whole register context (uc_context_save), writes the exception frame to the stack, runs the
handler to its return in a nested emulation, restores the context and lets the interrupted block run: the
background resumes exactly (its registers, flags and FP registers are the context's; the tests check its outputs
bit for bit and its cycle count against runs without interrupts). The frame keeps the interrupted xPSR, the
If-Then state included (Unicorn may start a block inside an IT block), and the handler starts without it.

Granularity: the handler runs at the block boundary, but its timing is that of the silicon, which takes an
interrupt at the next instruction boundary: the release is placed in the block it fell in by that block's
instruction costs, and the wait (release -> that boundary, the instruction in progress completing), the entry,
the handler and the return are inserted there. The background's own cycles are the same either way and the total
time of the job is the sum, so response times and latencies are the silicon's under the cycle model; only the
point of the background's instruction stream the handler's side effects land at differs (by less than one block,
which matters to neither the estimator nor the current loop: they share no data). A release in a job's last block
is taken before the job completes, as on the silicon. Multi-cycle instructions (LDM/STM/POP with N registers,
VDIV/VSQRT 14, SDIV 12) complete before the interrupt is taken (the core may abandon and restart some of them:
this is the conservative reading). PRIMASK (CPSID I) and BASEPRI masking are honoured at block boundaries.

The exception model (`ExceptionCosts`, Cortex-M4 with zero wait states: the Cortex-M4 TRM's figures as ARM's
knowledge article 103489845 quotes them, entry 12 and exit 10 cycles, each plus 17 with the FP context; J. Yiu, The
Definitive Guide to the ARM Cortex-M3 and Cortex-M4 Processors, 3rd ed., ch. 8; ARM AN298 "Cortex-M4(F) Lazy
Stacking and Context Switching"; docs/tutorials/firmware.md has the table a test pins them to): entry 12 cycles
(8-word frame stacked, vector fetched) to the handler's first instruction; return 10;
tail-chaining 6 instead of return + entry when the next release is pending at the handler's return; FP context:
when CONTROL.FPCA is set at the preemption (the background has executed a floating-point instruction since reset:
without an RTOS nothing clears it) the frame reserves S0-S15 and FPSCR (lazy stacking, LSPEN set as after reset),
and the handler's first floating-point instruction stores them first, 17 cycles; the return then reloads them,
17 more. An idle core (WFI between jobs) takes the interrupt at its release (no wake-up latency modelled).
Releases long before a job are not emulated (`start_interrupts` / `release_at` skip whole idle periods): only the
releases within `IDLE_LOOKBACK` periods before a job run, so that an interrupt in progress at the release delays
the job as it would.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from unicorn import UcError
from unicorn import arm_const as arm

from target_sim.firmware.elf import ElfImage, FirmwareError, read_elf
from target_sim.firmware.emulator import FLASH, HALT, Firmware, FirmwareFault

ISR_RETURN = HALT + 0x40          # the handler's LR: emulation of the handler stops here (EXC_RETURN's stand-in)
FRAME_WORDS, FP_FRAME_WORDS = 8, 18   # basic frame; S0-S15, FPSCR and a reserved word more with FP context
FIRST_IRQ = 16                    # exception number of IRQ 0
XPSR_THUMB = 1 << 24
XPSR_IT = 0x0600_FC00             # ITSTATE: xPSR[26:25] and [15:10] (the If-Then block in progress)
MAX_CHAIN_PERIODS = 100          # tail-chained handlers in a row before the period is called too short
IDLE_LOOKBACK = 2                 # periods before a job whose releases are emulated
_MAX_ISR_INSTRUCTIONS = 1_000_000


@dataclass(frozen=True)
class ExceptionCosts:
    """Cortex-M4 exception overheads in cycles (zero wait states; see the module docstring)."""

    entry: int = 12               # release taken -> the handler's first instruction (stacking, vector fetch)
    exit: int = 10                # the handler's return -> the interrupted instruction (unstacking)
    tail_chain: int = 6           # return straight into the next pending handler
    lazy_fp: int = 17             # S0-S15 + FPSCR stored at the handler's first FP instruction (FPCA was set)
    fp_exit: int = 17             # and reloaded at its return


@dataclass(frozen=True)
class IsrEvent:
    """One interrupt: release, where it was taken and what it cost (cycles on the core's timeline)."""

    release: int
    taken: int                    # the instruction boundary where the core took it (or the release, idle)
    start: int                    # the handler's first instruction
    end: int                      # the interrupted code resumes (or the core idles again)
    handler_cycles: int           # the handler's own counted cycles
    lazy_fp: bool                 # FP context was active: S0-S15 stacked lazily, reloaded at return
    tail_chained: bool
    preempted: str | None         # the background function interrupted, None when the core was idle

    @property
    def latency(self) -> int:
        """Release -> the handler's first instruction."""
        return self.start - self.release

    @property
    def wait(self) -> int:
        """Release -> the boundary where it was taken: what the interrupted code adds to the latency."""
        return self.taken - self.release

    @property
    def busy(self) -> int:
        """Cycles the interrupt took from the core: stacking, handler, lazy FP stacking, return."""
        return self.end - self.taken


@dataclass(frozen=True)
class Job:
    """One background call on the timeline."""

    function: str
    release: int
    start: int                    # the core was free (an interrupt in progress at the release delays it)
    end: int                      # the call returned (every interrupt taken inside it included)
    cycles: int                   # the call's own counted cycles (as without interrupts)
    preemptions: int

    @property
    def response(self) -> int:
        return self.end - self.release


@dataclass
class _Block:
    """The last background block entered: where it started on the timeline and its instructions' costs."""

    start: int = 0
    costs: tuple[int, ...] = ()
    taken_extra: int = 0          # added to its last instruction when its final branch was taken
    fp_at: int = -1               # index of its first FP instruction, -1 without
    fp_before: bool = False       # the FP context was active when it started


@dataclass
class _Timeline:
    period: int
    next_release: int
    costs: ExceptionCosts
    skipped: int = 0              # idle releases not emulated
    events: list[IsrEvent] = field(default_factory=list)


class InterruptedFirmware(Firmware):
    """`Firmware` with a periodic interrupt preempting every call (see the module docstring)."""

    def __init__(self, image: ElfImage, *, irq: int, period_cycles: int, costs: ExceptionCosts = ExceptionCosts(),
                 **options):
        super().__init__(image, **options)
        if self.cycle_model is None:
            raise FirmwareError("interrupts need the cycle count (count_cycles=True)")
        if period_cycles <= 0:
            raise FirmwareError(f"the interrupt period must be a positive number of cycles, not {period_cycles}")
        self.irq = irq
        self.handler = self._vector(FIRST_IRQ + irq)
        self.handler_name = self._inside(self.handler).removeprefix(" (in ").removesuffix(")") or f"IRQ {irq}"
        self._uc.mem_write(ISR_RETURN, struct.pack("<HH", 0xE7FE, 0xE7FE))
        self._uc.ctl_exits_enabled(True)          # both stops hold in nested runs (`until` is then ignored)
        self._uc.ctl_set_exits([HALT, ISR_RETURN])
        self._timeline = _Timeline(period_cycles, 0, costs)
        self._enabled = False
        self.now = 0
        self.jobs: list[Job] = []
        self.before_handler: Callable[[int], None] | None = None   # called with each release before the handler
        self.dwt_reads: list[tuple[int, int]] = []   # (timeline, the call's own cycles) at each DWT_CYCCNT read
        self.fp_context = False               # CONTROL.FPCA of the background (thread mode)
        self._block_costs: dict[tuple[int, int], tuple[tuple[int, ...], int]] = {}
        self._in_isr = self._isr_fp = self._isr_lazy = False
        self._isr_start = 0
        self._release: int | None = None
        self._block = _Block()
        self._call_start = self._inserted = self._preemptions = 0
        self._in_call = False
        self._function = ""
        self._isr_fault: FirmwareFault | None = None
        self._masking = self._has_masking()

    @classmethod
    def load(cls, source: str | os.PathLike | bytes, *, irq: int, period_cycles: int,
             costs: ExceptionCosts = ExceptionCosts(), **options) -> InterruptedFirmware:
        return cls(read_elf(source), irq=irq, period_cycles=period_cycles, costs=costs, **options)

    # ------------------------------------------------------------------ the timeline
    @property
    def isr_events(self) -> list[IsrEvent]:
        return self._timeline.events

    @property
    def period(self) -> int:
        return self._timeline.period

    @property
    def skipped_releases(self) -> int:
        return self._timeline.skipped

    def start_interrupts(self, at: int = 0) -> None:
        """Enable the interrupt: its first release at cycle `at` of the timeline (`now` moves there)."""
        self._enabled = True
        self.now = max(self.now, at)
        self._timeline.next_release = at

    def release_at(self, cycle: int) -> None:
        """The next `call` is a job released at `cycle` (not before `now`): the idle core runs the releases before
        it (those of the last `IDLE_LOOKBACK` periods; earlier ones are skipped and counted in
        `skipped_releases`)."""
        cycle = max(cycle, self.now)
        if self._enabled:
            line = self._timeline
            horizon = cycle - IDLE_LOOKBACK * line.period
            if self.now <= line.next_release < horizon:
                skip = (horizon - line.next_release) // line.period
                line.skipped += skip
                line.next_release += skip * line.period
            self._idle_until(cycle)
        self._release = cycle

    @property
    def job_release(self) -> int:
        """When the next `call` is released (`release_at`'s cycle, else now)."""
        return self.now if self._release is None else max(self._release, self.now)

    def idle_until(self, cycle: int) -> None:
        """The core idles (WFI) until `cycle`, taking every release before it."""
        self._idle_until(cycle)
        self.now = max(self.now, cycle)

    def _idle_until(self, cycle: int) -> None:
        line = self._timeline
        while self._enabled and line.next_release < cycle:
            self.now = self._take(max(line.next_release, self.now), None, self.fp_context)

    # ------------------------------------------------------------------ calls
    def call(self, function: str | int, *args: int | float, returns: type[int] | type[float] | None = None
             ) -> int | float | None:
        release = self.now if self._release is None else max(self._release, self.now)
        self._release = None
        self._call_start = self.now = max(self.now, release)
        self._inserted = self._preemptions = 0
        self._block = _Block(start=self._call_start, fp_before=self.fp_context)
        self._isr_fault = None
        self._function = self._entry(function)[1]
        self._in_call = True
        try:
            result = super().call(function, *args, returns=returns)
        except (FirmwareFault, RuntimeError):
            if self._isr_fault is not None:
                raise self._isr_fault from None
            raise
        finally:
            self._in_call = False
        if self._enabled:              # released in its last block: taken before the call completes
            self._preempt(self._fall != HALT, self._function)
        end = self._call_start + self.last.cycles + self._inserted
        self.now = end
        self.jobs.append(Job(self.last.function, release, self._call_start, end, self.last.cycles,
                             self._preemptions))
        return result

    def _on_block(self, engine: object, address: int, size: int, user_data: object) -> None:
        try:
            if self._in_isr:
                if not self._isr_fp and self._costs(address, size)[1] >= 0:
                    self._isr_fp = True
            else:
                taken = address != self._fall
                boundary = self._call_start + self._inserted + self._cycles + (self._extra if taken else 0)
                if self._enabled and self._timeline.next_release < boundary and not self._masked():
                    self._preempt(taken, self._function)
                    boundary = self._call_start + self._inserted + self._cycles + (self._extra if taken else 0)
                costs, fp_at = self._costs(address, size)
                self._block = _Block(boundary, costs, 0, fp_at, self.fp_context)
                if fp_at >= 0:
                    self.fp_context = True
        except Exception as error:         # a C callback must not raise: stop and report it
            self._hook_error = error
            self._uc.emu_stop()
            return
        Firmware._on_block(self, engine, address, size, user_data)
        if self._instructions > self.max_instructions:      # a nested run resets unicorn's own count
            self._uc.emu_stop()

    def _costs(self, address: int, size: int) -> tuple[tuple[int, ...], int]:
        """(cycles of each instruction, branch not taken; index of the first FP instruction or -1) of a block."""
        key = (address, size)
        known = self._block_costs.get(key)
        if known is None:
            decoded = self.cycle_model.instructions_of(address, size)
            fp = [index for index, cost in enumerate(decoded) if cost.mnemonic.startswith("v")]
            known = self._block_costs[key] = (tuple(cost.cycles for cost in decoded), fp[0] if fp else -1)
        return known

    # ------------------------------------------------------------------ taking the interrupt
    def _preempt(self, branch_taken: bool, function: str) -> None:
        """Take every release before the end of the last block entered, each at the instruction boundary after
        it (see the module docstring), and shift the rest of the block by what the interrupt took."""
        block, line = self._block, self._timeline
        costs = list(block.costs)
        if costs and branch_taken:
            costs[-1] += self._extra
        at, index = block.start, 0
        remaining = sum(costs)
        while line.next_release < at + remaining:
            release = line.next_release
            while at < release and index < len(costs):     # the instruction in progress completes
                at += costs[index]
                remaining -= costs[index]
                index += 1
            fp = block.fp_before or 0 <= block.fp_at < index
            end = self._take(max(at, release), function, fp)
            self._inserted += end - max(at, release)
            self._preemptions += 1
            at = end

    def _take(self, taken: int, preempted: str | None, fp_context: bool) -> int:
        """Run the handler for the pending release (and those that tail-chain on it) from the boundary `taken`;
        the cycle the interrupted code resumes (or the core idles again)."""
        line, costs = self._timeline, self._timeline.costs
        start, chained, stacked = taken + costs.entry, False, False
        first = taken
        while True:
            release = line.next_release
            line.next_release += line.period
            handler_cycles, used_fp = self._run_handler(fp_context, release, start, stacked)
            lazy = fp_context and used_fp and not stacked
            stacked = stacked or lazy
            done = start + handler_cycles + (costs.lazy_fp if lazy else 0)
            if line.next_release <= done:                 # pending at the return: tail-chain into it
                if done - first > MAX_CHAIN_PERIODS * line.period:
                    raise FirmwareFault(f"the interrupt handler {self.handler_name} in {self.name} runs longer than "
                                        f"its period of {line.period} cycles: the background never runs again",
                                        function=self.handler_name, pc=self.handler, kind="endless loop")
                line.events.append(IsrEvent(release, taken, start, done, handler_cycles, lazy, chained, preempted))
                taken, start, chained = done, done + costs.tail_chain, True
                continue
            end = done + costs.exit + (costs.fp_exit if stacked else 0)
            line.events.append(IsrEvent(release, taken, start, end, handler_cycles, lazy, chained, preempted))
            return end

    def _run_handler(self, fp_context: bool, release: int, start: int = 0, stacked: bool = False
                     ) -> tuple[int, bool]:
        """Run the handler once (a nested emulation when a call is running) from its first instruction at `start`
        on the timeline; (its cycles, whether it used the FPU). The background's registers are saved and restored
        whole; its accounting is put back. `stacked`: the FP context is already stacked (a tail-chained run)."""
        uc = self._uc
        saved = (self._cycles, self._instructions, self._extra, self._fall, self._fault)
        context = uc.context_save()
        sp = uc.reg_read(arm.UC_ARM_REG_SP)
        if not self._in_call:
            sp = self._stack_top
        frame = [uc.reg_read(register) for register in _STACKED]
        xpsr = uc.reg_read(arm.UC_ARM_REG_XPSR)
        words = FRAME_WORDS + (FP_FRAME_WORDS if fp_context else 0)
        frame_sp = (sp - 4 * words) & ~7
        uc.mem_write(frame_sp, struct.pack("<8I", *frame, xpsr | XPSR_THUMB) + bytes(4 * (words - FRAME_WORDS)))
        uc.reg_write(arm.UC_ARM_REG_SP, frame_sp)
        if xpsr & XPSR_IT:       # taken inside an IT block: the frame keeps ITSTATE, the handler starts without it
            uc.reg_write(arm.UC_ARM_REG_XPSR, xpsr & ~XPSR_IT)
        uc.reg_write(arm.UC_ARM_REG_LR, ISR_RETURN | 1)
        if self.before_handler is not None:      # what the peripherals left for the handler (e.g. a DMA)
            self.before_handler(release)
        self._cycles = self._instructions = self._extra = 0
        self._fall = self.handler
        self._in_isr, self._isr_fp, self._fault = True, False, None
        self._isr_start, self._isr_lazy = start, fp_context and not stacked
        fault: FirmwareFault | None = None
        try:
            uc.emu_start(self.handler | 1, ISR_RETURN, count=_MAX_ISR_INSTRUCTIONS)
            pc = uc.reg_read(arm.UC_ARM_REG_PC)
            if self._fault is not None or pc != ISR_RETURN:
                what = self._fault[1] if self._fault is not None else f"did not return, stopped at PC {pc:#010x}"
                fault = FirmwareFault(f"the interrupt handler {self.handler_name} in {self.name} faulted: {what}",
                                      function=self.handler_name, pc=pc, kind="exception")
        except UcError as error:
            pc = uc.reg_read(arm.UC_ARM_REG_PC)
            fault = FirmwareFault(f"the interrupt handler {self.handler_name} in {self.name} faulted at PC "
                                  f"{pc:#010x}{self._inside(pc)}: {error}", function=self.handler_name, pc=pc,
                                  kind="memory")
        cycles = self._cycles + (self._extra if self._fall != ISR_RETURN else 0)
        used_fp = self._isr_fp
        self._in_isr = False
        uc.context_restore(context)
        self._cycles, self._instructions, self._extra, self._fall, self._fault = saved
        if fault is not None:
            self._isr_fault = fault
            if self._in_call:
                uc.emu_stop()
            raise fault
        return cycles, used_fp

    # ------------------------------------------------------------------ DWT_CYCCNT: the timeline
    def _timeline_now(self) -> int:
        if self._in_isr:          # the handler's first instruction, its cycles so far, the lazy FP stacking once due
            return self._isr_start + self._cycles + (self._timeline.costs.lazy_fp
                                                     if self._isr_lazy and self._isr_fp else 0)
        return self._call_start + self._inserted + self._cycles if self._in_call else self.now

    def cyccnt_at(self, cycle: int) -> int:
        """What DWT_CYCCNT reads at `cycle` of the timeline (e.g. a CAN controller's time stamp of a reception)."""
        return (cycle - self._cyccnt_base) & 0xFFFF_FFFF

    def _on_dwt_read(self, _uc, offset: int, _size: int, _user: object) -> int:
        """DWT_CYCCNT counts the timeline (interrupts and all), as on the silicon."""
        if offset != 4:
            return 0
        now = self._timeline_now()
        if not self._in_isr:       # the background's reads (the node's around fw_step)
            self.dwt_reads.append((now, self._cycles))
        return (now - self._cyccnt_base) & 0xFFFF_FFFF

    def _on_dwt_write(self, _uc, offset: int, _size: int, value: int, _user: object) -> None:
        if offset == 4 and not self._in_isr:
            self._cyccnt_base = (self._timeline_now() - value) & 0xFFFF_FFFF

    # ------------------------------------------------------------------ the image
    def _vector(self, number: int) -> int:
        vector_table = self.symbols.get("fw_vector_table")
        base = vector_table.address if vector_table is not None else FLASH[0]
        try:
            address = struct.unpack("<I", self.read_bytes(base + 4 * number, 4))[0]
        except UcError:
            address = 0
        if not address & 1 or not self.flash[0] <= address < self.flash[0] + self.flash[1]:
            raise FirmwareError(f"{self.name} has no handler for exception {number} (IRQ {number - FIRST_IRQ}) in "
                                "its vector table; build it with the interrupt (bench firmware timing)")
        return address & ~1

    def _has_masking(self) -> bool:
        """Whether the image can mask interrupts (CPSID, MSR PRIMASK/BASEPRI): only then is PRIMASK read."""
        return any(cost.mnemonic in ("cps", "msr") for cost in self.cycle_model.instructions.values())

    def _masked(self) -> bool:
        if not self._masking:
            return False
        uc = self._uc
        return bool(uc.reg_read(arm.UC_ARM_REG_PRIMASK) & 1 or uc.reg_read(arm.UC_ARM_REG_BASEPRI))


_STACKED = (arm.UC_ARM_REG_R0, arm.UC_ARM_REG_R1, arm.UC_ARM_REG_R2, arm.UC_ARM_REG_R3, arm.UC_ARM_REG_R12,
            arm.UC_ARM_REG_LR, arm.UC_ARM_REG_PC)
