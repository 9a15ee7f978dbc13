"""A bare-metal Cortex-M4F firmware image read from its ELF file: checks, loadable segments, symbols, memory figures.

The checks refuse, with one sentence naming the file, anything the emulated Cortex-M4F cannot run as intended: a
file that is not ELF, an ELF for another machine, class or byte order, an unlinked object, a soft-float ABI (floats
passed in core registers), an image built without an FPU or for another FPU (FPv5 of the M7/M33), or for a core
that is not M-profile. They read the ELF header's e_flags (EABI version 5, hard-float ABI) and the
`.ARM.attributes` build attributes (Tag_CPU_arch, Tag_CPU_arch_profile, Tag_FP_arch, Tag_ABI_VFP_args).
"""

from __future__ import annotations

import bisect
import io
import os
from dataclasses import dataclass
from pathlib import Path

from elftools.common.exceptions import ELFError
from elftools.elf.constants import SH_FLAGS
from elftools.elf.descriptions import describe_e_machine
from elftools.elf.elffile import ELFFile

from target_sim.errors import TargetError

EF_ARM_EABIMASK = 0xFF000000
EF_ARM_EABI_VER5 = 0x05000000
EF_ARM_ABI_FLOAT_SOFT = 0x200
EF_ARM_ABI_FLOAT_HARD = 0x400

# .ARM.attributes values the Cortex-M4F runs (ARM IHI 0045, "Addenda to the ARM ABI")
M_PROFILE_ARCHS = {10: "v7-M", 11: "v6-M", 12: "v6S-M", 13: "v7E-M"}        # Tag_CPU_arch (10 = v7, with profile M)
PROFILE_M = ord("M")                                                        # Tag_CPU_arch_profile
FP_ARCHS = {2: "VFPv2", 4: "VFPv3-D16", 6: "VFPv4-D16"}                     # Tag_FP_arch: subsets of FPv4-SP-D16
FP_ARCH_NAMES = {1: "VFPv1", 3: "VFPv3", 5: "VFPv4", 7: "FPv5/ARMv8-A FP", 8: "FPv5-D16 (Cortex-M7/M33)"}
VFP_ARGS_IN_VFP_REGISTERS = 1                                               # Tag_ABI_VFP_args

# linker-script symbols of a reserved stack, by common spelling
STACK_SIZE_SYMBOLS = ("_stack_size", "__stack_size", "_Min_Stack_Size", "__STACK_SIZE", "_STACK_SIZE")
STACK_TOP_SYMBOLS = ("_estack", "__stack_top", "_stack_top", "__StackTop", "__stack", "_stack_end")


class FirmwareError(TargetError):
    """A firmware image the emulated Cortex-M4F cannot load: the message is one sentence naming the file."""


@dataclass(frozen=True)
class Segment:
    """A PT_LOAD segment: `data` (its file image) goes to `vaddr`, and to `paddr` too where they differ."""

    vaddr: int
    paddr: int
    data: bytes
    memsz: int
    flags: int


@dataclass(frozen=True)
class Symbol:
    """A .symtab symbol; `address` has the Thumb bit cleared."""

    name: str
    address: int
    size: int
    kind: str        # "STT_FUNC", "STT_OBJECT", "STT_NOTYPE", ...
    thumb: bool      # a function whose value had bit 0 set


@dataclass(frozen=True)
class Section:
    """An allocated section: where it runs (`address`), how big, whether it has an image in the file."""

    name: str
    address: int
    size: int
    has_image: bool   # not NOBITS: its bytes are part of the flash image (.data at its load address)
    writable: bool
    executable: bool


@dataclass(frozen=True)
class ElfImage:
    """What the emulator needs of a checked firmware ELF."""

    name: str
    segments: tuple[Segment, ...]
    symbols: dict[str, Symbol]
    sections: tuple[Section, ...]
    thumb_ranges: tuple[tuple[int, int], ...]   # [start, end) of code, from the $t/$d/$a mapping symbols
    lines: tuple[tuple[int, str, int], ...] = ()   # (address, source file name, line), by address: the DWARF line
                                                   # table of an image built with one (none: -g0)

    def line_of(self, address: int) -> tuple[str, int] | None:
        """(source file name, line) of the instruction at `address`, from the line table (None without one)."""
        index = bisect.bisect_right(self.lines, (address, "\uffff", 1 << 30)) - 1
        if index < 0:
            return None
        _, name, line = self.lines[index]
        return (name, line) if line > 0 else None


def _read_source(source: str | os.PathLike | bytes) -> tuple[bytes, str]:
    if isinstance(source, bytes | bytearray | memoryview):
        return bytes(source), "<firmware bytes>"
    path = Path(source)
    try:
        return path.read_bytes(), str(path)
    except OSError as error:
        raise FirmwareError(f"cannot read firmware {path}: {error.strerror or error}") from None


