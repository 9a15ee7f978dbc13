"""Bad input everywhere: every command, given a broken file, bus or output path, prints one sentence naming the
problem and the fix, exits non-zero, prints no traceback and leaves no output behind (or leaves it unchanged).

Each case runs the real CLI in a child process (see conftest.Cli) and checks:
exit status != 0, stderr exactly one line with the command's `error:` prefix, no "Traceback", the fragments the
case names (the file and the fix), and the output paths (--out, --log, --report, --plots, --stats) exactly as
they were before (absent, or with the same bytes).
"""

from __future__ import annotations

import json
import os
import random
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from host.canlog import mf4_available

from helpers import TiedProcess, start_target

IDENTIFY_FAST = ("--swarm", "6", "--iterations", "2", "--lm-iterations", "2", "--quiet")
REBUILD = "rebuild it with 'bench identify'"
LOG_FIX = "pass a complete log written by 'bench run' or the host"


def random_bytes(seed: int, size: int) -> bytes:
    rng = random.Random(seed)
    data = bytes(rng.randrange(256) for _ in range(size))
    return b"\xff\xfe" + data  # never valid UTF-8, never a known file signature


def tree(path: Path):
    """Every file under path (or the file itself) with its bytes; None when nothing is there."""
    path = Path(path)
    if path.is_file():
        return {".": path.read_bytes()}
    if not path.exists():
        return None
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def assert_one_sentence(result, fragments=(), *, prefix="bench: error: ", rc=None) -> str:
    assert result.rc != 0, str(result)
    if rc is not None:
        assert result.rc == rc, str(result)
    assert "Traceback" not in result.stderr, str(result)
    assert len(result.lines) == 1, f"stderr is not one line\n{result}"
    line = result.lines[0]
    assert line.startswith(prefix), str(result)
    for fragment in fragments:
        assert fragment in line, f"{fragment!r} missing\n{result}"
    return line


# ---------------------------------------------------------------- broken inputs


def _csv_lines(material) -> list[str]:
    return material.data.read_text().splitlines()


def _with_row(lines: list[str], row: int, column: int, value: str) -> list[str]:
    out = list(lines)
    fields = out[row].split(",")
    fields[column] = value
    out[row] = ",".join(fields)
    return out


def bad_dataset(material, variant: str) -> Path:
    """cycle_coolant20.csv-compatible broken datasets (no sidecar, unless the variant is about it)."""
    path = material.bad / f"ds_{variant}.csv"
    lines = _csv_lines(material)
    text = "\n".join(lines) + "\n"
    if variant == "missing":
        return path
    if variant == "empty":
        path.write_bytes(b"")
    elif variant == "truncated":
        cut = len(text) // 2
        cut += 3 if text[cut] != "\n" and text[cut + 3] != "\n" else 1
        path.write_text(text[:cut])
    elif variant == "garbage":
        path.write_bytes(random_bytes(1, 700))
    elif variant == "nan":
        path.write_text("\n".join(_with_row(lines, 10, 3, "nan")) + "\n")
    elif variant == "header":
        path.write_text(text.replace("torque_Nm", "torque", 1))
    elif variant == "quote":
        path.write_text('"' + text)
    elif variant == "text":
        path.write_text("\n".join(_with_row(lines, 5, 1, "12.5x")) + "\n")
    elif variant == "time":
        path.write_text("\n".join(_with_row(lines, 7, 0, "0.4")) + "\n")
    elif variant == "rate":
        rows = [lines[0]] + [",".join([f"{n:.1f}", *line.split(",")[1:]]) for n, line in enumerate(lines[1:])]
        path.write_text("\n".join(rows) + "\n")
    elif variant == "other":  # a fine dataset, but not the one the log was recorded from
        torque = float(lines[20].split(",")[1])
        path.write_text("\n".join(_with_row(lines, 20, 1, f"{torque + 50:.1f}")) + "\n")
    elif variant == "short":
        path.write_text("\n".join(lines[:11]) + "\n")
    elif variant == "sidecar":
        path.write_text("\n".join(_with_row(lines, 3, 5, "99.9")) + "\n")
        shutil.copy(material.data.with_suffix(".json"), path.with_suffix(".json"))
    else:
        raise ValueError(variant)
    return path


# variant -> (fragment naming the problem, fragment with the fix)
DATASET_CASES = {
    "missing": ("cannot be read", "check the path"),
    "empty": ("is empty", "it needs a header line"),
    "truncated": ("fields, the header has 8", "fix or remove that line"),
    "garbage": ("is not UTF-8 text", "save it as a UTF-8 CSV"),
    "nan": ("value is NaN", "fix the source data"),
    "header": ("column 'torque_Nm' is missing", "rename it or map it"),
    "quote": ("cannot be read as CSV", "save it as a plain comma-separated file"),
    "text": ("is not a number", "fix or remove that row"),
    "time": ("does not increase", "rows must be in time order"),
    "rate": ("the sample period is 1 s", "resample the data first"),
    "sidecar": ("does not match the sha256 in its sidecar", "regenerate it with 'bench data' or delete the sidecar"),
}


def bad_campaign(material, variant: str) -> Path:
    """A --data DIR whose cycle_coolant20.csv is the broken variant (or missing)."""
    directory = material.bad / f"campaign_{variant}"
    if directory.exists():
        return directory
    shutil.copytree(material.campaign, directory)
    target = directory / "cycle_coolant20.csv"
    source = bad_dataset(material, variant)
    target.unlink()
    if source.exists():
        shutil.copy(source, target)
        if source.with_suffix(".json").exists():
            shutil.copy(source.with_suffix(".json"), target.with_suffix(".json"))
    return directory


