"""An emulated Cortex-M4F (Unicorn) that runs functions of a bare-metal firmware ELF and counts their cycles.

    fw = Firmware.load("model.elf")                 # checks the ELF, maps flash and RAM, loads .data, zeroes .bss
    u, y = fw.alloc_f32(4), fw.alloc_f32([0.0] * 4)
    fw.write_f32(u, inputs)
    fw.call("fw_step", u, y)                        # AAPCS hard-float: ints/pointers in r0-r3, floats in s0-s15
    fw.read_f32(y, 4), fw.last.cycles, fw.last.instructions

Memory map: the firmware's flash (default 256 kB at 0x08000000, read/execute: a store to flash faults) and RAM
(default 64 kB at 0x20000000, read/write, not executable: a jump into data faults); every other address is
unmapped, so a stray pointer faults instead of reading zeros. Two regions the real MCU does not have are added for
the host: a scratch area for the caller's input and output buffers (`SCRATCH`, so they take no firmware RAM) and
one page holding the return address every call returns to (`HALT`; emulation stops when the PC reaches it).

One Unicorn instance serves every call: `call` writes the argument registers, SP (the stack top: `_estack` or a
like symbol, else the end of RAM) and LR (the halt address), and runs; nothing is re-mapped. Registers, memory and
emu_start go straight through libunicorn's C API (`_RawCore`: one uc_reg_write_batch from preallocated ctypes
arrays), which makes a call of a small entry point about 5 us instead of 13 us through the binding's wrappers;
`RAW_CALLS = False` uses the binding (the same results, counts and faults: a test compares them). `caller` prepares
an entry point called again and again (the node's per-frame calls): its register batch fixed once, the memory the
caller reads next and the stack's guard word in one read, about 4.5 us a call of node_on_tick instead of 5.5 us
through `call`. Memory persists
between calls, as on the target (the model's state lives in its RAM); `reset` restores .data and zeroes .bss.
Flash is loaded once (host writes to it, `write_bytes`, are not undone by `reset` nor seen by the cycle model).

Faults never hang the caller: an access to unmapped or protected memory, an undefined instruction, any CPU
exception (BKPT, SVC, ...), a call running past `max_instructions` (an endless loop) or overflowing its stack (a
guard word at the bottom of the stack changed) raises `FirmwareFault` with one sentence (function, PC, kind).

Cycles are counted by `target_sim.firmware.cycles` (Cortex-M4 TRM timings, zero wait states; its docstring
states the table and assumptions) from a block hook: one dict look-up and a few additions per executed basic
block. `count_cycles=False` drops the hook, for speed when only the results matter. With the compiled hook
(`native_hook`) the firmware's reads of DWT_CYCCNT are answered in compiled code too (`native_hook.dwt_read`), and a
call's PC is not read back when the hook ran it to its end (it stops a call early only past the instruction limit).

Unicorn quirks met (unicorn 2.1): the Cortex-M4 model starts with the FPU enabled (CPACR CP10/CP11 full access,
CONTROL.FPCA set) and does not emulate the System Control Space, so CPACR at 0xE000ED88 cannot be written and there
is no CPACR register for M-profile in the API: `load` checks the FPU by running one VFP instruction instead. A
return address at 0xF0000000 and above is an M-profile EXC_RETURN value (so the halt page sits at 0x1F000000).
Unicorn does not check alignment: an unaligned VLDR/LDM that would UsageFault on silicon runs. The core's default
FPSCR (round to nearest, no flush-to-zero, no default NaN) matches numpy's float32.
"""

from __future__ import annotations

import ctypes
import os
import struct
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
from unicorn import (
    UC_ARCH_ARM,
    UC_ERR_INSN_INVALID,
    UC_ERR_OK,
    UC_HOOK_BLOCK,
    UC_HOOK_INTR,
    UC_HOOK_MEM_INVALID,
    UC_MEM_FETCH_PROT,
    UC_MEM_FETCH_UNMAPPED,
    UC_MEM_READ_PROT,
    UC_MEM_READ_UNMAPPED,
    UC_MEM_WRITE_PROT,
    UC_MEM_WRITE_UNMAPPED,
    UC_MODE_MCLASS,
    UC_MODE_THUMB,
    UC_PROT_EXEC,
    UC_PROT_READ,
    UC_PROT_WRITE,
    Uc,
    UcError,
)
from unicorn import arm_const as arm

from target_sim.errors import TargetError
from target_sim.firmware.cycles import CycleModel, new_disassembler
from target_sim.firmware.elf import (
    STACK_TOP_SYMBOLS,
    ElfImage,
    FirmwareError,
    Symbol,
    memory_from_elf,
    read_elf,
    stack_bytes,
)
from target_sim.firmware.native_hook import CYCCNT_BEFORE, CYCLES, EXTRA, FALL, INSTRUCTIONS, BlockCounter

