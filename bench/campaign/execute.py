"""A campaign's runs on Dask workers: each run is `python -m bench run ... --json` in a subprocess of a worker,
with its own bus port, log and report under OUT/runs/<run-id>.<attempt-id>/ (a directory per execution: Dask may
run a task twice, and the table names the attempt it recorded, `bench.campaign.once`).

Results: "done" (the bench ran and printed its JSON summary; exit 0, or 1 for a verdict that is not clean, which
is a result), "failed" (any other exit: a crash, a bad option), "timeout" (stopped after the campaign's timeout),
"lost-worker" (the Dask worker running it died). A run that is not done is submitted once more; each outcome is
one row of the table, written when it arrives, and a done row is never replaced. dask and distributed are
imported only in `run_campaign` (and on the workers), so no other command pays for them.
"""

from __future__ import annotations

import contextlib
import datetime
import functools
import hashlib
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.analysis.results import ResultsError, RunSummary
from bench.campaign.once import WorkerWatch, discard, new_attempt_dir, say, sweep
from bench.campaign.spec import Campaign, Run
from bench.campaign.store import DONE, Store, flatten, option_columns
from bench.errors import BenchError
from bench.progress import progress_bar
from bench.run.child import bench_command, run_summary, start_bench, stop_bench_process

MAX_ATTEMPTS = 2                  # a run that crashed, timed out or lost its worker is retried once
CONNECT_TIMEOUT_S = 10.0
POLL_S = 2.0                      # how often the driver, waiting for results, looks whether the cluster has workers


def now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


# ---------------------------------------------------------------- on the worker

_RUNNING: dict[str, set[subprocess.Popen]] = {}   # campaign token -> its runs' processes in this worker
_RUNNING_LOCK = threading.Lock()


