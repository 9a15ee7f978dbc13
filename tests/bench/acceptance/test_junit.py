"""The JUnit XML as CI servers read it: junitparser (what GitLab-like readers and the tests use) reads back every
suite and testcase attribute, property, result and system-out the bench wrote, with attachment paths relative to
the project directory (GitLab resolves `[[ATTACHMENT|path]]` against $CI_PROJECT_DIR, Jenkins against its
workspace)."""

from __future__ import annotations

from pathlib import Path

import junitparser
import pytest

from bench.acceptance.junit import (
    COMMAND_ERROR,
    CRITERION_FAILURE,
    NOT_CLEAN,
    PROJECT_DIR_VARIABLE,
    CleanCase,
    attachment_path,
    write_junit,
    write_junit_error,
)
from bench.analysis.results import Acceptance, CheckResult

PASSED = CheckResult("tooth_rmse", "rmse", "RMSE of tooth against measured", 0.812345678, 3.0, "°C", True,
                     "tooth_rmse: RMSE of tooth against measured 0.8123 °C <= limit 3 °C")
FAILED = CheckResult("pm_rmse", "rmse", "RMSE of magnet against measured", 0.2863124, 0.2, "°C", False,
                     "pm_rmse: RMSE of magnet against measured 0.2863 °C > limit 0.2 °C")
CYCLES = CheckResult("cycles", "cycles", "C28x cycles per step", None, 9000.0, "", False,
                     "cycles: C28x cycles per step: no figure", source="estimated")


def props(element) -> dict[str, str]:
    found = element.child(junitparser.Properties)
    return {p.name: p.value for p in found} if found is not None else {}


@pytest.fixture
def project(tmp_path, monkeypatch) -> Path:
    """A project directory the command runs in, outside any GitLab job."""
    monkeypatch.delenv(PROJECT_DIR_VARIABLE, raising=False)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "out" / "ci" / "report").mkdir(parents=True)
    return tmp_path


def read(path: Path):
    xml = junitparser.JUnitXml.fromfile(str(path))
    (suite,) = list(xml)
    return xml, suite, {case.name: case for case in suite}


def test_junitparser_reads_back_what_the_bench_wrote_with_relative_attachments(project):
    log, report = project / "out/ci/bench.blf", project / "out/ci/report/report.md"
    junit = project / "out/ci/junit.xml"
    write_junit(junit, "bench run", CleanCase(True, "the run is clean"),
                Acceptance("examples/ci/criteria.toml", None, [PASSED, FAILED, CYCLES]), elapsed_s=12.34567,
                properties={"log": str(log), "report": str(report), "engine": "python"},
                attachments=[str(log), str(report)])
    xml, suite, cases = read(junit)
    assert (xml.name, xml.tests, xml.failures, xml.errors, xml.skipped) == ("bench", 4, 2, 0, 0)
    assert (suite.name, suite.tests, suite.failures, suite.errors, suite.time) == ("bench run", 4, 2, 0, 12.346)
    assert suite.timestamp and suite.hostname
    assert {p.name: p.value for p in suite.properties()} == {
        "log": str(log), "report": str(report), "engine": "python", "criteria": "examples/ci/criteria.toml"}
    assert list(cases) == ["clean", "tooth_rmse", "pm_rmse", "cycles"]
    clean = cases["clean"]
    assert (clean.classname, clean.time, clean.is_passed) == ("bench.run", 12.346, True)
    assert props(clean) == {"verdict": "pass", "problems": "0"}
    attached = "[[ATTACHMENT|out/ci/bench.blf]]\n[[ATTACHMENT|out/ci/report/report.md]]"
    assert clean.system_out == f"the run is clean\n{attached}"
    pm = cases["pm_rmse"]
    assert (pm.classname, pm.time) == ("bench.run.criteria", 0.0)
    assert props(pm) == {"kind": "rmse", "what": "RMSE of magnet against measured", "figure": "0.286312",
                         "limit": "0.2", "unit": "°C", "verdict": "fail"}
    (failure,) = pm.result
    assert isinstance(failure, junitparser.Failure)
    assert (failure.type, failure.message, failure.text) == (
        CRITERION_FAILURE, FAILED.message, "RMSE of magnet against measured: figure 0.286312 °C, limit 0.2 °C")
    assert pm.system_out == f"{FAILED.message}\n{attached}"
    assert cases["tooth_rmse"].is_passed and props(cases["tooth_rmse"])["figure"] == "0.812346"
    assert props(cases["cycles"])["figure"] == "none" and props(cases["cycles"])["source"] == "estimated"
    assert "unit" not in props(cases["cycles"])


def test_a_dirty_run_fails_clean_with_its_problems(project):
    junit = project / "j.xml"
    write_junit(junit, "bench analyze", CleanCase(False, "the log has 2 gaps", ("gap at row 3", "gap at row 9")),
                None, elapsed_s=1.0, properties={}, attachments=[])
    xml, suite, cases = read(junit)
    (failure,) = cases["clean"].result
    assert (failure.type, failure.message, failure.text) == (NOT_CLEAN, "the log has 2 gaps",
                                                              "gap at row 3\ngap at row 9")
    assert (suite.tests, suite.failures) == (1, 1) and cases["clean"].classname == "bench.analyze"
    assert cases["clean"].system_out == "the log has 2 gaps"


def test_attachments_are_relative_to_a_gitlab_jobs_project_dir(project, monkeypatch, tmp_path_factory):
    elsewhere = tmp_path_factory.mktemp("cwd")
    monkeypatch.chdir(elsewhere)    # a job that changed directory: GitLab still resolves against the project
    monkeypatch.setenv(PROJECT_DIR_VARIABLE, str(project))
    assert attachment_path(project / "out/ci/bench.blf") == "out/ci/bench.blf"


def test_a_file_outside_the_project_keeps_its_absolute_path(project, tmp_path_factory):
    outside = tmp_path_factory.mktemp("outside") / "bench.blf"
    assert attachment_path(outside) == str(outside.resolve())
    assert attachment_path("bench.blf") == "bench.blf"


def test_a_command_that_ended_on_an_error_is_an_error_per_case(project):
    junit = project / "j.xml"
    write_junit_error(junit, "bench run", "the target died", ["pm_rmse", "cycles"], elapsed_s=2.5)
    xml, suite, cases = read(junit)
    assert (suite.tests, suite.errors, suite.failures, suite.time) == (3, 3, 0, 2.5)
    assert cases["clean"].time == 2.5 and cases["cycles"].classname == "bench.run.criteria"
    for name, message in (("clean", "the target died"), ("pm_rmse", "not judged: the target died")):
        (error,) = cases[name].result
        assert isinstance(error, junitparser.Error)
        assert (error.type, error.message, error.text) == (COMMAND_ERROR, message, message)