FLASH = (0x0800_0000, 256 * 1024)      # (base, size): STM32-like Cortex-M4F
RAM = (0x2000_0000, 64 * 1024)
SCRATCH = (0x3000_0000, 64 * 1024)     # the host's buffers: not target RAM
HALT = 0x1F00_0000                     # every call returns here: below EXC_RETURN values, far from flash/RAM
SCS = 0xE000_E000                      # System Control Space page (DEMCR at +0xDFC): writes taken, reads 0
DWT = 0xE000_1000                      # Data Watchpoint and Trace unit page: DWT_CTRL +0, DWT_CYCCNT +4
PAGE = 0x1000                          # Unicorn maps 4 kB pages
ONE_READ = 8192                        # `caller`: the stack guard read with the memory asked for when this close
MAX_INSTRUCTIONS = 1_000_000           # per call: an endless loop stops here (a model step runs ~300-20,000)
RAW_BLOCK_HOOK = True                  # hook blocks through libunicorn's C API (faster); False: the binding's hook_add
RAW_CALLS = True                       # registers, memory and emu_start of a call through libunicorn's C API (faster)
NATIVE_BLOCK_HOOK = True               # count known blocks in compiled code (`native_hook`); False: the Python hook
PF_W = 0x2                             # ELF segment flag: writable (RAM)
STACK_FILL = 0xA5                      # stack bytes before use: high-water mark and overflow guard
_GUARD = bytes([STACK_FILL]) * 4       # the bottom word of the stack: changed = overflowed

_HALT_CODE = struct.pack("<HH", 0xE7FE, 0xE7FE)   # "b ." twice: never runs (emulation stops at HALT)
_FPU_PROBE = struct.pack("<HH", 0xEEF1, 0x0A10)   # vmrs r0, fpscr: faults when the FPU is off
_R = (arm.UC_ARM_REG_R0, arm.UC_ARM_REG_R1, arm.UC_ARM_REG_R2, arm.UC_ARM_REG_R3)
_S = tuple(getattr(arm, f"UC_ARM_REG_S{index}") for index in range(16))
_F32, _U32 = struct.Struct("<f"), struct.Struct("<I")

_ACCESS = {UC_MEM_READ_UNMAPPED: "read of unmapped address", UC_MEM_WRITE_UNMAPPED: "write to unmapped address",
           UC_MEM_FETCH_UNMAPPED: "instruction fetch from unmapped address",
           UC_MEM_WRITE_PROT: "write to read-only address", UC_MEM_READ_PROT: "read of unreadable address",
           UC_MEM_FETCH_PROT: "instruction fetch from non-executable address"}
# QEMU's ARM exception numbers (target/arm/cpu.h EXCP_*) as Unicorn's interrupt hook reports them
_EXCEPTIONS = {1: "undefined instruction", 2: "supervisor call (SVC)", 3: "prefetch abort", 4: "data abort",
               5: "interrupt", 7: "breakpoint (BKPT)", 8: "exception return", 16: "semihosting call",
               17: "coprocessor access with the FPU disabled (NOCP)", 18: "invalid state (ARM-mode target)",
               19: "stack limit violation", 20: "lazy FP state preservation", 22: "unaligned access",
               23: "division by zero"}


class FirmwareFault(TargetError):
    """A firmware function that faulted or did not return; the message is one sentence."""

    def __init__(self, message: str, *, function: str, pc: int, kind: str):
        super().__init__(message)
        self.function = function
        self.pc = pc
        self.kind = kind     # "memory", "undefined instruction", "exception", "endless loop", "stack overflow"


@dataclass(slots=True)
class CallStats:
    """What the core executed in one call: instructions and Cortex-M4 cycles (None without the block hook).

    Not frozen: one is made per call, and a frozen dataclass's construction costs several times as much."""

    function: str
    instructions: int | None
    cycles: int | None


def _float32_bits(value: float) -> int:
    try:
        return _U32.unpack(_F32.pack(value))[0]
    except OverflowError:          # beyond float32's range: round to infinity, as numpy does
        return int(np.array(value, dtype=np.float64).astype(np.float32).view(np.uint32))


def _add_block_hook(uc: Uc, callback: Callable[[object, int, int, object], None]) -> object:
    """Hook every basic block; returns what must stay referenced while the hook lives.

    Straight through libunicorn's uc_hook_add where the binding exposes it: that skips the binding's two Python
    wrapper layers and takes ~40% off the time per block (0.26 instead of 0.45 us here). Otherwise `hook_add`.
    The callback gets (engine handle or Uc, address, size, user data) either way and must not raise.
    """
    if not RAW_BLOCK_HOOK:
        return uc.hook_add(UC_HOOK_BLOCK, callback)
    try:
        from unicorn.unicorn_py3 import unicorn as binding

        function = binding.HOOK_CODE_CFUNC(callback)
        handle = binding.uc_hook_h()
        status = binding.uclib.uc_hook_add(uc._uch, ctypes.byref(handle), UC_HOOK_BLOCK, function,
                                           ctypes.c_void_p(0), ctypes.c_uint64(1), ctypes.c_uint64(0))
    except (ImportError, AttributeError, TypeError, ctypes.ArgumentError):
        return uc.hook_add(UC_HOOK_BLOCK, callback)
    if status != UC_ERR_OK:
        raise UcError(status)
    return function


