"""--criteria, --baseline and --junit-xml on the commands: one run of the packaged model judged by the example
criteria (passes), its log judged again by a file whose PM limit is below its error (fails), a deliberately worse
model caught by the regression gate, and a bad criteria file refused before any work. The JUnit XML is read back
with a JUnit parser (junitparser)."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bench.acceptance.junit import PROJECT_DIR_VARIABLE
from bench.analysis.results import DataIdentity
from bench.drive.generate import ensure_default_datasets
from bench.model.default import default_artifact_path
from target_sim.artifact import encode_array, seal

from helpers import example_results, example_summary, run_cli, synthetic_columns, write_synthetic_dataset

junitparser = pytest.importorskip("junitparser")

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "examples" / "ci" / "criteria.toml"
ROWS = "600"
RUN_TIMEOUT_S = 300   # a bench run of 600 rows takes ~6 s alone; generous for a loaded 2-core runner


def failing_criteria(path: Path) -> Path:
    """The example criteria with the PM RMSE limit below the packaged model's error (0.2 °C; it is ~0.29 °C)."""
    text = EXAMPLE.read_text().replace('nodes = "magnet"\nagainst = "measured"\nmax = 3.0',
                                       'nodes = "magnet"\nagainst = "measured"\nmax = 0.2', 1)
    assert "max = 0.2" in text
    path.write_text(text)
    return path


def worse_artifact(path: Path) -> Path:
    """The packaged model with its input matrix B scaled by 1.1: a deliberately worse estimator (resealed)."""
    content = json.loads(default_artifact_path().read_text())
    block = content["linear_block"]
    B = np.array(block["B"]["f64"]).reshape(block["B"]["shape"])
    block["B"] = encode_array(B * 1.1)
    path.write_text(json.dumps(seal(content)))
    return path


def cases(path: Path) -> dict[str, object]:
    xml = junitparser.JUnitXml.fromfile(str(path))
    (suite,) = list(xml)
    return suite, {case.name: case for case in suite}


def props(case) -> dict[str, str]:
    found = case.child(junitparser.Properties)
    return {p.name: p.value for p in found} if found is not None else {}


@pytest.fixture(scope="module")
def passing_run(tmp_path_factory, default_data_root):
    """The default run in a directory of its own, as a CI job runs in its project's: the attachments are relative
    to it. Its default data (and the dataset `analyze` and `replay` match a log with) is the session's."""
    out = tmp_path_factory.mktemp("accept")
    ensure_default_datasets(default_data_root)
    (out / "out").mkdir()
    (out / "out" / "data").symlink_to(default_data_root, target_is_directory=True)   # the commands' out/data
    with pytest.MonkeyPatch.context() as env:
        env.delenv(PROJECT_DIR_VARIABLE, raising=False)   # not in a GitLab job, even when the tests run in one
        proc = run_cli("-m", "bench", "run", "--rows", ROWS, "--criteria", str(EXAMPLE), "--junit-xml", "junit.xml",
                       "--log", "bench.blf", "--report", "report", "--json", "-i", "udp_multicast", cwd=out,
                       timeout=RUN_TIMEOUT_S)
    return out, proc


def test_the_example_criteria_pass_on_the_packaged_model(passing_run):
    out, proc = passing_run
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads(proc.stdout)
    acceptance = summary["acceptance"]
    assert acceptance["passed"] and acceptance["failed"] == [] and len(acceptance["checks"]) == 9
    assert acceptance["verdict"] == "the run meets its 9 acceptance criteria"
    cycles = next(c for c in acceptance["checks"] if c["kind"] == "cycles")
    assert cycles["source"].startswith("estimated") and cycles["figure"] == summary["est_cycles"]
    report = (out / "report" / "report.md").read_text()
    assert "## Acceptance criteria: met" in report and "| pm_rmse: RMSE of magnet against measured |" in report
    suite, by_name = cases(out / "junit.xml")
    assert (suite.tests, suite.failures, suite.errors) == (10, 0, 0)
    assert list(by_name)[0] == "clean" and set(by_name) - {"clean"} == {c["name"] for c in acceptance["checks"]}
    pm = props(by_name["pm_rmse"])
    assert pm["limit"] == "3" and float(pm["figure"]) == pytest.approx(summary["rmse_C"]["magnet"], rel=1e-5)
    # relative to the directory the command ran in: what GitLab ($CI_PROJECT_DIR) and Jenkins (the workspace) serve
    assert "[[ATTACHMENT|bench.blf]]" in by_name["clean"].system_out
    assert "[[ATTACHMENT|report/report.md]]" in by_name["pm_rmse"].system_out
    assert by_name["clean"].classname == "bench.run" and by_name["clean"].time > 0
    suite_props = {p.name: p.value for p in suite.properties()}
    assert Path(suite_props["log"]).name == "bench.blf" and suite_props["criteria"] == str(EXAMPLE)


