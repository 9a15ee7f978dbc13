"""A stop asked for by a signal, seen by worker threads.

Python runs a signal handler in the main thread only, and only between bytecodes. The main thread of a command
that waits on a thread pool (the identification's polish, one Levenberg-Marquardt fit per core) gets its
`Terminated` at once, but leaving the pool waits for the workers' running tasks, which are long numeric loops
(tens of seconds under load). `bench.cli`'s handler sets this flag first; such loops call `check()` between their
model evaluations, so a worker leaves within one evaluation.
"""

from __future__ import annotations

import threading

_requested = threading.Event()
_signum: list[int] = []     # the signal that asked first


class StopRequested(BaseException):
    """Raised in a worker thread after a signal: a BaseException, as KeyboardInterrupt, so no `except Exception`
    on the way out (scipy's, a retry loop's) takes it for a numerical failure."""


def request(signum: int | None = None) -> None:
    """Ask every loop that checks to stop (called from the signal handler with its signal)."""
    if signum is not None and not _signum:
        _signum.append(signum)
    _requested.set()


def signal_number() -> int | None:
    """The signal that asked for the stop first, if a signal did."""
    return _signum[0] if _signum else None


def clear() -> None:
    """Forget a request (the CLI's `main` returns; a test calls it again in the same process)."""
    _signum.clear()
    _requested.clear()


def requested() -> bool:
    return _requested.is_set()


def check() -> None:
    """Raise StopRequested if a stop was asked for."""
    if _requested.is_set():
        raise StopRequested
