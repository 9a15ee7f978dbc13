"""Cross-compile the generated C for a Cortex-M4F (clang and lld from the `ziglang` package) into firmware.elf.

    python -m ziglang cc  COMPILE_FLAGS -c fw_model.c -o fw_model.o     (and startup.c)
    python -m ziglang ld.lld LINK_FLAGS -T firmware.ld -Map=firmware.map -o firmware.elf startup.o fw_model.o

The build runs in a fresh temporary directory with fixed file names and relative paths, no debug information
(-g0) and no build id, so the ELF holds no path, time or random bytes: the same sources and toolchain give the
same bytes (a test builds twice and compares). The compiler runs with every warning an error, -Wdouble-promotion
and -Wconversion included, and with FMA contraction off: the firmware must do exactly the float32 operations the
Python reference does (`target_sim.model`).

Flags, and why:
* -target thumb-freestanding-eabihf -mcpu=cortex_m4+vfp4d16sp: Armv7E-M, FPv4-SP-D16, hard-float ABI (without
  +vfp4d16sp clang calls soft-float helpers, which -nostdlib cannot link);
* -O2 -ffp-contract=off (no fused multiply-add: the reference rounds every product);
* -fno-math-errno: __builtin_sqrtf (an electrical loss model's current) becomes the FPU's VSQRT.F32 alone, with no
  call to a libm sqrtf for the errno of a negative argument (there is no libm; the link would fail);
* -ffreestanding -nostdlib: no libc, and no memcpy/memset calls invented by the optimizer;
* -ffunction-sections -fdata-sections + --gc-sections: only what the entry points reach (firmware.ld KEEPs the
  fw_* functions, which nothing in the image calls);
* -fno-unwind-tables -fno-asynchronous-unwind-tables (and firmware.ld discards .ARM.exidx): no unwind tables in
  flash; -fomit-frame-pointer: zig's clang keeps r7 as a frame pointer otherwise.
"""

from __future__ import annotations

import hashlib
import re
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path

from bench.errors import BenchError
from bench.fileio import scratch_dir
from bench.firmware.codegen import HEADER_NAME, SOURCE_NAME, GeneratedSource
from dbc.lifeline import EXEC_FAILED, tied_command, tied_environment
from target_sim.firmware import FirmwareError, memory_from_elf

COMPILER: list[str] = [sys.executable, "-m", "ziglang"]    # tests point this elsewhere to simulate a missing one
# the compiler is the project's `ziglang` dependency, so a missing one means a broken installation
INSTALL_HINT = "reinstall the project (pip install -e . in a checkout), whose ziglang dependency is the compiler"
TIMEOUT_S = 300.0
STARTUP_NAME = "startup.c"
LINKER_SCRIPT_NAME = "firmware.ld"
NODE_NAMES = ("node.c", "node.h", "xcp.c")   # the CAN node and its XCP slave (included by node.c), hand-written
SHIM_NAME = "string.h"                   # declares the two memory functions node.c defines (there is no libc)
SUPPORT_FILES = (STARTUP_NAME, *NODE_NAMES, SHIM_NAME, LINKER_SCRIPT_NAME)
ISR_NAMES = ("foc_isr.c", "foc_isr.h")   # the motor-control interrupt, linked only into a timing image (isr=True)
ELF_NAME = "firmware.elf"
MAP_NAME = "firmware.map"

TARGET_FLAGS = ("-target", "thumb-freestanding-eabihf", "-mcpu=cortex_m4+vfp4d16sp")
CODE_FLAGS = ("-std=c99", "-O2", "-g0", "-ffp-contract=off", "-fno-math-errno", "-ffreestanding", "-nostdlib",
              "-fno-common", "-fno-unwind-tables", "-fno-asynchronous-unwind-tables", "-fomit-frame-pointer",
              "-ffunction-sections", "-fdata-sections", "-fno-stack-protector")
WARNING_FLAGS = ("-Wall", "-Wextra", "-Werror", "-Wpedantic", "-Wdouble-promotion", "-Wconversion", "-Wshadow",
                 "-Wmissing-prototypes", "-Wstrict-prototypes", "-Wcast-qual", "-Wundef")
LINK_FLAGS = ("--gc-sections", "--build-id=none", "-nostdlib", "-static", "--no-undefined", "--nmagic")


