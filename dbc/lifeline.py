"""Child processes that die with their parent: however the parent ends (SIGTERM, SIGKILL, a crash, a CI job
cancelled), a child of the bench or of its pytest plugin stops soon after, the way it stops on SIGTERM (cleaning up
what it wrote).

Two ways, both armed by `tie_to_parent` in the child itself (a `preexec_fn` is not safe in a parent with threads):
- Linux's parent-death signal (prctl PR_SET_PDEATHSIG): the kernel sends the signal the moment the parent dies. It
  survives exec, and it fires when the *thread* that started the child ends, so a parent starts such children from
  a thread that lives as long as they do (the main thread).
- everywhere, a watcher thread that compares the parent id with the one it was given (an orphan is adopted by
  another process) and then sends the signal to its own process: at most `WATCH_INTERVAL_S` later.

A child learns its parent either from its command line (`python -m target_sim --parent-pid PID`) or from the
environment (`PARENT_ENV`, read and removed by `tie_from_environment`: its own children are not the parent's).
A program that is not the bench's own (a compiler) is started through `tied_command`: `python -m dbc.lifeline
PROGRAM ARGS...` arms the parent-death signal in itself, then becomes PROGRAM (exec: the signal stays armed; the
watcher thread does not survive it, so this tie is Linux's alone).
`dbc` imports nothing of the project, so every layer ties its children the same way.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
import sys
import threading
import time
from collections.abc import MutableMapping

PR_SET_PDEATHSIG = 1          # <linux/prctl.h>
WATCH_INTERVAL_S = 0.25       # how often the watcher compares the parent id
PARENT_ENV = "BENCH_PARENT_PID"   # the id of the process a child started with it must die with
EXEC_FAILED = 127             # `python -m dbc.lifeline`'s status when PROGRAM cannot be started (as a shell's)
PARENT_GONE = 143             # ... when its parent died before PROGRAM started (128 + SIGTERM, as if signalled)


def arm_parent_death(signum: int = signal.SIGTERM) -> bool:
    """Ask the kernel for `signum` when the parent dies (Linux); False where there is no such thing."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, int(signum), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def watch_parent(parent: int, signum: int = signal.SIGTERM,
                 interval_s: float = WATCH_INTERVAL_S) -> threading.Thread:
    """A daemon thread that sends `signum` to this process once its parent is no longer `parent` (it died, and
    the orphan was adopted), then ends."""
    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(interval_s)
        os.kill(os.getpid(), signum)

    thread = threading.Thread(target=watch, name=f"parent-{parent}-watcher", daemon=True)
    thread.start()
    return thread


def tie_to_parent(parent: int, signum: int = signal.SIGTERM, *, kernel: bool = True, watch: bool = True) -> bool:
    """Receive `signum` when process `parent`, this one's parent, dies: the kernel's parent-death signal (`kernel`,
    where there is one) and the watcher thread (`watch`; off for a process whose own loop checks the parent id).
    False when `parent` is not (or no longer) this process's parent: the caller should not start its work."""
    if kernel:
        arm_parent_death(signum)
    if os.getppid() != parent:   # checked after arming: a parent that died before is seen here
        return False
    if watch:
        watch_parent(parent, signum)
    return True


def tie_from_environment(signum: int = signal.SIGTERM) -> bool | None:
    """`tie_to_parent` to the process `PARENT_ENV` names, the variable removed (this process's own children are not
    tied to it); None when it is not set, else what `tie_to_parent` returned. A value that is no process id is
    ignored (None)."""
    text = os.environ.pop(PARENT_ENV, None)
    if text is None or not text.strip().isdigit():
        return None
    return tie_to_parent(int(text), signum)


def child_environment(env: MutableMapping[str, str] | None = None) -> dict[str, str]:
    """`env` (default: this process's) telling a child started with it to die with this process
    (`tie_from_environment`)."""
    return {**(os.environ if env is None else env), PARENT_ENV: str(os.getpid())}


def tied_command(argv: list[str]) -> list[str]:
    """The command line that runs `argv` tied to the process that starts it with `tied_environment()` (see the
    module docstring; exit EXEC_FAILED, saying so on stderr, when argv[0] cannot be started)."""
    return [sys.executable, "-m", "dbc.lifeline", *argv]


def tied_environment(env: MutableMapping[str, str] | None = None) -> dict[str, str]:
    """`child_environment(env)` in which `python -m dbc.lifeline` finds this very `dbc` from any directory (a
    checkout run without installing it is on the parent's path only through its working directory)."""
    out = child_environment(env)
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [out.get("PYTHONPATH")])])
    return out


def _exec_tied(argv: list[str]) -> int:
    """`python -m dbc.lifeline PROGRAM ARGS...`: tie to the parent `PARENT_ENV` names (the kernel's signal only: it
    survives exec), then become PROGRAM."""
    if not argv:
        print("usage: python -m dbc.lifeline PROGRAM [ARGS...]", file=sys.stderr)
        return 2
    text = os.environ.pop(PARENT_ENV, None)
    if text is not None and text.strip().isdigit() and not tie_to_parent(int(text), watch=False):
        return PARENT_GONE
    try:
        os.execvp(argv[0], argv)
    except OSError as exc:
        print(f"{argv[0]} cannot be started: {exc.strerror or exc}", file=sys.stderr)
    return EXEC_FAILED


if __name__ == "__main__":
    sys.exit(_exec_tied(sys.argv[1:]))
