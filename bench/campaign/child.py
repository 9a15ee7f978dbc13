"""`python -m bench.campaign.child PARENT_PID ARGS...`: become `python -m bench ARGS...`, SIGTERMed when the Dask
worker that started it (PARENT_PID) dies, however it dies.

A worker killed with SIGKILL cannot stop its children, and a `bench run` left running would write into a run
directory that the retry also writes into. The exec'd bench ties itself to PARENT_PID (`dbc.lifeline`: Linux's
parent-death signal, which survives exec, and a watcher of its parent id everywhere), in the child itself rather
than in a `preexec_fn` (not safe in a process with threads, as a Dask worker is).
"""

from __future__ import annotations

import os
import signal
import sys

from dbc.lifeline import PARENT_ENV


def main(argv: list[str]) -> None:
    parent = int(argv[0])
    if os.getppid() != parent:          # the worker died before the bench could tie itself to it
        sys.exit(128 + signal.SIGTERM)
    os.environ[PARENT_ENV] = str(parent)   # read (and removed) by `python -m bench` at its start
    os.execv(sys.executable, [sys.executable, "-m", "bench", *argv[1:]])


if __name__ == "__main__":
    main(sys.argv[1:])
