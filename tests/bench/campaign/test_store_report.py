"""The campaign table (a run's JSON summary flattened, rows replaced whole, a done row never replaced, what
--resume skips) and the report rebuilt from the table alone."""

from __future__ import annotations

import json
import sqlite3
from dataclasses import replace

import pytest

from bench.analysis.results import HostFaults
from bench.campaign.execute import pending_runs, table_row
from bench.campaign.report import verdict_matrix
from bench.campaign.spec import parse_spec
from bench.campaign.store import TABLE_NAME, Store, StoreError, flatten
from bench.cli import main

from helpers import example_results, example_summary

SPEC = """
[fixed]
rows = 300
[axes]
model = ["hammerstein", "lti-lptn"]
fault_seed = [1, 2, 3]
"""
PNG = b"\x89PNG\r\n\x1a\n"


def summary(clean: bool = True, winding: float = 0.5, pm: float = 0.25, faults: dict | None = None) -> dict:
    """A `bench run --json` summary (`RunSummary.to_json`) with these RMSEs and injected faults."""
    results = example_results()
    results.accuracy.rmse_C = replace(results.accuracy.rmse_C, winding=winding, magnet=pm)
    injected = faults or {}
    host_faults = HostFaults.of_run(
        {"injected": injected, "detected": dict(injected), "injected_total": sum(injected.values()),
         "detected_total": sum(injected.values()), "undetected": 0, "retransmitted_rows": 4,
         "gaps": [{"rows": [1, 2]}]}, None) if faults else None
    return example_summary(clean, metrics=results, faults=host_faults).to_json()


def outcome(s: dict | None, status: str = "done", verdict: str | None = "clean", code: int | None = 0,
            error: str | None = None, run_dir: str | None = None) -> dict:
    return {"status": status, "verdict": verdict, "exit_code": code, "error": error, "summary": s, "wall_s": 9.5,
            "started_at": "2026-01-01T00:00:00+00:00", "finished_at": "2026-01-01T00:00:10+00:00",
            "worker": "tcp://127.0.0.1:1", "log_sha256": "ab" * 32, "run_dir": run_dir}


def test_a_summary_is_flattened():
    row, kinds = flatten(summary(faults={"drop": 7, "kill": 1}))
    assert row["rmse_winding_C"] == 0.5 and row["rmse_pm_C"] == 0.25
    assert row["max_can_minus_float32_C"] == 0.0049
    assert (row["est_c28x_cycles"], row["m4_cycles_p50"], row["m4_cycles_max"]) == (1989, 1403, 1410)
    assert (row["faults_injected"], row["faults_detected"], row["faults_undetected"]) == (8, 8, 0)
    assert (row["retransmitted_rows"], row["gaps"], row["bus_port"]) == (4, 1, 40000)
    assert row["throughput_rows_per_s"] == 1083.0 and row["model_kind"] == "hammerstein"
    assert sorted(kinds) == [("drop", 7, 7), ("kill", 1, 1)]
    assert json.loads(row["summary"])["est_cycles"] == 1989
    clean, none = flatten(summary())
    assert clean["faults_injected"] == 0 and none == []
    assert flatten(None) == ({}, [])


def test_the_rows_left_out_of_the_figures_stand_beside_them():
    """Issue 23: the table holds the run's figures, which are over the kept rows, and the excluded rows by reason."""
    from bench.analysis.results import FigureRows

    results = replace(example_results(), figure_rows=FigureRows(2000, 1990, 0, {"replayed": 10}))
    row, _ = flatten(example_summary(False, metrics=results).to_json())
    assert (row["rows_kept"], row["rows_excluded"]) == (1990, 10)
    assert json.loads(row["rows_excluded_by_reason"]) == {"replayed": 10}
    assert json.loads(row["summary"])["figure_rows"]["excluded"] == {"replayed": 10}