def _error_sentence(stderr: str, code: int) -> str:
    """What the run said went wrong (its `bench: error:` line), else how it ended."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    for line in reversed(lines):
        if line.startswith("bench: "):
            return line.removeprefix("bench: ").removeprefix("error: ")
    if code < 0:
        return f"killed by {signal.Signals(-code).name}"
    if lines:
        return f"exited with status {code}: {lines[-1][:300]}"
    return f"exited with status {code} and printed nothing"


def _sha256(path: str | None) -> str | None:
    if not path or not Path(path).is_file():
        return None
    digest = hashlib.sha256()
    with Path(path).open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return f"{socket.gethostname()}:{os.getpid()}"


def _child_env() -> dict[str, str]:
    # without the user's python-can settings: a CAN_CHANNEL would put every run on one channel (and port)
    env = {k: v for k, v in os.environ.items() if not k.startswith("CAN_")}
    env.update(MPLBACKEND="Agg", PYTHONUNBUFFERED="1")
    return env


def execute_run(task: dict[str, Any]) -> dict[str, Any]:
    """Run one `bench run` (task: run_id; argv, a function of the run's directory giving its arguments; runs_dir;
    timeout_s; token) in a subprocess, in a new directory of this execution's own (RUNS_DIR/<run id>.<attempt id>,
    named in the outcome's run_dir); its outcome as a dict. Runs on a Dask worker; never raises for what the run
    did."""
    from bench.fileio import write_text_atomically

    run_dir = new_attempt_dir(Path(task["runs_dir"]), task["run_id"])
    started, clock = now(), time.perf_counter()
    # tied to this worker (a worker killed with SIGKILL cannot stop its children, and a run left running would write
    # into a run directory that the retry also writes into) and in its own process group (`bench.run.child`)
    proc = start_bench(bench_command(["run", *task["argv"](run_dir)]), env=_child_env(), cwd=run_dir)
    with _RUNNING_LOCK:
        _RUNNING.setdefault(task["token"], set()).add(proc)
    timed_out = False
    try:
        try:
            out, err = proc.communicate(timeout=task["timeout_s"])
        except subprocess.TimeoutExpired:
            timed_out = True
            # bench run stops its target and deletes its temporary files on SIGTERM; its group is killed after a grace
            out, err, _ = stop_bench_process(proc)
    finally:
        with _RUNNING_LOCK:
            running = _RUNNING.get(task["token"], set())
            running.discard(proc)
            if not running:
                _RUNNING.pop(task["token"], None)
    wall = time.perf_counter() - clock
    summary, unreadable = None, None
    if not timed_out:
        summary = run_summary(proc.returncode, out)
        if summary is not None and "clean" not in summary:
            summary = None
        if summary is not None:
            try:   # the table reads it as a RunSummary: a summary of another schema is no result
                RunSummary.from_json(summary)
            except ResultsError as exc:
                summary, unreadable = None, str(exc)
    if summary is not None:
        status, error = DONE, None
        verdict = "not clean" if proc.returncode else ("clean" if summary.get("clean") else "tolerated")
        if proc.returncode and summary.get("clean") and not (summary.get("acceptance") or {}).get("passed", True):
            verdict = "criteria failed"   # a clean run that fails its acceptance criteria (--criteria)
    elif timed_out:
        status, verdict = "timeout", None
        error = f"the run took longer than {task['timeout_s']:g} s and was stopped"
    else:
        status, verdict = "failed", None
        error = unreadable or _error_sentence(err, proc.returncode)
    if summary is not None:
        write_text_atomically(run_dir / "summary.json", out)
    write_text_atomically(run_dir / "stderr.txt", err)
    return {"run_id": task["run_id"], "status": status, "verdict": verdict, "exit_code": proc.returncode,
            "error": error, "summary": summary, "wall_s": round(wall, 3), "started_at": started,
            "finished_at": now(), "worker": _worker_name(), "run_dir": str(run_dir),
            "log_sha256": _sha256(summary.get("log")) if summary else None}


def stop_runs(token: str) -> int:
    """SIGTERM every run of campaign `token` this worker is running (an interrupted campaign); how many."""
    with _RUNNING_LOCK:
        procs = list(_RUNNING.get(token, ()))
    for proc in procs:
        with contextlib.suppress(OSError):
            proc.terminate()
    return len(procs)


# ---------------------------------------------------------------- on the driver


def prepare_datasets(runs: list[Run], out_dir: Path, quiet: bool) -> dict[str, Path]:
    """run id -> the data file it replays; the generated datasets a run names by set point are made here, once,
    before any run starts (runs generating them side by side would write the same files): the default seed's in
    out/data as `bench run` does, another seed's in OUT/data/seed-<N>."""
    from bench.drive.generate import ensure_default_datasets
    from bench.drive.seed import DEFAULT_SEED

    made: dict[int | None, dict[int, Path]] = {}
    paths = {}
    for run in runs:
        data = run.options["data"]
        if isinstance(data, str):
            paths[run.run_id] = run.path_of("data")
            continue
        seed = run.options["seed"]
        if seed not in made:
            where = (Path("out/data") if seed in (None, DEFAULT_SEED) else out_dir / "data" / f"seed-{seed}").resolve()
            if not quiet:
                print(f"bench: checking the generated datasets in {where} (made once if missing)", file=sys.stderr)
            made[seed] = ensure_default_datasets(where, seed)
        paths[run.run_id] = made[seed][data].resolve()
    return paths


@dataclass
class Outcome:
    """What `run_campaign` did: counts for the summary line and --json."""

    runs: int
    skipped: int
    ran: int = 0
    retried: int = 0
    statuses: dict[str, int] = field(default_factory=dict)
    verdicts: dict[str, int] = field(default_factory=dict)
    discarded: int = 0      # attempts of a run already recorded (a task Dask ran twice): deleted, never recorded
    workers: int = 0
    cluster: str = ""
    wall_s: float = 0.0


def check_reachable(address: str) -> str:
    """The scheduler's address with its scheme; BenchError (one sentence) when nothing listens there."""
    full = address if "://" in address else f"tcp://{address}"
    scheme, _, rest = full.partition("://")
    if scheme != "tcp":
        return full
    host, sep, port = rest.rpartition(":")
    if not sep or not port.isdigit() or not host:
        raise BenchError(f"--cluster {address!r} is not a scheduler address; give tcp://HOST:PORT, e.g. "
                         "tcp://127.0.0.1:8786")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S):
            pass
    except OSError as exc:
        raise BenchError(f"cannot reach a Dask scheduler at {full} ({exc.strerror or exc}); start one "
                         "(`dask scheduler`, then `dask worker ADDRESS`) or check the address") from None
    return full


