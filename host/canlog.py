"""Bus logs: python-can's writers and readers, chosen by the file's suffix.

`.blf` (Vector binary logging format, the default), `.asc` (Vector ASCII), `.log` (candump -l, readable by
`python -m cantools decode`), `.csv` (python-can's CSV) and `.mf4` (ASAM MDF 4, only where asammdf imports).
`FrameLog` writes through a temporary name beside the target and renames it on success, so a failed run leaves
no half file; timestamps are made non-decreasing (a frame never goes back in time in the log).
"""

from __future__ import annotations

import gc
import importlib.util
import os
import sys
from collections.abc import Iterator
from pathlib import Path

import can

from host.errors import HostError

LOG_SUFFIXES = (".blf", ".asc", ".log", ".csv", ".mf4")
NAME_MAX = 255   # bytes in one file name (Linux, macOS): the temporary name must fit where the log's does
DEFAULT_LOG_SUFFIX = ".blf"


class LogError(HostError):
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
        self.tmp_path = self.path.with_name(partial_name(self.path))
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
            if commit and self.tmp_path.exists():
                os.replace(self.tmp_path, self.path)
        finally:   # not committed (a failure, an interruption, a path that is a directory): no temporary file left
            self.tmp_path.unlink(missing_ok=True)
        return self.path if commit else None

    def __enter__(self) -> FrameLog:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(commit=exc_type is None)


def partial_name(path: Path) -> str:
    """`.STEM.<pid>.partial.SUFFIX`, STEM shortened (counted in bytes) to keep it within NAME_MAX."""
    stem, tail = path.stem, f".{os.getpid()}.partial{path.suffix}"
    while stem and len(os.fsencode(f".{stem}{tail}")) > NAME_MAX:
        stem = stem[:-1]
    return f".{stem}{tail}"


READ_FIX = "pass a complete log written by 'bench run' or the host"
# BLF file header (python-can's FILE_HEADER_STRUCT "<4sLBBBBBBBBQQLL8H8H"): the file size is the Q at byte 16
BLF_FILE_SIZE_OFFSET = 16
BLF_HEADER_PEEK = 512


def _reason(exc: BaseException, limit: int = 120) -> str:
    """An exception as a short single-line reason for a message."""
    text = " ".join(f"{exc.__class__.__name__}: {exc}".split())
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _ignore_unraisable(unraisable) -> None:  # noqa: ARG001 - sys.unraisablehook API
    """A reader that failed half-built (asammdf's MDF4) complains again from __del__: not news to the user."""


def _check_complete(path: Path) -> None:
    """Refuse an empty log, and one whose end is missing where the format shows it (before any frame is read).

    .blf: the header records the file size at close; .asc: our writer and Vector's end with 'End TriggerBlock';
    .log/.csv: every line, the last one too, ends with a newline.
    """
    size = path.stat().st_size
    if size == 0:
        raise LogError(f"log {path} is empty; {READ_FIX}")
    suffix = path.suffix.lower()
    with open(path, "rb") as fh:
        head = fh.read(BLF_HEADER_PEEK)
        fh.seek(max(0, size - 256))
        tail = fh.read()
    if suffix == ".blf" and head[:4] == b"LOGG" and len(head) >= BLF_FILE_SIZE_OFFSET + 8:
        recorded = int.from_bytes(head[BLF_FILE_SIZE_OFFSET:BLF_FILE_SIZE_OFFSET + 8], "little")
        if recorded > size:
            raise LogError(f"log {path} is truncated ({size} of the {recorded} bytes its header records); {READ_FIX}")
    elif suffix == ".asc" and b"begin triggerblock" in head.lower() and b"end triggerblock" not in tail.lower():
        raise LogError(f"log {path} is truncated (no 'End TriggerBlock' at its end); {READ_FIX}")
    elif suffix in (".log", ".csv") and not tail.endswith(b"\n"):
        raise LogError(f"log {path} is truncated (its last line is incomplete); {READ_FIX}")



def read_log(path: str | Path) -> Iterator[can.Message]:
    """Every frame of a log, in order (python-can's LogReader); LogError (one sentence) for a log that is
    missing, empty, truncated, damaged or holds no frame."""
    path = check_log_path(path, for_reading=True)
    try:
        _check_complete(path)
    except OSError as exc:
        raise LogError(f"cannot read the log {path} ({exc.strerror or _reason(exc)}); {READ_FIX}") from None
    hook = sys.unraisablehook
    sys.unraisablehook = _ignore_unraisable
    try:
        try:
            reader = can.LogReader(str(path))
        except Exception as exc:  # noqa: BLE001 - any reader failure is a bad file for the user
            reason = _reason(exc)
        else:
            reason = None
        if reason is not None:
            gc.collect()  # a half-built reader goes now, while its complaint is ignored
    finally:
        sys.unraisablehook = hook
    if reason is not None:
        raise LogError(f"log {path} is not a readable {path.suffix.lower()} log ({reason}); {READ_FIX}")
    count = 0
    try:
        for msg in reader:
            count += 1
            yield msg
    except Exception as exc:  # noqa: BLE001
        raise LogError(f"log {path} is damaged or truncated after {count} frames ({_reason(exc)}); {READ_FIX}"
                       ) from None
    finally:
        reader.stop()
    if count == 0:
        raise LogError(f"log {path} holds no CAN frames; {READ_FIX}")
