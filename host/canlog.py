"""Bus logs: python-can's writers and readers, chosen by the file's suffix.

`.blf` (Vector binary logging format, the default), `.asc` (Vector ASCII), `.log` (candump -l, readable by
`python -m cantools decode`), `.csv` (python-can's CSV) and `.mf4` (ASAM MDF 4, only where asammdf imports).
`FrameLog` writes through a temporary name beside the target and renames it on success, so a failed run leaves
no half file; timestamps are made non-decreasing (a frame never goes back in time in the log).
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Iterator
from pathlib import Path

import can

LOG_SUFFIXES = (".blf", ".asc", ".log", ".csv", ".mf4")
DEFAULT_LOG_SUFFIX = ".blf"


class LogError(Exception):
    """A log that cannot be written or read; the message says which and why."""


def mf4_available() -> bool:
    return importlib.util.find_spec("asammdf") is not None


def check_log_path(path: str | Path, *, for_reading: bool = False) -> Path:
    """The path, if its format is supported here; else LogError naming the supported suffixes."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in LOG_SUFFIXES:
        raise LogError(f"log {path} has an unsupported format {suffix or '(no suffix)'}; "
                       f"use one of {', '.join(LOG_SUFFIXES)}")
    if suffix == ".mf4" and not mf4_available():
        raise LogError(f"log {path} needs asammdf for .mf4; install the 'mf4' extra or use .blf")
    if for_reading and not path.is_file():
        raise LogError(f"log {path} does not exist; pass a log written by 'bench run' or the host")
    return path


class FrameLog:
    """Writes every frame given to `write` to `path`, atomically (temporary name, renamed by `close`)."""

    def __init__(self, path: str | Path):
        self.path = check_log_path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.tmp_path = self.path.with_name(f".{self.path.stem}.{os.getpid()}.partial{self.path.suffix}")
        try:
            self._writer = can.Logger(str(self.tmp_path))
        except (OSError, ValueError, ImportError) as exc:
            raise LogError(f"cannot write the log {self.path} ({exc})") from None
        self._last = float("-inf")
        self.count = 0
        self.closed = False

    def write(self, msg: can.Message) -> None:
        if msg.timestamp < self._last:
            msg.timestamp = self._last
        self._last = msg.timestamp
        self._writer.on_message_received(msg)
        self.count += 1

    def close(self, commit: bool = True) -> Path | None:
        """Finish the file; rename it into place if `commit`, else delete it. Returns the final path."""
        if self.closed:
            return self.path if commit else None
        self.closed = True
        try:
            self._writer.stop()
        finally:
            if commit and self.tmp_path.exists():
                os.replace(self.tmp_path, self.path)
            else:
                self.tmp_path.unlink(missing_ok=True)
        return self.path if commit else None

    def __enter__(self) -> FrameLog:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(commit=exc_type is None)


def read_log(path: str | Path) -> Iterator[can.Message]:
    """Every frame of a log, in order (python-can's LogReader)."""
    path = check_log_path(path, for_reading=True)
    try:
        reader = can.LogReader(str(path))
    except Exception as exc:  # noqa: BLE001 - any reader failure is a bad file for the user
        raise LogError(f"cannot read the log {path} ({exc.__class__.__name__}: {exc})") from None
    try:
        yield from reader
    except Exception as exc:  # noqa: BLE001
        raise LogError(f"log {path} is damaged or truncated ({exc.__class__.__name__}: {exc})") from None
    finally:
        reader.stop()
