"""examples/ci: the CI recipes run examples/ci/acceptance.sh and upload what it writes; the script itself runs here,
so its steps stay true (the bench run alone in the default suite, the pytest suite against all three targets in the
slow one), and so do the recipes' own commands in order (install from the checkout, then the script; slow)."""

import glob
import os
import re
import shutil
import subprocess
import sys
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


# --- the recipes' own commands, in order, on this machine ------------------------------------------------------------
# Skipped, as they need a CI runner's own features: every `uses:` step of the GitHub workflow (checkout, setup-python,
# the JUnit report, the artifact upload: the runner's actions), GitLab's `image:` and `artifacts:` (the runner's), and
# the vcan jobs/steps (`modprobe vcan` needs a kernel with SocketCAN and root on the runner; this machine has no
# AF_CAN, tests/vm runs the socketcan tests in a VM). Everything else runs as written, in a copy of the checkout, with
# `python` a fresh virtual environment's (system site-packages visible, so the install builds and installs the bench
# itself without downloading its dependencies again). One addition: BENCH_CI_EXTERNAL_PORT, a port unique to this test,
# so that a parallel run's external target is never heard.
RECIPE_TIMEOUT_S = 1800   # the install (~1 min) and the script (~2.5 min alone on 2 cores): generous under load
MATRIX = {"bus": "udp_multicast"}     # the GitHub matrix entry run here (the vcan one needs the runner's kernel)
# the only GitHub expression forms the recipe uses: `matrix.X == 'v' && 'a' || 'b'`, and `matrix.X == 'v'`
CHOICE = re.compile(r"\$\{\{\s*matrix\.(\w+) == '([^']*)' && '([^']*)' \|\| '([^']*)'\s*\}\}")
CONDITION = re.compile(r"^matrix\.(\w+) == '([^']*)'$")


def _github_value(text: str) -> str:
    value = CHOICE.sub(lambda m: m[3] if MATRIX[m[1]] == m[2] else m[4], str(text))
    assert "${{" not in value, f"teach this test the expression in {text!r}"
    return value


def _github_runs(step: dict) -> bool:
    condition = step.get("if")
    if condition is None or condition == "always()":
        return True
    match = CONDITION.match(condition)
    assert match, f"teach this test the condition {condition!r}"
    return MATRIX[match[1]] == match[2]


def github_commands() -> list[tuple[str, dict[str, str]]]:
    """The `run:` commands of the GitHub workflow's udp_multicast job, in order, with their step's environment."""
    import yaml

    job = yaml.safe_load((CI / "github-actions.yml").read_text())["jobs"]["acceptance"]
    assert MATRIX["bus"] in job["strategy"]["matrix"]["bus"]
    return [(step["run"], {k: _github_value(v) for k, v in (step.get("env") or {}).items()})
            for step in job["steps"] if "run" in step and _github_runs(step)]


def gitlab_commands() -> list[tuple[str, dict[str, str]]]:
    """The before_script and script lines of the GitLab udp_multicast job (its template's, as `extends` merges them),
    in order, with the job's variables."""
    import yaml

    recipe = yaml.safe_load((CI / "gitlab-ci.yml").read_text())
    job = recipe["acceptance:udp_multicast"]
    template = recipe[job["extends"]]
    merged = {**template, **job, "variables": {**template.get("variables", {}), **job.get("variables", {})}}
    variables = {k: str(v) for k, v in merged["variables"].items()}
    return [(line, variables) for line in [*merged.get("before_script", []), *merged["script"]]]


def _checkout_copy(into: Path) -> Path:
    """The repository's files (tracked, and new ones not ignored) copied into `into`: what a CI job checks out."""
    listed = subprocess.run(["git", "-C", str(ROOT), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                            capture_output=True, check=True).stdout.decode().split("\0")
    for name in filter(None, listed):
        source = ROOT / name
        if source.is_file():
            (into / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, into / name)
    return into


def test_the_recipes_commands_are_read_in_order():
    """What the slow test below runs: the install from the checkout, then the script (and no PyPI name)."""
    pytest.importorskip("yaml")
    for commands in (github_commands(), gitlab_commands()):
        assert [c for c, _ in commands] == ['python -m pip install ".[test]"', SCRIPT_RUN], commands
        assert commands[-1][1]["BENCH_CI_INTERFACE"] == "udp_multicast" and commands[-1][1]["BENCH_CI_OUT"]
    assert github_commands()[-1][1]["BENCH_CI_CHANNEL"] == ""


@pytest.mark.slow
@pytest.mark.parametrize("recipe", ["github", "gitlab"])
def test_each_recipe_runs_as_written_on_this_machine(tmp_path, recipe):
    pytest.importorskip("yaml")
    commands = github_commands() if recipe == "github" else gitlab_commands()
    checkout = _checkout_copy(tmp_path / "checkout")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)], check=True)
    for command, variables in commands:
        env = subprocess_env(can_settings=False, BENCH_CI_EXTERNAL_PORT=str(43000 + os.getpid() % 1000),
                             PATH=f"{venv / 'bin'}{os.pathsep}{os.environ['PATH']}", VIRTUAL_ENV=str(venv),
                             PIP_DISABLE_PIP_VERSION_CHECK="1", **variables)
        env.pop("PYTHONPATH", None)     # the job's python finds the bench it installed, as on a runner
        proc = subprocess.run(["bash", "-c", command], cwd=checkout, env=env, capture_output=True, text=True,
                              timeout=RECIPE_TIMEOUT_S)
        assert proc.returncode == 0, f"{command}: {proc.stdout[-2000:]}{proc.stderr[-3000:]}"
    # the install put the bench into the job's environment (not a name PyPI does not have)
    shown = subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "show", "-f", "pmsm-thermal-bench"],
                           capture_output=True, text=True)
    assert shown.returncode == 0 and f"Location: {venv}" in shown.stdout, shown.stdout + shown.stderr
    out = checkout / "out" / "ci"
    for pattern in UPLOADED:     # what the recipes upload is there
        assert glob.glob(str(checkout / pattern)), pattern
    (suite,) = list(junitparser.JUnitXml.fromfile(str(out / "bench-junit.xml")))
    assert (suite.tests, suite.failures) == (10, 0)
    for target in ("python", "firmware", "external"):
        (suite,) = list(junitparser.JUnitXml.fromfile(str(out / f"pytest-{target}.xml")))
        assert suite.failures + suite.errors == 0, target
