"""Short scheduling slices (`dbc.scheduling`): a target serving a bus runs its receive loop with the shortest slice
the kernel grants, so that on a loaded machine its wake-ups wait less; where the kernel cannot, nothing changes."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench.model.default import default_artifact_path
from dbc.database import frame_id
from dbc.scheduling import SLICE_US, request_short_slices, slice_us

from helpers import ROOT, private_udp_bus, start_target, subprocess_env


def kernel_slice_ns(pid: int) -> int | None:
    """The slice the kernel keeps for a process's main thread (/proc/PID/sched's se.slice, EEVDF kernels only)."""
    found = re.search(r"^se\.slice\s*:\s*(\d+)", Path(f"/proc/{pid}/sched").read_text(), re.MULTILINE)
    return int(found.group(1)) if found else None


needs_eevdf = pytest.mark.skipif(not Path("/proc/self/sched").is_file() or kernel_slice_ns(1) is None,
                                 reason="the kernel keeps no per-task slice (not EEVDF, Linux < 6.6)")


@needs_eevdf
def test_the_request_sets_the_calling_threads_slice():
    """In a fresh process (not to change this worker's scheduling): the kernel reports the slice asked for."""
    code = ("import re, pathlib; from dbc.scheduling import request_short_slices, slice_us; "
            "ok = request_short_slices(); "
            "s = re.search(r'se\\.slice\\s*:\\s*(\\d+)', pathlib.Path('/proc/self/sched').read_text()).group(1); "
            "print(ok, slice_us(), s)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                          env=subprocess_env(), timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["True", str(SLICE_US), str(SLICE_US * 1000)]


@needs_eevdf
def test_a_serving_target_runs_with_short_slices():
    config = private_udp_bus()
    with start_target("--model", str(default_artifact_path()), "--quiet", *config.to_argv(),
                      env=subprocess_env(can_settings=False)) as target:
        bus = config.open()
        try:
            deadline = time.monotonic() + 60
            while getattr(bus.recv(0.5), "arbitration_id", None) != frame_id("Status"):
                assert time.monotonic() < deadline, "the target sent no heartbeat within 60 s"
            assert kernel_slice_ns(target.pid) == SLICE_US * 1000
        finally:
            bus.shutdown()


def test_where_the_platform_cannot_nothing_changes(monkeypatch):
    monkeypatch.setattr("platform.machine", lambda: "sparc64")
    assert request_short_slices() is False and slice_us() is None
