"""Acceptance criteria (`bench.acceptance`): the file is read and checked whole, each kind judges its figure
against its limit, and a regression gate compares with a stored summary."""

import json
import pkgutil
from dataclasses import replace
from pathlib import Path

import pytest

import bench.acceptance.kinds
from bench.acceptance.criteria import CriteriaError, load_criteria, load_gate, parse_criteria
from bench.acceptance.kinds import KINDS, Kind, register
from bench.acceptance.kinds._base import judged
from bench.analysis.results import (
    Acceptance,
    CycleFigures,
    DataIdentity,
    NodeLabels,
    NodeValues,
    RunResults,
    RunSummary,
)

from helpers import example_results, example_summary

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "examples" / "ci" / "criteria.toml"


def results(**accuracy_changes) -> RunResults:
    base = example_results()
    accuracy = replace(base.accuracy, max_abs_error_C=NodeValues(3.0, 2.0, 4.0, 1.5),
                       rmse_vs_float64_C=NodeValues(0.01, 0.02, 0.01, 0.03),
                       max_abs_error_vs_float64_C=NodeValues(0.05, 0.06, 0.05, 0.07), **accuracy_changes)
    return replace(base, accuracy=accuracy)


def gate_of(tmp_path: Path, text: str, baseline: Path | None = None):
    path = tmp_path / "criteria.toml"
    path.write_text(text)
    return load_gate(path, baseline)


def judge(tmp_path: Path, text: str, on: RunResults | None = None, baseline: Path | None = None) -> Acceptance:
    return gate_of(tmp_path, text, baseline).judge(on or results())


SHIPPED = ("rmse", "max_error", "cycles", "deadline_misses", "missing_replies", "heartbeat_losses", "bus_load",
           "regression")


def test_the_shipped_kinds_are_kinds_and_the_example_file_uses_them():
    assert set(SHIPPED) <= set(KINDS)        # a new module adds a kind, with no edit here
    found = load_criteria(EXAMPLE)
    assert len(found.criteria) == 9
    assert {c.kind for c in found.criteria} == set(SHIPPED) - {"regression"}


def test_every_module_of_the_kinds_package_is_a_kind_under_its_name():
    """A criterion is a module of `bench/acceptance/kinds/` (named as its kind) that registers itself: no list."""
    package = bench.acceptance.kinds
    modules = {m.name for m in pkgutil.iter_modules(package.__path__) if not m.name.startswith("_")}
    assert set(KINDS) == modules
    assert KINDS.names()[:2] == ("rmse", "max_error")     # the order messages list them in


def test_a_registered_kind_is_read_from_a_criteria_file_and_judged(tmp_path):
    """What a new module does on import: `register(Kind(...))`; the file's kind, options and limit then work."""
    def judge_rows(criterion, subject):
        return judged(criterion, "", "data rows", float(subject.results.counts.steps_sent))

    register(Kind("rows", "data rows sent", "", judge_rows))
    try:
        acceptance = judge(tmp_path, "[criteria.few]\nkind = 'rows'\nmax = 1e9\n")
        assert [c.passed for c in acceptance.checks] == [True]
        with pytest.raises(CriteriaError, match="use one of rmse, max_error, .*, rows$"):
            judge(tmp_path, "[criteria.a]\nkind = 'speed'\nmax = 1\n")
    finally:
        KINDS.unregister("rows")


@pytest.mark.parametrize("text, words", [
    ("[criteria.x\nkind = 1", "is not valid TOML"),
    ("", "has no criteria"),
    ("limits = 1\n[criteria.a]\nkind = 'rmse'\nmax = 1", "unknown key 'limits'"),
    ("[criteria.a]\nkind = 'speed'\nmax = 1", "kind 'speed' is not a kind of criterion; use one of rmse"),
    ("[criteria.a]\nkind = ['rmse']\nmax = 1", "kind ['rmse'] is not a kind of criterion; use one of rmse"),
    ("[criteria.a]\nkind = 'rmse'", "[criteria.a] has no limit; give max = NUMBER"),
    ("[criteria.a]\nkind = 'rmse'\nmax = -1", "[criteria.a] max must be a number >= 0"),
    ("[criteria.a]\nkind = 'rmse'\nmax = 1\nnode = 'magnet'", "unknown key 'node'; a rmse criterion takes max, nodes"),
    ("[criteria.a]\nkind = 'rmse'\nmax = 1\nnodes = 'rotor'", "nodes must be a node (yoke, winding, tooth, magnet)"),
    ("[criteria.a]\nkind = 'bus_load'\nmax = 1\nat = 'peak'", "at must be one of data_rate, replay_peak"),
    ("[criteria.a]\nkind = 'regression'\nmax_worse_percent = 5", "is a regression criterion and no baseline"),
    ("baseline = 'nowhere.json'\n[criteria.a]\nkind = 'regression'\nmax_worse_percent = 5",
     "nowhere.json (named in the criteria file"),
])
def test_a_bad_file_is_one_sentence_naming_the_file_and_key(tmp_path, text, words):
    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(CriteriaError) as caught:
        load_gate(path, None)
    message = str(caught.value)
    assert words in message
    assert str(path) in message and "\n" not in message
    assert CriteriaError.exit_status == 2


