"""Issue 39: a robustness case the cluster ran twice is recorded once (the campaign's commit rule,
`bench.campaign.once`): the first done outcome wins, a later one is discarded and said; an outcome that is not done
is replaced by the retry's."""

from __future__ import annotations

from bench.robustness.cases import Case, StudyInput
from bench.robustness.store import TABLE_NAME, CaseStore
from bench.robustness.study import commit_case

SOURCE = StudyInput("model.json", "a" * 64, "data.csv", "b" * 64, None, None, 100)


def outcome(status: str, rmse: float | None = None) -> dict:
    result = None if rmse is None else {"outcome": "ok", "reason": None, "nodes": ["winding"],
                                        "lanes": [{"winding": {"rmse": rmse, "max_abs": 2 * rmse}}]}
    return {"case_id": "c", "status": status, "error": None if result else "boom", "result": result,
            "wall_s": 0.5, "started_at": "2026-01-01T00:00:00+00:00", "finished_at": "2026-01-01T00:00:01+00:00",
            "worker": "tcp://127.0.0.1:1"}


def test_a_case_run_twice_is_recorded_once_and_the_second_outcome_discarded(tmp_path, capsys):
    case = Case("clean-c", 0, SOURCE, "clean", "-", 0.0, "", 1, 0)
    with CaseStore(tmp_path / TABLE_NAME, create=True) as store:
        assert commit_case(store, case, outcome("failed"), 1)            # a first attempt that failed ...
        assert commit_case(store, case, outcome("done", 0.25), 2)        # ... is replaced by its retry
        recorded = store.row(case.case_id)
        assert (recorded["status"], recorded["attempts"], recorded["error"]) == ("done", 2, None)
        assert not commit_case(store, case, outcome("done", 0.75), 3)    # the same case again: discarded
        assert not commit_case(store, case, outcome("failed"), 3)
        assert store.rows() == [recorded] and store.done() == {case.case_id}
    said = capsys.readouterr().err.splitlines()
    assert said == [f"bench: case {case.case_id}: another attempt was recorded first; this one ({status}) is "
                    "discarded" for status in ("done", "failed")]