def _attributes(elf: ELFFile) -> dict[str, object] | None:
    section = elf.get_section_by_name(".ARM.attributes")
    if section is None or not hasattr(section, "iter_subsections"):
        return None
    found: dict[str, object] = {}
    for subsection in section.iter_subsections():
        if subsection.header["vendor_name"] != "aeabi":
            continue
        for subsubsection in subsection.iter_subsubsections():
            for attribute in subsubsection.iter_attributes():
                found.setdefault(attribute.tag, attribute.value)
    return found


def _check(elf: ELFFile, name: str) -> None:
    """Raise FirmwareError unless the ELF is a linked hard-float image for an M-profile core with FPv4-SP."""
    machine = elf["e_machine"]
    if machine != "EM_ARM":
        raise FirmwareError(f"{name} is an ELF for {describe_e_machine(machine)} ({machine}), "
                            "not for an ARM Cortex-M4F")
    if elf.elfclass != 32 or not elf.little_endian:
        raise FirmwareError(f"{name} is a {elf.elfclass}-bit {'little' if elf.little_endian else 'big'}-endian "
                            "ARM ELF, not a 32-bit little-endian one for a Cortex-M4F")
    if elf["e_type"] != "ET_EXEC":
        raise FirmwareError(f"{name} is not a linked executable ({elf['e_type']}): link it with the firmware's "
                            "linker script first")
    flags = elf["e_flags"]
    if flags & EF_ARM_EABIMASK != EF_ARM_EABI_VER5:
        raise FirmwareError(f"{name} is not an EABI version 5 ARM ELF (e_flags 0x{flags:08x})")
    attributes = _attributes(elf)
    if attributes is None:
        raise FirmwareError(f"{name} has no .ARM.attributes section, so its core and FPU cannot be checked")
    if not flags & EF_ARM_ABI_FLOAT_HARD or attributes.get("TAG_ABI_VFP_ARGS") != VFP_ARGS_IN_VFP_REGISTERS:
        raise FirmwareError(f"{name} uses the soft-float calling convention (floats in core registers): build it "
                            "with -target thumb-freestanding-eabihf -mcpu=cortex_m4+vfp4d16sp")
    arch = attributes.get("TAG_CPU_ARCH")
    profile = attributes.get("TAG_CPU_ARCH_PROFILE")
    if arch not in M_PROFILE_ARCHS or profile not in (None, 0, PROFILE_M):
        shown = chr(profile) if isinstance(profile, int) and profile else "?"
        raise FirmwareError(f"{name} is built for CPU architecture {arch} profile {shown}, not for an "
                            "M-profile core (Tag_CPU_arch v6-M/v7-M/v7E-M) a Cortex-M4F runs")
    fp_arch = attributes.get("TAG_FP_ARCH")
    if fp_arch is None or fp_arch == 0:
        raise FirmwareError(f"{name} is built without an FPU (no Tag_FP_arch): build it with "
                            "-mcpu=cortex_m4+vfp4d16sp")
    if fp_arch not in FP_ARCHS:
        raise FirmwareError(f"{name} is built for the {FP_ARCH_NAMES.get(fp_arch, f'Tag_FP_arch {fp_arch}')} FPU, "
                            "not the Cortex-M4F's FPv4-SP-D16")


def _thumb_ranges(elf: ELFFile, symbols: list) -> tuple[tuple[int, int], ...]:
    """Code ranges of the executable sections, split by the ARM mapping symbols ($t code, $d data)."""
    ranges: list[tuple[int, int]] = []
    for section in elf.iter_sections():
        if not section["sh_flags"] & SH_FLAGS.SHF_EXECINSTR or section["sh_size"] == 0:
            continue
        start, end = section["sh_addr"], section["sh_addr"] + section["sh_size"]
        marks = sorted((symbol["st_value"], symbol.name[1]) for symbol in symbols
                       if symbol.name[:2] in ("$t", "$d", "$a") and start <= symbol["st_value"] < end)
        if not marks:   # no mapping symbols (stripped): take the whole section for code
            ranges.append((start, end))
            continue
        for index, (address, kind) in enumerate(marks):
            if kind == "t":
                ranges.append((address, marks[index + 1][0] if index + 1 < len(marks) else end))
    return tuple(ranges)


