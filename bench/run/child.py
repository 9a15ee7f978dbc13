"""A `python -m bench run|host` child of another process (a campaign's worker, the pytest plugin): started tied to
its parent and in its own process group, stopped the way a user would stop it, its JSON summary read.

- start (`start_bench`): `python -m bench ARGS` (`bench_command`) with `dbc.lifeline.child_environment`, so the
  bench ties itself to this process at its start (`bench/__main__.py`: SIGTERM when this process dies, however it
  dies: Linux's parent-death signal and a watcher of the parent id), stdin closed, its output captured, in a new
  session: its own process group, which its target joins, so one kill of the group reaches both;
- stop (`stop_bench_process`): SIGTERM (the bench stops its target and removes its partial output itself), after
  `STOP_GRACE_S` SIGKILL of the whole group; whatever of the group is left (its target, after a SIGKILL of the
  bench) is killed too and waited for;
- read (`run_summary`): the JSON object it printed with --json, when it ended with a result (exit 0 or 1).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

from dbc.lifeline import child_environment

# after SIGTERM, how long a bench may take to stop its target (5 s at most, `bench.run.target`) and exit
STOP_GRACE_S = 20.0
RESULT_STATUSES = (0, 1)   # the exit statuses of a run with a result: clean (or tolerated), and not clean


def bench_command(args: Sequence[str]) -> list[str]:
    """The command line of `python -m bench ARGS` with this interpreter."""
    return [sys.executable, "-m", "bench", *args]


def start_bench(command: Sequence[str], *, env: Mapping[str, str] | None = None,
                cwd: str | Path | None = None) -> subprocess.Popen:
    """`command` (a `bench_command`) running, tied to this process and in a process group of its own (text output
    captured; `env`: its environment, default this process's)."""
    return subprocess.Popen(list(command), cwd=cwd, stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=child_environment(dict(os.environ if env is None else env)),
                            start_new_session=True)


def stop_bench_process(proc: subprocess.Popen, grace_s: float = STOP_GRACE_S) -> tuple[str, str, bool]:
    """Stop a bench started by `start_bench` (or any process leading its own group): SIGTERM, after `grace_s`
    SIGKILL of its group, then of what is left of the group, until none of it runs (at most `grace_s` more).
    (stdout, stderr, whether it had to be killed)."""
    if proc.poll() is None:
        proc.terminate()
    killed = False
    try:
        out, err = proc.communicate(timeout=grace_s)
    except subprocess.TimeoutExpired:
        killed = True
        kill_group(proc.pid)
        out, err = proc.communicate()
    kill_group(proc.pid)
    wait_group_gone(proc.pid, grace_s)
    return out or "", err or "", killed


def kill_group(pgid: int) -> None:
    """SIGKILL to every process of group `pgid` (none left: nothing to do)."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(pgid, signal.SIGKILL)


def wait_group_gone(pgid: int, timeout_s: float) -> None:
    """Until no process of group `pgid` exists (a zombie not yet reaped by its adopter counts, so bounded)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.killpg(pgid, 0)
        except (ProcessLookupError, PermissionError):
            return
        time.sleep(0.05)


def run_summary(returncode: int | None, stdout: str) -> dict | None:
    """The JSON object a bench printed with --json, when it ended with a result (`RESULT_STATUSES`); None when it
    did not (a refusal, a crash, a signal) or printed no JSON object."""
    if returncode not in RESULT_STATUSES:
        return None
    try:
        parsed = json.loads(stdout)
    except ValueError:
        return None
    return parsed if isinstance(parsed, dict) else None
