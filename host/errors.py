"""The base of the host node's errors (`DataRangeError`, `FaultSpecError`, `LogError`, `SessionError`).

One base per layer (`dbc.errors.CanLinkError`, `target_sim.errors.TargetError`, `bench.errors.BenchError`): a
command-line tool catches it once and prints its message, one sentence.
"""


class HostError(Exception):
    """A problem of the host node: its data, its fault options, its log, its session with the target; one sentence."""


def io_advice(errno_value: int | None) -> str:
    """What the user can do about a file the bench could not write, by the system's reason."""
    import errno

    if errno_value in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        return "free space on its file system (or raise the quota), or write it elsewhere"
    if errno_value in (errno.EACCES, errno.EPERM, errno.EROFS):
        return "make its directory writable, or write it elsewhere"
    if errno_value in (errno.ENOENT, errno.ENOTDIR, errno.EISDIR, errno.ENAMETOOLONG):
        return "check that the path exists and is of the right kind, or choose another"
    return "check the path and its file system, or write it elsewhere"


def write_failure(path, what: str, exc: OSError) -> str:
    """'cannot write the log out/x.blf (No space left on device); free space ...': the file, what it is, the
    system's reason and what to do."""
    reason = exc.strerror or str(exc) or exc.__class__.__name__
    return f"cannot write {what} {path} ({reason}); {io_advice(exc.errno)}"
