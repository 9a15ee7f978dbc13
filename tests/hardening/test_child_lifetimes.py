"""Every process the bench or its pytest plugin starts dies with its parent (`dbc.lifeline`; a run started by
`bench.run.child`, as campaigns and the plugin start theirs, with its target), and the plugin stops a run the way a
user would (SIGTERM first, SIGKILL after a grace period) and removes what it left.

Each case starts real processes: a pytest session running the `thermal_bench` fixture on a real-time run (300 rows
at 5 Hz: a minute, far longer than the cases wait), signalled in the middle of it once the run's partial log
exists. Its processes are found by their command lines, which all hold the case's own directory (the bench's --log
under pytest's --basetemp, the target's --stats under the session's TMPDIR). Each case then waits, polling, up to
`GONE_TIMEOUT_S` for every one of them to have ended and for the partial log and the scratch directories to be
gone.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from helpers import alive, processes_of, subprocess_env, synthetic_columns, wait_for, write_synthetic_dataset

GONE_TIMEOUT_S = 30.0      # for the processes and files to go, polling (a loaded CI machine)
START_TIMEOUT_S = 120.0    # for pytest to start, the bench to load and the run to log its first frames


def end_group(parent: subprocess.Popen) -> None:
    """Whatever a test left: the parent and its process group, killed and reaped."""
    if parent.poll() is None:
        parent.kill()
        parent.wait()
    try:
        os.killpg(parent.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def leftovers(case: Path) -> list[str]:
    """What a stopped run may leave: partial logs under pytest's base directory, the bench's scratch directories
    (`bench-KIND-PID-*`) in the session's temporary directory."""
    partials = [str(p) for p in (case / "basetemp").rglob("*.partial.*")]
    scratch = [str(p) for p in (case / "tmp").glob("bench-*")]
    return partials + scratch


@pytest.fixture(scope="module")
def minute_data(tmp_path_factory) -> Path:
    """300 rows at 5 Hz: a minute in real time."""
    return write_synthetic_dataset(tmp_path_factory.mktemp("lifetimes") / "minute.csv",
                                   synthetic_columns(300, seed=4), "child lifetime tests")


def start_session(case: Path, test_body: str, *options: str) -> subprocess.Popen:
    """pytest on one test using `thermal_bench` (the plugin from this tree), its --basetemp and TMPDIR in `case`;
    without pytest-xdist unless `options` ask for its workers."""
    (case / "tmp").mkdir(parents=True)
    (case / "test_inner.py").write_text(textwrap.dedent(test_body))
    env = subprocess_env(can_settings=False, TMPDIR=str(case / "tmp"), OPENBLAS_NUM_THREADS="1")
    argv = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *(options or ("-p", "no:xdist")),
            "-p", "no:bench", "-p", "bench.pytest_plugin", "--basetemp", str(case / "basetemp"), "test_inner.py"]
    return subprocess.Popen(argv, cwd=case, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)


def running_run(case: Path, session: subprocess.Popen) -> dict[int, str]:
    """Once the run logs (its partial log exists) and its target runs: the session's other processes."""
    def started() -> bool:
        assert session.poll() is None, f"pytest ended before the signal:\n{session.communicate()[0][-3000:]}"
        procs = processes_of(str(case), exclude=(session.pid,))
        return (any("target_sim" in argv for argv in procs.values())
                and any((case / "basetemp").rglob("*.partial.*")))

    assert wait_for(started, START_TIMEOUT_S), "the run did not start logging"
    time.sleep(1.0)
    procs = processes_of(str(case), exclude=(session.pid,))
    benches = [pid for pid, argv in procs.items() if " bench run " in argv]
    assert benches, procs
    parent = parent_of(benches[0])
    if parent != session.pid:   # a pytest-xdist worker between pytest and the bench
        procs[parent] = "the pytest-xdist worker"
    return procs


def parent_of(pid: int) -> int:
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])


def kill_all(case: Path) -> None:
    for pid in processes_of(str(case)):
        os.kill(pid, signal.SIGKILL)


MINUTE_RUN = """
def test_minute(thermal_bench):
    thermal_bench.run(data={data!r}, mode="realtime")
"""


@pytest.mark.parametrize("signum, options", [(signal.SIGTERM, ()), (signal.SIGKILL, ()),
                                             # 10 s: kept out of the 5-min default run
                                             pytest.param(signal.SIGTERM, ("-n", "1"), marks=pytest.mark.slow)],
                         ids=["SIGTERM", "SIGKILL", "SIGTERM to the xdist controller"])
