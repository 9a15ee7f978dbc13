"""What a bench killed without a chance to clean up (SIGKILL, a crash, a power cut) leaves behind, and its removal
by the next bench.

Every temporary file or directory a bench writes carries the id of the process that writes it: a log's partial
file `.STEM.<pid>.partial.SUFFIX` beside the log (`host.canlog.partial_name`), and the scratch directories in the
system's temporary directory, `bench-<kind>-<pid>-XXXXXXXX` (`bench.fileio.scratch_dir`). A later bench removes
those whose process no longer runs: the partial files of the log it is about to write, and every stale scratch
directory. A process that still runs (another bench writing the same log, or a process that reused the id) keeps
its files.
"""

from __future__ import annotations

import os
import re
import shutil
import sys
import tempfile
from pathlib import Path

from bench.fileio import SCRATCH_PREFIX
from host.canlog import partials_of

SCRATCH_NAME = re.compile(r"^bench-(?P<kind>[a-z-]+?)-(?P<pid>[0-9]+)-[^/]+$")


def process_alive(pid: int) -> bool:
    """True while process `pid` exists (also one of another user, or a zombie not yet reaped)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:   # it exists, it is not ours
        return True
    return True


def remove_stale_scratch(parent: Path | None = None) -> list[Path]:
    """Remove the scratch directories (`scratch_dir`) in `parent` (default: the system's temporary directory)
    whose process no longer runs; the paths removed."""
    parent = Path(parent or tempfile.gettempdir())
    removed = []
    try:
        entries = [e for e in parent.iterdir() if e.name.startswith(SCRATCH_PREFIX)]
    except OSError:
        return []
    for entry in entries:
        match = SCRATCH_NAME.match(entry.name)
        if match is None or entry.is_symlink() or not entry.is_dir() or process_alive(int(match["pid"])):
            continue
        shutil.rmtree(entry, ignore_errors=True)
        if not entry.exists():
            removed.append(entry)
    return removed


def remove_stale_partials(log_path: Path) -> dict[int, Path]:
    """Remove the partial files of log `log_path` whose writing process no longer runs; the paths removed, by
    the id of the process that left each."""
    removed = {}
    for pid, path in sorted(partials_of(Path(log_path)).items()):
        if pid == os.getpid() or process_alive(pid) or path.is_symlink() or not path.is_file():
            continue
        try:
            path.unlink()
        except FileNotFoundError:   # another bench removed it first
            continue
        removed[pid] = path
    return removed


def clear_leftovers(log_path: Path | None) -> list[str]:
    """Remove what killed benches left: the partial files of `log_path` (if given) and the stale scratch
    directories. One sentence per removal, for the user (what was removed and why)."""
    notes = []
    if log_path is not None:
        for pid, path in remove_stale_partials(log_path).items():
            notes.append(f"removed {path}, the partial log of a bench that ended without finishing it (process "
                         f"{pid} no longer runs)")
    for path in remove_stale_scratch():
        notes.append(f"removed {path}, the temporary directory of a bench that ended without removing it")
    return notes


def clear_and_say(log_path: Path | None, quiet: bool) -> None:
    """`clear_leftovers`, each removal said on stderr (`bench: removed ...`) unless `quiet`."""
    for note in clear_leftovers(log_path):
        if not quiet:
            print(f"bench: {note}", file=sys.stderr)
