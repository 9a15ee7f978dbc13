"""`bench run` and `bench host` with fault options: exit status, JSON summary, log marks, report, errors."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from helpers import ROOT, run_cli

DBC = ROOT / "dbc" / "thermal_bench.dbc"
LATE = "missed their reply deadline without an injected fault"  # a reply later than 50 ms: a loaded machine


def load_only(problems: list[str]) -> bool:
    """True when every problem is a late reply that no fault explains (seen on a heavily loaded machine)."""
    return all(LATE in p for p in problems)


@pytest.fixture(scope="module")
def faulted_run(tmp_path_factory, fault_dataset):
    out = tmp_path_factory.mktemp("faultrun")
    log, report = out / "bench.log", out / "report"
    proc = run_cli("-m", "bench", "run", "--data", str(fault_dataset), "--rows", "400", "--log", str(log),
                   "--report", str(report), "--faults", "drop=0.02,corrupt=0.01,kill=1", "--fault-seed", "2",
                   "--json", "--tolerate-faults")
    return proc, log, report


def test_a_tolerated_faulted_run_exits_0_and_reports_every_fault(faulted_run):
    proc, log, report = faulted_run
    s = json.loads(proc.stdout)
    assert proc.returncode == 0 or load_only(s["problems"]), proc.stderr
    faults = s["faults"]
    assert faults["injected"]["drop"] >= 3 and faults["injected"]["corrupt"] >= 1 and faults["injected"]["kill"] == 1
    assert faults["detected"] == faults["injected"] and faults["undetected"] == 0
    assert faults["marked_in_log"] == faults["injected"]
    assert len(faults["gaps"]) == 1 and faults["gaps_in_log"][0]["rows"] == faults["gaps"][0]["rows"]
    assert (s["steps_sent"], s["replies"], s["missing"]) == (400, 400, 0)
    assert load_only(s["problems"]) and s["clean"] is False  # survived, not clean
    assert max(s["max_abs_can_minus_float32_C"].values()) <= 0.005 + 1e-9
    text = (report / "report.md").read_text()
    assert "## Injected faults" in text and "| kill | 1 | 1 |" in text and "marked gap" in text
    assert (log.with_name(log.name + ".faults.json")).is_file()


def test_the_marks_decode_with_cantools(faulted_run):
    _, log, _ = faulted_run
    decoded = subprocess.run([sys.executable, "-m", "cantools", "decode", str(DBC)], stdin=log.open(),
                             capture_output=True, text=True, timeout=60)
    assert decoded.returncode == 0, decoded.stderr
    out = decoded.stdout
    assert "BenchEvent(" in out and "FaultKind: DROP" in out and "FaultKind: KILL" in out
    assert "Event: TARGET-LOST" in out and "Event: REINIT" in out and "Event: RETRANSMIT" in out


def test_injected_faults_make_the_run_fail_unless_tolerated(fault_dataset, tmp_path):
    proc = run_cli("-m", "bench", "run", "--data", str(fault_dataset), "--rows", "200", "--log",
                   str(tmp_path / "f.blf"), "--no-report", "--fault", "duplicate=0.05", "--fault-seed", "1", "--json")
    assert proc.returncode == 1, proc.stderr
    s = json.loads(proc.stdout)
    assert s["faults"]["injected"]["duplicate"] >= 3 and s["faults"]["undetected"] == 0
    assert "pass --tolerate-faults" in s["problems"][-1] and load_only(s["problems"][:-1])


@pytest.mark.parametrize(("argv", "needle"), [
    (["-m", "bench", "run", "--fault", "bitrot=0.1"], "unknown fault kind 'bitrot'"),
    (["-m", "bench", "run", "--mode", "realtime", "--faults", "drop=0.1,kill=1"], "need lockstep mode"),
    (["-m", "bench", "host", "--data", "x.csv", "--fault", "kill=1"], "need the bench runner"),
])
def test_bad_fault_options_are_one_sentence_exit_2(argv, needle):
    proc = run_cli(*argv, "--quiet")
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and "Traceback" not in proc.stderr


def _analyze(log, tmp_path, *extra: str) -> subprocess.CompletedProcess:
    return run_cli("-m", "bench", "analyze", str(log), "--report", str(tmp_path / "rep"), *extra)


@pytest.mark.slow
def test_analyze_of_a_faulted_log_exits_1_unless_tolerated(faulted_run, tmp_path):
    """As `bench run`: the injected faults marked in the log are a problem unless --tolerate-faults."""
    _, log, _ = faulted_run
    strict = _analyze(log, tmp_path, "--json")
    assert strict.returncode == 1, strict.stderr
    s = json.loads(strict.stdout)
    assert s["faults"]["injected"]["kill"] == 1 and s["faults"]["undetected"] == 0 and s["clean"] is False
    assert "injected fault(s) are marked in the log" in s["problems"][-1], s["problems"]
    assert "pass --tolerate-faults" in s["problems"][-1] and load_only(s["problems"][:-1])
    lines = _analyze(log, tmp_path, "--quiet").stderr.strip().splitlines()  # without --json: one sentence
    assert len(lines) == 1 and lines[0].startswith(f"bench: error: the log {log} is not clean: "), lines
    assert "pass --tolerate-faults" in lines[0] and "Traceback" not in lines[0]
    tolerated = _analyze(log, tmp_path, "--json", "--tolerate-faults")
    t = json.loads(tolerated.stdout)
    assert load_only(t["problems"]) and t["clean"] is False
    assert tolerated.returncode == (1 if t["problems"] else 0), tolerated.stderr


def test_analyze_fails_when_the_sidecar_says_a_fault_went_undetected(faulted_run, tmp_path):
    _, log, _ = faulted_run
    copy = tmp_path / log.name
    copy.write_bytes(log.read_bytes())
    sidecar = json.loads(log.with_name(log.name + ".faults.json").read_text())
    sidecar["undetected"] = 1
    sidecar["undetected_faults"] = [dict(sidecar["injections"][0], detected=False, detected_by=None)]
    copy.with_name(copy.name + ".faults.json").write_text(json.dumps(sidecar))
    proc = _analyze(copy, tmp_path, "--json", "--tolerate-faults")
    assert proc.returncode == 1, proc.stderr
    s = json.loads(proc.stdout)
    assert any("1 injected fault(s) went undetected" in p for p in s["problems"]), s["problems"]


@pytest.mark.slow
def test_replay_of_a_log_with_process_faults_reproduces_every_reply(faulted_run, tmp_path):
    """The recorded target was killed and restored from its checkpoint; the replay's target is not killed but
    gets the same RestoreState/RESTORE, and a restore is exact: every row's final reply comes back identical."""
    _, log, _ = faulted_run
    new_log = tmp_path / "r.blf"
    proc = run_cli("-m", "bench", "replay", str(log), "--log", str(new_log), "--as-fast-as-possible", "--json")
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert s["reproduced"] and s["different"] == 0 and s["missing_in_replay"] == 0, s
    assert s["identical"] == s["recorded_answered"] == s["rows_recorded"]
    assert s["faults_in_log"]["kill"] == 1 and s["rejections_compared"] is False
    assert new_log.exists()


def test_realtime_faults_need_room_for_the_reply_timeout_in_the_sample_interval(fault_dataset, tmp_path):
    log = tmp_path / "f.blf"
    proc = run_cli("-m", "bench", "run", "--data", str(fault_dataset), "--rows", "50", "--mode", "realtime",
                   "--speed", "10", "--faults", "drop=0.1", "--log", str(log), "--no-report", "--quiet")
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "at least 4 reply timeouts (20 ms < 4 x 50 ms)" in lines[0], proc.stderr
    assert not log.exists()
