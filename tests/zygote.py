"""Fork server for the tests (`helpers.ForkServer`): `python -m bench` / `python -m target_sim`, minus the import
time.

Every `bench` process spends about 2.5 CPU-s importing (numpy, scipy, python-can, which imports asammdf whenever
it is installed: 1.1 CPU-s of it) before it looks at its arguments; the bad-input matrix has dozens of cases and
the integration tests dozens of commands. This interpreter imports what those entry points import once, then
forks one child per request that runs the entry point exactly as `python -m MODULE ARGS` does
(`runpy.run_module(MODULE, run_name="__main__")`, fd 1 and 2 redirected to files, its own cwd, environment and
session) and reports the exit status. The child is a fresh process of a fresh interpreter that never ran pytest,
so no test state (logging handlers, warning filters, captured streams) leaks into what is asserted.

Protocol: one JSON request per line on stdin ({"module", "args", "cwd", "env" (the whole environment),
"stdout", "stderr", "timeout"}), one JSON reply per line on stdout ({"rc", "timed_out", "seconds"}).
EOF ends the server.

Neither outlives the test process: EOF on stdin ends the server; while it waits for a child it compares its parent's
id with the one it started with, and once the test process is gone it stops the child (SIGTERM to its session, as a
signal would, SIGKILL 10 s later) and ends; a child also gets the kernel's parent-death signal (SIGTERM) if the
server dies. So a pytest killed in the middle of a `run_cli` leaves no command running.
"""

from __future__ import annotations

import atexit
import gc
import json
import os
import runpy
import signal
import sys
import time
import traceback

# Run as a script, this file's folder (tests/, which has a bench/ folder of tests) comes first on sys.path, and
# that folder then shadows an editable install's `bench` as a namespace package (the editable finder is asked
# after the path). `python -m bench` has no such entry: drop it.
if sys.path and os.path.realpath(sys.path[0] or ".") == os.path.dirname(os.path.realpath(__file__)):
    del sys.path[0]
os.environ.setdefault("MPLBACKEND", "Agg")

import importlib  # noqa: E402

import bench.cli  # noqa: E402
import dbc.transport  # noqa: E402, F401
import target_sim.node  # noqa: E402, F401 - what `python -m target_sim` imports
from dbc.lifeline import arm_parent_death  # noqa: E402

# What the subcommands import when they run (the fit, the numerics, the observer's tuning, the run pipeline, the log
# decoder; with them scipy and numba), which `bench` itself imports only in the command that needs it: here once, so
# a forked command finds it imported as it did when building the parser imported it all.
RUN_TIME_MODULES = ("bench.drive.generate", "scipy.signal", "bench.thermal.precision", "bench.model.identify",
                    "bench.model.pipeline", "bench.model.undetermined", "bench.model.coverage",
                    "bench.observer.section", "bench.acceptance.criteria", "bench.acceptance.junit",
                    "bench.analysis.logdecode", "bench.analysis.rowfilter", "bench.analysis.verdict",
                    "bench.run.execute", "bench.run.judge", "bench.run.prepare", "bench.run.leftovers",
                    "host.results")

bench.cli.build_parser()  # imports every subcommand module, as every `bench` invocation does first
for _module in RUN_TIME_MODULES:
    importlib.import_module(_module)
gc.collect()
gc.freeze()  # what was imported is permanent: a child's collections scan only what the child made

PROTOCOL_OUT = os.fdopen(os.dup(1), "w", buffering=1)
os.dup2(2, 1)  # a stray print of the server itself must not corrupt the protocol


def _child(request: dict) -> int:
    out = os.open(request["stdout"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    err = os.open(request["stderr"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    os.dup2(out, 1)
    os.dup2(err, 2)
    for fd in (null, out, err, PROTOCOL_OUT.fileno()):
        os.close(fd)
    os.setsid()
    arm_parent_death(signal.SIGTERM)     # the server's death (it follows the test process's) stops the command
    if os.getppid() != request["server"]:
        return 143                       # the server died before the signal was armed
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    sys.argv = ["-m", *request["args"]]
    code = 0
    try:
        runpy.run_module(request["module"], run_name="__main__", alter_sys=True)
    except SystemExit as exc:
        if exc.code is None:
            code = 0
        elif isinstance(exc.code, int):
            code = exc.code
        else:
            print(exc.code, file=sys.stderr)
            code = 1
    except BaseException:  # noqa: BLE001 - exactly what the interpreter would print
        traceback.print_exc()
        code = 1
    gc.collect()  # finalizers that would run at interpreter exit write their complaints now
    atexit._run_exitfuncs()  # and what the libraries registered for the exit (os._exit below skips it)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    return code


def _stop_orphaned(pid: int) -> None:
    """The test process is gone: stop the child's session as a signal would (SIGTERM; SIGKILL 10 s later), then
    end the server."""
    for signum in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(pid, signum)
        except ProcessLookupError:
            break
        until = time.monotonic() + 10.0
        while time.monotonic() < until:
            if os.waitpid(pid, os.WNOHANG)[0]:
                os._exit(143)
            time.sleep(0.05)
    os._exit(143)


def serve() -> None:
    parent = os.getppid()
    for line in sys.stdin:
        request = json.loads(line)
        sys.stdout.flush()
        sys.stderr.flush()
        started = time.perf_counter()
        request["server"] = os.getpid()
        pid = os.fork()
        if pid == 0:
            code = 1
            try:
                code = _child(request)
            finally:
                os._exit(code & 0xFF if code >= 0 else 1)
        deadline = started + float(request.get("timeout", 60))
        timed_out = False
        while True:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                break
            if time.perf_counter() > deadline:
                timed_out = True
                try:
                    os.killpg(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                _, status = os.waitpid(pid, 0)
                break
            if os.getppid() != parent:
                _stop_orphaned(pid)
            time.sleep(0.005)
        rc = os.waitstatus_to_exitcode(status)
        PROTOCOL_OUT.write(json.dumps({"rc": rc, "timed_out": timed_out,
                                       "seconds": round(time.perf_counter() - started, 3)}) + "\n")


if __name__ == "__main__":
    serve()