@contextlib.contextmanager
def dask_client(workers: int, address: str | None) -> Iterator[tuple[Any, str]]:
    """A distributed Client: on the scheduler at `address`, or on an embedded LocalCluster of `workers` worker
    processes (one thread each: a run is a subprocess, the worker only waits for it). Yields (client, label)."""
    os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "critical")   # the workers inherit it: no log chatter
    import dask
    from distributed import Client, LocalCluster

    logging.getLogger("distributed").setLevel(logging.CRITICAL)
    if address is not None:
        full = check_reachable(address)
        try:
            client = Client(full, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError) as exc:
            raise BenchError(f"cannot connect to a Dask scheduler at {full} ({exc}); check the address") from None
        try:
            wait_for_a_worker(client, f"the scheduler at {full}", full)
        except BaseException:
            client.close()
            raise
        try:
            yield client, f"the scheduler at {full}"
        finally:
            client.close()
        return
    # a worker that dies running a run fails that run at once (KilledWorker); the campaign retries it itself
    with dask.config.set({"distributed.scheduler.allowed-failures": 0,
                          "distributed.worker.preload": ["bench.campaign.worker_setup"]}):
        # dashboard_address ":0": the scheduler's HTTP server (it starts one even without a dashboard) on a free
        # port; with None it tries 8787 and warns on stderr when another cluster or program holds it
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                               memory_limit=0, host="127.0.0.1", silence_logs=logging.CRITICAL)
        try:
            client = Client(cluster)
            try:
                yield client, f"a local cluster of {workers} worker process(es)"
            finally:
                client.close()
        finally:
            cluster.close()


def wait_for_a_worker(client, where: str, address: str) -> None:
    """Return once the cluster has a worker, saying every NO_WORKER_NOTICE_S that it has none; NoWorkerError (one
    sentence) after NO_WORKER_LIMIT_S."""
    watch = WorkerWatch(where, address)
    while True:
        watch.check(len(client.nthreads()), 0)     # says so at once, then every NO_WORKER_NOTICE_S; raises at the limit
        if not watch.waiting:
            return
        with contextlib.suppress(TimeoutError):
            client.wait_for_workers(1, timeout=POLL_S)


def _lost_outcome(run_id: str, exc: BaseException) -> dict[str, Any]:
    return {"run_id": run_id, "status": "lost-worker", "verdict": None, "exit_code": None,
            "error": f"the Dask worker running it died ({type(exc).__name__})", "summary": None, "wall_s": None,
            "started_at": None, "finished_at": now(), "worker": None, "log_sha256": None, "run_dir": None}


def _failed_outcome(run_id: str, exc: BaseException) -> dict[str, Any]:
    return {"run_id": run_id, "status": "failed", "verdict": None, "exit_code": None,
            "error": f"the task failed on its worker: {type(exc).__name__}: {exc}"[:500], "summary": None,
            "wall_s": None, "started_at": None, "finished_at": now(), "worker": None, "log_sha256": None,
            "run_dir": None}


def table_row(run: Run, outcome: dict[str, Any],
              attempts: int) -> tuple[dict[str, Any], list[tuple[str, int, int | None]]]:
    """The run's row and fault rows for the store; its run_dir is the outcome's (the attempt's directory)."""
    flat, kinds = flatten(outcome.get("summary"))
    row = {"run_id": run.run_id, "position": run.index, "axes": json.dumps(run.axes),
           "options": json.dumps(run.options, sort_keys=True), **option_columns(run.options), **flat,
           "status": outcome["status"], "verdict": outcome["verdict"], "exit_code": outcome["exit_code"],
           "error": outcome["error"], "attempts": attempts, "wall_s": outcome["wall_s"],
           "worker": outcome["worker"], "log_sha256": outcome["log_sha256"], "run_dir": outcome["run_dir"],
           "started_at": outcome["started_at"], "finished_at": outcome["finished_at"]}
    return row, kinds


def pending_runs(campaign: Campaign, store: Store, resume: bool) -> list[Run]:
    """The runs to do: all of them, or with `resume` those the table does not hold as done (a failed, timed-out or
    lost run is done again)."""
    done = store.done() if resume else set()
    return [run for run in campaign.runs if run.run_id not in done]


def _stop_everywhere(client, token: str, wait_s: float = 5.0) -> None:
    """Ask every worker to stop this campaign's runs, waiting at most `wait_s` (a dead worker is not waited for)."""
    def ask() -> None:
        with contextlib.suppress(Exception):
            client.run(stop_runs, token, on_error="ignore")

    thread = threading.Thread(target=ask, daemon=True)
    thread.start()
    thread.join(wait_s)