def test_a_pm_limit_below_its_error_fails_and_names_the_criterion(passing_run, tmp_path):
    out, _ = passing_run
    junit = tmp_path / "junit.xml"
    proc = run_cli("-m", "bench", "analyze", str(out / "bench.blf"), "--no-report", "--criteria",
                   str(failing_criteria(tmp_path / "fail.toml")), "--junit-xml", str(junit), cwd=out,
                   timeout=RUN_TIMEOUT_S)
    assert proc.returncode == 1, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith(f"bench: error: the log {out / 'bench.blf'} fails 1 of its 9 acceptance criteria: "
                           "pm_rmse: RMSE of magnet against measured 0.2")
    assert "> limit 0.2 °C" in last
    suite, by_name = cases(junit)
    assert (suite.tests, suite.failures) == (10, 1)
    (failure,) = by_name["pm_rmse"].result
    assert isinstance(failure, junitparser.Failure) and failure.type == "AcceptanceCriterion"
    assert failure.message == last.split("criteria: ", 1)[1]
    assert by_name["clean"].is_passed and props(by_name["pm_rmse"])["verdict"] == "fail"


@pytest.mark.slow
def test_a_worse_model_is_caught_by_the_regression_gate(passing_run, tmp_path):
    out, proc = passing_run
    baseline = tmp_path / "baseline.json"
    baseline.write_text(proc.stdout)
    run = run_cli("-m", "bench", "run", "--rows", ROWS, "--model", str(worse_artifact(tmp_path / "worse.json")),
                  "--baseline", str(baseline), "--no-report", "--log", str(tmp_path / "w.blf"), "--json",
                  "-i", "udp_multicast", timeout=RUN_TIMEOUT_S)
    assert run.returncode == 1, run.stderr[-2000:]
    summary = json.loads(run.stdout)
    assert summary["clean"]   # the transport is fine: only the estimate got worse
    (check,) = summary["acceptance"]["checks"]
    assert (check["name"], check["verdict"], check["limit"]) == ("regression", "fail", 5.0)
    assert check["figure"] > 5.0
    assert "bench: error: the run fails 1 of its 1 acceptance criteria: regression: RMSE of " in run.stderr


@pytest.mark.slow
def test_the_replay_judges_its_own_log(passing_run, tmp_path):
    out, _ = passing_run
    junit = tmp_path / "junit.xml"
    proc = run_cli("-m", "bench", "replay", str(out / "bench.blf"), "--as-fast-as-possible", "--log",
                   str(tmp_path / "r.blf"), "--criteria", str(EXAMPLE), "--junit-xml", str(junit), "--json",
                   "-i", "udp_multicast", cwd=out, timeout=RUN_TIMEOUT_S)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads(proc.stdout)["acceptance"]["passed"]
    suite, by_name = cases(junit)
    assert (suite.tests, suite.failures) == (10, 0) and "reproduced" in by_name["clean"].system_out


@pytest.mark.parametrize("command", [
    ["run", "--rows", "10", "-i", "udp_multicast"], ["host", "--data", "nowhere.csv", "-i", "udp_multicast"],
    ["analyze", "nowhere.blf", "--no-report"], ["replay", "nowhere.blf", "-i", "udp_multicast"]])
def test_a_bad_criteria_file_is_refused_before_any_work(tmp_path, command):
    bad = tmp_path / "bad.toml"
    bad.write_text("[criteria.pm]\nkind = 'rmse'\nmax = 'three'\n")
    log = tmp_path / "log.blf"
    extra = [] if command[0] == "analyze" else ["--log", str(log)]
    proc = run_cli("-m", "bench", *command, *extra, "--criteria", str(bad), timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == f"bench: error: {bad}: [criteria.pm] max must be a number >= 0"
    assert not log.exists() and proc.stdout == ""


def test_a_junit_path_that_is_a_directory_is_refused_before_the_run(tmp_path):
    proc = run_cli("-m", "bench", "run", "--rows", "10", "--junit-xml", str(tmp_path), "--log",
                   str(tmp_path / "x.blf"), timeout=60)
    assert proc.returncode != 0 and "--junit-xml" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x.blf").exists()


def test_a_command_that_ends_on_an_error_still_writes_its_junit_xml(tmp_path):
    junit = tmp_path / "junit.xml"
    proc = run_cli("-m", "bench", "analyze", str(tmp_path / "missing.blf"), "--no-report", "--criteria",
                   str(EXAMPLE), "--junit-xml", str(junit), timeout=60)
    assert proc.returncode == 1
    sentence = proc.stderr.strip().removeprefix("bench: error: ")
    suite, by_name = cases(junit)
    assert (suite.tests, suite.errors, suite.failures) == (10, 10, 0)
    (error,) = by_name["clean"].result
    assert isinstance(error, junitparser.Error) and error.message == sentence
    assert by_name["pm_rmse"].result[0].message == f"not judged: {sentence}"


@pytest.mark.parametrize("command", ["run", "host"])
def test_a_baseline_of_other_data_is_refused_before_any_work(tmp_path, command):
    """The same rows of another dataset: before summaries carried the data's identity, the gate compared the two
    and reported a false regression (44.78 %)."""
    data = write_synthetic_dataset(tmp_path / "drive.csv", synthetic_columns(300, seed=4), "other data")
    stored = replace(example_results(), data=DataIdentity(300, "0" * 64))
    baseline = tmp_path / "baseline.json"
    baseline.write_text(json.dumps(example_summary(metrics=stored).to_json()))
    log = tmp_path / "run.blf"
    proc = run_cli("-m", "bench", command, "--data", str(data), "--rows", "300", "--baseline", str(baseline),
                   "--log", str(log), "-i", "udp_multicast", timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().startswith(f"bench: error: the baseline {baseline} is a run on other data (rows of "
                                          "sha256 000000000000…, not ")
    assert len(proc.stderr.strip().splitlines()) == 1 and not log.exists()