@pytest.fixture
def table(tmp_path):
    """A campaign directory whose table holds 5 of the spec's 6 runs: clean, not clean, failed, timed out, lost."""
    campaign = parse_spec(SPEC, tmp_path / "spec.toml")
    runs = campaign.runs
    with Store(tmp_path / TABLE_NAME, create=True) as store:
        store.set_meta({"name": "unit", "axes": json.dumps(campaign.axes)})
        results = [outcome(summary(faults={"drop": 3})), outcome(summary(False, 0.8, 0.4), verdict="not clean",
                                                                 code=1),
                   outcome(None, "failed", None, 1, "model x cannot be loaded"),
                   outcome(None, "timeout", None, -15, "the run took longer than 5 s and was stopped"),
                   outcome(None, "lost-worker", None, None, "the Dask worker running it died (KilledWorker)")]
        for run, result in zip(runs, results, strict=False):
            assert store.commit(*table_row(run, result, 1)).applied
    return tmp_path, campaign


def test_rows_that_are_not_done_are_replaced_whole_and_resume_skips_only_done_runs(table):
    out, campaign = table
    runs = campaign.runs
    with Store(out / TABLE_NAME) as store:
        assert store.done() == {runs[0].run_id, runs[1].run_id}     # a verdict that is not clean is done too
        assert [r.run_id for r in pending_runs(campaign, store, resume=True)] == [r.run_id for r in runs[2:]]
        assert len(pending_runs(campaign, store, resume=False)) == 6
        assert store.faults() == [{"run_id": runs[0].run_id, "kind": "drop", "injected": 3, "detected": 3}]
        # the timed-out run (fault_seed 1 of lti-lptn) done at its second attempt: its row is replaced whole
        assert runs[3].axes == {"model": "lti-lptn", "fault_seed": 1}
        done = store.commit(*table_row(runs[3], outcome(summary(faults={"drop": 2})), 2))
        assert done.applied and done.previous["status"] == "timeout"
        row = store.row(runs[3].run_id)
        assert (row["attempts"], row["status"], row["verdict"], row["model"], row["fault_seed"], row["rows"]) == \
            (2, "done", "clean", "lti-lptn", 1, 300)
        assert row["error"] is None and json.loads(row["axes"]) == {"model": "lti-lptn", "fault_seed": 1}
        assert len(store.rows()) == 5


def test_a_done_row_is_never_replaced_the_first_commit_wins(table):
    """Issue 39: Dask may run a task twice; the second outcome of a run already done is not written, whatever it
    says (done with other figures, or failed), and the run's fault rows stay as the first attempt left them."""
    out, campaign = table
    run = campaign.runs[0]
    with Store(out / TABLE_NAME) as store:
        before, faults = store.row(run.run_id), store.faults()
        for late in (outcome(summary(False, 9.0, 9.0), run_dir="/elsewhere"), outcome(None, "failed", None, 1, "x")):
            refused = store.commit(*table_row(run, late, 2))
            assert not refused.applied and refused.previous == before
        assert store.row(run.run_id) == before and store.faults() == faults


