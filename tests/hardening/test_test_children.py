"""Issue 39: a target a test starts dies with the test process. Tests that start `python -m target_sim` (or another
long-running child) themselves do it through `helpers.TiedProcess` (`dbc.lifeline`: the parent-death signal), so a
pytest killed mid-test (SIGKILL, a CI job cancelled) leaves no target behind; one was seen orphaned."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

from helpers import ROOT, alive, processes_of, subprocess_env, wait_for

# a stand-in for pytest: starts a target the way a test does, says its pid, then waits to be killed
TEST_PROCESS = """
import sys, time
sys.path.insert(0, sys.argv[1])
from helpers import start_target
target = start_target("--model", sys.argv[2], "-i", "udp_multicast", "--bus-kwargs", f"port={sys.argv[3]}",
                      "--quiet")
print(target.pid, flush=True)
time.sleep(600)
"""


def test_a_target_started_by_a_test_dies_with_the_test_process():
    from bench.model.default import default_artifact_path
    from dbc.transport import free_udp_port

    port = free_udp_port()
    test = subprocess.Popen([sys.executable, "-c", TEST_PROCESS, str(ROOT / "tests"), str(default_artifact_path()),
                             str(port)], cwd=ROOT, env=subprocess_env(can_settings=False), stdout=subprocess.PIPE,
                            text=True)
    pid = int(test.stdout.readline())
    try:
        # the target itself runs (`dbc.lifeline` became `python -m target_sim`, same pid)
        assert wait_for(lambda: pid in processes_of(f"port={port}"), 60), "the target did not start within 60 s"
        test.kill()                               # the test process dies without stopping its target
        test.wait(30)
        assert wait_for(lambda: not alive(pid), 30), "the target outlived the test process that started it"
    finally:
        test.kill()
        if alive(pid):
            os.kill(pid, signal.SIGKILL)


# the same, for a target `run_cli` forked from the fork server (tests/zygote.py) in a helper thread
TEST_PROCESS_FORKED = """
import json, sys, threading, time
sys.path.insert(0, sys.argv[1])
from helpers import ROOT, fork_server, subprocess_env
argv = json.loads(sys.argv[3])
threading.Thread(target=fork_server().run, args=("target_sim", ["--model", sys.argv[2], "--quiet", *argv]),
                 kwargs={"cwd": ROOT, "env": subprocess_env(), "timeout": 600}, daemon=True).start()
time.sleep(600)
"""


def _children(pid: int) -> list[int]:
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(stat.parent.name))
        except (OSError, IndexError, ValueError):
            continue
    return found


def test_a_command_forked_for_a_test_dies_with_the_test_process():
    import json

    from bench.model.default import default_artifact_path
    from dbc.database import frame_id

    from helpers import private_udp_bus

    config = private_udp_bus()
    listener = config.open()
    test = subprocess.Popen([sys.executable, "-c", TEST_PROCESS_FORKED, str(ROOT / "tests"),
                             str(default_artifact_path()), json.dumps(config.to_argv())], cwd=ROOT,
                            env=subprocess_env(can_settings=False))
    try:
        status = frame_id("Status")
        assert wait_for(lambda: (m := listener.recv(0.2)) is not None and m.arbitration_id == status, 120), (
            "the forked target sent no heartbeat within 120 s")
        (server,) = _children(test.pid)           # the fork server, and its child: the target
        (target,) = _children(server)
        test.kill()                               # the test process dies in the middle of its run_cli
        test.wait(30)
        assert wait_for(lambda: not alive(target) and not alive(server), 30), (
            "the forked target or the fork server outlived the test process")
    finally:
        listener.shutdown()
        test.kill()
        for pid in _children(test.pid) + [c for s in _children(test.pid) for c in _children(s)]:
            os.kill(pid, signal.SIGKILL)


def test_no_test_starts_a_target_untied():
    """No test module starts `python -m target_sim` with subprocess.Popen of its own: `helpers.start_target` does."""
    popen = re.compile(r"subprocess\.Popen\(\s*\[[^\]]*?[\"']target_sim[\"']", re.S)
    found = [str(path.relative_to(ROOT)) for path in sorted((ROOT / "tests").rglob("*.py"))
             if path.name != "helpers.py" and popen.search(path.read_text(encoding="utf-8"))]
    assert found == [], f"start the target through helpers.start_target (tied to the test process): {found}"
