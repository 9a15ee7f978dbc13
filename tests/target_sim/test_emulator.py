"""The emulated Cortex-M4F: ELF checks, AAPCS calls bit-exact against numpy float32, counted cycles, faults, memory.

Fixture firmware (tests/target_sim/fixtures/) is built here with the project's compiler command; the emulator
itself never needs the compiler.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from elftools.elf.constants import SH_FLAGS
from elftools.elf.elffile import ELFFile
from unicorn import UC_HOOK_CODE

from target_sim.firmware import (
    CYCLES,
    PIPELINE_REFILL,
    Firmware,
    FirmwareError,
    FirmwareFault,
    emulator,
    memory_from_elf,
)
from target_sim.firmware.emulator import HALT

# the fixtures are compiled here (the ziglang dependency); the emulator itself runs without the compiler
FIXTURES = Path(__file__).resolve().parent / "fixtures"
TARGET = ["-target", "thumb-freestanding-eabihf", "-mcpu=cortex_m4+vfp4d16sp"]
FLAGS = ["-O2", "-ffp-contract=off", "-nostdlib"]
P = PIPELINE_REFILL


def zig_cc(*args: str | Path) -> None:
    done = subprocess.run([sys.executable, "-m", "ziglang", "cc", *map(str, args)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    """build(name, *compiler args) -> path of an ELF built once per module."""
    directory = tmp_path_factory.mktemp("firmware")
    built: dict[str, Path] = {}

    def make(name: str, *args: str | Path) -> Path:
        if name not in built:
            out = directory / name
            zig_cc(*args, "-o", out)
            built[name] = out
        return built[name]

    return make


@pytest.fixture(scope="module")
def elf(build) -> Path:
    return build("firmware.elf", *TARGET, *FLAGS, "-T", FIXTURES / "firmware.ld", FIXTURES / "firmware.c",
                 FIXTURES / "timing.S")


@pytest.fixture(scope="module")
def top_stack_elf(build) -> Path:
    return build("top_stack.elf", *TARGET, *FLAGS, "-T", FIXTURES / "firmware_top_stack.ld",
                 FIXTURES / "firmware.c", FIXTURES / "timing.S")


@pytest.fixture
def fw(elf) -> Firmware:
    return Firmware.load(elf)


# --- calls, bit for bit ------------------------------------------------------------------------------------------


def reference_step(A: np.ndarray, B: np.ndarray, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """fw_step of firmware.c in numpy float32, the same operations in the same order."""
    xn = np.empty(4, np.float32)
    for i in range(4):
        acc = B[i, 0] * u[0]
        acc = acc + B[i, 1] * u[1]
        for j in range(4):
            acc = acc + A[i, j] * x[j]
        xn[i] = acc
    d = np.float32(1.0) + u[1] * u[1]
    return xn, np.array([xn[i] / d for i in range(4)], np.float32)


def test_fw_step_equals_numpy_float32_bit_for_bit(fw):
    A = fw.read_f32(fw.address("A"), 16).reshape(4, 4)
    B = fw.read_f32(fw.address("B"), 8).reshape(4, 2)
    # the firmware's constants are the C literals rounded to float32, as numpy rounds them
    np.testing.assert_array_equal(A[0], np.array([0.95, 0.01, 0.0, 0.02], np.float32))
    np.testing.assert_array_equal(B[3], np.array([0.07, 0.003], np.float32))
    rng = np.random.default_rng(7)
    x = rng.uniform(20, 120, 4).astype(np.float32)
    u_address, y_address = fw.alloc_f32(2), fw.alloc_f32(4)
    fw.call("fw_reset", fw.alloc_f32(x))
    for _ in range(300):
        u = rng.uniform(-50, 250, 2).astype(np.float32)
        fw.write_f32(u_address, u)
        assert fw.call("fw_step", u_address, y_address) is None
        x, y_ref = reference_step(A, B, x, u)
        y = fw.read_f32(y_address, 4)
        np.testing.assert_array_equal(y.view(np.uint32), y_ref.view(np.uint32))
        np.testing.assert_array_equal(fw.read_f32(fw.address("x"), 4).view(np.uint32), x.view(np.uint32))
    assert fw.read_i32(fw.address("steps"), 1)[0] == 300


def test_int_and_mixed_arguments_follow_the_hard_float_convention(fw):
    # C truncates toward zero; ints in r0-r3 (negative ones as two's complement), the result in r0, signed
    assert fw.call("int_mix", 7, -5, 4, returns=int) == int((7 * -5 - 4) / 3) == -13
    assert fw.call("int_mix", 100000, 3, -1, returns=int) == 100000
    # floats in s0, s1 and ints in r0, r1, whatever their interleaving; float result in s0
    a, n, b, m = np.float32(1.1), 3, np.float32(0.3), -7
    expected = a * np.float32(n) - b * np.float32(m) + np.float32(2.5)
    got = fw.call("mixed_args", float(a), n, b, m, returns=float)
    assert np.float32(got).view(np.uint32) == expected.view(np.uint32)
    assert got == float(expected)     # a float32 value, exact as a Python float
    # by address as well as by name
    assert fw.call(fw.address("int_mix"), 9, 1, 0, returns=int) == 3


def test_data_is_initialised_bss_zeroed_and_reset_restores_both(fw):
    gain = fw.address("gain")
    assert fw.read_f32(gain, 1)[0] == np.float32(2.5)          # copied from its load address in flash
    assert fw.read_i32(fw.address("steps"), 1)[0] == 0
    fw.write_f32(gain, [4.0])
    fw.call("fw_step", fw.alloc_f32(2), fw.alloc_f32(4))
    assert fw.read_i32(fw.address("steps"), 1)[0] == 1
    assert fw.call("mixed_args", 0.0, 0, 0.0, 0, returns=float) == 4.0
    fw.reset()
    assert fw.read_f32(gain, 1)[0] == np.float32(2.5)
    assert fw.read_i32(fw.address("steps"), 1)[0] == 0


def test_bad_arguments_and_names_are_one_sentence_errors(fw):
    with pytest.raises(FirmwareError, match="has no function 'nope'"):
        fw.call("nope")
    with pytest.raises(FirmwareError, match="neither an int nor a float"):
        fw.call("int_mix", "7", 1, 2)
    with pytest.raises(FirmwareError, match="more than 4 integer arguments"):
        fw.call("int_mix", 1, 2, 3, 4, 5)
    with pytest.raises(FirmwareError, match="no symbol 'missing'"):
        fw.address("missing")


# --- cycles ------------------------------------------------------------------------------------------------------

# straight (timing.S), one line per instruction: cycles by the table of target_sim.firmware.cycles
STRAIGHT = [
    ("push {r4, lr}", 1 + 2),
    ("movs r1, #3", 1), ("adds r0, r0, r1", 1), ("mul r0, r1, r0", 1), ("mla r0, r0, r1, r1", 1),
    ("vmov s0, r0", 1), ("vcvt.f32.s32 s0, s0", 1), ("vmul.f32 s1, s0, s0", 1), ("vadd.f32 s0, s0, s1", 1),
    ("vdiv.f32 s0, s0, s1", 14), ("vsqrt.f32 s2, s1", 14), ("vmla.f32 s0, s1, s2", 3), ("vfma.f32 s0, s1, s2", 3),
    ("sub sp, #8", 1), ("vstr s0, [sp]", 2), ("vldr s3, [sp]", 2), ("str r0, [sp, #4]", 2),
    ("ldr r1, [sp, #4]", 2), ("add sp, #8", 1), ("sdiv r0, r0, r1", 12),
    ("vpush {s16, s17}", 1 + 2), ("vpop {s16, s17}", 1 + 2),
    ("pop {r4, pc}", 1 + 2 + P),
]


def test_straight_line_cycles_are_the_table_sum(fw):
    assert fw.call("straight", 1, returns=int) == 1
    assert fw.last.instructions == len(STRAIGHT) == 23
    assert fw.last.cycles == sum(cycles for _, cycles in STRAIGHT) == 78
    start = fw.address("straight")
    costs = [fw.cycle_model.instructions[address] for address in sorted(fw.cycle_model.instructions)
             if start <= address < fw.address("count_down")]
    assert [(cost.text, cost.cycles) for cost in costs] == STRAIGHT


def test_loop_counts_taken_and_not_taken_branches(fw):
    # movs; n x (cbz not taken 1, adds 1, subs 1, b taken 1+P); cbz taken 1+P; mov; bx lr 1+P
    for n in (0, 1, 5, 40):
        assert fw.call("count_down", n, returns=int) == n * (n + 1) // 2
        assert fw.last.instructions == 4 + 4 * n
        assert fw.last.cycles == 1 + n * (1 + 1 + 1 + (1 + P)) + (1 + P) + 1 + (1 + P)


def test_conditional_return_inside_an_it_block_and_a_call(fw):
    # cmp, itt, moveq, bxeq lr taken (1+P) | cmp, itt, moveq (counted executed), bxeq failed (1), movs, bx lr
    assert fw.call("is_zero", 0, returns=int) == 1
    assert (fw.last.instructions, fw.last.cycles) == (4, 1 + 1 + 1 + (1 + P))
    assert fw.call("is_zero", 5, returns=int) == 2
    assert (fw.last.instructions, fw.last.cycles) == (6, 1 + 1 + 1 + 1 + 1 + (1 + P))
    # push {r4, lr}, bl (1+P), is_zero, adds, pop {r4, pc} (1+2+P)
    assert fw.call("calls_is_zero", 0, returns=int) == 11
    assert fw.last.cycles == 3 + (1 + P) + 6 + 1 + (1 + 2 + P)
    assert fw.call("calls_is_zero", 5, returns=int) == 12
    assert fw.last.cycles == 3 + (1 + P) + 8 + 1 + (1 + 2 + P)


def test_single_instruction_costs_follow_the_rules(fw):
    start = fw.address("cost_probe")
    costs = {cost.text: cost for address, cost in fw.cycle_model.instructions.items() if address >= start}
    expected = {
        "ldm r0!, {r1, r2, r3}": 1 + 3, "push.w {r4, r5}": 1 + 2, "vpush {d8, d9}": 1 + 4, "vldr d0, [r0]": 3,
        "vmov r0, r1, s0, s1": 2, "vmov s0, r0": 1, "ldrd r0, r1, [r2]": 3, "udiv r0, r1, r2": CYCLES["udiv"],
        "vnmls.f32 s0, s1, s2": 3, "vcmpe.f32 s0, #0": 1, "vmrs apsr_nzcv, fpscr": 1,
        "pop {r4, r5, r6, pc}": 1 + 4 + P,
    }
    assert {text: costs[text].cycles for text in expected} == expected
    assert costs["pop {r4, r5, r6, pc}"].writes_pc and not costs["pop {r4, r5, r6, pc}"].conditional_branch


def traced_cycles(fw: Firmware, function: str, *args) -> tuple[int, int]:
    """(instructions, cycles) of one call from an instruction-by-instruction trace: a check of the block hook."""
    trace: list[int] = []
    hook = fw.uc.hook_add(UC_HOOK_CODE, lambda uc, address, size, _: trace.append(address))
    try:
        fw.call(function, *args)
    finally:
        fw.uc.hook_del(hook)
    cycles = 0
    for address, following in zip(trace, [*trace[1:], HALT], strict=True):
        cost = fw.cycle_model.instructions[address]
        taken = following != address + cost.size
        cycles += cost.cycles + (cost.taken_extra if cost.conditional_branch and taken else 0)
    return len(trace), cycles


def test_block_counts_equal_an_instruction_trace(fw):
    u, y = fw.alloc_f32([3.0, 40.0]), fw.alloc_f32(4)
    for function, args in (("fw_step", (u, y)), ("recurse", (6,)), ("count_down", (9,)), ("is_zero", (0,))):
        fw.reset()
        instructions, cycles = traced_cycles(fw, function, *args)
        fw.reset()
        fw.call(function, *args)
        assert (fw.last.instructions, fw.last.cycles) == (instructions, cycles), function
    fw.call("fw_step", u, y)
    assert 100 < fw.last.instructions < fw.last.cycles
    assert fw.cycle_model.unknown == set()


def test_the_bindings_hook_add_counts_the_same(elf, monkeypatch):
    monkeypatch.setattr(emulator, "NATIVE_BLOCK_HOOK", False)
    monkeypatch.setattr(emulator, "RAW_BLOCK_HOOK", False)
    fw = Firmware.load(elf)
    assert fw.call("count_down", 5, returns=int) == 15
    assert (fw.last.instructions, fw.last.cycles) == (24, 38)


def test_the_native_block_hook_counts_what_the_python_hook_counts(elf, fw, monkeypatch):
    """The compiled hook (`native_hook`) against the Python one: instructions, cycles, the DWT count the firmware
    reads and the endless-loop fault, call for call, from its first (unseen) blocks on."""
    monkeypatch.setattr(emulator, "NATIVE_BLOCK_HOOK", False)
    python = Firmware.load(elf)
    assert fw._native is not None and python._native is None
    seen = []
    for firmware in (fw, python):
        u, y = firmware.alloc_f32([5.0, 90.0]), firmware.alloc_f32(4)
        firmware.call("fw_reset", firmware.alloc_f32([50.0, 60.0, 70.0, 80.0]))
        counts = []
        for n in range(30):
            firmware.write_f32(u, [5.0 + 7 * n, 90.0 - n])
            firmware.call("fw_step", u, y)
            counts.append((firmware.last.instructions, firmware.last.cycles, firmware.cyccnt(),
                           firmware.read_f32(y, 4).tobytes()))
        for function, args in (("recurse", (6,)), ("count_down", (9,)), ("is_zero", (0,))):
            firmware.call(function, *args)
            counts.append((firmware.last.instructions, firmware.last.cycles, firmware.cyccnt()))
        firmware.max_instructions = 5000
        with pytest.raises(FirmwareFault) as raised:
            firmware.call("spin_forever")
        counts.append((raised.value.kind, raised.value.pc))
        seen.append(counts)
    assert seen[0] == seen[1]


@pytest.mark.parametrize("function", ["read_bad_pointer", "trap", "spin_forever", "recurse"])
def test_the_bindings_calls_give_the_same_results_counts_and_faults(elf, fw, monkeypatch, function):
    """RAW_CALLS off: registers, memory and emu_start through the binding's wrappers, as before the fast path."""
    monkeypatch.setattr(emulator, "RAW_CALLS", False)
    slow = Firmware.load(elf)
    assert slow._raw is None and fw._raw is not None
    results = []
    for firmware in (fw, slow):
        u, y = firmware.alloc_f32([5.0, 90.0]), firmware.alloc_f32(4)
        firmware.call("fw_reset", firmware.alloc_f32([50.0, 60.0, 70.0, 80.0]))
        firmware.call("fw_step", u, y)
        mixed = firmware.call("mixed_args", 1.1, 3, 0.3, -7, returns=float)
        results.append((firmware.read_f32(y, 4).tobytes(), firmware.last.cycles, mixed,
                        firmware.call("int_mix", 7, -5, 4, returns=int), firmware.call("count_down", 5, returns=int),
                        firmware.last.cycles))
        with pytest.raises(FirmwareFault) as raised:
            firmware.call(function, *((100,) if function == "recurse" else ()))
        results.append((raised.value.kind, raised.value.pc))
    assert results[:2] == results[2:]