def retried(result: dict[str, Any], attempt: int) -> bool:
    """Whether a task with this outcome is run once more: it did not end done and had only one attempt."""
    return result["status"] != DONE and attempt < MAX_ATTEMPTS


def run_tasks(client, function: Callable[[dict[str, Any]], dict[str, Any]], tasks: dict[str, dict[str, Any]], *,
              key: Callable[[str, int], str], record: Callable[[str, dict[str, Any], int, bool], bool],
              lost: Callable[[str, BaseException], dict[str, Any]],
              failed: Callable[[str, BaseException], dict[str, Any]], where: str, address: str) -> None:
    """`function(task)` for every task on the client's workers, each outcome handed to `record(task id, outcome,
    attempt, final)` as it arrives (the driver commits it to its table; False: the table holds the task as done
    already and the outcome was discarded); an outcome that is not done is not final the first time: the task is
    submitted again (attempt 2, before the tasks still waiting). A task whose worker died gives `lost(id, exc)`, a
    task that raised `failed(id, exc)`. No more tasks in flight than worker threads: a task waits here, not in a
    worker's queue, so a worker that dies loses only what it was running. A future is let go as soon as its result
    is in, so the scheduler does not run a finished task again when the worker holding its result dies. While the
    cluster (`where`, its scheduler at `address`) has no worker, the driver says so (`once.WorkerWatch`): it never
    waits longer than POLL_S without asking the scheduler how many workers it has, also while it fetches a result
    (one whose worker died as it was fetched is computed again once a worker joins). `bench campaign` and `bench
    robustness` share it (and `run_tasks_serially`, the same policy in a plain loop)."""
    from distributed import CancelledError, KilledWorker, wait

    in_flight: dict[str, Any] = {}                # task key -> its future
    submitted: dict[str, tuple[str, int]] = {}    # task key -> (task id, attempt)
    waiting = deque((task_id, 1) for task_id in tasks)
    watch = WorkerWatch(where, address)

    def check(fetching: int = 0) -> int:
        """The cluster's worker threads, after telling the watch (which says so when there are none)."""
        threads = sum(client.nthreads().values())
        watch.check(threads, len(waiting) + len(in_flight) + fetching)
        return threads

    def fill() -> None:
        threads = check()
        while waiting and len(in_flight) < max(threads, 1):
            task_id, attempt = waiting.popleft()
            name = key(task_id, attempt)
            in_flight[name] = client.submit(function, tasks[task_id], key=name, pure=False, retries=0)
            submitted[name] = (task_id, attempt)

    def fetch(future) -> dict[str, Any]:
        """The future's result, asking after the cluster every POLL_S: a result whose worker died before it
        reached the driver waits for a worker to compute it again, and the driver says meanwhile that none is
        there (a plain `result()` waited in silence)."""
        while True:
            try:
                return future.result(timeout=POLL_S)
            except TimeoutError:
                if future.status == "error":     # the task's own TimeoutError
                    raise
                check(fetching=1)

    fill()
    while in_flight:
        try:
            finished = wait(list(in_flight.values()), timeout=POLL_S, return_when="FIRST_COMPLETED").done
        except TimeoutError:
            fill()        # nothing ended: does the cluster still have a worker?
            continue
        except CancelledError:     # `wait` raises for a cancelled future among the done ones: each is taken alone
            finished = [future for future in in_flight.values() if future.done()]
        for future in finished:
            name = future.key
            del in_flight[name]
            task_id, attempt = submitted.pop(name)
            try:
                result = fetch(future)
            except KilledWorker as exc:
                result = lost(task_id, exc)
            except Exception as exc:  # noqa: BLE001 - a task that errored: its worker, or its environment
                gone = type(exc).__name__ in ("CommClosedError", "FutureCancelledError", "CancelledError")
                result = lost(task_id, exc) if gone else failed(task_id, exc)
            future.release()      # the scheduler forgets the task: a lost copy of its result is not computed again
            again = retried(result, attempt)
            if record(task_id, result, attempt, not again) and again:
                waiting.appendleft((task_id, attempt + 1))
        fill()


def run_tasks_serially(function: Callable[[dict[str, Any]], dict[str, Any]], tasks: dict[str, dict[str, Any]], *,
                       record: Callable[[str, dict[str, Any], int, bool], bool]) -> None:
    """`run_tasks` in a plain loop in this process (a comparison's baseline): the same retry, the same records."""
    for task_id, task in tasks.items():
        attempt = 1
        while True:
            result = function(task)
            again = retried(result, attempt)
            if not record(task_id, result, attempt, not again) or not again:
                break
            attempt += 1