def _line_table(elf: ELFFile) -> tuple[tuple[int, str, int], ...]:
    """The DWARF line table's rows (address, file name, line), sorted; an end of sequence ends a range (line 0)."""
    if not elf.has_dwarf_info() or elf.get_section_by_name(".debug_line") is None:
        return ()
    dwarf = elf.get_dwarf_info()
    rows: list[tuple[int, str, int]] = []
    for unit in dwarf.iter_CUs():
        program = dwarf.line_program_for_CU(unit)
        if program is None:
            continue
        files = program["file_entry"]
        base = 0 if program["version"] >= 5 else 1                # DWARF 5 numbers files from 0
        for entry in program.get_entries():
            state = entry.state
            if state is None:
                continue
            if state.end_sequence:
                rows.append((state.address, "", 0))
                continue
            index = state.file - base
            name = files[index].name if 0 <= index < len(files) else b"?"
            rows.append((state.address, Path(name.decode("utf-8", "replace")).name, state.line))
    return tuple(sorted(rows))


def read_elf(source: str | os.PathLike | bytes) -> ElfImage:
    """Parse and check a firmware ELF (a path or its bytes); FirmwareError if it is not one for a Cortex-M4F."""
    data, name = _read_source(source)
    if data[:4] != b"\x7fELF":
        raise FirmwareError(f"{name} is not an ELF file (it starts with {data[:4]!r})")
    try:
        elf = ELFFile(io.BytesIO(data))
        _check(elf, name)
        segments = tuple(Segment(seg["p_vaddr"], seg["p_paddr"], seg.data(), seg["p_memsz"], seg["p_flags"])
                         for seg in elf.iter_segments() if seg["p_type"] == "PT_LOAD" and seg["p_memsz"] > 0)
        symtab = elf.get_section_by_name(".symtab")
        raw = list(symtab.iter_symbols()) if symtab is not None else []
        symbols = {}
        for symbol in sorted(raw, key=lambda symbol: symbol["st_info"]["bind"] != "STB_GLOBAL"):  # globals win
            if not symbol.name or symbol.name.startswith("$") or symbol["st_shndx"] == "SHN_UNDEF":
                continue
            value, kind = symbol["st_value"], symbol["st_info"]["type"]
            thumb = kind == "STT_FUNC" and bool(value & 1)
            symbols.setdefault(symbol.name, Symbol(symbol.name, value & ~1 if thumb else value, symbol["st_size"],
                                                   kind, thumb))
        sections = tuple(
            Section(section.name, section["sh_addr"], section["sh_size"], section["sh_type"] != "SHT_NOBITS",
                    bool(section["sh_flags"] & SH_FLAGS.SHF_WRITE), bool(section["sh_flags"] & SH_FLAGS.SHF_EXECINSTR))
            for section in elf.iter_sections() if section["sh_flags"] & SH_FLAGS.SHF_ALLOC and section["sh_size"])
        thumb_ranges = _thumb_ranges(elf, raw)
        lines = _line_table(elf)
    except (ELFError, ValueError, KeyError, OSError) as error:   # truncated or malformed tables
        raise FirmwareError(f"{name} is not a readable ELF file: {error}") from None
    if not segments:
        raise FirmwareError(f"{name} has no loadable segments (PT_LOAD): nothing to run")
    return ElfImage(name, segments, symbols, sections, thumb_ranges, lines)


def stack_bytes(image: ElfImage) -> int:
    """The stack the linker script reserves: a .stack section, else a stack-size symbol, else 0."""
    for section in image.sections:
        if "stack" in section.name.lower() and section.writable:
            return section.size
    for name in STACK_SIZE_SYMBOLS:
        if name in image.symbols:
            return image.symbols[name].address
    return 0


def memory_from_elf(source: str | os.PathLike | bytes | ElfImage) -> dict:
    """Flash and RAM a firmware needs, from its ELF's allocated sections.

    flash_bytes = every allocated section with an image in the file (.text, .rodata, .ARM.exidx, and .data, whose
    initial values are stored in flash at its load address); ram_bytes = every writable allocated section (.data,
    .bss, a .stack or .heap section), plus the stack-size symbol's value (`_stack_size`, `__stack_size`, ...) when
    the stack is not a section of its own. `sections` maps each allocated section to its size; `stack_bytes` is
    the stack counted in RAM (0 when the linker script reserves none).
    """
    image = source if isinstance(source, ElfImage) else read_elf(source)
    flash = sum(section.size for section in image.sections if section.has_image)
    ram = sum(section.size for section in image.sections if section.writable)
    stack = stack_bytes(image)
    stack_is_section = any("stack" in section.name.lower() and section.writable for section in image.sections)
    if not stack_is_section:
        ram += stack
    return {"flash_bytes": flash, "ram_bytes": ram, "stack_bytes": stack,
            "sections": {section.name: section.size for section in image.sections}}