def test_a_missing_file_and_a_baseline_of_another_kind_are_refused(tmp_path):
    with pytest.raises(CriteriaError, match="the criteria file .* does not exist"):
        load_gate(tmp_path / "none.toml", None)
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"schema_version": 2, "hello": 1}))
    with pytest.raises(CriteriaError, match="is not a summary this bench can compare with"):
        load_gate(None, other)


def test_node_errors_take_the_worst_chosen_node_against_the_chosen_reference(tmp_path):
    text = """
[criteria.pm]
kind = "rmse"
nodes = "magnet"
against = "measured"
max = 0.2
[criteria.all_f64]
kind = "rmse"
against = "float64"
max = 0.05
[criteria.peak]
kind = "max_error"
nodes = ["winding", "magnet"]
max = 1.8
"""
    acceptance = judge(tmp_path, text)
    pm, f64, peak = acceptance.checks
    assert (pm.figure, pm.passed) == (0.25, False)
    assert pm.message == "pm: RMSE of magnet against measured 0.25 °C > limit 0.2 °C"
    assert (f64.figure, f64.passed) == (0.03, True) and "magnet against float64 model (the worst node)" in f64.what
    assert (peak.figure, peak.passed) == (2.0, False) and "winding" in peak.what
    assert acceptance.failed == [pm, peak]
    assert acceptance.sentence() == ("the run fails 2 of its 3 acceptance criteria: " + pm.message + "; "
                                     + peak.message)


def test_a_node_the_data_does_not_measure_fails_against_the_measurement(tmp_path):
    check, = judge(tmp_path, "[criteria.y]\nkind = 'rmse'\nnodes = 'yoke'\nagainst = 'measured'\nmax = 9").checks
    assert not check.passed and check.figure is None
    assert "the data has no measurement of the yoke temperature" in check.message


def test_cycles_are_counted_on_the_firmware_engine_and_estimated_otherwise(tmp_path):
    text = "[criteria.c]\nkind = 'cycles'\nmax = 1500\n[criteria.counted]\nkind = 'cycles'\ncounted = true\nmax = 9e9"
    firmware = judge(tmp_path, text)     # example_results: the firmware engine, 1403/1410 cycles counted
    assert firmware.checks[0].figure == 1410 and firmware.checks[0].source.startswith("counted")
    assert firmware.passed
    python = replace(results(), timing=replace(results().timing, engine="python", m4_cycles=None))
    estimated = judge(tmp_path, text, python)
    assert estimated.checks[0].figure == 1989 and estimated.checks[0].source.startswith("estimated")
    assert not estimated.checks[0].passed and not estimated.checks[1].passed
    assert "counted = true and the run's engine counts none" in estimated.checks[1].message


def test_counts_and_bus_load(tmp_path):
    text = """
[criteria.dl]
kind = "deadline_misses"
max = 0
[criteria.miss]
kind = "missing_replies"
max = 2
[criteria.hb]
kind = "heartbeat_losses"
max = 0
[criteria.load]
kind = "bus_load"
max = 1.0
[criteria.peak]
kind = "bus_load"
at = "replay_peak"
max = 20
"""
    base = results()
    lossy = replace(base, counts=replace(base.counts, missing=3),
                    timing=replace(base.timing, overruns=1))
    checks = {c.name: c for c in judge(tmp_path, text, lossy).checks}
    assert [checks[n].passed for n in ("dl", "miss", "hb", "load", "peak")] == [False, False, True, False, True]
    assert checks["miss"].figure == 3 and checks["load"].figure == 1.2 and checks["peak"].figure == 12.5


def write_baseline(tmp_path: Path, metrics: RunResults) -> Path:
    path = tmp_path / "baseline.json"
    path.write_text(json.dumps(example_summary(metrics=metrics).to_json()))
    return path


def test_regression_gate_against_a_stored_summary(tmp_path):
    baseline = write_baseline(tmp_path, results())
    text = "[criteria.reg]\nkind = 'regression'\nmax_worse_percent = 5"
    same = judge(tmp_path, text, results(), baseline)
    assert same.passed and same.checks[0].figure == 0.0 and same.baseline == str(baseline)
    worse = results(rmse_C=NodeValues(1.0, 0.5, 2.0, 0.3))      # magnet 0.25 -> 0.3: +20 %
    check, = judge(tmp_path, text, worse, baseline).checks
    assert not check.passed and check.figure == pytest.approx(20.0)
    assert "RMSE of magnet, change from the baseline (0.3 °C against 0.25 °C, the worst node) 20 % > limit 5 %" \
        in check.message
    better = results(rmse_C=NodeValues(0.5, 0.4, 1.0, 0.2))
    assert judge(tmp_path, text, better, baseline).passed