class ToolchainError(BenchError):
    """The cross-compiler is missing or failed; the message is one sentence."""


@dataclass(frozen=True)
class BuildResult:
    """What a build produced: the ELF's bytes, its map, the sources it was built from and its memory figures."""

    elf: bytes
    map_text: str
    sources: dict[str, str]          # file name -> text: fw_model.h/.c, startup.c, firmware.ld
    memory: dict                     # target_sim.firmware.memory_from_elf
    toolchain: str

    @property
    def elf_sha256(self) -> str:
        return hashlib.sha256(self.elf).hexdigest()

    @property
    def model_flash(self) -> dict[str, int]:
        """The model's own flash (fw_model.o in the map): `object_flash`."""
        return object_flash(self.map_text, Path(SOURCE_NAME).with_suffix(".o").name)

    @property
    def files(self) -> dict[str, bytes]:
        """Every output file of `bench firmware build`, by name."""
        out = {name: text.encode("utf-8") for name, text in self.sources.items()}
        out[ELF_NAME] = self.elf
        out[MAP_NAME] = self.map_text.encode("utf-8")
        return out


# one input section of the linker map: address, load address, size, alignment, "object:(section.name)"
_MAP_SECTION = re.compile(r"^\s*[0-9a-f]+\s+[0-9a-f]+\s+([0-9a-f]+)\s+\d+\s+(\S+?):\((\.[a-z]+)")


def object_flash(map_text: str, obj: str) -> dict[str, int]:
    """Flash bytes of one object of the link, from lld's map: {"code": .text, "constants": .rodata, "bytes": the
    sum} (its .bss and .data RAM are not flash; .data would be both and the model has none)."""
    sizes = {".text": 0, ".rodata": 0}
    for line in map_text.splitlines():
        match = _MAP_SECTION.match(line)
        if match and match.group(2) == obj and match.group(3) in sizes:
            sizes[match.group(3)] += int(match.group(1), 16)
    return {"code": sizes[".text"], "constants": sizes[".rodata"], "bytes": sizes[".text"] + sizes[".rodata"]}


def support_file(name: str) -> str:
    """startup.c or firmware.ld, shipped beside this module."""
    return (files("bench.firmware") / name).read_text(encoding="utf-8")


def _first_line(text: str) -> str:
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    errors = [line for line in lines if "error" in line.lower()]
    return (errors or lines or ["no output"])[0][:300]


def _run(args: list[str], cwd: Path, what: str) -> subprocess.CompletedProcess:
    """The compiler on `args`, tied to this process (`dbc.lifeline.tied_command`): a bench killed while it
    compiles (SIGKILL, a cancelled CI job) leaves no compiler running."""
    command = [*COMPILER, *args]
    try:
        done = subprocess.run(tied_command(command), cwd=cwd, capture_output=True, text=True, timeout=TIMEOUT_S,
                              env=tied_environment())
    except subprocess.TimeoutExpired:
        raise ToolchainError(f"{what} took longer than {TIMEOUT_S:g} s and was stopped; try again on a less "
                             "loaded machine") from None
    if done.returncode == EXEC_FAILED and done.stderr.startswith(f"{command[0]} cannot be started"):
        raise ToolchainError(f"the C cross-compiler cannot be started ({command[0]} not found); {INSTALL_HINT}")
    return done


_VERSIONS: dict[tuple[str, ...], str] = {}   # asked once per process and compiler: it cannot change meanwhile


def toolchain_version(cwd: Path | None = None) -> str:
    """'zig 0.17.1', or ToolchainError (one sentence) when `python -m ziglang` does not run."""
    key = tuple(COMPILER)
    if key not in _VERSIONS:
        done = _run(["version"], cwd or Path(tempfile.gettempdir()), "asking the compiler for its version")
        if done.returncode != 0 or not done.stdout.strip():
            raise ToolchainError(f"the C cross-compiler (python {' '.join(COMPILER[1:])}) is not available "
                                 f"({_first_line(done.stderr + done.stdout)}); {INSTALL_HINT}")
        _VERSIONS[key] = f"zig {done.stdout.strip()}"
    return _VERSIONS[key]


ISR_DEFINE = "-DNODE_WITH_ISR"            # the node of a timing image sends Timing5 (node.c)


