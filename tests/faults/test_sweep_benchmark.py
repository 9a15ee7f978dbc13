"""The fault sweep benchmark's pieces (tests/benchmarks/bench_fault_sweep.py): its kinds come from the registry,
its verdict from the runs, its log evidence from the log, and the results page renders its record."""

from __future__ import annotations

import argparse
import sys

import pytest

from host.faults.spec import FRAME_KINDS, KINDS, PROCESS_KINDS, REPLY_KINDS, ROW_KINDS

from helpers import ROOT

sys.path.insert(0, str(ROOT / "tests" / "benchmarks"))
sys.path.insert(0, str(ROOT / "docs" / "_ext"))

import bench_fault_sweep as sweep  # noqa: E402
import results_page  # noqa: E402


def test_the_sweep_runs_every_kind_of_the_registry_and_the_quick_run_one_per_family():
    assert sweep.fault_kinds() == list(KINDS)
    quick = sweep.quick_kinds()
    assert len(quick) == 4 and set(quick) <= set(KINDS)
    for family in (FRAME_KINDS, ROW_KINDS, PROCESS_KINDS, REPLY_KINDS):
        assert len(set(quick) & set(family)) == 1


def test_process_kinds_get_a_count_and_the_others_a_rate():
    assert [sweep.fault_argument(k, 0.02, 1) for k in ("kill", "freeze", "drop", "reply_drop")] == [
        "kill=1", "freeze=1", "drop=0.02", "reply_drop=0.02"]


def _run(engine: str, kind: str, exit_: int, injected: int, detected: int | None) -> dict:
    return {"engine": engine, "kind": kind, "fault": f"{kind}=0.02", "exit": exit_, "wall_s": 1.0,
            "load_average": {"start": 1.0, "end": 1.5}, "verdict": "not clean", "problems": [] if exit_ == 0 else
            ["1 row(s) missed their reply deadline without an injected fault (rows [7])"],
            "injected": {kind: injected}, "detected": {kind: detected}, "deadline_misses": 3, "late_replies": 1,
            "late_reply_max_ms": 80.0, "unexplained_deadline_misses": 0 if exit_ == 0 else 1}


def test_the_sweep_passes_only_when_every_run_exits_0_with_every_fault_detected():
    good = [_run("python", "drop", 0, 5, 5), _run("firmware", "drop", 0, 5, 5)]
    assert sweep.summarize(good)["passed"]
    failed = sweep.summarize(good + [_run("firmware", "kill", 1, 1, 1)])
    assert not failed["passed"] and failed["unexplained_misses"] == 1
    assert failed["engines"]["firmware"]["failed"] == {"kill": "1 row(s) missed their reply deadline without an "
                                                                "injected fault (rows [7])"}
    assert failed["engines"]["firmware"]["exit_0"] == 1 and failed["engines"]["python"]["exit_0"] == 1
    undetected = sweep.summarize([_run("python", "corrupt", 0, 5, 4)])
    assert not undetected["passed"] and undetected["engines"]["python"]["all_detected"] == 0


def test_the_results_section_shows_each_run_and_the_verdict():
    record = {"benchmark": "fault_sweep", "variant": None, "date": "2026-11-26T06:00:00Z",
              "command": "python tests/benchmarks/bench_fault_sweep.py", "wall_s": 10.0,
              "machine": {"cpu": "cpu", "cpus": 2, "memory_GB": 1.0, "os": "os", "python": "3.11", "numpy": "2"},
              "code": {"version": "0", "commit": None}, "load_average": {"start": 1.0, "end": 2.0},
              "parameters": {"rows": 1000, "seed": 3, "engines": ["python", "firmware"], "kinds": ["drop", "kill"],
                             "parallel": 2, "artifact": {"observer": "obs", "measurements": ["ntc_C", "flux"],
                                                         "form": "ud", "data": "profile_09.csv"}},
              "figures": {"runs": (runs := [_run("python", "drop", 0, 5, 5), _run("firmware", "drop", 0, 5, 5),
                                            _run("python", "kill", 0, 1, 1), _run("firmware", "kill", 1, 1, 1)]),
                          "summary": sweep.summarize(runs)}}
    page = results_page.render_results({"fault_sweep": [record]})
    assert "## Fault sweep" in page
    assert "| `kill=0.02` | exit 0, 1/1; misses 3, 1 late (max 80 ms), 0 unexplained; 1 s, load 1.0–1.5 |" in page
    assert "**The sweep does not pass**: firmware kill: 1 row(s) missed" in page
    assert 'Verdicts: "not clean" (4 runs).' in page
    assert "Not measured yet: `python tests/benchmarks/bench_fault_sweep.py`" in results_page.render_results({})


@pytest.mark.slow
def test_a_small_sweep_run_gives_its_figures_and_the_logs_evidence(flux_observer_artifact, tmp_path):
    """One real `bench run` with the NTC + flux observer and a 0.2 ms deadline: its misses are late replies, and the
    log shows each answered once per send. (1 ms was met by every row on an idle CI machine: 0 late replies.)"""
    artifact, data = flux_observer_artifact
    for deadline in (0.0002, 0.0001):   # a fast idle machine meets 0.2 ms on every row now and then
        args = argparse.Namespace(rows=60, rate=0.03, count=1, seed=3, reply_timeout=deadline)
        out = tmp_path / str(deadline)
        out.mkdir()
        run = sweep.run_one("python", "drop", {"model": artifact, "data": data}, out, args)
        assert run["exit"] == 0, run
        assert run["injected"]["drop"] == run["detected"]["drop"] > 0 and run["rows"] == 60
        assert run["unexplained_deadline_misses"] == 0
        if run["late_replies"] > 0:
            break
    else:
        pytest.skip("every row met the 0.2 and 0.1 ms deadlines on this machine: nothing came late")
    evidence = sweep.miss_evidence(out / "python-drop.blf", list(range(60)))
    late = [e for e in evidence if e["sends"] > 1 and e["replies"] == e["sends"]]
    assert late and all(e["first_reply_ms"] > 0 for e in late)
    assert sweep.passed(run) and sweep.summarize([run])["passed"]