def test_regression_refuses_figures_that_do_not_compare(tmp_path):
    baseline = write_baseline(tmp_path, results())
    text = "[criteria.reg]\nkind = 'regression'\nmax_worse_percent = 5"
    longer = replace(results(), counts=replace(results().counts, steps_sent=600))
    check, = judge(tmp_path, text, longer, baseline).checks
    assert not check.passed and "the baseline is over 300 rows and this run over 600" in check.message
    relabelled = results(rmse_reference=NodeLabels("float64 model", "float64 model", "float64 model", "measured"))
    check, = judge(tmp_path, text, relabelled, baseline).checks
    assert not check.passed and "against float64 model, the baseline's against measured" in check.message


def test_a_baseline_of_other_data_is_refused_before_the_run_and_never_judged(tmp_path):
    """Summaries carry the data's identity: a baseline of other rows (same count) gave a false "regression" of
    44.78 % before; now the command refuses it before any work, and a regression against it is never judged."""
    stored = replace(results(), data=DataIdentity(300, "a" * 64))
    baseline = write_baseline(tmp_path, stored)
    text = "[criteria.reg]\nkind = 'regression'\nmax_worse_percent = 5\n[criteria.pm]\nkind = 'rmse'\nmax = 3.0"
    gate = gate_of(tmp_path, text, baseline)
    assert gate.baseline.data == DataIdentity(300, "a" * 64)     # the identity survives the JSON round trip
    gate.check_data(DataIdentity(300, "a" * 64), "this run")      # the same data: nothing to say
    gate.check_data(None, "a log no dataset matched")             # nothing known: compared as before
    with pytest.raises(CriteriaError, match=r"the baseline .*baseline.json is a run on other data \(rows of sha256 "
                                            r"aaaaaaaaaaaa…, not bbbbbbbbbbbb…\) than this run; store a baseline"):
        gate.check_data(DataIdentity(300, "b" * 64), "this run")
    acceptance = gate.judge(replace(results(), data=DataIdentity(300, "b" * 64)))
    regression, pm = acceptance.checks
    assert not regression.passed and regression.figure is None and "is a run on other data" in regression.message
    assert pm.passed                                              # the other criteria are judged as ever
    older = write_baseline(tmp_path, results())                   # a summary of a bench before the identity
    assert gate_of(tmp_path, text, older).judge(replace(results(), data=DataIdentity(300, "b" * 64))).passed


def test_a_baseline_alone_adds_the_default_rmse_regression(tmp_path):
    baseline = write_baseline(tmp_path, results())
    gate = load_gate(None, baseline)
    assert [(c.name, c.kind, c.limit) for c in gate.criteria.criteria] == [("regression", "regression", 5.0)]
    worse = results(rmse_C=NodeValues(1.2, 0.5, 2.0, 0.25))       # yoke +20 %
    assert gate.judge(worse).failed[0].what.startswith("RMSE of yoke")


def test_without_figures_every_criterion_fails_saying_why(tmp_path):
    acceptance = gate_of(tmp_path, EXAMPLE.read_text()).judge(None, "the log holds no row")
    assert len(acceptance.failed) == 9
    assert acceptance.failed[0].message == "pm_rmse: cannot be judged (the log holds no row)"


def test_acceptance_round_trips_through_the_summary_json(tmp_path):
    acceptance = judge(tmp_path, "[criteria.pm]\nkind = 'rmse'\nnodes = 'magnet'\nmax = 0.2")
    summary = example_summary(metrics=replace(results(), acceptance=acceptance))
    data = json.loads(json.dumps(summary.to_json()))
    assert data["acceptance"]["failed"] == ["pm"] and data["acceptance"]["checks"][0]["verdict"] == "fail"
    assert data["metrics"]["acceptance"]["verdict"].startswith("the run fails 1 of its 1")
    again = RunSummary.from_json(data).metrics.acceptance
    assert again == acceptance


def test_parse_keeps_a_relative_baseline_relative_to_the_file(tmp_path):
    found = parse_criteria("baseline = 'b.json'\n[criteria.a]\nkind = 'missing_replies'\nmax = 0",
                           tmp_path / "sub" / "c.toml")
    assert found.baseline == tmp_path / "sub" / "b.json"
    assert found.criteria[0].limit == 0.0


def test_cycle_figures_of_the_firmware_engine_use_the_chosen_statistic(tmp_path):
    timing = replace(results().timing, m4_cycles=CycleFigures(1200, 1900))
    on = replace(results(), timing=timing)
    check, = judge(tmp_path, "[criteria.c]\nkind = 'cycles'\nstatistic = 'p50'\nmax = 1500", on).checks
    assert check.figure == 1200 and check.passed and "(p50)" in check.what
