"""The pytest plugin (`bench.pytest_plugin`): the thermal_bench fixture runs the bench and returns typed results,
the bench_engines marker selects targets, the figures reach pytest's JUnit XML, the pytest11 entry point turns it on
and `-p no:bench` off. Each session is a pytest subprocess in a directory of its own, with the plugin loaded as
`-p no:bench -p bench.pytest_plugin` (the module, whether or not the package's entry point is installed: both at
once would register it twice)."""

import sys
import tomllib
from pathlib import Path

import pytest

from bench.acceptance.junit import PROJECT_DIR_VARIABLE

from helpers import start_target, subprocess_env

junitparser = pytest.importorskip("junitparser")

ROOT = Path(__file__).resolve().parents[3]
SESSION_TIMEOUT_S = 300   # one bench run of 200 rows inside (~5 s alone)

SUITE = '''
import pytest

def test_run(thermal_bench):
    result = thermal_bench.run(rows=200)
    assert type(result.summary).__name__ == "RunSummary"
    assert result.clean, result.verdict
    assert result.metrics.counts.replies == 200 and result.passed

@pytest.mark.bench_engines("firmware")
def test_firmware_only(thermal_bench):
    raise AssertionError("the python target must skip this test")

def test_refused(thermal_bench):
    from bench.pytest_plugin import BenchRunError
    with pytest.raises(BenchRunError, match="does not exist") as caught:
        thermal_bench.run(rows=10, criteria="nowhere.toml")
    assert caught.value.status == 2
'''


def pytest_session(tmp_path: Path, *args: str, plugin: bool = True, extra_path: Path | None = None):
    import subprocess

    env = subprocess_env(can_settings=False)
    env.pop(PROJECT_DIR_VARIABLE, None)   # attachments relative to the session's directory, also in a GitLab job
    if extra_path is not None:
        env["PYTHONPATH"] = f"{extra_path}:{env.get('PYTHONPATH', '')}"
    argv = [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", *(["-p", "no:bench", "-p", "bench.pytest_plugin"]
                                                                        if plugin else []), *args]
    return subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=SESSION_TIMEOUT_S)


@pytest.mark.slow
def test_the_fixture_runs_the_bench_and_records_its_figures(tmp_path, small_dataset):
    (tmp_path / "test_suite.py").write_text(SUITE)
    (tmp_path / "profile.toml").write_text(f'[target]\nengine = "python"\n[run]\ndata = "{small_dataset}"\n')
    proc = pytest_session(tmp_path, "-q", "-o", "junit_family=xunit1", "-o", "junit_logging=system-out",
                          "--junitxml", "j.xml", "--bench-out", "runs", "--bench-profile", "profile.toml",
                          "test_suite.py")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "2 passed, 1 skipped" in proc.stdout
    (suite,) = list(junitparser.JUnitXml.fromfile(str(tmp_path / "j.xml")))
    cases = {case.name: case for case in suite}
    found = cases["test_run"].child(junitparser.Properties)
    figures = {p.name: p.value for p in found}
    assert figures["bench_clean"] == "True" and figures["bench_rows"] == "200" and figures["bench_engine"] == "python"
    assert float(figures["bench_rmse_C_magnet"]) >= 0 and figures["bench_cycles_source"].startswith("estimated")
    assert Path(figures["bench_log"]).name == "bench.blf" and (tmp_path / figures["bench_junit_xml"]).is_file()
    # the run's files as attachments, relative to the session's directory (GitLab's project directory)
    attached = [line for line in cases["test_run"].system_out.splitlines() if line.startswith("[[ATTACHMENT|")]
    assert attached == ["[[ATTACHMENT|runs/test_suite.py__test_run/run1/bench.blf]]",
                        "[[ATTACHMENT|runs/test_suite.py__test_run/run1/junit.xml]]"]
    (skipped,) = cases["test_firmware_only"].result
    assert "this session's is python" in skipped.message


def test_under_xunit2_the_figures_are_suite_properties(tmp_path):
    (tmp_path / "test_x.py").write_text("def test_target(thermal_bench):\n    assert thermal_bench.target == "
                                        "'external'\n")
    proc = pytest_session(tmp_path, "--junitxml", "j.xml", "--bench-interface", "udp_multicast",
                          "--bench-channel", "ff11::7", "--bench-bus-kwargs", "port=43999", "test_x.py")
    assert proc.returncode == 0, proc.stdout[-3000:]
    (suite,) = list(junitparser.JUnitXml.fromfile(str(tmp_path / "j.xml")))
    names = {p.name: p.value for p in suite.properties()}
    assert names["test_x.py::test_target::bench_target"] == ("the target on -i udp_multicast -c ff11::7 "
                                                              "--bus-kwargs port=43999")
    assert "thermal bench: the target on -i udp_multicast" in proc.stdout   # the report header


