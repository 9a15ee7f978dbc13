"""Files as every layer writes them: a name within the file system's limit, and a file written whole or not at all.

`dbc` imports nothing of the project and every layer may import it, so the facts of file names and the one atomic
write live here once: the lab's outputs (`bench.fileio`), the host's bus log and fault summary (`host.canlog`,
`host.faults`) and the target's counters (`python -m target_sim --stats`) are written the same way. Each layer
adds only its own error sentence (an OSError passes through here).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

NAME_MAX = 255        # bytes in one file name (Linux, macOS): a temporary name must fit where the output's does
RANDOM_PART = 8       # what mkstemp/mkdtemp add between prefix and suffix
MAX_TEMP_SUFFIX = 16  # a longer "suffix" is no format's: the temporary name goes without it


def fitted_name(part: str, name: Callable[[str], str], reserve: int = 0) -> str:
    """`name(part)`, `part` shortened (by characters, counted in bytes) until that name and `reserve` more bytes fit
    in NAME_MAX: a file made from a legal long name (a temporary name, a derived name) gets a legal name."""
    while part and len(os.fsencode(name(part))) + reserve > NAME_MAX:
        part = part[:-1]
    return name(part)


def temporary_prefix(name: str, reserve: int) -> str:
    """`.NAME.`, NAME shortened so that the prefix and `reserve` more bytes (the random part, a suffix) fit."""
    return fitted_name(name, lambda n: f".{n}.", reserve)


def write_atomically(path: str | Path, write: Callable[[Path], None]) -> None:
    """`write(tmp)` into a temporary file beside `path`, then rename it into place: `path` ends whole, or as it was,
    and no temporary file is left either way. The temporary name is legal however long `path`'s is and keeps its
    suffix (writers pick formats by it); the file gets the permissions of any new file (the umask), its directory
    is created. Not fsync'ed: a crash of the machine (not of the process) may lose the newest content."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix if len(os.fsencode(path.suffix)) <= MAX_TEMP_SUFFIX else ""
    fd, tmp = tempfile.mkstemp(prefix=temporary_prefix(path.name, RANDOM_PART + len(os.fsencode(suffix))),
                               suffix=suffix, dir=path.parent)
    os.close(fd)
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; the output should look like any other file
        write(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def same_file(a: str | Path, b: str | Path) -> bool:
    """True when the paths `a` and `b` name one file: the same path once symlinks and `..` are resolved, or (both
    existing) the same inode on the same device, as a hard link is. A path that does not exist yet matches only by
    name: writing it cannot touch another file."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        sa, sb = os.stat(a), os.stat(b)
    except (OSError, ValueError):
        return False
    return (sa.st_dev, sa.st_ino) == (sb.st_dev, sb.st_ino)
