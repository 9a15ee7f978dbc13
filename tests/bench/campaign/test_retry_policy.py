"""One retry policy for the campaign's runs and the robustness study's cases (bench.campaign.execute)."""

from __future__ import annotations

from bench.campaign.execute import MAX_ATTEMPTS, run_tasks_serially
from bench.campaign.store import DONE


def _flaky(failures: dict[str, int]):
    def function(task: dict) -> dict:
        left = failures.get(task["id"], 0)
        failures[task["id"]] = left - 1
        return {"status": "failed" if left > 0 else DONE, "error": "boom" if left > 0 else None}
    return function


def test_a_task_that_fails_once_is_retried_and_its_second_outcome_is_final():
    seen: list[tuple[str, str, int, bool]] = []
    run_tasks_serially(_flaky({"a": 1}), {"a": {"id": "a"}, "b": {"id": "b"}},
                       record=lambda tid, res, attempt, final: not seen.append((tid, res["status"], attempt, final)))
    assert seen == [("a", "failed", 1, False), ("a", DONE, 2, True), ("b", DONE, 1, True)]


def test_a_task_that_keeps_failing_is_recorded_failed_after_the_last_attempt():
    seen: list[tuple[str, int, bool]] = []
    run_tasks_serially(_flaky({"a": 5}), {"a": {"id": "a"}},
                       record=lambda tid, result, attempt, final: not seen.append((result["status"], attempt, final)))
    assert seen[-1] == ("failed", MAX_ATTEMPTS, True) and len(seen) == MAX_ATTEMPTS


def test_an_outcome_the_table_refuses_is_not_retried():
    """`record` returns False when the table holds the task as done already (issue 39): nothing to retry."""
    seen: list[int] = []
    run_tasks_serially(_flaky({"a": 5}), {"a": {"id": "a"}},
                       record=lambda tid, result, attempt, final: seen.append(attempt) and False)
    assert seen == [1]