def run_campaign(campaign: Campaign, store: Store, out_dir: Path, *, workers: int, address: str | None,
                 resume: bool, timeout_s: float | None, quiet: bool,
                 on_event: Callable[[str], None] | None = None) -> Outcome:
    """Run what the table does not hold as done (everything without `resume`), committing each outcome."""
    started = time.perf_counter()
    todo = pending_runs(campaign, store, resume)
    outcome = Outcome(runs=len(campaign.runs), skipped=len(campaign.runs) - len(todo))
    if not todo:
        return outcome
    data = prepare_datasets(todo, out_dir, quiet)
    timeout = timeout_s if timeout_s is not None else campaign.timeout_s
    token = uuid.uuid4().hex
    runs_dir = (out_dir / "runs").resolve()
    tasks = {run.run_id: run_task(run, data[run.run_id], runs_dir, timeout, token) for run in todo}
    by_id = {run.run_id: run for run in todo}
    previous = {run.run_id: (store.row(run.run_id) or {}).get("attempts") or 0 for run in todo}

    with dask_client(workers, address) as (client, label):
        outcome.cluster = label
        outcome.workers = len(client.nthreads())
        if not quiet:
            print(f"bench: campaign {campaign.name}: {len(todo)} run(s) to do"
                  + (f", {outcome.skipped} done already" if outcome.skipped else "")
                  + f", on {label}; table {store.path}", file=sys.stderr)
        bar = progress_bar(len(todo), campaign.name, "run", quiet)

        def record(run_id: str, result: dict[str, Any], attempt: int, final: bool) -> bool:
            if not commit_run(store, by_id[run_id], result, previous[run_id] + attempt):
                outcome.discarded += 1
                return False
            outcome.ran += attempt == 1
            if not final:
                outcome.retried += 1
                if on_event:
                    on_event(f"run {run_id} {result['status']} ({result['error']}); retrying it once")
                return True
            outcome.statuses[result["status"]] = outcome.statuses.get(result["status"], 0) + 1
            verdict = result["verdict"] or result["status"]
            outcome.verdicts[verdict] = outcome.verdicts.get(verdict, 0) + 1
            bar.set_postfix_str(", ".join(f"{k} {v}" for k, v in sorted(outcome.verdicts.items())), refresh=False)
            bar.update(1)
            return True

        try:
            run_tasks(client, execute_run, tasks, key=lambda run_id, attempt: f"bench-run-{run_id}-{token[:8]}-"
                      f"{attempt}", record=record, lost=_lost_outcome, failed=_failed_outcome, where=label,
                      address=client.scheduler.address)
        finally:
            # ended or interrupted: stop what still runs on a worker (an interrupted campaign's runs; a copy of a
            # task the scheduler started again), then delete the attempts no row names; the table holds the runs
            # that ended, each row whole and naming its own files
            _stop_everywhere(client, token)
            bar.close()
            outcome.discarded += sweep(runs_dir, by_id, {r["run_dir"] for r in store.rows() if r["run_dir"]})
    outcome.wall_s = time.perf_counter() - started
    return outcome


def run_task(run: Run, data: Path, runs_dir: Path, timeout_s: float, token: str) -> dict[str, Any]:
    """The task `execute_run` gets for a run: its arguments are a function of the attempt's directory."""
    return {"run_id": run.run_id, "argv": functools.partial(run.argv, data=data), "runs_dir": str(runs_dir),
            "timeout_s": timeout_s, "token": token}


def commit_run(store: Store, run: Run, result: dict[str, Any], attempts: int) -> bool:
    """Commit one outcome of `run` (`SqliteTable.commit`): False when the table holds the run as done already, and
    then this attempt's directory is deleted and the driver says so; a row it replaces (an attempt that failed,
    timed out or lost its worker) takes its directory with it."""
    row, kinds = table_row(run, result, attempts)
    done = store.commit(row, kinds)
    if not done.applied:
        discard(result.get("run_dir"))
        say(f"run {run.run_id}: another attempt was recorded first ({done.previous['run_dir']}); this one "
            f"({result.get('run_dir') or 'no files'}, {result['status']}) is discarded")
        return False
    if done.previous is not None and done.previous["run_dir"] != row["run_dir"]:
        discard(done.previous["run_dir"])
    return True
