"""One JSON shape of a run (issue 38, part 2): `bench run --json` and `bench host --json` print one `RunSummary`,
which keeps every key each command printed before, and reads back with `RunSummary.from_json`."""

from __future__ import annotations

from dataclasses import replace

from bench.analysis.results import RunSummary

from helpers import example_summary

HOST_RECORD = {"mode": "lockstep", "rows": 300, "rows_sent": 300, "replies": 300, "missing": 0, "sequence_gaps": 0,
               "target_state": "STOPPED", "wall_time_s": 1.5, "engine": "firmware"}


def test_the_hosts_record_is_under_host_and_at_the_top_where_each_command_had_it():
    data = example_summary(host=HOST_RECORD, log_path="/x/bench.blf").to_json()
    assert data["host"] == HOST_RECORD                                # where `bench run --json` has it
    for key in ("rows_sent", "sequence_gaps", "target_state", "wall_time_s", "mode"):   # where `bench host` has it
        assert data[key] == HOST_RECORD[key]
    assert data["log_path"] == "/x/bench.blf"
    # a key both had keeps the summary's value: the log's counts, the run's engine
    assert data["steps_sent"] == data["replies"] == 300 and data["engine"] == "firmware"
    back = RunSummary.from_json(data)
    assert back.host == HOST_RECORD and back.log_path == "/x/bench.blf"
    assert back.to_json() == data


def test_a_run_whose_log_holds_no_figures_keeps_its_verdict_and_has_no_figure_keys():
    summary = replace(example_summary(clean=False, host=HOST_RECORD), metrics=None,
                      problems=["the log x.blf cannot be compared with the offline float32 reference (empty)"])
    data = summary.to_json()
    assert "metrics" not in data and "rmse_C" not in data and "steps_sent" not in data
    assert data["clean"] is False and data["verdict"].startswith("not clean: the log x.blf cannot be compared")
    assert data["rows_sent"] == 300 and data["host"] == HOST_RECORD