def test_an_error_inside_the_block_hook_stops_the_call_and_is_reported(fw, monkeypatch):
    def broken(address: int, size: int):
        raise ValueError("no such block")

    fw.cycle_model.blocks.clear()
    monkeypatch.setattr(fw.cycle_model, "block", broken)
    with pytest.raises(RuntimeError, match="counting the cycles of count_down failed: no such block"):
        fw.call("count_down", 3)


def test_without_the_block_hook_results_are_the_same_and_counts_are_none(elf, fw):
    fast = Firmware.load(elf, count_cycles=False)
    for firmware in (fw, fast):
        firmware.call("fw_reset", firmware.alloc_f32([50.0, 60.0, 70.0, 80.0]))
    u_fw, y_fw, u_fast, y_fast = fw.alloc_f32([5.0, 90.0]), fw.alloc_f32(4), fast.alloc_f32([5.0, 90.0]), \
        fast.alloc_f32(4)
    for _ in range(20):
        fw.call("fw_step", u_fw, y_fw)
        fast.call("fw_step", u_fast, y_fast)
    np.testing.assert_array_equal(fw.read_f32(y_fw, 4).view(np.uint32), fast.read_f32(y_fast, 4).view(np.uint32))
    assert fast.last.cycles is None and fast.last.instructions is None and fast.cycle_model is None


