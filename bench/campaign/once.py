"""Results exactly once on any Dask cluster, for `bench campaign` and `bench robustness` (issue 39).

Dask may run a task more than once: a worker that dies after a task finished loses the result it held and the
scheduler runs the task again while the driver still holds its future; a scheduler the user started retries a task
whose worker died by itself (`distributed.scheduler.allowed-failures`), and the driver never hears of it. So:

* a task writes its files under a directory of its own execution (`new_attempt_dir`: the run's id and a random
  attempt id), in full, and returns; no two executions share a file;
* only the driver commits, one SQLite transaction per outcome (`bench.campaign.store.SqliteTable.commit`): the row
  goes in unless the table holds the id as done already. The first done row wins; a later attempt is discarded
  (`discard`: its directory deleted) and the driver says so. The row names its attempt's directory, so the table
  and the files agree by construction (summary.json is the row's summary, the log's sha256 its log_sha256);
* the driver lets go of a future as soon as it has the result (`bench.campaign.execute.run_tasks`), so the
  scheduler forgets the task instead of running it again;
* while the cluster has no worker, the driver says so on stderr, naming the scheduler, every `NO_WORKER_NOTICE_S`
  (`WorkerWatch`), and gives up after `NO_WORKER_LIMIT_S` with one sentence (--resume does the rest later).
"""

from __future__ import annotations

import re
import shutil
import sys
import time
import uuid
from collections.abc import Callable, Iterable
from pathlib import Path

from bench.errors import BenchError

NO_WORKER_NOTICE_S = 15.0   # how often the driver repeats that the cluster has no worker
NO_WORKER_LIMIT_S = 60.0    # how long it waits for a worker (at the start, or after every worker died)
ATTEMPT_HEX = 12            # hex digits of an attempt id: a run's directory is <run id>.<attempt id>


def new_attempt_dir(runs_dir: Path, run_id: str) -> Path:
    """A new, empty directory for one execution of run `run_id`: RUNS_DIR/<run id>.<random attempt id>."""
    path = Path(runs_dir) / f"{run_id}.{uuid.uuid4().hex[:ATTEMPT_HEX]}"
    path.mkdir(parents=True, exist_ok=False)      # an id drawn twice would fail here, never share a directory
    return path


def attempt_dirs(runs_dir: Path, run_id: str) -> list[Path]:
    """The attempt directories of run `run_id` under RUNS_DIR, whatever became of them."""
    pattern = re.compile(rf"{re.escape(run_id)}\.[0-9a-f]{{{ATTEMPT_HEX}}}")
    runs_dir = Path(runs_dir)
    if not runs_dir.is_dir():
        return []
    return sorted(p for p in runs_dir.iterdir() if p.is_dir() and pattern.fullmatch(p.name))


def discard(path: str | Path | None) -> bool:
    """Delete an attempt's directory that no row names (a discarded or superseded attempt); whether it was there."""
    if not path or not Path(path).is_dir():
        return False
    shutil.rmtree(path, ignore_errors=True)
    return True


def sweep(runs_dir: Path, run_ids: Iterable[str], named: set[str]) -> int:
    """Delete the attempt directories of these runs that no row names (`named`: the rows' directories): left by an
    execution whose result never reached the driver (a task the scheduler ran again, a killed worker's run).
    How many."""
    gone = 0
    for run_id in run_ids:
        for path in attempt_dirs(runs_dir, run_id):
            if str(path) not in named:
                gone += discard(path)
    return gone


def say(text: str) -> None:
    """A line on stderr that --quiet does not silence: the user has to act (the cluster has no worker)."""
    print(f"bench: {text}", file=sys.stderr, flush=True)


class NoWorkerError(BenchError):
    """The cluster had no worker for NO_WORKER_LIMIT_S."""


class WorkerWatch:
    """Says, every `notice_s`, that the cluster `where` (its scheduler at `address`) has no worker, and raises
    NoWorkerError once it had none for `limit_s`. The driver calls `check` whenever it waits."""

    def __init__(self, where: str, address: str, *, notice: Callable[[str], None] = say,
                 notice_s: float = NO_WORKER_NOTICE_S, limit_s: float = NO_WORKER_LIMIT_S,
                 clock: Callable[[], float] = time.monotonic):
        self.where, self.address = where, address
        self.notice, self.notice_s, self.limit_s, self.clock = notice, notice_s, limit_s, clock
        self.since: float | None = None      # when the workers were first seen gone
        self.said_at: float | None = None
        self.notices = 0

    @property
    def waiting(self) -> bool:
        """Whether the last check found no worker."""
        return self.since is not None

    def check(self, workers: int, waiting: int) -> None:
        """`waiting`: the tasks not done yet (the sentence says how many)."""
        now = self.clock()
        if workers > 0:
            if self.since is not None and self.notices:
                self.notice(f"a Dask worker joined {self.where}; going on")
            self.since = self.said_at = None
            return
        if self.since is None:
            self.since = now
        waited = now - self.since
        if waited >= self.limit_s:
            tasks = f", {waiting} task(s) not done" if waiting else ""
            raise NoWorkerError(f"{self.where} has had no worker for {waited:.0f} s{tasks}; "
                                f"start one (`dask worker {self.address}`) and run again with --resume")
        if self.said_at is None or now - self.said_at >= self.notice_s:
            self.said_at = now
            self.notices += 1
            tasks = f", {waiting} task(s) waiting" if waiting else ""
            self.notice(f"no Dask worker is available on {self.where} ({waited:.0f} s so far{tasks}); waiting up "
                        f"to {self.limit_s:.0f} s for one to join (`dask worker {self.address}`)")