def test_a_terminated_or_killed_pytest_leaves_no_bench_target_or_partial_log(tmp_path, minute_data, signum, options):
    """pytest signalled (a CI job cancelled) while `thermal_bench.run()` goes: waits up to 30 s for the bench and its
    target (and the pytest-xdist worker running the test) to have ended, and for the partial log and the scratch
    directories to be gone (the bench gets SIGTERM when its pytest dies, and stops as on any SIGTERM; a worker
    whose controller is gone is interrupted by execnet, and the plugin stops its run with SIGTERM)."""
    case = tmp_path / "case"
    session = start_session(case, MINUTE_RUN.format(data=str(minute_data)), *options)
    try:
        procs = running_run(case, session)
        os.kill(session.pid, signum)
        session.communicate(timeout=60)
        assert wait_for(lambda: not any(alive(pid) for pid in procs), GONE_TIMEOUT_S), \
            {pid: argv for pid, argv in procs.items() if alive(pid)}
        assert wait_for(lambda: not leftovers(case), GONE_TIMEOUT_S), leftovers(case)
        assert processes_of(str(case)) == {}
    finally:
        if session.poll() is None:
            session.kill()
            session.communicate()
        kill_all(case)


TIMEOUT_RUN = """
import pytest
from bench.pytest_plugin import BenchRunError

def test_timeout(thermal_bench, tmp_path):
    with pytest.raises(BenchRunError, match="did not finish within 15 s .*stopped with SIGTERM"):
        thermal_bench.run(data={data!r}, mode="realtime", timeout=15)
    assert [p.name for p in (tmp_path / "run1").iterdir()] == []   # no partial log, no JUnit XML
"""


@pytest.mark.slow
def test_the_plugin_stops_a_run_past_its_timeout_with_sigterm_and_cleans_up(tmp_path, minute_data):
    """`thermal_bench.run(timeout=15)` on a one-minute run: BenchRunError saying it was stopped with SIGTERM (not
    killed), nothing in the run's directory; waits up to 30 s after pytest's end for no process of the run and no
    scratch directory."""
    case = tmp_path / "case"
    session = start_session(case, TIMEOUT_RUN.format(data=str(minute_data)))
    try:
        out, _ = session.communicate(timeout=START_TIMEOUT_S + 60)
        assert session.returncode == 0, out[-3000:]
        assert wait_for(lambda: processes_of(str(case)) == {}, GONE_TIMEOUT_S), processes_of(str(case))
        assert wait_for(lambda: not leftovers(case), GONE_TIMEOUT_S), leftovers(case)
    finally:
        if session.poll() is None:
            session.kill()
            session.communicate()
        kill_all(case)


def test_a_bench_that_ignores_sigterm_is_killed_with_its_group_after_the_grace_period(tmp_path):
    """`stop_bench` on a process that ignores SIGTERM and has a child: both gone after the grace period (SIGKILL
    of the process group), and the sentence says so. Waits up to 30 s for the child to end."""
    from bench.pytest_plugin import stop_bench

    script = ("import signal, subprocess, sys, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
              "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(120)']); "
              "print(child.pid, flush=True); time.sleep(120)")
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        child = int(proc.stdout.readline())
        how = stop_bench(proc, tmp_path / "bench.blf", grace_s=1.0)
        assert how == "it did not stop within 1 s of SIGTERM and was killed (SIGKILL)"
        assert proc.returncode == -signal.SIGKILL
        assert wait_for(lambda: not alive(child), GONE_TIMEOUT_S)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


TIED_BENCH_PARENT = """
import sys, time
from bench.run.child import bench_command, start_bench
bench = start_bench(bench_command(["run", "--data", sys.argv[1], "--mode", "realtime", "--log", sys.argv[2],
                                   "--no-report", "--json", "--quiet", "-i", "udp_multicast"]))
print(bench.pid, flush=True)
time.sleep(300)
"""