# --- faults --------------------------------------------------------------------------------------------------------


@pytest.mark.timing
@pytest.mark.parametrize(("function", "args", "kind", "text"), [
    ("read_bad_pointer", (), "memory", "read of unmapped address 0x40000000"),
    ("write_flash", (), "memory", "write to read-only address 0x08000010"),
    ("call_null", (), "memory", "instruction fetch from unmapped address 0x00000000"),
    ("trap", (), "undefined instruction", "undefined instruction"),
    ("spin_forever", (), "endless loop", "did not return within 1,000,000 instructions"),
    ("recurse", (100,), "stack overflow", "overflowed its stack"),
])
def test_faults_raise_one_sentence_quickly_and_leave_the_core_usable(fw, function, args, kind, text):
    started = time.perf_counter()
    with pytest.raises(FirmwareFault) as raised:
        fw.call(function, *args)
    assert time.perf_counter() - started < 2.0
    fault = raised.value
    assert (fault.function, fault.kind) == (function, kind)
    assert text in str(fault) and function in str(fault) and f"{fault.pc:#010x}" in str(fault)
    assert str(fault).count(". ") == 0 and "\n" not in str(fault)
    if kind in ("memory", "undefined instruction") and function != "call_null":
        symbol = fw.symbols[function]
        assert symbol.address <= fault.pc < symbol.address + symbol.size
    assert fw.last.cycles is None
    assert fw.call("int_mix", 7, 2, 2, returns=int) == 4       # the next call runs normally
    assert fw.last.cycles is not None


