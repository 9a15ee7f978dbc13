"""The typed run results: JSON round trip, schema version, and one object read by the run JSON, the report and
the campaign store."""

from __future__ import annotations

import json

import pytest

from bench.analysis.report import render_markdown
from bench.analysis.results import (
    SCHEMA_VERSION,
    FaultGap,
    FaultResults,
    HostFaults,
    LogSummary,
    ResultsError,
    RunResults,
    RunSummary,
)
from bench.campaign.store import flatten, summary_of

from helpers import example_results, example_summary


def faulted() -> RunResults:
    faults = FaultResults(injected={"kill": 1}, injected_total=1, detected={"kill": 1}, undetected=0,
                          detection={"kill": "heartbeat"}, sidecar_injected_total=1, retransmitted_rows=2,
                          gaps=[FaultGap([10, 12], 12, 10, 0.4, 3.0)], reinitializations=1,
                          unexplained_deadline_misses=0, unexplained_deadline_miss_rows=[], seed=7, mode="lockstep",
                          sidecar_problems=[], sidecar="/x/bench.blf.faults.json")
    return example_results(faults=faults, report="/x/report/report.md")


@pytest.mark.parametrize("results", [example_results(), faulted()])
def test_run_results_round_trip_through_json(results):
    data = json.loads(json.dumps(results.to_json(), allow_nan=False))
    assert data["schema_version"] == SCHEMA_VERSION
    assert RunResults.from_json(data) == results
    assert RunResults.from_json(data).to_json() == results.to_json()


def test_the_json_keeps_its_flat_keys():
    data = example_results().to_json()
    # the groups (counts, agreement, timing, ...) add no level to the JSON
    assert {"steps_sent", "max_abs_can_minus_float32_C", "rmse_C", "step_time_us", "flash_bytes",
            "round_trip_us", "heartbeat", "log", "bus_load", "null_values"} <= set(data)
    assert not {"counts", "agreement", "accuracy", "timing", "memory", "throughput", "integrity"} & set(data)
    assert data["max_abs_can_minus_float32_C"] == {"yoke": 0.001, "winding": 0.0049, "tooth": 0.002, "magnet": 0.003}
    assert "report" not in data and "window_percent" not in example_results().to_json(windows=False)["bus_load"]


def test_a_run_summary_round_trips_and_keeps_the_brief_numbers_on_top():
    host = HostFaults.of_run({"injected": {"drop": 3}, "detected": {"drop": 3}, "injected_total": 3,
                              "detected_total": 3, "undetected": 0, "retransmitted_rows": 1, "gaps": [],
                              "spec": "drop=0.01", "seed": 7}, faulted().faults)
    summary = example_summary(faults=host, metrics=faulted())
    data = json.loads(json.dumps(summary.to_json()))
    assert data["schema_version"] == SCHEMA_VERSION and data["metrics"]["schema_version"] == SCHEMA_VERSION
    assert data["faults"]["spec"] == "drop=0.01" and data["faults"]["marked_in_log"] == {"kill": 1}
    assert (data["steps_sent"], data["est_cycles"], data["report"]) == (300, 1989, "/x/report/report.md")
    back = RunSummary.from_json(data)
    assert back.to_json() == data
    assert back.metrics == RunResults.from_json(summary.metrics.to_json(windows=False))


@pytest.mark.parametrize("version", [None, 0, SCHEMA_VERSION + 1, "1"])
def test_another_schema_version_is_refused_in_one_sentence(version):
    data = example_results().to_json()
    data.pop("schema_version")
    if version is not None:
        data["schema_version"] = version
    with pytest.raises(ResultsError) as caught:
        RunResults.from_json(data)
    message = str(caught.value)
    assert f"this bench reads schema_version {SCHEMA_VERSION}" in message and "\n" not in message
    assert message.count(". ") == 0


def test_a_missing_key_is_refused_in_one_sentence():
    data = example_results().to_json()
    del data["rmse_C"]
    with pytest.raises(ResultsError, match="lack rmse_C"):
        RunResults.from_json(data)


def test_run_json_report_and_campaign_store_read_the_same_object():
    summary = example_summary(metrics=faulted())
    printed = json.loads(json.dumps(summary.to_json()))          # what `bench run --json` prints
    row, kinds = flatten(printed)                                # what the campaign stores
    stored = summary_of(row)
    assert stored == RunSummary.from_json(printed)
    assert stored.metrics.model == summary.metrics.model and stored.metrics.faults == summary.metrics.faults
    assert row["rmse_winding_C"] == summary.metrics.accuracy.rmse_C.winding and kinds == []
    # the report renders the printed object as it renders the run's own (the windows are not in the summary)
    read = RunSummary.from_json(printed)
    assert render_markdown(read.metrics, read.problems, None, {}) == \
        render_markdown(summary.metrics, summary.problems, None, {})
    # `bench analyze --json` is the same metrics, flat, with the verdict
    analyzed = LogSummary(summary.metrics, [], True).to_json()
    assert LogSummary.from_json(analyzed).metrics == stored.metrics


def test_the_run_json_says_what_each_rmse_is_against_and_its_verdict_in_words():
    data = example_summary().to_json()
    reference = example_results().accuracy.rmse_reference
    assert data["rmse_reference"] == {n: reference.get(n) for n in ("yoke", "winding", "tooth", "magnet")}
    assert list(data).index("rmse_reference") == list(data).index("rmse_C") + 1
    assert (data["clean"], data["verdict"]) == (True, "clean")
    failed = example_summary(clean=False, problems=["3 of 300 rows got no reply", "the heartbeat was lost"])
    assert failed.to_json()["verdict"] == "not clean: 3 of 300 rows got no reply; the heartbeat was lost"
    # faults injected, each detected and tolerated: no problem, and still not clean
    host = HostFaults.of_run({"injected": {"drop": 3}, "detected": {"drop": 3}, "injected_total": 3,
                              "detected_total": 3, "undetected": 0, "retransmitted_rows": 1, "gaps": []}, None)
    tolerated = example_summary(clean=False, problems=[], faults=host)
    assert tolerated.to_json()["verdict"] == "not clean: 3 faults injected, all detected, nothing else went wrong"
    assert RunSummary.from_json(json.loads(json.dumps(failed.to_json()))).verdict == failed.verdict


def test_the_analyze_json_has_the_verdict_in_words():
    assert LogSummary(example_results(), [], True).to_json()["verdict"] == "clean"
    assert LogSummary(faulted(), ["the log is incomplete"], False).to_json()["verdict"] == \
        "not clean: the log is incomplete"
    assert LogSummary(faulted(), [], False).to_json()["verdict"] == \
        "not clean: 1 fault injected, all detected, nothing else went wrong"