def test_a_bench_started_by_the_shared_helper_leaves_nothing_when_its_parent_is_killed(tmp_path, minute_data):
    """`bench.run.child.start_bench` (the campaign's and the plugin's way to start a run) in a parent that is then
    SIGKILLed while the run logs in real time: the bench leads its own process group, and waits up to 30 s for the
    bench and its target to have ended and for its partial log and scratch directory to be gone."""
    case = tmp_path / "case"
    (case / "tmp").mkdir(parents=True)
    env = subprocess_env(can_settings=False, TMPDIR=str(case / "tmp"), OPENBLAS_NUM_THREADS="1")
    parent = subprocess.Popen([sys.executable, "-c", TIED_BENCH_PARENT, str(minute_data), str(case / "bench.blf")],
                              cwd=case, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True,
                              start_new_session=True)
    try:
        bench = int(parent.stdout.readline())
        assert os.getpgid(bench) == bench != os.getpgid(parent.pid)

        def logging() -> bool:
            assert parent.poll() is None and alive(bench), "the bench ended before its parent was killed"
            procs = processes_of(str(case), exclude=(parent.pid,))
            return any("target_sim" in argv for argv in procs.values()) and any(case.glob("*.partial.*"))

        assert wait_for(logging, START_TIMEOUT_S), "the run did not start logging"
        procs = processes_of(str(case), exclude=(parent.pid,))
        assert bench in procs and len(procs) >= 2, procs              # the bench and its target
        parent.kill()
        parent.wait()
        assert wait_for(lambda: not any(alive(pid) for pid in procs), GONE_TIMEOUT_S), \
            {pid: argv for pid, argv in procs.items() if alive(pid)}
        assert wait_for(lambda: not [*case.glob("*.partial.*"), *(case / "tmp").glob("bench-*")], GONE_TIMEOUT_S)
        assert processes_of(str(case)) == {}
    finally:
        end_group(parent)
        kill_all(case)


PARENT = """
import os, subprocess, sys, time
child = subprocess.Popen([sys.executable, "-c", {child!r}, str(os.getpid())])
print(child.pid, flush=True)
time.sleep(120)
"""
CHILD = """
import sys, time
from dbc.lifeline import tie_to_parent
print("tied" if tie_to_parent(int(sys.argv[1]), kernel={kernel}) else "parent gone", flush=True)
time.sleep(120)
"""


@pytest.mark.parametrize("kernel", [True, False], ids=["parent-death signal and watcher", "watcher alone"])
def test_a_tied_child_ends_when_its_parent_is_killed(kernel):
    """SIGKILL of the parent of a process tied with `dbc.lifeline.tie_to_parent`: waits up to 30 s for the child to
    end, with Linux's parent-death signal and with the portable watcher of the parent id alone."""
    code = PARENT.format(child=CHILD.format(kernel=kernel))
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                              env=subprocess_env(can_settings=False), start_new_session=True)
    try:
        child = int(parent.stdout.readline())
        assert parent.stdout.readline() == "tied\n"   # the child's line (it shares the parent's stdout)
        assert alive(child)
        parent.kill()
        parent.wait()
        assert wait_for(lambda: not alive(child), GONE_TIMEOUT_S), f"process {child} outlived its parent"
    finally:
        end_group(parent)


COMPILING_PARENT = """
import sys
from bench.firmware import toolchain
# a "compiler" that says who it is and takes its time: the bench waits for it as for ziglang
toolchain.COMPILER = [sys.executable, "-c", "import os, sys, time; open(sys.argv[1] + '.tmp', 'w').write("
                      "str(os.getpid())); os.replace(sys.argv[1] + '.tmp', sys.argv[1]); time.sleep(120)",
                      sys.argv[1]]
toolchain.toolchain_version()
"""


def test_the_compiler_ends_when_the_bench_compiling_is_killed(tmp_path):
    """SIGKILL of a bench process while its cross-compiler runs (`bench.firmware.toolchain`, through
    `dbc.lifeline.tied_command`): the compiler ends too (it ran on, orphaned, before)."""
    pid_file = tmp_path / "compiler.pid"
    parent = subprocess.Popen([sys.executable, "-c", COMPILING_PARENT, str(pid_file)],
                              env=subprocess_env(can_settings=False), start_new_session=True)
    try:
        assert wait_for(pid_file.exists, START_TIMEOUT_S), "the compiler never started"
        compiler = int(pid_file.read_text())
        assert alive(compiler) and compiler != parent.pid
        parent.kill()
        parent.wait()
        assert wait_for(lambda: not alive(compiler), GONE_TIMEOUT_S), f"the compiler {compiler} outlived the bench"
    finally:
        end_group(parent)
