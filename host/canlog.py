"""Bus logs: python-can's writers and readers, chosen by the file's suffix.

`.blf` (Vector binary logging format, the default), `.asc` (Vector ASCII), `.log` (candump -l, readable by
`python -m cantools decode`), `.csv` (python-can's CSV) and `.mf4` (ASAM MDF 4, only where asammdf imports).
`FrameLog` writes through a temporary name beside the target and renames it on success, so a failed run leaves
no half file; timestamps are made non-decreasing (a frame never goes back in time in the log).

The .asc and .mf4 headers state when the recording started, and MF4's frame times count from it. python-can's
writers put the time of writing there (an export made later had MF4 times of -120 s, or -1.8e9 s in drive time,
and an ASC dated the export): `FrameLog` gives them the recording's start, its first frame's time or the
`start_time` it is given (0.0: times that count from 0, e.g. drive time). How, per format:
- .asc through python-can's public API: the writer gets a text stream of ours (its `file` argument takes one) that
  states the start on the header's `date` line (the first line of Vector's ASC format, formatted with the writer's
  public `FORMAT_DATE`), and the measurement starts at the first event the writer is given (its documented rule):
  the first frame, or an event at the start when that comes before the first frame.
- .mf4: python-can's MF4Writer takes the time of writing as the start and counts the frame times from it, and has
  no argument to change that; it writes the file, then `_restart_mf4` re-times it with asammdf's public API
  (`MDF.cut(start=..., time_from_zero=True)` moves every frame time by the same amount, `header.start_time` states
  the start), so python-can's reader reads the recorded times back and asammdf's times count from the start. The
  times pass through python-can's offsets from the time of writing: they keep a float64's resolution at an epoch
  time (0.24 µs).
"""

from __future__ import annotations

import gc
import importlib.util
import io
import os
import re
import sys
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path

import can

from dbc.files import fitted_name
from host.errors import HostError, write_failure

LOG_SUFFIXES = (".blf", ".asc", ".log", ".csv", ".mf4")
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


STARTED_SUFFIXES = (".asc", ".mf4")   # formats whose header holds the recording's start time


# the event that starts an .asc measurement before its first frame (an export of the host's frames only)
ASC_START_EVENT = "Start of the recording"


class _DatedASCFile(io.TextIOBase):
    """The text file an ASCWriter writes into, with the header's first line, `date ...`, stating `date` (python-can
    dates the file when it is written)."""

    def __init__(self, path: str, date: str) -> None:
        super().__init__()
        self._file = open(path, "w", encoding="utf-8")   # noqa: SIM115 - closed by close(), which the writer calls
        self._date_line = f"date {date}\n"
        self._head: str | None = ""    # what came before the first line's end; None once that line is written

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        if self._head is not None:
            self._head += text
            if "\n" not in self._head:
                return len(text)
            first, rest = self._head.split("\n", 1)
            self._head = None
            self._file.write((self._date_line if first.startswith("date ") else first + "\n") + rest)
            return len(text)
        return self._file.write(text)

    def tell(self) -> int:
        return self._file.tell()

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        if self.closed:
            return
        try:
            if self._head:     # a header that never ended its first line: as it came
                self._file.write(self._head)
            super().close()    # flushes first
        finally:
            self._file.close()