def compile_flags(work: Path, *, isr: bool = False) -> list[str]:
    # the build directory's path never reaches the objects (there is no debug info, but be sure)
    code = [flag for flag in CODE_FLAGS if not (isr and flag == "-g0")]
    # a timing image carries the line table (no other debug information, the same code): the WCET analysis finds
    # the C loop of each machine loop by it, and that loop's stated bound (target_sim.firmware.wcet.loop_facts)
    lines = ("-gline-tables-only", "-gdwarf-4") if isr else ()
    return [*TARGET_FLAGS, *code, *lines, *WARNING_FLAGS, *((ISR_DEFINE,) if isr else ()), "-I.",
            f"-ffile-prefix-map={work}=."]


def firmware_sources(generated: GeneratedSource, *, isr: bool = False) -> dict[str, str]:
    """Every file a build compiles or links: the generated model and node files and the shipped support files
    (with `isr`, the motor-control interrupt's too)."""
    names = (*SUPPORT_FILES, *ISR_NAMES) if isr else SUPPORT_FILES
    return {**generated.files, **{name: support_file(name) for name in names}}


# told of each build step as it starts (its name, steps done, steps in all) and once at the end (all done)
StepReport = Callable[[str, int, int], None]


def _no_report(_step: str, _done: int, _total: int) -> None:
    pass


def build_firmware(generated: GeneratedSource, *, isr: bool = False, on_step: StepReport = _no_report
                   ) -> BuildResult:
    """Compile and link `generated` with the start-up code and linker script; ToolchainError if that fails.

    `isr` links the field-oriented current loop's interrupt (foc_isr.c) into the image as well, for
    `bench firmware timing`; without it the image is the engine's, byte for byte as before. `on_step` is told of
    each compile and the link as it starts (a compiler call has no progress of its own), then of the end."""
    version = toolchain_version()
    sources = firmware_sources(generated, isr=isr)
    with scratch_dir("firmware") as tmp:   # named by this process: a later bench removes it if we are killed
        work = Path(tmp)
        for name, text in sources.items():
            (work / name).write_text(text, encoding="utf-8")
        objects = []
        compiled = (STARTUP_NAME, SOURCE_NAME, NODE_NAMES[0], *ISR_NAMES[:1]) if isr else (
            STARTUP_NAME, SOURCE_NAME, NODE_NAMES[0])                    # node.c includes the packers' .c
        steps = len(compiled) + 1        # each compile and the link
        for index, source in enumerate(compiled):
            on_step(f"compiling {source}", index, steps)
            obj = Path(source).with_suffix(".o").name
            done = _run(["cc", *compile_flags(work, isr=isr), "-c", source, "-o", obj], work,
                        f"compiling {source}")
            if done.returncode != 0:
                raise ToolchainError(f"compiling {source} for the Cortex-M4F failed: "
                                     f"{_first_line(done.stderr + done.stdout)}")
            objects.append(obj)
        on_step(f"linking {ELF_NAME}", steps - 1, steps)
        done = _run(["ld.lld", *LINK_FLAGS, "-T", LINKER_SCRIPT_NAME, f"-Map={MAP_NAME}", "-o", ELF_NAME, *objects],
                    work, "linking the firmware")
        if done.returncode != 0:
            reason = _first_line(done.stderr + done.stdout)
            hint = ("the model does not fit the 256 kB flash / 64 kB RAM map" if "will not fit" in reason
                    or "overflowed" in reason else "see the linker's message")
            raise ToolchainError(f"linking the firmware failed ({hint}): {reason}")
        elf = (work / ELF_NAME).read_bytes()
        map_text = (work / MAP_NAME).read_text(encoding="utf-8")
    on_step("linked", steps, steps)
    try:
        memory = memory_from_elf(elf)
    except FirmwareError as exc:     # the linker wrote something the emulator cannot load: a toolchain problem
        raise ToolchainError(f"the linked firmware is not a Cortex-M4F image the emulator accepts: {exc}") from None
    return BuildResult(elf=elf, map_text=map_text, sources=sources, memory=memory, toolchain=version)


__all__ = ["BuildResult", "COMPILER", "ELF_NAME", "HEADER_NAME", "ISR_NAMES", "MAP_NAME", "SOURCE_NAME",
           "StepReport", "ToolchainError", "build_firmware", "firmware_sources", "support_file", "toolchain_version"]