class _RawCore:
    """The few libunicorn calls every `Firmware.call` makes, straight through ctypes: the binding's wrappers cost
    ~2 us per register or memory access (type dispatch, a fresh ctypes object each time), several times what the
    emulated function itself takes for the firmware's small entry points. Registers go in one uc_reg_write_batch
    from preallocated arrays; `Firmware` falls back to the binding when this cannot be set up."""

    SLOTS = len(_R) + len(_S) + 2          # argument registers, SP and LR

    def __init__(self, uc: Uc):
        from unicorn.unicorn_py3 import unicorn as binding

        self.uc = uc
        self.lib = binding.uclib
        self.uch = uc._uch
        self.ids = (ctypes.c_int * self.SLOTS)()
        self._ids: tuple[int, ...] = ()       # what `ids` holds
        self.values = (ctypes.c_uint32 * self.SLOTS)()
        base = ctypes.addressof(self.values)
        self.pointers = (ctypes.c_void_p * self.SLOTS)(*(base + 4 * i for i in range(self.SLOTS)))
        self.word = ctypes.c_uint32()
        self.buffers: dict[int, ctypes.Array[ctypes.c_char]] = {}
        for name in ("uc_reg_write_batch", "uc_reg_read", "uc_emu_start", "uc_mem_read", "uc_mem_write"):
            getattr(self.lib, name)        # AttributeError here: use the binding instead

    def set_registers(self, registers: list[tuple[int, int]]) -> None:
        """Write (register, value) pairs in one batch; the ids are rewritten only when they change (a call's
        registers are those of the last call of the same arguments' kinds)."""
        ids = tuple(register for register, _ in registers)
        if ids != self._ids:
            for slot, register in enumerate(ids):
                self.ids[slot] = register
            self._ids = ids
        self.values[:len(registers)] = [value for _, value in registers]
        self.write_registers(len(registers))

    def write_registers(self, count: int) -> None:
        status = self.lib.uc_reg_write_batch(self.uch, self.ids, self.pointers, count)
        if status != UC_ERR_OK:
            raise UcError(status)

    def read_register(self, register: int) -> int:
        status = self.lib.uc_reg_read(self.uch, register, ctypes.byref(self.word))
        if status != UC_ERR_OK:
            raise UcError(status)
        return self.word.value

    def start(self, begin: int, until: int, count: int) -> None:
        """uc_emu_start, raising what the binding's emu_start raises (a hook's stored exception too)."""
        self.uc._hook_exception = None
        status = self.lib.uc_emu_start(self.uch, begin, until, 0, count)
        if status != UC_ERR_OK:
            raise UcError(status)
        if self.uc._hook_exception is not None:
            raise self.uc._hook_exception

    def read(self, address: int, size: int) -> bytes:
        # a buffer of each size read (a call's few: the stack guard, the node's output): `.raw` copies it whole
        buffer = self.buffers.get(size)
        if buffer is None:
            buffer = ctypes.create_string_buffer(size)
            if len(self.buffers) < 64:
                self.buffers[size] = buffer
        status = self.lib.uc_mem_read(self.uch, address, buffer, size)
        if status != UC_ERR_OK:
            raise UcError(status, address, size)
        return buffer.raw

    def write(self, address: int, data: bytes) -> None:
        status = self.lib.uc_mem_write(self.uch, address, data, len(data))
        if status != UC_ERR_OK:
            raise UcError(status, address, len(data))


def _native_counter(fw: Firmware) -> BlockCounter | None:
    """The compiled block hook on `fw`'s core (`native_hook`), or None where it cannot be set up (then the Python
    hook counts)."""
    if not NATIVE_BLOCK_HOOK:
        return None
    try:
        from unicorn.unicorn_py3 import unicorn as binding

        counter = BlockCounter(fw.flash, fw.max_instructions, fw._on_block_native)
        handle = binding.uc_hook_h()
        status = binding.uclib.uc_hook_add(fw.uc._uch, ctypes.byref(handle), UC_HOOK_BLOCK,
                                           ctypes.c_void_p(counter.function), ctypes.c_void_p(counter.user_data),
                                           ctypes.c_uint64(1), ctypes.c_uint64(0))
    except (ImportError, AttributeError, TypeError, ctypes.ArgumentError):
        return None
    if status != UC_ERR_OK:
        raise UcError(status)
    return counter


def _native_dwt(fw: Firmware) -> object | None:
    """The DWT page mapped with `native_hook.dwt_read` answering its reads (writes still go to `_on_dwt_write`):
    what stays referenced while the mapping lives, or None where the Python callbacks must answer (no native
    hook, a subclass's own DWT)."""
    native = fw._native
    if native is None or type(fw)._on_dwt_read is not Firmware._on_dwt_read:
        return None
    try:
        from unicorn.unicorn_py3 import unicorn as binding

        from target_sim.firmware.native_hook import dwt_read

        def write(_engine: object, offset: int, size: int, value: int, _user: object) -> None:
            fw._on_dwt_write(fw.uc, offset, size, value, None)

        write_callback = binding.MMIO_WRITE_CFUNC(write)
        status = binding.uclib.uc_mmio_map(fw.uc._uch, DWT, PAGE, ctypes.c_void_p(dwt_read.address),
                                           ctypes.c_void_p(native.user_data), write_callback, None)
    except (ImportError, AttributeError, TypeError, ctypes.ArgumentError):
        return None
    if status != UC_ERR_OK:
        raise UcError(status)
    fw._sync_cyccnt()
    return write_callback