def _asc_writer(path: str, start: float, first: float | None) -> can.ASCWriter:
    """python-can's ASC writer, dated and started at `start` (seconds since the epoch), before frame `first`."""
    when = datetime.fromtimestamp(start)   # local time, as python-can writes and reads ASC dates
    date = when.strftime(can.ASCWriter.FORMAT_DATE.format(when.microsecond // 1000))
    writer = can.ASCWriter(_DatedASCFile(path, date))
    if first is None or start < first:    # else the first frame starts the measurement, at `start`
        writer.log_event(ASC_START_EVENT, start)
    return writer


MF4_COMPRESSION = 2   # python-can's MF4Writer default: transposed and deflated


def _restart_mf4(path: Path, start: float) -> None:
    """Re-time the .mf4 python-can wrote at `path` to start at `start` (seconds since the epoch): the header states
    `start` and every frame time counts from it, each frame keeping its absolute time. asammdf's public API only."""
    from asammdf import MDF

    written = MDF(str(path))
    try:
        shift = start - written.header.start_time.timestamp()   # the writer's start (its time of writing) to ours
        restarted = written.cut(start=shift, time_from_zero=True, include_ends=False)
    finally:
        written.close()
    try:
        restarted.header.start_time = datetime.fromtimestamp(start, UTC)
        restarted.save(str(path), overwrite=True, compression=MF4_COMPRESSION)
    finally:
        restarted.close()


class FrameLog:
    """Writes every frame given to `write` to `path`, atomically (temporary name, renamed by `close`).

    `start_time` (seconds since the epoch) is the recording's start an .asc or .mf4 header states and MF4's frame
    times count from; None: the first frame's time (0.0: times from 0, as drive time is)."""

    def __init__(self, path: str | Path, start_time: float | None = None):
        self.path = check_log_path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.tmp_path = self.path.with_name(partial_name(self.path))
        self.start_time = start_time
        self.start: float | None = None   # the start a header states, once the writer is open
        self._writer: can.io.generic.MessageWriter | None = None
        if self.path.suffix.lower() in STARTED_SUFFIXES:
            try:   # the writer waits for the first frame's time; whether the file can be written is known now
                self.tmp_path.touch()
            except OSError as exc:
                raise LogError(write_failure(self.path, "the log", exc)) from None
        else:
            self._writer = self._open(None)
        # a frame never goes back before the start a header states (MF4's re-timing would drop it)
        self._last = float("-inf") if start_time is None else start_time
        self.count = 0
        self.closed = False

    def _open(self, first: float | None):
        """python-can's writer for the suffix; .asc and .mf4 started at `start_time`, else at `first` (else now)."""
        suffix = self.path.suffix.lower()
        try:
            if suffix not in STARTED_SUFFIXES:
                return can.Logger(str(self.tmp_path))
            start = self.start_time if self.start_time is not None else first
            start = datetime.now().timestamp() if start is None else start
            self.start = start
            if suffix == ".asc":
                return _asc_writer(str(self.tmp_path), start, first)
            return can.MF4Writer(str(self.tmp_path), compression_level=MF4_COMPRESSION)
        except (OSError, ValueError, ImportError, NotImplementedError) as exc:
            raise LogError(f"cannot write the log {self.path} ({exc})") from None

    def write(self, msg: can.Message) -> None:
        if msg.timestamp < self._last:
            msg.timestamp = self._last
        self._last = msg.timestamp
        if self._writer is None:
            self._writer = self._open(msg.timestamp)
        try:
            self._writer.on_message_received(msg)
        except OSError as exc:   # a full disk, a removed directory: name the log, not "a file"
            raise LogError(write_failure(self.path, "the log", exc)) from None
        self.count += 1

    def close(self, commit: bool = True) -> Path | None:
        """Finish the file; rename it into place if `commit`, else delete it. Returns the final path."""
        if self.closed:
            return self.path if commit else None
        self.closed = True
        try:
            if self._writer is None and commit:   # no frame: still a valid (empty) log
                self._writer = self._open(None)
            if self._writer is not None:
                self._stop_writer(commit)
            if commit and self.path.suffix.lower() == ".mf4":
                self._restart_mf4()
            if commit and self.tmp_path.exists():
                os.replace(self.tmp_path, self.path)
        except OSError as exc:
            raise LogError(write_failure(self.path, "the log", exc)) from None
        finally:   # not committed (a failure, an interruption, a path that is a directory): no temporary file left
            self.tmp_path.unlink(missing_ok=True)
        return self.path if commit else None

    def _restart_mf4(self) -> None:
        """The finished .mf4 re-timed to its start; an OSError is close's to report, like any write's."""
        try:
            _restart_mf4(self.tmp_path, self.start)
        except Exception as exc:  # noqa: BLE001 - asammdf's failures have no common base
            if isinstance(exc, OSError):
                raise
            raise LogError(f"cannot write the log {self.path} ({_reason(exc)})") from None

    def _stop_writer(self, commit: bool) -> None:
        """Flush and close the writer; a log that is being discarded may fail to flush (the disk that stopped it
        is still full): the error that discarded it is the one to report."""
        try:
            self._writer.stop()
        except OSError:
            if commit:
                raise

    def __enter__(self) -> FrameLog:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(commit=exc_type is None)


def partial_name(path: Path, pid: int | None = None) -> str:
    """`.STEM.<pid>.partial.SUFFIX` (pid: this process's by default), STEM shortened (counted in bytes) to keep it
    within NAME_MAX (`dbc.files`)."""
    tail = f".{os.getpid() if pid is None else pid}.partial{path.suffix}"
    return fitted_name(path.stem, lambda stem: f".{stem}{tail}")


PARTIAL_PID = re.compile(r"\.(?P<pid>[0-9]+)\.partial\.[^.]*$")


def partials_of(path: Path) -> dict[int, Path]:
    """The temporary files of log `path` beside it, by the id of the process that was writing each (a process
    that died without cleaning up, SIGKILL, leaves one)."""
    path = Path(path)
    found = {}
    try:
        entries = list(path.parent.iterdir())
    except OSError:   # no directory yet: nothing left there
        return {}
    for entry in entries:
        match = PARTIAL_PID.search(entry.name)
        if match and entry.name == partial_name(path, int(match["pid"])):
            found[int(match["pid"])] = entry
    return found


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