def test_an_exception_instruction_is_a_fault(fw):
    # a BKPT written over fw_reset's first instruction (flash is writable from the host only)
    fw.write_bytes(fw.address("fw_reset"), bytes.fromhex("00be"))
    with pytest.raises(FirmwareFault, match=r"breakpoint \(BKPT\)") as raised:
        fw.call("fw_reset", fw.alloc_f32(4))
    assert raised.value.kind == "exception" and raised.value.pc == fw.address("fw_reset")


def test_stack_overflow_into_free_ram_is_caught_by_the_guard(top_stack_elf):
    fw = Firmware.load(top_stack_elf)
    bottom, top = fw.stack
    assert (top, top - bottom) == (0x2001_0000, 0x800)        # _estack and _stack_size of the linker script
    assert fw.call("recurse", 4, returns=int) == 4 + 3 + 2 + 1
    assert 4 * 256 < fw.stack_used() < 0x800
    with pytest.raises(FirmwareFault, match="overflowed its stack") as raised:
        fw.call("recurse", 12)                                  # 13 frames of > 256 bytes: past 2 kB, into free RAM
    assert raised.value.kind == "stack overflow"
    assert fw.call("recurse", 1, returns=int) == 1              # the guard is re-armed


def test_instruction_limit_is_configurable(elf):
    fw = Firmware.load(elf, max_instructions=50)
    assert fw.call("count_down", 5, returns=int) == 15          # 24 instructions
    with pytest.raises(FirmwareFault, match="within 50 instructions"):
        fw.call("count_down", 20)


