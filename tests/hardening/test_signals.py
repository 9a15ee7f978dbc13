"""Signals: a `bench` command that starts a target and is told to stop (SIGTERM, SIGHUP) says so in one sentence,
stops its target, leaves no temporary file and exits 128 + the signal; a target whose bench dies without stopping it
(SIGKILL) stops by itself; a target started by hand runs on.

Each case starts the real CLI as a plain child process (not the fork server: the signal must reach a process of its
own), on a udp_multicast port of its own, so the target it starts can be found by its command line.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from helpers import ROOT, subprocess_env, synthetic_columns, write_synthetic_dataset

NOTE = "no half-written file is left and any target process it started was stopped"


def child_env() -> dict[str, str]:
    return subprocess_env(can_settings=False, OPENBLAS_NUM_THREADS="1")


def _port() -> int:
    from dbc.transport import free_udp_port

    return free_udp_port()


def _targets(port: int) -> list[int]:
    """Process ids of every `python -m target_sim` on udp port `port` (from /proc/*/cmdline)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            argv = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"target_sim" in argv and f"port={port}".encode() in argv:
            found.append(int(entry.name))
    return found


def _wait_for(predicate, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.05)
    return predicate()


def _start(args: list, cwd: Path, port: int) -> subprocess.Popen:
    argv = [sys.executable, "-m", *map(str, args), "-i", "udp_multicast", "--bus-kwargs", f"port={port}"]
    return subprocess.Popen(argv, cwd=cwd, env=child_env(), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)


def _signal_when_running(process: subprocess.Popen, port: int, signum: int, settle_s: float = 1.5):
    """Send `signum` once the command's target has run `settle_s` (the host connected, rows going out); the
    command's exit status, stdout, stderr, and the targets on the port still running when it had exited (which are
    then killed)."""
    left: list[int] = []
    try:
        assert _wait_for(lambda: _targets(port) or process.poll() is not None, 60), "no target started"
        assert process.poll() is None, f"the command ended before the signal: {process.communicate()}"
        time.sleep(settle_s)
        assert process.poll() is None, f"the command ended before the signal: {process.communicate()}"
        process.send_signal(signum)
        stdout, stderr = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        left = _targets(port)
        for pid in left:
            os.kill(pid, signal.SIGKILL)
    return process.returncode, stdout, stderr, left


def _leftovers(path: Path) -> list[str]:
    return sorted(str(p.relative_to(path)) for p in path.rglob("*") if p.is_file()) if path.exists() else []


@pytest.fixture(scope="module")
def long_data(tmp_path_factory) -> Path:
    """30 000 rows (6000 s at 5 Hz): seconds of lockstep, long enough to be interrupted in the middle."""
    columns = synthetic_columns(30_000, seed=3, torque_sd=20.0, speed_sd=100.0, coolant_amplitude=1.5,
                                coolant_period=30.0, ambient_period=45.0)
    return write_synthetic_dataset(tmp_path_factory.mktemp("long") / "long.csv", columns, "signal tests")


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_run_stops_its_target_and_removes_the_partial_log(material, scratch, signum):
    """`bench run` in real time (60 rows at 5 Hz: 12 s), signalled in the middle of the run."""
    port = _port()
    out = scratch / "out"
    process = _start(["bench", "run", "--data", material.data, "--model", material.art, "--mode", "realtime",
                      "--log", out / "x.blf", "--report", out / "rep", "--quiet"], scratch, port)
    rc, stdout, stderr, left = _signal_when_running(process, port, signum)
    name = signal.Signals(signum).name
    assert rc == 128 + signum, stderr
    assert stderr.splitlines() == [f"bench: terminated ({name}); {NOTE}"], stderr
    assert stdout == ""
    assert left == []   # stopped before the command returned, not later
    assert _leftovers(out) == []


def test_replay_stops_its_target_and_removes_the_partial_log(material, scratch):
    """`bench replay` with the recorded timing slowed down 500 times: the 50-row lockstep log spans tens of ms, so
    at 0.02 a replay could end (and its log be complete) before the signal on a loaded machine; at 0.002 it lasts
    far longer than the wait for the signal."""
    port = _port()
    out = scratch / "out"
    process = _start(["bench", "replay", material.log, "--model", material.art, "--speed", "0.002", "--log",
                      out / "r.blf", "--quiet"], scratch, port)
    rc, _, stderr, left = _signal_when_running(process, port, signal.SIGTERM, settle_s=1.0)
    assert rc == 143, stderr
    assert stderr.splitlines() == [f"bench: terminated (SIGTERM); {NOTE}"], stderr
    assert left == []
    assert _leftovers(out) == []


def test_compare_stops_its_target_and_removes_the_partial_log(material, scratch, long_data):
    port = _port()
    out = scratch / "cmp"
    process = _start(["bench", "compare", "--models", material.art, "--data", long_data, "--engine", "python",
                      "--out", out, "--quiet"], scratch, port)
    rc, _, stderr, left = _signal_when_running(process, port, signal.SIGTERM, settle_s=1.0)
    assert rc == 143, stderr
    assert stderr.splitlines() == [f"bench: terminated (SIGTERM); {NOTE}"], stderr
    assert left == []
    assert _leftovers(out) == []


def test_target_stops_by_itself_when_its_bench_is_killed(material, scratch):
    """SIGKILL cannot be handled: the target notices that its parent is gone (parent-death signal, parent-pid
    check) and stops, so the channel is free for the next run."""
    port = _port()
    out = scratch / "out"
    process = _start(["bench", "run", "--data", material.data, "--model", material.art, "--mode", "realtime",
                      "--log", out / "x.blf", "--no-report", "--quiet"], scratch, port)
    try:
        assert _wait_for(lambda: _targets(port), 60), "no target started"
        targets = _targets(port)
        time.sleep(1.0)
        process.kill()
        process.wait()
        assert process.returncode == -signal.SIGKILL
        assert _wait_for(lambda: not _targets(port), 5), f"target {targets} still running after its bench died"
    finally:
        for pid in _targets(port):
            os.kill(pid, signal.SIGKILL)
        process.stdout.close()
        process.stderr.close()


def test_a_target_started_by_hand_outlives_the_shell_that_started_it(material, scratch):
    """No --parent-pid: the target runs until it is stopped, whoever its parent was."""
    port = _port()
    shell = subprocess.run(["sh", "-c", f'"{sys.executable}" -m target_sim --model "{material.art}" -i udp_multicast '
                            f'--bus-kwargs port={port} --quiet </dev/null >/dev/null 2>&1 & echo $!'],
                           cwd=ROOT, env=child_env(), capture_output=True, text=True, timeout=30)
    pid = int(shell.stdout.strip())
    try:
        assert _wait_for(lambda: _targets(port) == [pid], 10)
        time.sleep(2.0)   # its parent, the shell, is long gone
        assert _targets(port) == [pid]
    finally:
        os.kill(pid, signal.SIGTERM)
    assert _wait_for(lambda: not _targets(port), 10)


def test_target_refuses_a_parent_pid_that_is_not_its_parent(cli, material, scratch):
    port = _port()
    result = cli("target_sim", "--model", material.art, "--parent-pid", "1", "-i", "udp_multicast",
                 "--bus-kwargs", f"port={port}", cwd=scratch, timeout=30)
    for pid in _targets(port):   # (one that started anyway)
        os.kill(pid, signal.SIGTERM)
    assert result.rc == 1, str(result)
    assert result.lines == ["target_sim: error: process 1 (--parent-pid) is not the parent of this target (it has "
                            "exited?); the target does not start"], str(result)
