"""Atomic file writes: every output goes through a temporary name in its directory and a rename, so a failed or
interrupted command never leaves a half-written file; and the scratch directories, named by the process that
owns them so that a later bench removes those a killed one left (`bench.run.leftovers`). Imported by every part
of `bench` that writes files."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable, Collection, Mapping
from pathlib import Path

from bench import stop
from bench.errors import BenchError
from dbc import files
from dbc.files import RANDOM_PART, temporary_prefix
from host.errors import write_failure

SCRATCH_PREFIX = "bench-"


class OutputError(BenchError, OSError):
    """An output that could not be written (a full disk, a directory that went away): one sentence naming the file,
    what it is and what to do. Still an OSError, for the callers that add their own context."""

    def __init__(self, path: Path, what: str, exc: OSError):
        OSError.__init__(self, exc.errno, exc.strerror, str(path))
        self.sentence = write_failure(path, what, exc)

    def __str__(self) -> str:
        return self.sentence


def write_atomically(path: Path, write: Callable[[Path], None], what: str = "the file") -> None:
    """Write through a temporary file in the same directory, then rename: never a half-written output. An OSError
    becomes an OutputError naming `path` (`what` it is: "the model artifact", ...)."""
    def write_then_check(tmp: Path) -> None:
        write(tmp)
        stop.check()     # a stop asked for never ends in a finished output, even if its signal was swallowed

    try:
        files.write_atomically(path, write_then_check)
    except OutputError:
        raise
    except OSError as exc:
        raise OutputError(Path(path), what, exc) from None


def write_bytes_atomically(path: Path, payload: bytes, what: str = "the file") -> None:
    """`path` holds exactly `payload`, or is as it was before."""
    write_atomically(path, lambda tmp: tmp.write_bytes(payload), what)


def write_text_atomically(path: Path, text: str, what: str = "the file") -> None:
    """`path` holds exactly `text` (UTF-8), or is as it was before."""
    write_atomically(path, lambda tmp: tmp.write_text(text, encoding="utf-8"), what)


def foreign_entries(path: Path, replaceable: Collection[str]) -> list[str]:
    """Names in the existing directory `path` that `write_directory_atomically` would refuse to replace: anything
    not a regular file named in `replaceable` (an earlier output of the same command). [] if `path` is absent."""
    path = Path(path)
    if not path.is_dir():
        return []
    return sorted(entry.name for entry in path.iterdir()
                  if entry.name not in replaceable or entry.is_symlink() or not entry.is_file())


def write_directory_atomically(path: Path, contents: Mapping[str, bytes], *,
                               replaceable: Collection[str] = ()) -> None:
    """`path` becomes a directory holding exactly `contents` (file name -> bytes), or stays as it was.

    The files are written into a temporary directory beside `path`, which is then renamed into place. An
    existing `path` is replaced only if it holds nothing but regular files named in `replaceable` (an earlier
    output of the same command): else FileExistsError, and nothing is written. (Between moving the old directory
    aside and renaming the new one in, `path` is briefly absent; it is never half-written.)"""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise FileExistsError(f"{path} is a file, not a directory")
    foreign = foreign_entries(path, replaceable)
    if foreign:
        raise FileExistsError(f"{path} holds {', '.join(foreign[:3])}{', ...' if len(foreign) > 3 else ''}, "
                              "which this command did not write")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=temporary_prefix(path.name, RANDOM_PART), dir=path.parent))
    umask = os.umask(0)
    os.umask(umask)
    old: Path | None = None
    try:
        for name, payload in contents.items():
            target = tmp / name
            try:
                target.write_bytes(payload)
            except OSError as exc:   # named as the file it was to become (the temporary name means nothing)
                raise OutputError(path / name, "the file", exc) from None
            os.chmod(target, 0o666 & ~umask)   # mkdtemp makes 0700 and files follow the umask
        os.chmod(tmp, 0o777 & ~umask)
        stop.check()     # see write_atomically
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=temporary_prefix(path.name, RANDOM_PART + 4) + "old.", dir=path.parent))
            os.replace(path, old / path.name)
            try:
                os.replace(tmp, path)
            except BaseException:
                os.replace(old / path.name, path)   # put the previous output back
                raise
        else:
            os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


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


def scratch_dir(kind: str) -> tempfile.TemporaryDirectory:
    """A temporary directory `bench-KIND-<pid>-XXXXXXXX` in the system's temporary directory, removed on
    cleanup; one that outlives its process is removed by a later bench (`bench.run.leftovers`)."""
    return tempfile.TemporaryDirectory(prefix=f"{SCRATCH_PREFIX}{kind}-{os.getpid()}-")