def test_the_report_is_rebuilt_from_the_table_alone(table, capsys):
    out, campaign = table
    labels, columns, cells = verdict_matrix(Store(out / TABLE_NAME).rows())
    assert labels == ["model=hammerstein", "model=lti-lptn"]
    assert columns == ["fault_seed=1", "fault_seed=2", "fault_seed=3"]
    assert cells == [["clean", "not clean", "failed"], ["timeout", "lost-worker", "not run"]]
    (out / "spec.toml").unlink(missing_ok=True)                     # nothing but the table is needed
    assert main(["campaign", "report", str(out)]) == 0
    assert "5 run(s)" in capsys.readouterr().out
    report = out / "report"
    assert sorted(p.name for p in report.iterdir()) == ["axis-fault_seed.png", "axis-model.png", "report.md",
                                                       "verdicts.png"]
    assert all(p.read_bytes().startswith(PNG) for p in report.glob("*.png"))
    md = (report / "report.md").read_text()
    assert "| model=hammerstein | clean | not clean | failed |" in md
    assert "| model=lti-lptn | timeout | lost-worker | not run |" in md
    assert "model x cannot be loaded" in md and "3 of 300 rows got no reply" in md
    assert "drop 3/3" in md
    # a row changed in the table changes the rebuilt report; an earlier report is replaced
    with Store(out / TABLE_NAME) as store:
        run = campaign.runs[2]
        assert store.commit(*table_row(run, outcome(summary()), 2)).applied      # it had failed
    assert main(["campaign", "report", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["runs"] == 5
    assert "| model=hammerstein | clean | not clean | clean |" in (report / "report.md").read_text()


def test_a_report_directory_with_foreign_files_and_a_foreign_table_are_refused(table, tmp_path_factory, capsys):
    out, _ = table
    (out / "report").mkdir()
    (out / "report" / "mine.txt").write_text("keep")
    assert main(["campaign", "report", str(out)]) == 1
    assert "mine.txt, which the campaign report did not write" in capsys.readouterr().err
    assert sorted(p.name for p in (out / "report").iterdir()) == ["mine.txt"]
    other = tmp_path_factory.mktemp("other")
    (other / TABLE_NAME).write_text("not sqlite at all")
    assert main(["campaign", "report", str(other)]) == 1
    assert "is not a campaign table" in capsys.readouterr().err
    foreign = tmp_path_factory.mktemp("foreign")
    sqlite3.connect(foreign / TABLE_NAME).execute("CREATE TABLE runs (x TEXT)").connection.commit()
    for create in (False, True):
        with pytest.raises(StoreError, match="not a campaign table"):
            Store(foreign / TABLE_NAME, create=create)
    tables = sqlite3.connect(foreign / TABLE_NAME).execute("SELECT name FROM sqlite_master").fetchall()
    assert tables == [("runs",)]                                     # checked, never altered


def test_a_resume_with_another_spec_is_refused_before_any_run(table, capsys):
    """A resume into a finished campaign with another spec mixed both specs' runs in one table and replaced the
    stored spec; now one sentence, exit 2 (refused before any work, as `bench robustness --resume` refuses another
    study), the table as it was; so is the same table without --resume."""
    out, campaign = table
    (out / "spec.toml").write_text(SPEC)
    with Store(out / TABLE_NAME) as store:
        store.set_meta({"axes": json.dumps(campaign.axes), "fixed": json.dumps(campaign.fixed),
                        "spec_path": str(out / "spec.toml"), "spec_sha256": "ab" * 32})
        before = store.meta(), store.rows()
    other = out.parent / "other.toml"
    other.write_text(SPEC.replace("[1, 2, 3]", "[4]"))
    assert main(["campaign", "run", str(other), "--out", str(out), "--resume", "--quiet"]) == 2
    said = capsys.readouterr().err.strip()
    assert said == (f"bench: error: {out} holds the campaign 'unit' of {out / 'spec.toml'} (spec sha256 "
                    f"abababababab…), whose axes or fixed options differ from {other}'s; resume it with that spec "
                    "and the same --set values, or choose another --out")
    assert main(["campaign", "run", str(out / "spec.toml"), "--out", str(out), "--resume", "--quiet",
                 "--set", "rows=200"]) == 2                         # the same spec with other values: another one
    assert "whose axes or fixed options differ" in capsys.readouterr().err
    assert main(["campaign", "run", str(out / "spec.toml"), "--out", str(out), "--quiet"]) == 2
    assert "already holds a campaign (campaign.sqlite); pass --resume" in capsys.readouterr().err
    with Store(out / TABLE_NAME) as store:
        assert (store.meta(), store.rows()) == before


def test_a_damaged_table_is_one_sentence_and_never_written(table, capsys):
    """One page of campaign.sqlite overwritten with random bytes: --resume and `campaign report` ended in a
    traceback, and the resume wrote to the damaged table first."""
    import random

    out, _ = table
    (out / "spec.toml").write_text(SPEC)
    path = out / TABLE_NAME
    data = bytearray(path.read_bytes())
    size = int.from_bytes(data[16:18], "big")                       # the page size, from the file's header
    assert len(data) >= 3 * size
    data[size:2 * size] = random.Random(5).randbytes(size)           # the second page
    path.write_bytes(bytes(data))
    for argv in (["campaign", "report", str(out)],
                 ["campaign", "run", str(out / "spec.toml"), "--out", str(out), "--resume", "--quiet"]):
        assert main(argv) == 1
        said = capsys.readouterr().err.strip()
        assert said.startswith(f"bench: error: {path} is damaged (SQLite finds: ") and "\n" not in said
        assert "run the campaign again into another --out" in said
        assert path.read_bytes() == bytes(data)
