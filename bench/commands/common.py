"""Argument types and output helpers shared by the subcommands."""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from bench.errors import BenchError, UsageError


def float_list(text: str) -> list[float]:
    """'0.5,1,2' -> [0.5, 1.0, 2.0]; each value must be a positive number."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise UsageError(f"{text!r} is not a comma-separated list of numbers, e.g. 0.5,1,2,4") from None
    if not values or any(not math.isfinite(v) or v <= 0 for v in values):
        raise UsageError(f"{text!r} must list positive numbers, e.g. 0.5,1,2,4")
    return values


def choice_list(choices: tuple[str, ...]) -> Callable[[str], list[str]]:
    """An argparse type for a comma-separated subset of `choices`."""
    def parse(text: str) -> list[str]:
        values = [v.strip() for v in text.split(",") if v.strip()]
        bad = [v for v in values if v not in choices]
        if bad or not values:
            raise UsageError(f"{text!r} is not a comma-separated list of {', '.join(choices)}")
        return values
    return parse


def add_output_flags(parser) -> None:
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object")
    parser.add_argument("--quiet", action="store_true", help="no progress output")


def finite_or_none(value):
    """JSON has no infinity or NaN: those become null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: finite_or_none(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite_or_none(v) for v in value]
    return value


def print_json(obj) -> None:
    json.dump(finite_or_none(obj), sys.stdout, indent=2, allow_nan=False)
    sys.stdout.write("\n")


def write_atomically(path: Path, write: Callable[[Path], None]) -> None:
    """Write through a temporary file in the same directory, then rename: never a half-written output."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; the output should look like any other file
    try:
        write(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def check_writable(path: Path, option: str, *, directory: bool = False) -> Path:
    """Refuse an output path before any work is done, creating nothing: `path` (a file, or with `directory` a
    directory) must be creatable or replaceable, i.e. not of the other kind, and its nearest existing ancestor a
    writable directory. BenchError names the path, the option and what to do."""
    path = Path(path)
    if directory and path.exists() and not path.is_dir():
        raise BenchError(f"{option} {path} is a file, not a directory; choose a directory for {option}")
    if not directory and path.is_dir():
        raise BenchError(f"{option} {path} is a directory; name a file for {option}")
    ancestor = (path if directory else path.parent).absolute()
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise BenchError(f"cannot write {path}: {ancestor} is a file, not a directory; choose another {option}")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise BenchError(f"cannot write {path}: the directory {ancestor} is not writable; choose another {option}")
    return path


@dataclass(frozen=True)
class Verdict:
    """Whether a run, or the log of one, passes: the problems to report and the exit status."""

    problems: list[str]
    status: int

    def exit_status(self, subject: str, as_json: bool) -> int:
        """The status, after one sentence on stderr when it fails (with --json the problems are in the JSON)."""
        if self.status and not as_json:
            print(f"bench: error: {subject} is not clean: " + "; ".join(self.problems), file=sys.stderr)
        return self.status


def verdict(problems: list[str], fault_note: str | None, *, faulted: bool, tolerate_faults: bool,
            tolerate_gaps: bool = False) -> Verdict:
    """The rule of `bench run` and `bench analyze`: every problem fails (status 1); injected faults are one
    (`fault_note`, the sentence that says so) unless tolerated; --tolerate-gaps forgives only a run without faults,
    so an undetected fault, or anything the faults do not explain, always fails."""
    found = list(dict.fromkeys(problems))
    if fault_note and not tolerate_faults:
        found.append(fault_note)
    return Verdict(found, 1 if found and (faulted or not tolerate_gaps) else 0)
