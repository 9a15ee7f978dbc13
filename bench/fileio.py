"""Atomic file writes: every output goes through a temporary name in its directory and a rename, so a failed or
interrupted command never leaves a half-written file. Imported by every part of `bench` that writes files."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path


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


def write_bytes_atomically(path: Path, payload: bytes) -> None:
    """`path` holds exactly `payload`, or is as it was before."""
    write_atomically(path, lambda tmp: tmp.write_bytes(payload))


def write_text_atomically(path: Path, text: str) -> None:
    """`path` holds exactly `text` (UTF-8), or is as it was before."""
    write_atomically(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
