"""examples/ci: the CI recipes run examples/ci/acceptance.sh and upload what it writes; the script itself runs here,
so its steps stay true (the bench run alone in the default suite, the pytest suite against all three targets in the
slow one)."""

import glob
import os
import subprocess
from pathlib import Path

import pytest

from helpers import subprocess_env

junitparser = pytest.importorskip("junitparser")

ROOT = Path(__file__).resolve().parents[3]
CI = ROOT / "examples" / "ci"
SCRIPT_RUN = "bash examples/ci/acceptance.sh"
# what the script writes into $BENCH_CI_OUT, as the recipes name it
UPLOADED = {"out/ci/bench.blf", "out/ci/report/", "out/ci/summary.json", "out/ci/bench-junit.xml",
            "out/ci/pytest-*.xml", "out/ci/runs-*/", "out/ci/external-target.log"}
SCRIPT_TIMEOUT_S = 1200   # the bench run and the suite three times (~2.5 min alone on 2 cores)


def run_script(out: Path, targets: str, rows: int) -> subprocess.CompletedProcess:
    env = subprocess_env(can_settings=False, BENCH_CI_OUT=str(out), BENCH_CI_TARGETS=targets,
                         BENCH_CI_ROWS=str(rows), BENCH_PYTEST_ARGS="-p no:bench -p bench.pytest_plugin",
                         BENCH_CI_EXTERNAL_PORT=str(43000 + os.getpid() % 1000))
    return subprocess.run(["bash", str(CI / "acceptance.sh")], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=SCRIPT_TIMEOUT_S)


def test_both_recipes_run_the_script_and_upload_what_it_writes():
    yaml = pytest.importorskip("yaml")
    github = yaml.safe_load((CI / "github-actions.yml").read_text())
    steps = github["jobs"]["acceptance"]["steps"]
    runs = [s.get("run", "") for s in steps]
    assert SCRIPT_RUN in runs and any("pip install" in r for r in runs)
    assert any("modprobe vcan" in r for r in runs)
    (upload,) = [s for s in steps if s.get("uses", "").startswith("actions/upload-artifact")]
    assert set(upload["with"]["path"].split()) == UPLOADED and upload["if"] == "always()"
    gitlab = yaml.safe_load((CI / "gitlab-ci.yml").read_text())
    job = gitlab[".acceptance"]
    assert job["script"] == [SCRIPT_RUN] and set(job["artifacts"]["paths"]) == UPLOADED
    assert job["artifacts"]["when"] == "always" and set(job["artifacts"]["reports"]["junit"]) <= UPLOADED
    assert any("modprobe vcan" in line for line in gitlab["acceptance:vcan"]["before_script"])


@pytest.mark.slow
def test_the_script_runs_the_bench_with_the_criteria(tmp_path):
    out = tmp_path / "out" / "ci"
    proc = run_script(out, targets="", rows=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    for pattern in ("bench.blf", "report/", "summary.json", "bench-junit.xml"):
        assert glob.glob(str(out / pattern)), pattern
    (suite,) = list(junitparser.JUnitXml.fromfile(str(out / "bench-junit.xml")))
    assert (suite.tests, suite.failures) == (10, 0)


@pytest.mark.slow
def test_the_script_runs_the_suite_against_all_three_targets(tmp_path):
    out = tmp_path / "out" / "ci"
    proc = run_script(out, targets="python firmware external", rows=1500)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    counts = {}
    for target in ("python", "firmware", "external"):
        (suite,) = list(junitparser.JUnitXml.fromfile(str(out / f"pytest-{target}.xml")))
        counts[target] = (suite.tests, suite.failures + suite.errors, suite.skipped)
    assert counts == {"python": (4, 0, 1), "firmware": (4, 0, 0), "external": (4, 0, 2)}
