"""A study's cases on Dask (the campaign's client and task loop: the embedded LocalCluster, or a scheduler with
--cluster; a case whose worker died or that failed is retried once), each outcome committed to the table as it
arrives, once (`bench.campaign.once`: a case the cluster ran twice is recorded once); or, for a comparison, the
same cases in a plain loop in this process."""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from bench.campaign.execute import dask_client, now, run_tasks, run_tasks_serially
from bench.campaign.once import say
from bench.campaign.store import DONE
from bench.progress import progress_bar
from bench.robustness.cases import Case
from bench.robustness.evaluate import evaluate_case
from bench.robustness.store import CaseStore


@dataclass
class StudyOutcome:
    cases: int
    skipped: int
    ran: int = 0
    retried: int = 0
    failed: int = 0
    discarded: int = 0      # outcomes of a case already recorded (a task Dask ran twice): never recorded
    workers: int = 0
    cluster: str = ""
    wall_s: float = 0.0


def _lost(case_id: str, exc: BaseException) -> dict[str, Any]:
    return {"case_id": case_id, "status": "lost-worker", "result": None, "worker": None, "wall_s": None,
            "error": f"the Dask worker running it died ({type(exc).__name__})", "started_at": None,
            "finished_at": now()}


def _failed(case_id: str, exc: BaseException) -> dict[str, Any]:
    return {"case_id": case_id, "status": "failed", "result": None, "worker": None, "wall_s": None,
            "error": f"the task failed on its worker: {type(exc).__name__}: {exc}"[:500], "started_at": None,
            "finished_at": now()}


def commit_case(store: CaseStore, case: Case, result: dict[str, Any], attempts: int) -> bool:
    """Commit one outcome of `case` (`SqliteTable.commit`): False, and the driver says so, when the table holds the
    case as done already (the first done outcome wins)."""
    if store.record(case, result, attempts).applied:
        return True
    say(f"case {case.case_id}: another attempt was recorded first; this one ({result['status']}) is discarded")
    return False


def run_study(cases: list[Case], store: CaseStore, *, workers: int, address: str | None, resume: bool,
              serial: bool = False, quiet: bool = True, on_event: Callable[[str], None] | None = None) -> StudyOutcome:
    """Run the cases the table does not hold as done (all of them without `resume`), recording each outcome."""
    started = time.perf_counter()
    done = store.done() if resume else set()
    todo = [c for c in cases if c.case_id not in done]
    outcome = StudyOutcome(cases=len(cases), skipped=len(cases) - len(todo))
    by_id = {c.case_id: c for c in todo}
    previous = {c.case_id: (store.row(c.case_id) or {}).get("attempts") or 0 for c in todo}
    bar = progress_bar(len(todo), "robustness", "case", quiet)

    def record(case_id: str, result: dict[str, Any], attempt: int, final: bool) -> bool:
        if not commit_case(store, by_id[case_id], result, previous[case_id] + attempt):
            outcome.discarded += 1
            return False
        outcome.ran += attempt == 1
        if not final:
            outcome.retried += 1
            if on_event:
                on_event(f"case {case_id} {result['status']} ({result['error']}); retrying it once")
            return True
        outcome.failed += result["status"] != DONE
        bar.update(1)
        return True

    try:
        if not todo:
            return outcome
        tasks = {c.case_id: c.task() for c in todo}
        if serial:
            outcome.cluster, outcome.workers = "a serial loop in this process", 1
            run_tasks_serially(evaluate_case, tasks, record=record)
            return outcome
        token = uuid.uuid4().hex[:8]
        with dask_client(workers, address) as (client, label):
            outcome.cluster, outcome.workers = label, len(client.nthreads())
            if on_event:
                on_event(f"{len(todo)} case(s) to do" + (f", {outcome.skipped} done already" if outcome.skipped
                                                         else "") + f", on {label}; table {store.path}")
            run_tasks(client, evaluate_case, tasks, key=lambda cid, attempt: f"robustness-{cid}-{token}-{attempt}",
                      record=record, lost=_lost, failed=_failed, where=label, address=client.scheduler.address)
        return outcome
    finally:
        bar.close()
        outcome.wall_s = time.perf_counter() - started