def _raw_core(uc: Uc) -> _RawCore | None:
    if not RAW_CALLS:
        return None
    try:
        return _RawCore(uc)
    except (ImportError, AttributeError, TypeError):
        return None


def _region_of(address: int, size: int, regions: Iterable[tuple[int, int]]) -> bool:
    return any(base <= address and address + size <= base + length for base, length in regions)


class Firmware:
    """A firmware ELF loaded into an emulated Cortex-M4F; call its functions by name."""

    def __init__(self, image: ElfImage, *, count_cycles: bool = True, max_instructions: int = MAX_INSTRUCTIONS,
                 flash: tuple[int, int] = FLASH, ram: tuple[int, int] = RAM, scratch: tuple[int, int] = SCRATCH):
        self.image = image
        self.name = image.name
        self.symbols: dict[str, Symbol] = image.symbols
        self.max_instructions = max_instructions
        self.flash, self.ram, self.scratch = flash, ram, scratch
        self.last = CallStats("", None, None)
        self._check_layout()
        self._uc = uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        uc.ctl_set_cpu_model(arm.UC_CPU_ARM_CORTEX_M4)
        try:
            uc.mem_map(flash[0], flash[1], UC_PROT_READ | UC_PROT_EXEC)
            uc.mem_map(ram[0], ram[1], UC_PROT_READ | UC_PROT_WRITE)
            uc.mem_map(scratch[0], scratch[1], UC_PROT_READ | UC_PROT_WRITE)
            uc.mem_map(HALT, PAGE, UC_PROT_READ | UC_PROT_EXEC)
        except UcError as error:
            raise FirmwareError(f"cannot map flash {flash[0]:#x}+{flash[1]}, RAM {ram[0]:#x}+{ram[1]} and scratch "
                                f"{scratch[0]:#x}+{scratch[1]} for {self.name}: {error} (4 kB-aligned, "
                                "non-overlapping regions needed)") from None
        uc.mem_write(HALT, _HALT_CODE + _FPU_PROBE)
        self._check_fpu()
        # the cycle counter firmware reads to time itself (DWT_CYCCNT): the counted cycles, running across calls
        self.total_cycles = 0
        self._cyccnt_base = 0
        uc.mmio_map(SCS, PAGE, lambda *_: 0, None, lambda *_: None, None)
        self._stack_top, self._stack_bottom = self._stack_range()
        self._scratch_next = scratch[0]
        self._entries: dict[str, int] = {}
        # per-call state the hooks write (attributes, not closures: the block hook stays one look-up and adds)
        self._cycles = self._instructions = self._extra = self._fall = 0
        self._fault: tuple[str, str, int] | None = None
        self._hook_error: Exception | None = None
        for segment in image.segments:     # flash once; RAM again on every reset
            if segment.paddr != segment.vaddr and segment.data:
                uc.mem_write(segment.paddr, segment.data)      # the load image of .data, as in flash
            if not segment.flags & PF_W:
                uc.mem_write(segment.vaddr, segment.data + bytes(segment.memsz - len(segment.data)))
        self.reset()                   # the image is in memory before the cycle model disassembles it
        self.cycle_model: CycleModel | None = None
        self._native = None
        if count_cycles:
            self.cycle_model = CycleModel(lambda address, size: bytes(uc.mem_read(address, size)),
                                          image.thumb_ranges)
            self._blocks = self.cycle_model.blocks
            self._native = _native_counter(self) if type(self)._on_block is Firmware._on_block else None
            self._block_hook = self._native or _add_block_hook(uc, self._on_block)
        self._dwt = _native_dwt(self)       # the DWT page (the cycle counter) answered natively, or here
        if self._dwt is None:
            uc.mmio_map(DWT, PAGE, self._on_dwt_read, None, self._on_dwt_write, None)
        uc.hook_add(UC_HOOK_MEM_INVALID, self._on_invalid_memory)
        uc.hook_add(UC_HOOK_INTR, self._on_exception)
        self._raw = _raw_core(uc)

    @classmethod
    def load(cls, source: str | os.PathLike | bytes, *, count_cycles: bool = True,
             max_instructions: int = MAX_INSTRUCTIONS, flash: tuple[int, int] = FLASH, ram: tuple[int, int] = RAM,
             scratch: tuple[int, int] = SCRATCH) -> Firmware:
        """Check and load a firmware ELF (path or bytes); FirmwareError (one sentence) if it is not for this core."""
        return cls(read_elf(source), count_cycles=count_cycles, max_instructions=max_instructions, flash=flash,
                   ram=ram, scratch=scratch)

    # --- loading -----------------------------------------------------------------------------------------------

    def _check_layout(self) -> None:
        regions = (self.flash, self.ram)
        for segment in self.image.segments:
            if not _region_of(segment.vaddr, segment.memsz, regions):
                raise FirmwareError(f"{self.name} has a segment at {segment.vaddr:#010x} ({segment.memsz} bytes) "
                                    f"outside flash {self.flash[0]:#010x}+{self.flash[1] // 1024} kB and RAM "
                                    f"{self.ram[0]:#010x}+{self.ram[1] // 1024} kB")
            if segment.paddr != segment.vaddr and segment.data and not _region_of(segment.paddr, len(segment.data),
                                                                                  regions):
                raise FirmwareError(f"{self.name} stores a segment's initial values at {segment.paddr:#010x}, "
                                    "outside flash and RAM")

    def _check_fpu(self) -> None:
        try:
            self._uc.emu_start((HALT + len(_HALT_CODE)) | 1, HALT + len(_HALT_CODE) + len(_FPU_PROBE), count=1)
        except UcError as error:
            raise FirmwareError(f"the emulated Cortex-M4 has its FPU disabled ({error}), so {self.name} cannot "
                                "run: the installed unicorn does not enable CP10/CP11") from None

    def _stack_range(self) -> tuple[int, int]:
        """(top, bottom) of the stack: a stack-top symbol or the end of RAM, down to the reserved size or .bss."""
        ram_end = self.ram[0] + self.ram[1]
        top = next((self.symbols[name].address for name in STACK_TOP_SYMBOLS if name in self.symbols
                    and self.ram[0] < self.symbols[name].address <= ram_end), ram_end) & ~7
        reserved = stack_bytes(self.image)
        used = [section.address + section.size for section in self.image.sections
                if section.writable and self.ram[0] <= section.address < top and "stack" not in section.name.lower()]
        bottom = max([self.ram[0], *used])
        if reserved and top - reserved >= bottom:
            bottom = top - reserved
        return top, bottom

    def reset(self) -> None:
        """RAM as after loading: writable segments rewritten (.data initial values, .bss zeroed), stack filled."""
        uc = self._uc
        for segment in self.image.segments:
            if segment.flags & PF_W:
                uc.mem_write(segment.vaddr, segment.data + bytes(segment.memsz - len(segment.data)))
        if self._stack_top > self._stack_bottom:
            uc.mem_write(self._stack_bottom, bytes([STACK_FILL]) * (self._stack_top - self._stack_bottom))
        uc.reg_write(arm.UC_ARM_REG_FPSCR, 0)

    # --- symbols and memory ------------------------------------------------------------------------------------

    def address(self, name: str) -> int:
        """Address of a symbol (Thumb bit cleared); FirmwareError if the ELF has none of that name."""
        symbol = self.symbols.get(name)
        if symbol is None:
            raise FirmwareError(f"{self.name} has no symbol {name!r}")
        return symbol.address

    def write_bytes(self, address: int, data: bytes) -> None:
        if self._raw is not None:
            self._raw.write(address, bytes(data))
        else:
            self._uc.mem_write(address, bytes(data))

    def read_bytes(self, address: int, size: int) -> bytes:
        return self._raw.read(address, size) if self._raw is not None else bytes(self._uc.mem_read(address, size))

    def write_f32(self, address: int, values: Iterable[float] | np.ndarray) -> None:
        """Store values as little-endian float32 (numpy's conversion: round to nearest) from `address` on."""
        data = np.asarray(values, dtype="<f4").tobytes()
        if self._raw is not None:
            self._raw.write(address, data)
        else:
            self._uc.mem_write(address, data)

    def read_f32(self, address: int, count: int) -> np.ndarray:
        """`count` float32 values from `address`, bit for bit."""
        data = self._raw.read(address, 4 * count) if self._raw is not None else self._uc.mem_read(address, 4 * count)
        return np.frombuffer(data, dtype="<f4").astype(np.float32)

    def write_i32(self, address: int, values: Iterable[int] | np.ndarray) -> None:
        self._uc.mem_write(address, np.asarray(values, dtype="<i4").tobytes())

    def read_i32(self, address: int, count: int) -> np.ndarray:
        return np.frombuffer(self._uc.mem_read(address, 4 * count), dtype="<i4").astype(np.int32)

    def alloc(self, size: int, align: int = 8) -> int:
        """Reserve `size` bytes of the scratch area (the host's buffers) and return their address."""
        start = -(-self._scratch_next // align) * align
        if start + size > self.scratch[0] + self.scratch[1]:
            raise FirmwareError(f"the scratch area ({self.scratch[1]} bytes) has no room for {size} more bytes")
        self._scratch_next = start + size
        return start

    def alloc_f32(self, values: int | Iterable[float] | np.ndarray) -> int:
        """A float32 buffer in the scratch area: `values` floats written there, or that many zeros for an int."""
        array = np.zeros(values, np.float32) if isinstance(values, int) else np.asarray(values, dtype=np.float32)
        address = self.alloc(4 * array.size)
        self.write_f32(address, array)
        return address

    def free_scratch(self) -> None:
        """Forget every scratch buffer (their addresses may be handed out again)."""
        self._scratch_next = self.scratch[0]

    def stack_used(self) -> int:
        """Deepest stack use since the last reset, in bytes (the stack fill pattern overwritten)."""
        size = self._stack_top - self._stack_bottom
        raw = np.frombuffer(self._uc.mem_read(self._stack_bottom, size), np.uint8)
        touched = np.flatnonzero(raw != STACK_FILL)
        return int(size - touched[0]) if touched.size else 0

    @property
    def memory(self) -> dict:
        """Flash and RAM figures of the image (`memory_from_elf`)."""
        return memory_from_elf(self.image)

    @property
    def uc(self) -> Uc:
        """The Unicorn instance, for tracing and tests (hooks added here slow every call)."""
        return self._uc

    @property
    def stack(self) -> tuple[int, int]:
        """(bottom, top) of the stack the calls run on."""
        return self._stack_bottom, self._stack_top

    # --- calls ---------------------------------------------------------------------------------------------------

    def _entry(self, function: str | int) -> tuple[int, str]:
        if isinstance(function, int):
            return function | 1, f"function at {function & ~1:#010x}"
        entry = self._entries.get(function)
        if entry is None:
            symbol = self.symbols.get(function)
            if symbol is None or symbol.kind not in ("STT_FUNC", "STT_NOTYPE"):
                raise FirmwareError(f"{self.name} has no function {function!r}")
            entry = self._entries[function] = symbol.address | 1    # Thumb state: the M4 has no other
        return entry, function

    def call(self, function: str | int, *args: int | float, returns: type[int] | type[float] | None = None
             ) -> int | float | None:
        """Call a function with the AAPCS hard-float convention and return its result.

        Python/numpy ints (and pointers, e.g. from `alloc_f32`) go to r0-r3, floats to s0-s15 (as float32, rounded
        to nearest) in order; `returns=float` reads s0 (a float32 value, exact as a Python float), `returns=int`
        reads r0 as a signed 32-bit int, None returns None. `last` then holds the call's instructions and cycles.
        """
        if returns not in (None, int, float):
            raise TypeError(f"returns must be None, int or float, not {returns!r}")
        entry, name = self._entry(function)
        uc = self._uc
        registers: list[tuple[int, int]] = []
        ints = floats = 0
        for value in args:
            if type(value) is int and ints < len(_R):     # the common case first (the node's calls: ints only)
                registers.append((_R[ints], value & 0xFFFFFFFF))
                ints += 1
            elif isinstance(value, float | np.floating):
                if floats == len(_S):
                    raise FirmwareError(f"{name}: more than {len(_S)} float arguments need the stack (unsupported)")
                registers.append((_S[floats], _float32_bits(value)))
                floats += 1
            elif isinstance(value, int | np.integer):
                if ints == len(_R):
                    raise FirmwareError(f"{name}: more than {len(_R)} integer arguments need the stack (unsupported)")
                registers.append((_R[ints], int(value) & 0xFFFFFFFF))
                ints += 1
            else:
                raise FirmwareError(f"{name}: argument {value!r} is neither an int nor a float")
        registers += ((arm.UC_ARM_REG_SP, self._stack_top), (arm.UC_ARM_REG_LR, HALT | 1))
        raw = self._raw
        if raw is not None:
            raw.set_registers(registers)
        else:
            for register, value in registers:
                uc.reg_write(register, value)
        self._execute(entry, name)
        if returns is None:
            return None
        read = raw.read_register if raw is not None else uc.reg_read
        if returns is float:
            return _F32.unpack(_U32.pack(read(_S[0])))[0]
        value = read(arm.UC_ARM_REG_R0)
        return value - (1 << 32) if value & 0x8000_0000 else value

    def caller(self, function: str, ints: int, read: tuple[int, int] | None = None
               ) -> Callable[..., bytes | None] | None:
        """`function` with `ints` int arguments (at most 4) and no result, prepared once: `caller(...)(a, b)` runs
        as `call(function, a, b)` does (the same run, checks, faults and `last`), with its register ids, SP and LR
        written into a batch of its own beforehand, so a call costs one uc_reg_write_batch of the arguments (the
        firmware engine's per-frame calls). With `read` (address, size) it returns the memory from that address
        after the call (at least `size` bytes: the stack's guard word comes from the same read when it lies
        within ONE_READ bytes above, one call into the emulator less). None where `call` must run instead: no raw
        core, or a subclass's `call` (an interrupted core times its jobs there)."""
        raw = self._raw
        if raw is None or type(self).call is not Firmware.call or not 0 <= ints <= len(_R):
            return None
        entry, name = self._entry(function)
        batch = _RawCore(self._uc)
        batch.set_registers([*((register, 0) for register in _R[:ints]), (arm.UC_ARM_REG_SP, self._stack_top),
                             (arm.UC_ARM_REG_LR, HALT | 1)])
        values, count, run = batch.values, ints + 2, self._execute
        lib, uch, ids, pointers = batch.lib, batch.uch, batch.ids, batch.pointers
        after = None
        if read is not None:
            address, size = read
            guard = self._stack_bottom - address
            after = (address, max(size, guard + 4), guard) if self._stack_top > self._stack_bottom and \
                0 <= guard <= ONE_READ - 4 else (address, size, None)

        def call(*args: int) -> bytes | None:
            values[:ints] = [value & 0xFFFFFFFF for value in args]    # (a wrong count raises here)
            status = lib.uc_reg_write_batch(uch, ids, pointers, count)   # (write_registers, inline: per frame)
            if status != UC_ERR_OK:
                raise UcError(status)
            return run(entry, name, after)

        return call

    def _execute(self, entry: int, name: str, after: tuple[int, int, int | None] | None = None) -> bytes | None:
        """Run from `entry` (the registers written) to the halt address; `last` and the faults as `call` says.
        `after` (address, size, the guard word's offset in it or None): that memory, read after the call."""
        uc, raw = self._uc, self._raw
        self._cycles = self._instructions = self._extra = 0
        self._fall = entry & ~1        # the first block is entered by the call: no branch of ours to charge
        self._fault = self._hook_error = None
        native = self._native
        if native is not None:         # the counters live in the native hook's state during the call
            counters = native.counters
            counters[0] = counters[1] = counters[2] = 0
            counters[3], counters[4] = self._fall, self.max_instructions
        # the instruction limit: with the block hook it counts them itself (unicorn's own count adds a callback per
        # instruction, which costs more than the call's blocks); without the hook, unicorn's count
        count = 0 if self.cycle_model is not None else self.max_instructions
        try:
            if raw is not None:
                raw.start(entry, HALT, count)
            else:
                uc.emu_start(entry, HALT, count=count)
        except UcError as error:
            raise self._failed(self._fault_from(error, name)) from None
        finally:
            if native is not None:
                self._cycles, self._instructions, self._extra, self._fall = counters[:4]
        if self._hook_error is not None:
            raise RuntimeError(f"counting the cycles of {name} failed: {self._hook_error}") from self._hook_error
        if native is not None and self._fault is None and self._instructions <= self.max_instructions:
            pc = HALT      # the native hook stops a call only past its instruction limit, or a fault's hook does
        else:
            pc = raw.read_register(arm.UC_ARM_REG_PC) if raw is not None else uc.reg_read(arm.UC_ARM_REG_PC)
        if self._fault is not None:
            kind, what, at = self._fault
            raise self._failed(FirmwareFault(f"{name} in {self.name} raised a CPU exception at PC {at:#010x}"
                                             f"{self._inside(at)}: {what}", function=name, pc=at, kind=kind))
        if pc != HALT:
            raise self._failed(FirmwareFault(f"{name} in {self.name} did not return within "
                                             f"{self.max_instructions:,} instructions (an endless loop?), stopped at "
                                             f"PC {pc:#010x}", function=name, pc=pc, kind="endless loop"))
        data = raw.read(after[0], after[1]) if after is not None else None
        if self._stack_top <= self._stack_bottom:
            guard = _GUARD
        elif after is not None and after[2] is not None:
            guard = data[after[2]:after[2] + 4]
        else:
            guard = raw.read(self._stack_bottom, 4) if raw is not None else bytes(uc.mem_read(self._stack_bottom, 4))
        if guard != _GUARD:
            raise self._failed(FirmwareFault(f"{name} in {self.name} overflowed its stack "
                                             f"({self._stack_top - self._stack_bottom} bytes from "
                                             f"{self._stack_bottom:#010x})", function=name, pc=pc,
                                             kind="stack overflow"))
        if self.cycle_model is not None:
            if self._fall != HALT:     # the return itself is the last block's branch, taken
                self._cycles += self._extra
            self.last = CallStats(name, self._instructions, self._cycles)
            self.total_cycles += self._cycles
            if self._dwt is not None:
                self._sync_cyccnt()
        else:
            self.last = CallStats(name, None, None)
        return data

    # --- hooks ---------------------------------------------------------------------------------------------------

    def _on_block(self, _engine: object, address: int, size: int, _user_data: object) -> None:
        try:
            block = self._blocks.get((address, size))
            if block is None:
                block = self.cycle_model.block(address, size)
            cycles, extra, fall, count = block
            if address != self._fall:      # the previous block's final branch was taken
                cycles += self._extra
            self._cycles += cycles
            self._extra, self._fall = extra, fall
            self._instructions += count
            if self._instructions > self.max_instructions:   # an endless loop: stop here, `call` reports it
                self._uc.emu_stop()
        except Exception as error:         # a C callback must not raise: stop and report it
            self._hook_error = error
            self._uc.emu_stop()

    def _on_block_native(self, _engine: object, address: int, size: int, _user_data: object) -> None:
        """`_on_block` for the native hook's blocks it has not seen (and calls past their instruction limit): the
        block's cost computed and entered in its table, and counted here with the same rule on its state."""
        try:
            block = self._blocks.get((address, size))
            if block is None:
                block = self.cycle_model.block(address, size)
            native = self._native
            native.learn(address, size, block)
            state = native.state
            cycles, extra, fall, count = block
            if address != state[FALL]:
                cycles += int(state[EXTRA])
            state[CYCLES] += cycles
            state[EXTRA], state[FALL] = extra, fall
            state[INSTRUCTIONS] += count
            if state[INSTRUCTIONS] > self.max_instructions:
                self._uc.emu_stop()
        except Exception as error:         # a C callback must not raise: stop and report it
            self._hook_error = error
            self._uc.emu_stop()

    def _call_cycles(self) -> int:
        """The cycles counted so far in the running call."""
        return int(self._native.state[CYCLES]) if self._native is not None else self._cycles

    def cyccnt(self) -> int:
        """What DWT_CYCCNT reads between calls: the cycles of every call so far."""
        return (self.total_cycles - self._cyccnt_base) & 0xFFFF_FFFF

    def _on_dwt_read(self, _uc: Uc, offset: int, _size: int, _user: object) -> int:
        """DWT_CYCCNT: the cycles counted so far (whole blocks: a block's cost is added when it is entered, so a
        difference of two reads is exact to within the instructions after the second read in its block)."""
        if offset != 4:
            return 0
        return (self.total_cycles + self._call_cycles() - self._cyccnt_base) & 0xFFFF_FFFF

    def _on_dwt_write(self, _uc: Uc, offset: int, _size: int, value: int, _user: object) -> None:
        if offset == 4:            # DWT_CYCCNT = value
            self._cyccnt_base = (self.total_cycles + self._call_cycles() - value) & 0xFFFF_FFFF
            if self._dwt is not None:
                self._sync_cyccnt()

    def _sync_cyccnt(self) -> None:
        """What DWT_CYCCNT reads at a call's start, for the native read (`native_hook.dwt_read`)."""
        self._native.counters[CYCCNT_BEFORE] = self.total_cycles - self._cyccnt_base

    def _on_invalid_memory(self, uc: Uc, access: int, address: int, size: int, value: int, _user: object) -> bool:
        what = _ACCESS.get(access, f"invalid access {access} to address")
        self._fault = ("memory", f"{what} {address:#010x} ({size} bytes)", uc.reg_read(arm.UC_ARM_REG_PC))
        return False                   # not handled: emulation stops with an error

    def _on_exception(self, uc: Uc, number: int, _user: object) -> None:
        what = _EXCEPTIONS.get(number, f"CPU exception {number}")
        self._fault = ("exception", what, uc.reg_read(arm.UC_ARM_REG_PC))
        uc.emu_stop()

    def _failed(self, fault: FirmwareFault) -> FirmwareFault:
        """Re-arm the stack guard so the next call is not blamed for this one's overflow."""
        if self._stack_top > self._stack_bottom:
            self._uc.mem_write(self._stack_bottom, _GUARD)
        self.last = CallStats(fault.function, None, None)
        return fault

    def _fault_from(self, error: UcError, name: str) -> FirmwareFault:
        pc = self._uc.reg_read(arm.UC_ARM_REG_PC)
        if self._fault is not None and self._fault[0] == "memory":
            _, what, at = self._fault
            sp = self._uc.reg_read(arm.UC_ARM_REG_SP)
            if sp < self._stack_bottom:    # ran off the bottom of its stack into unmapped or protected memory
                return FirmwareFault(f"{name} in {self.name} overflowed its stack (SP {sp:#010x} below its bottom "
                                     f"{self._stack_bottom:#010x}) and faulted at PC {at:#010x}: {what}",
                                     function=name, pc=at, kind="stack overflow")
            return FirmwareFault(f"{name} in {self.name} faulted at PC {at:#010x}{self._inside(at)}: {what}",
                                 function=name, pc=at, kind="memory")
        if error.errno == UC_ERR_INSN_INVALID:
            return FirmwareFault(f"{name} in {self.name} hit an undefined instruction at PC {pc:#010x}"
                                 f"{self._inside(pc)}{self._disassemble(pc)}", function=name, pc=pc,
                                 kind="undefined instruction")
        return FirmwareFault(f"{name} in {self.name} stopped at PC {pc:#010x} with an emulator error: {error}",
                             function=name, pc=pc, kind="exception")

    def _inside(self, pc: int) -> str:
        """" (in fw_step)": the function of the image holding `pc`, when the symbol table says."""
        for name, symbol in self.symbols.items():
            if symbol.kind == "STT_FUNC" and symbol.address <= pc < symbol.address + max(symbol.size, 1):
                return f" (in {name})"
        return ""

    def _disassemble(self, pc: int) -> str:
        try:
            code = bytes(self._uc.mem_read(pc, 4))
        except UcError:
            return ""
        insn = next(new_disassembler().disasm(code, pc), None)
        return f" ({insn.mnemonic} {insn.op_str})".replace(" )", ")") if insn is not None else ""
