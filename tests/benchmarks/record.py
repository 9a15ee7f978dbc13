"""What every benchmark script writes beside what it prints: one JSON record of its figures, with the date, the
machine, the code and the load, so the results page (`docs/results.md`) and the README's headline table are built
from measurements and never typed by hand.

    parser = argparse.ArgumentParser(...)
    add_record_arguments(parser)
    record = Record("can", parser.parse_args(), parameters={"rows": ...})
    record.figures["lockstep"] = {...}
    record.write()

By default a record goes to `docs/results/<benchmark>[-<variant>].json` (committed: the page shows what was last
measured and when); `--json PATH` writes elsewhere, `--no-json` nowhere. The file is written whole (a temporary
file renamed into place), so an interrupted benchmark leaves the previous record as it was.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
RESULTS_DIR = ROOT / "docs" / "results"
RECORD_SCHEMA = 1


def add_record_arguments(parser: argparse.ArgumentParser) -> None:
    """The options every benchmark shares: where its JSON record goes."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--json", type=Path, default=None, metavar="PATH",
                       help=f"write the record here (default: {RESULTS_DIR.relative_to(ROOT)}/<benchmark>.json)")
    group.add_argument("--no-json", action="store_true", help="print only, write no record")


def _first_line(path: str, prefix: str) -> str | None:
    try:
        for line in Path(path).read_text(encoding="utf-8").splitlines():
            if line.startswith(prefix):
                return line.split(":", 1)[1].strip()
    except OSError:
        return None
    return None


def machine() -> dict[str, Any]:
    """The machine as a reader of the figures needs it: CPU, cores, memory, OS, Python and numpy."""
    import numpy

    memory = _first_line("/proc/meminfo", "MemTotal")
    return {"cpu": _first_line("/proc/cpuinfo", "model name") or platform.processor() or platform.machine(),
            "cpus": os.cpu_count(),
            "memory_GB": round(int(memory.split()[0]) / 2**20, 1) if memory else None,
            "os": platform.platform(terse=True),
            "python": platform.python_version(),
            "numpy": numpy.__version__,
            "openblas_coretype": os.environ.get("OPENBLAS_CORETYPE")}


def code() -> dict[str, Any]:
    """The code measured: the package version and, in a git checkout, the commit and whether it had changes."""
    sys.path.insert(0, str(ROOT))
    from bench import package_version

    out: dict[str, Any] = {"version": package_version(), "commit": None, "dirty": None}
    try:
        commit = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=ROOT, capture_output=True,
                                text=True, timeout=10)
        status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                                capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return out
    if commit.returncode == 0:
        out["commit"] = commit.stdout.strip()
        out["dirty"] = bool(status.stdout.strip())
    return out


def stop_on_sigterm() -> None:
    """A benchmark stopped with SIGTERM (kill, a CI timeout) stops as on Ctrl-C: SystemExit unwinds it, so the child
    `subprocess.run` waits for is killed and temporary directories are removed; without this the script died at
    once and left its `bench` child running and its work directory behind. Only from the main thread, and only
    where SIGTERM still has its default action (a caller's own handler stays)."""
    if threading.current_thread() is threading.main_thread() and \
            signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _exit_on_sigterm)


def _exit_on_sigterm(signum, _frame) -> None:
    raise SystemExit(128 + signum)


class Record:
    """The figures of one benchmark invocation, written as one JSON file by `write()`."""

    def __init__(self, benchmark: str, args: argparse.Namespace, parameters: dict[str, Any] | None = None,
                 variant: str | None = None) -> None:
        self.benchmark = benchmark
        self.variant = variant
        self.path: Path | None = None if args.no_json else (
            args.json or RESULTS_DIR / f"{benchmark}{'-' + variant if variant else ''}.json")
        self.parameters = parameters or {}
        self.figures: dict[str, Any] = {}
        self._started = time.perf_counter()
        self._date = _dt.datetime.now(_dt.UTC).replace(microsecond=0)
        self._load_start = os.getloadavg()[0]
        self._code = code()            # the code as it was when the measurement started
        stop_on_sigterm()

    def to_json(self) -> dict[str, Any]:
        return {"record_schema": RECORD_SCHEMA, "benchmark": self.benchmark, "variant": self.variant,
                "date": self._date.isoformat().replace("+00:00", "Z"),
                "command": " ".join(["python", str(Path(sys.argv[0]).resolve().relative_to(ROOT))] + sys.argv[1:]),
                "machine": machine(), "code": self._code,
                "load_average": {"start": round(self._load_start, 2), "end": round(os.getloadavg()[0], 2)},
                "wall_s": round(time.perf_counter() - self._started, 1),
                "parameters": self.parameters, "figures": self.figures}

    def write(self) -> Path | None:
        """Write the record whole (temporary file, then rename); the path written, or None with --no-json."""
        if self.path is None:
            return None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        partial = self.path.with_name(f".{self.path.name}.{os.getpid()}.partial")
        partial.write_text(json.dumps(self.to_json(), indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
        partial.replace(self.path)
        print(f"record written: {self.path}")
        return self.path


def percentiles(values: Any) -> dict[str, float | None]:
    """p50/p99/max of a sequence, as the run results give them, for figures the script computes itself."""
    import numpy as np

    data = np.asarray(list(values), dtype=float)
    if data.size == 0:
        return {"p50": None, "p99": None, "max": None}
    return {"p50": float(np.percentile(data, 50)), "p99": float(np.percentile(data, 99)), "max": float(data.max())}