# --- ELF checks ------------------------------------------------------------------------------------------------


def test_accepts_the_project_build_and_reads_its_symbols(elf):
    fw = Firmware.load(elf.read_bytes())
    assert fw.symbols["fw_step"].kind == "STT_FUNC" and fw.symbols["fw_step"].thumb
    assert fw.address("fw_step") % 2 == 0
    assert fw.address("gain") == 0x2000_0000


@pytest.mark.parametrize(("variant", "args", "message"), [
    ("softfloat.elf", ["-target", "thumb-freestanding-eabi", "-mcpu=cortex_m4"], "soft-float calling convention"),
    ("nofpu.elf", ["-target", "thumb-freestanding-eabihf", "-mcpu=cortex_m4"], "without an FPU"),
    ("m7.elf", ["-target", "thumb-freestanding-eabihf", "-mcpu=cortex_m7+fp_armv8d16sp"], "FPv5"),
])
def test_rejects_arm_elves_for_another_fpu_or_abi(build, tmp_path, variant, args, message):
    source = tmp_path / "add.c"
    source.write_text("int add(int a, int b) { return a + b; }\n")
    path = build(variant, *args, "-O2", "-nostdlib", "-T", FIXTURES / "firmware.ld", source)
    with pytest.raises(FirmwareError, match=message) as raised:
        Firmware.load(path)
    assert str(path) in str(raised.value) and "\n" not in str(raised.value)