@pytest.mark.parametrize("profile, words", [
    ("[bus]\nspeed = 1\n", "[bus] has an unknown key 'speed'; use interface, channel, bitrate, bus_kwargs"),
    ("[target]\nattach = true\n", "attaching to a target needs its bus: --bench-interface"),
    ("[x\n", "is not valid TOML"),
    # these failed every test at run time, naming no profile
    # the run request's own checks (`bench.run.request`), in the words a campaign spec's key gets
    ("[run]\nrows = -5\n", "p.toml: [run] rows must be a positive whole number of rows"),
    ("[run]\nmode = 'fast'\n", "p.toml: [run] mode must be one of lockstep, realtime"),
    ("[run]\nreply_timeout = 0\n", "p.toml: [run] reply_timeout must be a positive number"),
    ("[run]\ntimeout = 0\n", "p.toml: [run] timeout must be a number of seconds above 0"),
    ("[run]\ndata = 'nowhere.csv'\n", "p.toml: [run] data 'nowhere.csv' does not exist"),
    ("[bus]\ninterface = 'udp_multicst'\n", "the bench interface 'udp_multicst' (--bench-interface or [bus] "
                                            "interface) is not a python-can interface; did you mean "
                                            "'udp_multicast'?"),
])
def test_a_bad_profile_is_one_usage_error(tmp_path, profile, words):
    (tmp_path / "p.toml").write_text(profile)
    (tmp_path / "test_x.py").write_text("def test_x(thermal_bench):\n    pass\n")
    proc = pytest_session(tmp_path, "-q", "--bench-profile", "p.toml", "test_x.py")
    assert proc.returncode == 4, proc.stdout + proc.stderr
    assert words in proc.stderr


def test_an_unknown_interface_on_the_command_line_is_one_usage_error(tmp_path):
    (tmp_path / "test_x.py").write_text("def test_x(thermal_bench):\n    pass\n")
    proc = pytest_session(tmp_path, "-q", "--bench-interface", "nosuchiface", "test_x.py")
    assert proc.returncode == 4, proc.stdout + proc.stderr
    assert "the bench interface 'nosuchiface' (--bench-interface or [bus] interface) is not a python-can " \
           "interface; use one of auto, " in proc.stderr


def test_the_entry_point_turns_it_on_and_no_bench_off(tmp_path):
    """The pyproject's pytest11 entry point, as an installed package declares it (a dist-info on the path)."""
    points = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]["pytest11"]
    assert points == {"bench": "bench.pytest_plugin"}
    dist = tmp_path / "site" / "thermal_bench_probe-1.0.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: thermal-bench-probe\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("".join(f"[pytest11]\n{k} = {v}\n" for k, v in points.items()))
    on = pytest_session(tmp_path, "--help", plugin=False, extra_path=tmp_path / "site")
    off = pytest_session(tmp_path, "--help", "-p", "no:bench", plugin=False, extra_path=tmp_path / "site")
    assert on.returncode == 0 and "--bench-engine" in on.stdout and "--bench-profile" in on.stdout
    assert off.returncode == 0 and "--bench-engine" not in off.stdout


@pytest.mark.slow
def test_the_projects_own_tests_collect_with_the_plugin_on(tmp_path):
    import subprocess

    proc = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:bench", "-p", "bench.pytest_plugin",
                           "--collect-only", "-q",
                           "-n", "0", "-p", "no:cacheprovider", "tests/bench/acceptance", "tests/dbc"], cwd=ROOT,
                          env=subprocess_env(), capture_output=True, text=True, timeout=SESSION_TIMEOUT_S)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert " tests collected" in proc.stdout.splitlines()[-1]


ATTACHED_SUITE = '''
def test_attached(thermal_bench):
    result = thermal_bench.run(rows=120)
    assert type(result.summary).__name__ == "RunSummary", result.summary
    assert result.clean and result.passed, result.verdict
    assert result.argv[3] == "host"                      # an attached target: `bench host` made the run
    assert result.metrics.counts.replies == 120 and result.summary.host["rows_sent"] == 120
    assert result.summary.bus.interface == "udp_multicast"
'''


@pytest.mark.slow
def test_an_attached_targets_run_reads_as_the_same_summary(tmp_path, small_dataset, udp_bus):
    """Issue 38: `bench host --json` prints the summary `bench run --json` prints, so the fixture reads a run on an
    attached target with `RunSummary.from_json` as it reads its own (no conversion between two shapes)."""
    import subprocess

    from bench.model.default import default_artifact_path

    with start_target("--model", default_artifact_path(), *udp_bus.to_argv(), stderr=subprocess.PIPE, text=True):
        (tmp_path / "test_suite.py").write_text(ATTACHED_SUITE)
        (tmp_path / "profile.toml").write_text(f'[target]\nattach = true\n[run]\ndata = "{small_dataset}"\n')
        bus = ["--bench-interface", udp_bus.interface, "--bench-channel", str(udp_bus.channel),
               "--bench-bus-kwargs", *(f"{k}={v}" for k, v in udp_bus.kwargs.items())]
        proc = pytest_session(tmp_path, "-q", "--bench-out", "runs", "--bench-profile", "profile.toml", *bus,
                              "test_suite.py")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "1 passed" in proc.stdout
