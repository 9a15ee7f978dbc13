"""The numba kernels compiled ahead of use (`bench.thermal.kernels`): the warm-up reaches every kernel, the
wrappers give every kernel one signature whatever flags their arrays have, and a worker waits for the warm-up's
lock, for a while."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import pytest

from bench.thermal import kernels

from helpers import KERNELS_LOCK_ENV, ROOT, subprocess_env, wait_for_kernels

# In a fresh process (nothing else called a kernel): the kernels compile_kernels() compiles or loads, and the ones
# it reaches inside them (a kernel that is compiled into its caller has no signature of its own when the caller
# comes from the cache).
REACHED = """
import importlib, importlib.util, inspect, json, pkgutil, re
from pathlib import Path
from numba.core.registry import CPUDispatcher
import bench
from bench.thermal.kernels import KERNEL_MODULES, compile_kernels

compile_kernels()
modules = [m.name for m in pkgutil.walk_packages(bench.__path__, "bench.", onerror=lambda name: None) if not m.ispkg]
defining = sorted(m for m in modules
                  if re.search(r"@(numba\\.)?n?jit\\b", Path(importlib.util.find_spec(m).origin).read_text()))
found = {f"{m}.{n}": d for m in defining for n, d in vars(importlib.import_module(m)).items()
         if isinstance(d, CPUDispatcher) and d.__module__ == m}
reached = {name for name, d in found.items() if d.signatures}
grown = True
while grown:
    sources = "".join(inspect.getsource(found[name].py_func) for name in reached)
    more = {name for name, d in found.items() if name not in reached and f"{d.py_func.__name__}(" in sources}
    reached |= more
    grown = bool(more)
print(json.dumps({"defining": defining, "modules": sorted(KERNEL_MODULES), "kernels": sorted(found),
                  "reached": sorted(reached)}))
"""


def test_the_warm_up_reaches_every_kernel_of_the_bench():
    proc = subprocess.run([sys.executable, "-W", "ignore", "-c", REACHED], cwd=ROOT, env=subprocess_env(),
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout)
    assert got["defining"] == got["modules"]            # every module that defines a kernel is warmed
    assert len(got["kernels"]) >= 18 and got["reached"] == got["kernels"]


def _signatures() -> dict[str, int]:
    import importlib

    from numba.core.registry import CPUDispatcher

    return {f"{m}.{n}": len(d.signatures) for m in kernels.KERNEL_MODULES
            for n, d in vars(importlib.import_module(m)).items() if isinstance(d, CPUDispatcher)}


def _read_only(a) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.flags.writeable = False
    return a


def test_read_only_strided_and_float32_arrays_compile_no_kernel_again():
    """An artifact's arrays are read-only views, and numba would compile a kernel again for each such type."""
    from bench.thermal import portable
    from bench.thermal.estimator import StepInputs, identity_sigmoid, run_batch
    from bench.thermal.kalman import Readings, run_filters

    kernels.compile_kernels()
    before = _signatures()
    m = _read_only([[2.0, 0.5], [0.5, 3.0]])
    portable.inv(m)
    portable.inv(np.stack([m, m]))
    portable.solve(m, _read_only([1.0, 2.0]))
    portable.matmul(m, np.asfortranarray(m))
    portable.expm(m.astype(np.float32))
    portable.svd(np.eye(6)[::2, ::2])
    portable.exp_array(np.ones((3, 3))[:, 1])
    steps = 4
    inputs = StepInputs(_read_only(np.ones((steps, 5))), np.full(steps, 0.5, dtype=np.float32),
                        np.full(steps, 40.0), np.full(steps, 25.0), 100.0)
    a = _read_only(np.eye(4)[None] * 0.9)
    eight = np.full((4, 16), 0.01)[:, ::2]                                       # a strided view
    sig = _read_only(identity_sigmoid(np.ones(4)))
    run_batch(a, eight[None], _read_only(np.eye(4)[None]), _read_only(np.ones((1, 14))), sig[None], inputs,
              np.full(8, 40.0)[::2], keep_trajectories=np.bool_(True))
    readings = Readings(np.full((steps, 1), 41.0), np.zeros((steps, 1)), np.ones((steps, 1)),
                        _read_only([[0.0, 1.0, 0.0, 0.0]]), np.array([0.5]), bias=True)
    run_filters(a[0], eight, _read_only(np.eye(4)), _read_only(np.ones(14)), sig, inputs, _read_only(np.full(4, 40.0)),
                readings, _read_only(np.eye(6)[None] * 1e-4), [0.1], _read_only(np.eye(6)), keep=np.bool_(False))
    assert _signatures() == before


def test_the_command_names_an_unknown_module_in_one_sentence(capsys):
    assert kernels.main(["bench.thermal.nope"]) == 2
    err = capsys.readouterr().err
    assert err.strip() == ("bench.thermal.nope is not one of bench.thermal.estimator, bench.thermal.kalman, "
                           "bench.thermal.portable, bench.thermal.blocked_qr")


HOLD = "import fcntl, sys, time; f = open(sys.argv[1], 'w'); fcntl.flock(f, fcntl.LOCK_EX); print(1, flush=True); " \
       "time.sleep(float(sys.argv[2]))"


def test_a_worker_waits_for_the_warm_up_lock_then_gives_up_after_its_timeout(tmp_path, monkeypatch):
    lock = tmp_path / "kernels.lock"
    monkeypatch.setenv(KERNELS_LOCK_ENV, str(lock))
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(lock), "1.5"], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "1"                      # it holds the lock
        start = time.monotonic()
        assert wait_for_kernels(timeout=0.3) is False                       # still held: gave up
        assert wait_for_kernels(timeout=60) is True                          # released when the holder exited
        assert 1.0 < time.monotonic() - start < 30
    finally:
        holder.kill()
        holder.wait()
    monkeypatch.setenv(KERNELS_LOCK_ENV, str(tmp_path / "gone.lock"))
    assert wait_for_kernels(timeout=0.3) is True                             # no warm-up: nothing to wait for
    monkeypatch.delenv(KERNELS_LOCK_ENV)
    assert wait_for_kernels(timeout=0.3) is True


@pytest.mark.slow
def test_no_kernel_warns_when_it_compiles(tmp_path):
    """numba's compile-time warnings (NumbaPerformanceWarning: '@' on a strided view) are printed on a user's stderr
    at a command's first run: every kernel compiles from an empty cache with none (about 40 CPU-s)."""
    env = subprocess_env(NUMBA_CACHE_DIR=str(tmp_path / "numba-cache"))
    proc = subprocess.run([sys.executable, "-W", "default", "-m", "bench.thermal.kernels"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, proc.stderr
    assert "Warning" not in proc.stderr, proc.stderr
    assert any((tmp_path / "numba-cache").rglob("*.nbi"))     # compiled into the empty cache, not loaded