def test_rejects_files_that_are_not_cortex_m4f_firmware(build, tmp_path):
    host = Path(os.path.realpath(sys.executable))
    with pytest.raises(FirmwareError, match=r"is an ELF for .*not for an ARM Cortex-M4F") as raised:
        Firmware.load(host)
    assert str(host) in str(raised.value)
    with pytest.raises(FirmwareError, match="is not an ELF file"):
        Firmware.load(FIXTURES / "firmware.c")
    with pytest.raises(FirmwareError, match="cannot read firmware"):
        Firmware.load(tmp_path / "missing.elf")
    obj = build("add.o", *TARGET, *FLAGS, "-c", FIXTURES / "firmware.c")
    with pytest.raises(FirmwareError, match="not a linked executable"):
        Firmware.load(obj)


def test_rejects_a_truncated_elf_and_one_that_does_not_fit_the_memory_map(elf):
    with pytest.raises(FirmwareError, match="<firmware bytes> is not a readable ELF file"):
        Firmware.load(elf.read_bytes()[:200])
    with pytest.raises(FirmwareError, match="outside flash 0x08000000"):
        Firmware.load(elf, ram=(0x2000_0000, 0x1000))            # the 4 kB stack section does not fit


# --- memory figures ------------------------------------------------------------------------------------------


def section_sizes(path: Path) -> dict[str, tuple[int, int, str]]:
    with path.open("rb") as file:
        return {section.name: (section["sh_size"], section["sh_flags"], section["sh_type"])
                for section in ELFFile(file).iter_sections() if section["sh_flags"] & SH_FLAGS.SHF_ALLOC}


def test_memory_from_elf_sums_the_sections(elf):
    sizes = section_sizes(elf)
    memory = memory_from_elf(elf)
    unwind = [name for name in sizes if name.startswith(".ARM.ex")]      # .ARM.exidx/.ARM.extab: C unwind tables
    in_flash = [".text", ".rodata", *unwind, ".data"]
    assert sorted(in_flash) == sorted(name for name, (_, _, kind) in sizes.items() if kind != "SHT_NOBITS")
    assert memory["flash_bytes"] == sum(sizes[name][0] for name in in_flash)
    assert memory["ram_bytes"] == sizes[".data"][0] + sizes[".bss"][0] + sizes[".stack"][0]
    assert memory["stack_bytes"] == sizes[".stack"][0] == 0x1000
    assert memory["sections"] == {name: size for name, (size, _, _) in sizes.items()}
    assert sizes[".data"][0] == 4 and sizes[".bss"][0] == 4 * 4 + 4     # gain; x[4] and steps
    assert Firmware.load(elf).memory == memory


def test_memory_from_elf_adds_a_stack_size_symbol(top_stack_elf):
    sizes = section_sizes(top_stack_elf)
    memory = memory_from_elf(top_stack_elf)
    assert ".stack" not in sizes
    assert memory["stack_bytes"] == 0x800
    assert memory["ram_bytes"] == sizes[".data"][0] + sizes[".bss"][0] + 0x800
    assert memory["flash_bytes"] == memory_from_elf(top_stack_elf.read_bytes())["flash_bytes"]
