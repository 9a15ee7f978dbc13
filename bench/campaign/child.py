"""`python -m bench.campaign.child PARENT_PID ARGS...`: become `python -m bench ARGS...`, SIGTERMed by the kernel
when the Dask worker that started it (PARENT_PID) dies, however it dies.

A worker killed with SIGKILL cannot stop its children, and a `bench run` left running would write into a run
directory that the retry also writes into. Linux's PR_SET_PDEATHSIG survives exec, so it is set here, in the child
itself, rather than in a `preexec_fn` (not safe in a process with threads, as a Dask worker is). Elsewhere the
child simply runs (a timeout still stops it).
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys

PR_SET_PDEATHSIG = 1


def main(argv: list[str]) -> None:
    parent = int(argv[0])
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):   # not Linux: no parent-death signal
        pass
    if os.getppid() != parent:          # the worker died before the signal was armed
        sys.exit(128 + signal.SIGTERM)
    os.execv(sys.executable, [sys.executable, "-m", "bench", *argv[1:]])


if __name__ == "__main__":
    main(sys.argv[1:])