def bad_artifact(material, variant: str) -> Path:
    from target_sim.artifact import dumps, encode_array

    path = material.bad / f"art_{variant}.json"
    text = material.art.read_text()
    content = json.loads(text)
    if variant == "missing":
        return path
    if variant == "empty":
        path.write_text("")
    elif variant == "truncated":
        path.write_text(text[: len(text) // 2])
    elif variant == "garbage":
        path.write_bytes(random_bytes(2, 900))
    elif variant == "edited":
        edited = text.replace('"dt_s": 0.5', '"dt_s": 0.25', 1)
        assert edited != text
        path.write_text(edited)
    elif variant == "schema":
        path.write_text(json.dumps({**content, "schema_version": 4}))
    elif variant == "shape":  # hand-edited and resealed: the checksum is right, the matrix is not
        content["linear_block"]["A"] = encode_array(np.eye(3))
        path.write_text(dumps(content))
    elif variant == "nested":
        path.write_text("[" * 100_000 + "]" * 100_000)
    elif variant == "bignum":
        path.write_text('{"schema": ' + "9" * 5000 + "}")
    elif variant == "nan":
        path.write_text(text.replace('"dt_s": 0.5', '"dt_s": NaN', 1))
    elif variant == "directory":
        path.mkdir(exist_ok=True)
    else:
        raise ValueError(variant)
    return path


ARTIFACT_CASES = {
    "missing": ("does not exist", "pass an existing file with --model"),
    "empty": ("is empty", REBUILD),
    "truncated": ("is not valid JSON", REBUILD),
    "garbage": ("is not UTF-8 JSON text", REBUILD),
    "edited": ("checksum does not match", REBUILD),
    "schema": ("schema version 4 is not supported", REBUILD),
    "shape": ("linear_block.A has shape [3, 3]", REBUILD),
    "nested": ("absurd numbers or nesting", REBUILD),
    "bignum": ("absurd numbers or nesting", REBUILD),
    "nan": ("not plain JSON", REBUILD),
    "directory": ("is a directory", "pass the artifact's JSON file with --model"),
}


def bad_log(material, variant: str) -> Path:
    """variant: <kind>.<suffix>, e.g. truncated.asc."""
    kind, _, suffix = variant.partition(".")
    suffix = f".{suffix}" if suffix else ""
    path = material.bad / f"log_{kind}{suffix}"
    source = material.logs.get(suffix or ".blf", material.log).read_bytes()
    if kind == "missing":
        return path
    if kind == "empty":
        path.write_bytes(b"")
    elif kind == "truncated":
        cut = len(source) // 2
        while source[cut - 1:cut] == b"\n":
            cut += 1
        path.write_bytes(source[:cut])
    elif kind == "random":
        path.write_bytes(random_bytes(3, 2000))
    elif kind == "flipped":  # the middle of the compressed container
        data = bytearray(source)
        for i in range(len(data) // 3, len(data) // 3 + 40):
            data[i] ^= 0x55
        path.write_bytes(bytes(data))
    elif kind == "noframes":
        path.write_text("date Mon Jan 1 00:00:00 2024\nbase hex  timestamps absolute\nno frames here\n")
    elif kind in ("unknown", "nosuffix"):
        path.write_bytes(material.log.read_bytes())
    else:
        raise ValueError(variant)
    return path


LOG_CASES = {
    "missing.blf": ("does not exist", "pass a log written by 'bench run' or the host"),
    "empty.blf": ("is empty", LOG_FIX),
    "empty.asc": ("is empty", LOG_FIX),
    "truncated.blf": ("is truncated", LOG_FIX),
    "truncated.asc": ("is truncated", LOG_FIX),
    "truncated.log": ("is truncated", LOG_FIX),
    "truncated.csv": ("is truncated", LOG_FIX),
    "random.blf": ("is not a readable .blf log", LOG_FIX),
    "random.asc": ("log_random.asc", LOG_FIX),
    "random.log": ("log_random.log", LOG_FIX),
    "random.csv": ("log_random.csv", LOG_FIX),
    "random.mf4": ("is not a readable .mf4 log", LOG_FIX),
    "flipped.blf": ("is damaged or truncated", LOG_FIX),
    "noframes.asc": ("holds no CAN frames", LOG_FIX),
    "unknown.txt": ("unsupported format .txt", "use one of .blf"),
    "nosuffix": ("unsupported format (no suffix)", "use one of .blf"),
}


# ---------------------------------------------------------------- the matrix


@dataclass
class Case:
    """One bad-input run: argv (with {placeholders}), the fragments its one line must contain, its outputs."""

    id: str
    module: str
    args: tuple[str, ...]
    fragments: tuple[str, ...]
    outputs: tuple[str, ...] = ()
    rc: int | None = None
    prefix: str = "bench: error: "
    env: dict[str, str] = field(default_factory=dict)
    prepare: Callable | None = None  # (material) -> {placeholder: path} for the bad input
    preexisting: bool = False  # create the outputs first: they must be left byte for byte as they were
    timeout: float = 60
    marks: tuple = ()


def _ds(variant):
    return lambda m: {"bad": bad_dataset(m, variant), "badname": bad_dataset(m, variant).name}


def _camp(variant):
    return lambda m: {"bad": bad_campaign(m, variant), "badname": "cycle_coolant20.csv"}


def _art(variant):
    return lambda m: {"bad": bad_artifact(m, variant), "badname": bad_artifact(m, variant).name}


def _log(variant):
    return lambda m: {"bad": bad_log(m, variant), "badname": bad_log(m, variant).name}


def dataset_cases() -> list[Case]:
    cases = []
    for variant, (problem, fix) in DATASET_CASES.items():
        cases += [
            Case(f"run-data-{variant}", "bench",
                 ("run", "--data", "{bad}", "--model", "{art}", "--rows", "50", "--log", "{out}/x.blf",
                  "--report", "{out}/rep", "--quiet"),
                 ("{badname}", problem, fix), ("x.blf", "rep"), prepare=_ds(variant),
                 preexisting=variant == "truncated"),
            Case(f"analyze-data-{variant}", "bench",
                 ("analyze", "{log}", "--model", "{art}", "--data", "{bad}", "--report", "{out}/rep"),
                 ("{badname}", problem, fix), ("rep",), prepare=_ds(variant), preexisting=variant == "nan"),
        ]
        if variant == "missing":
            problem, fix = "is missing", "run 'bench data --out"
        cases += [
            Case(f"identify-data-{variant}", "bench",
                 ("identify", "--data", "{bad}", "--out", "{out}/m.json", *IDENTIFY_FAST),
                 ("{badname}", problem, fix), ("m.json",), prepare=_camp(variant),
                 preexisting=variant == "garbage"),
            Case(f"evaluate-data-{variant}", "bench",
                 ("evaluate", "--data", "{bad}", "--model", "{art}", "--dt", "0.5", "--plots", "{out}/plots",
                  "--quiet"),
                 ("{badname}", problem, fix), ("plots",), prepare=_camp(variant)),
        ]
    cases += [
        Case(f"analyze-data-{variant}", "bench",
             ("analyze", "{log}", "--model", "{art}", "--data", "{bad}", "--report", "{out}/rep"),
             ("{badname}", problem, "pass that one, or leave --data out"), ("rep",), prepare=_ds(variant))
        for variant, problem in (("other", "differs from the log's drive values at data row 20"),
                                 ("short", "has 10 rows, the log 50"))
    ]
    cases += [
        Case("identify-dt-nan", "bench", ("identify", "--data", "{campaign}", "--dt", "nan", "--out", "{out}/m.json"),
             ("--dt must be a positive number of seconds",), ("m.json",), rc=2),
        Case("identify-data-is-a-file", "bench", ("identify", "--data", "{data}", "--out", "{out}/m.json",
                                                  *IDENTIFY_FAST),
             ("small.csv is a file", "pass the directory that holds cycle_coolant20.csv"), ("m.json",)),
        Case("evaluate-data-no-such-dir", "bench", ("evaluate", "--data", "{out}/nodir", "--model", "{art}"),
             ("nodir does not exist", "run 'bench data --out"), ("nodir",)),
    ]
    return cases


def artifact_cases() -> list[Case]:
    cases = []
    for variant, (problem, fix) in ARTIFACT_CASES.items():
        cases += [
            Case(f"run-model-{variant}", "bench",
                 ("run", "--model", "{bad}", "--data", "{data}", "--rows", "50", "--log", "{out}/x.blf",
                  "--report", "{out}/rep", "--quiet"),
                 ("{badname}", problem, fix), ("x.blf", "rep"), prepare=_art(variant),
                 preexisting=variant == "edited"),
            Case(f"evaluate-model-{variant}", "bench",
                 ("evaluate", "--model", "{bad}", "--data", "{campaign}", "--dt", "0.5", "--plots", "{out}/plots"),
                 ("{badname}", problem, fix), ("plots",), prepare=_art(variant)),
            Case(f"target_sim-model-{variant}", "target_sim", ("--model", "{bad}", "--stats", "{out}/stats.json"),
                 ("{badname}", problem, fix), ("stats.json",), prefix="target_sim: error: ",
                 prepare=_art(variant), timeout=20),
        ]
    for variant in ("truncated", "edited", "shape"):
        problem, fix = ARTIFACT_CASES[variant]
        cases += [
            Case(f"analyze-model-{variant}", "bench", ("analyze", "{log}", "--model", "{bad}", "--report",
                                                       "{out}/rep"),
                 ("{badname}", problem, fix), ("rep",), prepare=_art(variant)),
            Case(f"replay-model-{variant}", "bench", ("replay", "{log}", "--model", "{bad}", "--log", "{out}/r.blf",
                                                      "--quiet"),
                 ("{badname}", problem, fix), ("r.blf",), prepare=_art(variant)),
            Case(f"compare-model-{variant}", "bench", ("compare", "--models", "{art},{bad}", "--data", "{data}",
                                                       "--rows", "50", "--out", "{out}/cmp", "--quiet"),
                 ("{badname}", problem, fix), ("cmp",), prepare=_art(variant)),
        ]
    return cases


def log_cases() -> list[Case]:
    cases = []
    for variant, (problem, fix) in LOG_CASES.items():
        marks = (pytest.mark.skipif(not mf4_available(), reason="asammdf is not installed"),) \
            if variant.endswith(".mf4") else ()
        cases += [
            Case(f"analyze-log-{variant}", "bench", ("analyze", "{bad}", "--model", "{art}", "--report", "{out}/rep"),
                 ("{badname}", problem, fix), ("rep",), prepare=_log(variant), marks=marks,
                 preexisting=variant == "truncated.blf"),
            Case(f"replay-log-{variant}", "bench",
                 ("replay", "{bad}", "--model", "{art}", "--log", "{out}/r.blf", "--as-fast-as-possible", "--quiet"),
                 ("{badname}", problem, fix), ("r.blf",), prepare=_log(variant), marks=marks),
        ]
    return cases


BUS_FIX = "choose another with -i/--interface and -c/--channel"


def bus_cases() -> list[Case]:
    run = ("run", "--data", "{data}", "--model", "{art}", "--rows", "50", "--log", "{out}/x.blf", "--report",
           "{out}/rep", "--quiet")
    replay = ("replay", "{log}", "--model", "{art}", "--log", "{out}/r.blf", "--quiet")
    return [
        Case("run-interface-unknown", "bench", (*run, "-i", "nosuchbus"), ("'nosuchbus'", "choose from"),
             ("x.blf", "rep"), rc=2),
        Case("run-channel-unknown", "bench", (*run, "-i", "socketcan", "-c", "nosuch0"), ("nosuch0", BUS_FIX),
             ("x.blf", "rep")),
        Case("run-group-invalid", "bench", (*run, "-i", "udp_multicast", "-c", "no-group.invalid"),
             ("no-group.invalid", BUS_FIX), ("x.blf", "rep")),
        Case("run-interface-env-unknown", "bench", run, ("'nosuch'", "pass -i"), ("x.blf", "rep"),
             env={"CAN_INTERFACE": "nosuch"}),
        Case("run-can-config-garbage", "bench", (*run, "--can-config", "{bad}"),
             ("configuration cannot be read", "fix it or pass -i"), ("x.blf", "rep"),
             prepare=lambda m: {"bad": _write(m.bad / "can.ini", b"garbage\x00[[[\n")}),
        Case("replay-channel-unknown", "bench", (*replay, "-i", "socketcan", "-c", "nosuch0"), ("nosuch0", BUS_FIX),
             ("r.blf",)),
        Case("replay-interface-unknown", "bench", (*replay, "-i", "nosuchbus"), ("'nosuchbus'", "choose from"),
             ("r.blf",), rc=2),
        Case("target_sim-channel-unknown", "target_sim",
             ("--model", "{art}", "--stats", "{out}/stats.json", "-i", "socketcan", "-c", "nosuch0"),
             ("nosuch0", BUS_FIX), ("stats.json",), prefix="target_sim: error: ", timeout=20),
        Case("target_sim-interface-unknown", "target_sim", ("--model", "{art}", "-i", "nosuchbus"),
             ("'nosuchbus'", "choose from"), (), prefix="target_sim: error: ", rc=2, timeout=20),
        Case("target_sim-group-invalid", "target_sim",
             ("--model", "{art}", "--stats", "{out}/stats.json", "-i", "udp_multicast", "-c", "no-group.invalid"),
             ("no-group.invalid", BUS_FIX), ("stats.json",), prefix="target_sim: error: ", timeout=20),
        *virtual_cases(),
    ]


VIRTUAL = ("'virtual' interface does not cross processes", "use udp_multicast, socketcan or auto")


def virtual_cases() -> list[Case]:
    """python-can's virtual bus lives in one process: every command that talks to another process refuses it up
    front (exit 2), instead of waiting out a connect timeout (host) or serving nobody until killed (target).
    The short timeouts are the point: before the fix the host failed after 15 s and the target never."""
    host = ("host", "--data", "{data}", "--model", "{art}", "--log", "{out}/h.blf", "--quiet")
    target = ("--model", "{art}", "--stats", "{out}/stats.json", "--events", "{out}/events.jsonl")
    return [
        Case("run-interface-virtual", "bench", ("run", "--data", "{data}", "--model", "{art}", "--rows", "50",
                                                "--log", "{out}/x.blf", "--report", "{out}/rep", "--quiet", "-i",
                                                "virtual"), VIRTUAL, ("x.blf", "rep"), rc=2, timeout=10),
        Case("host-interface-virtual", "bench", (*host, "-i", "virtual"), VIRTUAL, ("h.blf",), rc=2, timeout=5),
        Case("host-interface-env-virtual", "bench", host, VIRTUAL, ("h.blf",), rc=2,
             env={"CAN_INTERFACE": "virtual"}, timeout=5),
        Case("target_sim-interface-virtual", "target_sim", (*target, "-i", "virtual"), VIRTUAL,
             ("stats.json", "events.jsonl"), rc=2, prefix="target_sim: error: ", timeout=5),
        Case("target_sim-interface-env-virtual", "target_sim", target, VIRTUAL, ("stats.json", "events.jsonl"),
             rc=2, prefix="target_sim: error: ", env={"CAN_INTERFACE": "virtual"}, timeout=5),
    ]


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def output_cases() -> list[Case]:
    return [
        Case("identify-out-below-a-file", "bench", ("identify", "--data", "{campaign}", "--out", "{afile}/m.json",
                                                    *IDENTIFY_FAST),
             ("afile", "choose another --out"), ()),
        Case("identify-out-is-a-directory", "bench", ("identify", "--data", "{campaign}", "--out", "{out}",
                                                      *IDENTIFY_FAST),
             ("is a directory", "name a file for --out"), ()),
        Case("evaluate-plots-below-a-file", "bench", ("evaluate", "--data", "{campaign}", "--model", "{art}",
                                                      "--dt", "0.5", "--plots", "{afile}/plots"),
             ("afile", "choose another --plots"), ()),
        Case("analyze-report-below-a-file", "bench", ("analyze", "{log}", "--model", "{art}", "--report",
                                                      "{afile}/rep"),
             ("afile", "choose another --report"), ()),
        Case("replay-log-below-a-file", "bench", ("replay", "{log}", "--model", "{art}", "--log", "{afile}/r.blf",
                                                  "--quiet"),
             ("afile", "choose another --log"), ()),
        Case("data-out-below-a-file", "bench", ("data", "--out", "{afile}/d", "--coolant", "20", "--quiet"),
             ("afile", "choose another --out"), ()),
        Case("compare-out-below-a-file", "bench", ("compare", "--models", "{art}", "--data", "{data}", "--rows", "50",
                                                   "--out", "{afile}/cmp", "--quiet"),
             ("afile", "choose another --out"), ()),
        Case("run-log-below-a-file", "bench", ("run", "--data", "{data}", "--model", "{art}", "--rows", "50",
                                               "--log", "{afile}/x.blf", "--report", "{out}/rep", "--quiet"),
             ("afile",), ("rep",)),
        Case("run-report-below-a-file", "bench", ("run", "--data", "{data}", "--model", "{art}", "--rows", "50",
                                                  "--log", "{out}/x.blf", "--report", "{afile}/rep", "--quiet"),
             ("afile",), ("x.blf",)),
    ]


# ---------------------------------------------------------------- the firmware: toolchain, ELF, emulator

EXTRA = "reinstall the project"
SHADOW_ZIG = {  # a `ziglang` package first on PYTHONPATH: `python -m ziglang` as a missing or a failing compiler
    "missing": {"__init__.py": "raise ImportError('No module named ziglang (shadowed by the test)')\n"},
    "failing": {"__init__.py": "", "__main__.py": "import sys\nif sys.argv[1:] == ['version']:\n"
                "    print('0.17.1')\n    sys.exit(0)\nprint('error: the compiler fails (a test double)', "
                "file=sys.stderr)\nsys.exit(1)\n"},
}


def _shadow_zig(variant: str) -> Callable:
    def prepare(material) -> dict:
        root = material.bad / f"zig-{variant}"
        package = root / "ziglang"
        package.mkdir(parents=True, exist_ok=True)
        for name, text in SHADOW_ZIG[variant].items():
            (package / name).write_text(text)
        return {"shadow": root}

    return prepare


def _elf(variant: str) -> Callable:
    """A bad firmware ELF for the default (packaged hammerstein) model, or the path of one."""
    def prepare(material) -> dict:
        from bench.firmware.images import packaged_elf_path

        from helpers import patched_elf

        good = packaged_elf_path("hammerstein")
        path = material.bad / f"fw_{variant}.elf"
        if variant == "other-core":
            path = Path(os.path.realpath(sys.executable))   # an ELF, for this machine's core
        elif variant == "other-model":
            path = good                                     # the packaged model's, not the test artifact's
        elif variant == "truncated":
            path.write_bytes(good.read_bytes()[:3000])
        elif variant == "udf":
            path.write_bytes(patched_elf(good, "fw_step", b"\xfe\xde"))   # loads, faults in fw_step
        elif variant == "text":
            path.write_text("not firmware\n")
        elif variant != "missing":
            raise ValueError(variant)
        return {"bad": path, "badname": path.name}

    return prepare


def firmware_cases() -> list[Case]:
    build = ("firmware", "build", "--model", "{art}", "--out", "{out}/fw", "--quiet")
    check = ("firmware", "check", "--data", "{data}", "--quiet")
    target = ("--model", "{art}", "--stats", "{out}/stats.json", "--events", "{out}/events.jsonl")
    t_prefix = "target_sim: error: "
    run = ("run", "--engine", "firmware", "--data", "{data}", "--model", "{art}", "--rows", "50", "--log",
           "{out}/x.blf", "--report", "{out}/rep", "--quiet")
    return [
        Case("firmware-build-toolchain-missing", "bench", build,
             ("the C cross-compiler (python -m ziglang) is not available", EXTRA), ("fw",),
             env={"PYTHONPATH": "{shadow}"}, prepare=_shadow_zig("missing")),
        Case("firmware-build-toolchain-failing", "bench", build,
             ("compiling startup.c for the Cortex-M4F failed", "the compiler fails"), ("fw",),
             env={"PYTHONPATH": "{shadow}"}, prepare=_shadow_zig("failing")),
        Case("firmware-build-inexpressible", "bench", ("firmware", "build", "--model", "{bad}", "--out",
                                                       "{out}/fw", "--quiet"),
             ("{badname}", "realization 'jordan'"), ("fw",),
             prepare=lambda m: {"bad": _resealed(m, "jordan"), "badname": "art_jordan.json"}),
        Case("firmware-check-toolchain-missing", "bench", (*check, "--model", "{art}"),
             ("firmware is not packaged and must be built", "is not available", EXTRA), (),
             env={"PYTHONPATH": "{shadow}"}, prepare=_shadow_zig("missing")),
        Case("firmware-check-elf-other-core", "bench", (*check, "--firmware", "{bad}"),
             ("{badname}", "not for an ARM Cortex-M4F"), (), prepare=_elf("other-core")),
        Case("firmware-check-elf-other-model", "bench", (*check, "--model", "{art}", "--firmware", "{bad}"),
             ("{badname}", "is the firmware of model", "build it from this artifact"), (),
             prepare=_elf("other-model")),
        Case("firmware-check-elf-truncated", "bench", (*check, "--firmware", "{bad}"),
             ("{badname}", "is not a readable ELF file"), (), prepare=_elf("truncated")),
        Case("firmware-check-elf-text", "bench", (*check, "--firmware", "{bad}"),
             ("{badname}", "is not an ELF file"), (), prepare=_elf("text")),
        Case("firmware-check-elf-missing", "bench", (*check, "--firmware", "{bad}"),
             ("cannot read firmware", "{badname}"), (), prepare=_elf("missing")),
        Case("firmware-check-emulator-fault", "bench", (*check, "--firmware", "{bad}"),
             ("{badname}", "faulted in the emulated core", "fw_step", "undefined instruction"), (),
             prepare=_elf("udf")),
        Case("firmware-check-rows-zero", "bench", (*check, "--rows", "0"), ("must be a positive whole number",), (),
             rc=2),
        Case("target_sim-firmware-other-core", "target_sim", (*target, "--engine", "firmware", "--firmware", "{bad}"),
             ("{badname}", "not for an ARM Cortex-M4F"), ("stats.json", "events.jsonl"), prefix=t_prefix, rc=1,
             prepare=_elf("other-core"), timeout=20),
        Case("target_sim-firmware-other-model", "target_sim", (*target, "--firmware", "{bad}"),
             ("{badname}", "is the firmware of model", "not of the artifact's model"), ("stats.json", "events.jsonl"),
             prefix=t_prefix, rc=1, prepare=_elf("other-model"), timeout=20),
        Case("target_sim-firmware-truncated", "target_sim", (*target, "--engine", "firmware", "--firmware", "{bad}"),
             ("{badname}", "is not a readable ELF file"), ("stats.json", "events.jsonl"), prefix=t_prefix, rc=1,
             prepare=_elf("truncated"), timeout=20),
        Case("target_sim-firmware-missing", "target_sim", (*target, "--engine", "firmware", "--firmware", "{bad}"),
             ("cannot read firmware", "{badname}"), ("stats.json", "events.jsonl"), prefix=t_prefix, rc=1,
             prepare=_elf("missing"), timeout=20),
        Case("target_sim-engine-firmware-without-elf", "target_sim", (*target, "--engine", "firmware"),
             ("--engine firmware needs the model's firmware: --firmware ELF",), ("stats.json", "events.jsonl"),
             prefix=t_prefix, rc=2, timeout=20),
        Case("target_sim-python-engine-with-elf", "target_sim", (*target, "--engine", "python", "--firmware",
                                                                 "{bad}"),
             ("--firmware is the firmware engine's ELF",), ("stats.json", "events.jsonl"), prefix=t_prefix, rc=2,
             prepare=_elf("other-model"), timeout=20),
        Case("run-engine-firmware-toolchain-missing", "bench", run,
             ("firmware is not packaged and must be built", EXTRA), ("x.blf", "rep"),
             env={"PYTHONPATH": "{shadow}"}, prepare=_shadow_zig("missing")),
        Case("compare-engine-firmware-toolchain-missing", "bench",
             ("compare", "--models", "{art}", "--data", "{data}", "--rows", "50", "--out", "{out}/cmp", "--quiet"),
             ("firmware is not packaged and must be built", EXTRA), ("cmp",),
             env={"PYTHONPATH": "{shadow}"}, prepare=_shadow_zig("missing")),
    ]


def _resealed(material, realization: str) -> Path:
    from target_sim.artifact import dumps, seal

    path = material.bad / f"art_{realization}.json"
    content = json.loads(material.art.read_text())
    content["realization"] = realization
    path.write_text(dumps(seal(content)))
    return path


CASES = dataset_cases() + artifact_cases() + log_cases() + bus_cases() + output_cases() + firmware_cases()


@pytest.mark.parametrize("case", [pytest.param(c, id=c.id, marks=c.marks) for c in CASES])
def test_bad_input_is_one_sentence_and_leaves_no_output(case: Case, cli, material, scratch):
    out = scratch / "out"
    out.mkdir()
    places = {"art": material.art, "lti": material.lti, "data": material.data, "campaign": material.campaign,
              "log": material.log, "out": out, "afile": material.afile, "bad": "", "badname": ""}
    if case.prepare is not None:
        places.update(case.prepare(material))
    args = [a.format(**places) for a in case.args]
    if case.preexisting:
        for name in case.outputs:
            target = out / name
            if Path(name).suffix:
                target.write_bytes(b"an earlier output\n")
            else:
                target.mkdir()
                (target / "report.md").write_text("an earlier report\n")
    before = {name: tree(out / name) for name in case.outputs}
    env = {key: value.format(**places) for key, value in case.env.items()}
    result = cli(case.module, *args, cwd=scratch, env=env, timeout=case.timeout)
    assert_one_sentence(result, [f.format(**places) for f in case.fragments], prefix=case.prefix, rc=case.rc)
    for name in case.outputs:
        assert tree(out / name) == before[name], f"output {name} changed\n{result}"
    leftovers = [p.name for p in out.rglob("*") if p.is_file() and (p.name.startswith(".") or "partial" in p.name)]
    assert not leftovers, f"temporary files left behind: {leftovers}\n{result}"


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_read_only_output_directory(cli, material, scratch):
    locked = scratch / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        result = cli("bench", "identify", "--data", material.campaign, "--out", locked / "m.json", *IDENTIFY_FAST,
                     cwd=scratch)
        assert_one_sentence(result, ("locked", "is not writable", "choose another --out"))
        result = cli("bench", "analyze", material.log, "--model", material.art, "--report", locked / "rep",
                     cwd=scratch)
        assert_one_sentence(result, ("locked", "is not writable", "choose another --report"))
        assert list(locked.iterdir()) == []
    finally:
        locked.chmod(0o755)


# ---------------------------------------------------------------- a channel already in use


@contextmanager
def _foreign_target(model: Path, port: int, workdir: Path) -> Iterator[TiedProcess]:
    """`python -m target_sim` on a udp_multicast port, tied to this process; the block runs once it serves (its
    'serving' line), and the target is stopped (SIGTERM) when it ends."""
    with open(workdir / f"target-{port}.stderr", "w+b") as stderr, \
            start_target("--model", model, "-i", "udp_multicast", "--bus-kwargs", f"port={port}", cwd=workdir,
                         env={**os.environ, "MPLBACKEND": "Agg"}, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                         stderr=stderr) as process:
        started = time.monotonic()
        serving = False
        while not serving and time.monotonic() < started + 60 and process.poll() is None:   # generous: busy machine
            stderr.seek(0)
            serving = b"serving" in stderr.read()   # its start line, printed as its bus opens
            time.sleep(0.05)
        stderr.seek(0)
        assert process.poll() is None and serving, (
            f"the foreign target did not say 'serving' within 60 s: {stderr.read().decode(errors='replace')}")
        time.sleep(0.5)   # its first heartbeats on the bus before the command under test listens for them
        yield process


def _port() -> int:
    from dbc.transport import free_udp_port

    return free_udp_port()


def test_channel_in_use_by_a_target_of_another_model(cli, material, scratch):
    """udp_multicast lets two processes bind one group and port, so "in use" is what the host can see: a target
    already answering there. One with another model id is refused in one sentence naming that id."""
    port = _port()
    with _foreign_target(material.lti, port, scratch):
        out = scratch / "out"
        result = cli("bench", "run", "--data", material.data, "--model", material.art, "--rows", 50, "--log",
                     out / "x.blf", "--report", out / "rep", "--quiet", "-i", "udp_multicast", "--bus-kwargs",
                     f"port={port}", cwd=scratch, timeout=60)
    assert_one_sentence(result, (f"runs model {material.model_id(material.lti)}",
                                 material.model_id(material.art)))
    assert tree(out) is None or tree(out) == {}


def test_channel_in_use_by_a_target_of_the_same_model(cli, material, scratch):
    """A target of the run's own model would pass the handshake and answer the run: the runner listens for one
    before it starts its own and refuses, naming the channel and the model, before anything is written."""
    port = _port()
    with _foreign_target(material.art, port, scratch):
        out = scratch / "out"
        result = cli("bench", "run", "--data", material.data, "--model", material.art, "--rows", 50, "--log",
                     out / "x.blf", "--no-report", "--quiet", "-i", "udp_multicast", "--bus-kwargs", f"port={port}",
                     cwd=scratch, timeout=60)
    line = assert_one_sentence(result, (f"port {port} on udp_multicast already has a target sending heartbeats",
                                        f"runs model {material.model_id(material.art)}, the same as this run's",
                                        "stop it or pick another channel"))
    assert re.search(r"already|in use|another target", line), str(result)
    assert tree(out) is None or tree(out) == {}


def test_replay_refuses_a_channel_with_a_target_on_it(cli, material, scratch):
    """`bench replay` starts a target of its own too (unless --no-start-target): the same check, the same line."""
    port = _port()
    with _foreign_target(material.art, port, scratch):
        out = scratch / "out"
        result = cli("bench", "replay", material.log, "--model", material.art, "--log", out / "r.blf", "--quiet",
                     "--as-fast-as-possible", "-i", "udp_multicast", "--bus-kwargs", f"port={port}", cwd=scratch,
                     timeout=60)
    assert_one_sentence(result, (f"port {port} on udp_multicast already has a target sending heartbeats",
                                 "stop it or pick another channel"))
    assert tree(out) is None or tree(out) == {}


def test_target_sim_refuses_a_channel_with_a_target_on_it(cli, material, scratch):
    """A second target would answer every row too: `python -m target_sim` listens before it joins, and refuses in
    one sentence naming the channel and the other target's model, writing neither stats nor events."""
    port = _port()
    with _foreign_target(material.art, port, scratch):
        out = scratch / "out"
        result = cli("target_sim", "--model", material.art, "--stats", out / "stats.json", "--events",
                     out / "events.jsonl", "-i", "udp_multicast", "--bus-kwargs", f"port={port}", cwd=scratch,
                     timeout=30)
    assert_one_sentence(result, (f"port {port} already has a target sending",
                                 f"heartbeats of model {material.model_id(material.art)}",
                                 "stop it or pick another channel"), prefix="target_sim: error: ", rc=1)
    assert tree(out) is None or tree(out) == {}


FOREIGN_HOST = """
import sys, time
import can
from dbc import FrameCodec
bus = can.Bus(interface="udp_multicast", channel=sys.argv[1], port=int(sys.argv[2]))
codec = FrameCodec("HOST")
print("sending", flush=True)
try:
    while True:
        bus.send(codec.encode("Control", {"Command": 0, "Step": 0}))
        time.sleep(0.05)
finally:
    bus.shutdown()
"""


def test_host_refuses_a_channel_with_another_host_on_it(cli, material, scratch):
    """Two hosts would both drive the target: `bench host` listens before it joins and refuses."""
    from dbc.transport import UDP_LOCAL_GROUP

    port = _port()
    with TiedProcess("-c", FOREIGN_HOST, UDP_LOCAL_GROUP, str(port), stdout=subprocess.PIPE,
                     stderr=subprocess.DEVNULL, text=True) as foreign:
        assert foreign.process.stdout.readline().strip() == "sending"
        out = scratch / "out"
        result = cli("bench", "host", "--data", material.data, "--model", material.art, "--log", out / "h.blf",
                     "--quiet", "-i", "udp_multicast", "-c", UDP_LOCAL_GROUP, "--bus-kwargs", f"port={port}",
                     cwd=scratch, timeout=30)
    assert_one_sentence(result, (f"port {port} already has a host sending (frame id 0x100)",
                                 "stop it or pick another channel"), rc=1)
    assert tree(out) is None or tree(out) == {}


# ---------------------------------------------------------------- a broken DBC (package data): real interpreters


def _shadow_dbc(root: Path, variant: str) -> Path:
    """A copy of the `dbc` package with a broken thermal_bench.dbc, to put first on PYTHONPATH."""
    import dbc.codec

    package = root / "shadow" / "dbc"
    package.mkdir(parents=True)
    source = Path(dbc.codec.__file__).parent
    for module in [*source.glob("*.py"), *source.glob("*.toml")]:    # the code and its side files (xcp.toml)
        shutil.copy(module, package / module.name)
    text = (source / "thermal_bench.dbc").read_bytes()
    if variant == "truncated":
        (package / "thermal_bench.dbc").write_bytes(text[: len(text) // 2])
    elif variant == "garbage":
        (package / "thermal_bench.dbc").write_bytes(random_bytes(4, 3000))
    elif variant != "missing":
        raise ValueError(variant)
    return package.parent


@pytest.mark.parametrize("variant", ["missing", "truncated"])
def test_broken_dbc_is_one_sentence(cli, material, scratch, variant):
    shadow = _shadow_dbc(scratch, variant)
    out = scratch / "out"
    result = cli.subprocess("bench", "analyze", material.log, "--model", material.art, "--report", out / "rep",
                            cwd=scratch, env={"PYTHONPATH": str(shadow)})
    assert_one_sentence(result, ("the CAN contract", str(shadow / "dbc" / "thermal_bench.dbc"),
                                 "reinstall the package or restore dbc/thermal_bench.dbc"))
    assert tree(out) is None


def test_broken_dbc_target_sim_is_one_sentence(cli, material, scratch):
    shadow = _shadow_dbc(scratch, "truncated")
    result = cli.subprocess("target_sim", "--model", material.art, cwd=scratch, env={"PYTHONPATH": str(shadow)},
                            timeout=20)
    assert_one_sentence(result, ("the CAN contract", "reinstall the package"), prefix="target_sim: error: ")


# ---------------------------------------------------------------- the fork server is the real thing


@pytest.mark.slow        # a cross-check of the fork server the whole file runs through
def test_plain_interpreters_agree_with_the_fork_server(cli, material, scratch):
    """A few cases once more as `sys.executable -m ...`, in parallel: the same exit status and the same line.
    They are the ones where interpreter exit matters (finalizers of half-built buses and readers)."""
    by_id = {c.id: c for c in CASES}
    chosen = ["target_sim-model-truncated", "analyze-log-random.mf4", "run-group-invalid"]
    if not mf4_available():
        chosen.remove("analyze-log-random.mf4")

    def both(case_id: str):
        case = by_id[case_id]
        work = scratch / case_id
        (work / "out").mkdir(parents=True)
        places = {"art": material.art, "data": material.data, "campaign": material.campaign, "log": material.log,
                  "out": work / "out", "afile": material.afile, "bad": "", "badname": ""}
        if case.prepare is not None:
            places.update(case.prepare(material))
        args = [a.format(**places) for a in case.args]
        return case, cli.subprocess(case.module, *args, cwd=work, env=case.env, timeout=60), args, work

    with ThreadPoolExecutor(max_workers=len(chosen)) as pool:
        real = list(pool.map(both, chosen))
    for case, result, args, work in real:
        forked = cli(case.module, *args, cwd=work, env=case.env)
        assert_one_sentence(result, prefix=case.prefix)
        same = [(r.rc, re.sub(r"port \d+", "port N", r.stderr)) for r in (result, forked)]
        assert same[0] == same[1], f"{result}\n--- forked ---\n{forked}"


# ---------------------------------------------------------------- another CSV dialect given to `bench run`

DIALECTS = {  # name -> (separator, decimal mark, what the sentence says the file looks like, the mapping keys)
    "semicolon": (";", ".", "semicolon-separated with '.' decimals", '"separator": ";"'),
    "decimal-comma": (";", ",", "semicolon-separated with decimal commas", '"separator": ";", "decimal": ","'),
    "tab": ("\t", ".", "tab-separated with '.' decimals", '"separator": "\\t"'),
}


@pytest.mark.parametrize("dialect", list(DIALECTS))
def test_run_names_the_separator_of_another_csv_dialect(cli, material, scratch, dialect):
    separator, decimal, looks, keys = DIALECTS[dialect]
    path = material.bad / f"dialect_{dialect}.csv"
    lines = [line.replace(",", separator).replace(".", decimal) for line in _csv_lines(material)]
    path.write_text("\n".join(lines) + "\n")
    out = scratch / "out"
    result = cli("bench", "run", "--data", path, "--model", material.art, "--rows", 50, "--log", out / "x.blf",
                 "--report", out / "rep", "--quiet", cwd=scratch)
    line = assert_one_sentence(result, (path.name, f"the file looks {looks}",
                                        "save it comma-separated with '.' decimals", f"pass --mapping with {keys}"),
                               rc=1)
    assert "column 'time_s' is missing" not in line
    assert tree(out) is None


# ---------------------------------------------------------------- the command line itself: help, version, usage


@pytest.mark.parametrize(("argv", "fragments"), [
    (("rnu",), ("invalid choice: 'rnu'", "did you mean 'run'?", "(see 'bench --help')")),
    (("run", "--nosuch"), ("unrecognized arguments: --nosuch", "(see 'bench run --help')")),
    (("run", "--criteira", "c.toml"), ("unrecognized arguments: --criteira c.toml", "did you mean '--criteria'?",
                                       "(see 'bench run --help')")),
    (("analyze", "--no-reprot"), ("did you mean '--no-report'?", "(see 'bench analyze --help')")),
    (("run", "--mode", "lokstep"), ("did you mean 'lockstep'?", "(see 'bench run --help')")),
    (("firmware", "buld"), ("did you mean 'build'?", "(see 'bench firmware --help')")),
    (("firmware", "build", "--nosuch"), ("(see 'bench firmware build --help')",)),
    (("--nosuch",), ("unrecognized arguments: --nosuch", "(see 'bench --help')")),
    (("run", "--wait-for-listener", "0"), ("argument --wait-for-listener: '0' must be a positive number",)),
    (("host", "--data", "d.csv", "--wait-for-listener", "x"), ("argument --wait-for-listener: 'x' is not a number",)),
    (("run", "--rows", "0"), ("argument --rows: '0' must be a positive whole number", "(see 'bench run --help')")),
    (("data", "--seed", "-3"), ("argument --seed: '-3' must be a whole number, 0 or more",)),
    (("run", "--sample-period", "x"), ("--sample-period 'x' is neither a number of seconds nor 'auto'",)),
])
def test_a_bad_argument_is_one_sentence_with_one_prefix(cli, scratch, argv, fragments):
    """One `bench: error: ` (it was doubled: 'bench: error: bench: argument ...'), a close subcommand or choice
    suggested, and the help of the (sub)command the argument was given to."""
    result = cli("bench", *argv, cwd=scratch)
    line = assert_one_sentence(result, fragments, rc=2)
    assert not line.startswith("bench: error: bench"), line
    assert not any(scratch.iterdir()), "a usage error did work"


def test_version_names_the_package_and_the_contracts(cli, scratch):
    from importlib.metadata import version

    from dbc.database import contract
    from target_sim.artifact import SCHEMA_VERSION

    result = cli("bench", "--version", cwd=scratch)
    assert result.rc == 0 and not result.stderr, str(result)
    assert result.stdout.strip() == (f"bench {version('pmsm-thermal-bench')} (pmsm-thermal-bench; DBC "
                                     f"thermal_bench.dbc {contract().version}, model artifact schema "
                                     f"{SCHEMA_VERSION})"), str(result)


def test_help_describes_the_tool_with_examples(cli, scratch):
    result = cli("bench", "--help", cwd=scratch)
    assert result.rc == 0, str(result)
    assert "hardware-in-the-loop bench" in result.stdout and "The main job is `bench run`" in result.stdout
    assert "one module per subcommand" not in result.stdout   # the code's description, not the tool's
    examples = result.stdout.split("examples:")[1]
    assert examples.count("\n  bench ") >= 3, result.stdout


@pytest.mark.parametrize(("option", "name", "make", "fragment"), [
    ("--log", "logs", lambda d: d.mkdir(), "has an unsupported format (no suffix)"),
    ("--log", "logs.blf", lambda d: d.mkdir(), "name a file for --log"),
    ("--report", "report", lambda d: d.write_text("a file\n"), "choose a directory for --report"),
])
def test_run_refuses_its_outputs_before_generating_data(cli, scratch, option, name, make, fragment):
    """In a fresh directory `bench run` makes the default datasets first (out/data): an output path the arguments
    already refuse must be refused before that (it was refused after a minute of data generation)."""
    place = scratch / name
    make(place)
    result = cli("bench", "run", option, place, "--quiet", cwd=scratch, timeout=30)
    assert_one_sentence(result, (str(place), fragment), rc=1)
    assert not (scratch / "out").exists(), "data were generated before the refusal"
