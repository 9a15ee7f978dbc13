"""Campaigns on a real Dask LocalCluster (scheduler in `bench campaign run`, worker processes spawned by its
nannies), each run a real `bench run` with its own target process and bus port: the table agrees with every run's
own JSON summary, a run whose worker is killed is recorded and retried once, a crashing run is retried once and
recorded as failed, and an interrupted campaign resumes with only the missing runs. Also one run's subprocess on
its own (a timeout, a run that refuses its arguments)."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from bench.campaign.execute import execute_run

from helpers import ROOT, assert_table_equals_files, subprocess_env

ROWS = 200


def start_campaign(spec: Path, out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "bench", "campaign", "run", str(spec), "--out", str(out), *extra],
                            cwd=ROOT, env=subprocess_env(can_settings=False), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def bench_runs_of(out: Path, needle: str = "") -> list[psutil.Process]:
    """The `bench run` processes writing into `out` (their --log is under it), optionally only those whose command
    line holds `needle`."""
    found = []
    for proc in psutil.process_iter(["cmdline"]):
        line = proc.info["cmdline"] or []
        if "bench" in line and "run" in line and any(str(out) in a for a in line) and needle in " ".join(line):
            found.append(proc)
    return found


def rows_of(out: Path) -> dict[str, dict]:
    db = sqlite3.connect(out / "campaign.sqlite")
    db.row_factory = sqlite3.Row
    return {r["run_id"]: dict(r) for r in db.execute("SELECT * FROM runs")}


def faults_of(out: Path, run_id: str) -> dict[str, tuple[int, int]]:
    db = sqlite3.connect(out / "campaign.sqlite")
    return {k: (n, d) for k, n, d in db.execute("SELECT kind, injected, detected FROM faults WHERE run_id = ?",
                                                 (run_id,))}


@pytest.mark.cluster
def test_a_campaign_agrees_with_its_runs_and_retries_a_lost_worker_and_a_crash(tmp_path, small_dataset):
    broken = tmp_path / "broken.csv"
    broken.write_text("time_s,torque_Nm\n0,1\n0.2,2\n")       # no speed, no temperatures: `bench run` refuses it
    spec = tmp_path / "spec.toml"
    spec.write_text(f"""
[fixed]
rows = {ROWS}
report = false
faults = "drop=0.02"
tolerate_faults = true
[axes]
data = ["{small_dataset}", "{broken}"]
model = ["hammerstein", "pv-lptn"]
""")
    out = tmp_path / "out"
    campaign = start_campaign(spec, out, "--workers", "2", "--json")
    # kill the worker process of the first good run it starts (SIGKILL: it cannot stop its children itself)
    victim = None
    deadline = time.monotonic() + 60
    while victim is None and time.monotonic() < deadline and campaign.poll() is None:
        found = bench_runs_of(out, str(small_dataset))
        if found:
            victim = found[0]
            run_dir = Path(next(a for a in victim.cmdline() if a.endswith("bench.blf"))).parent   # <run id>.<attempt>
            worker = psutil.Process(victim.ppid())
            assert "spawn_main" in " ".join(worker.cmdline())          # a worker process of the local cluster
            worker.send_signal(signal.SIGKILL)
        time.sleep(0.05)
    assert victim is not None, "no run started"
    victim.wait(timeout=15)          # the run's process went with its worker (the parent-death signal), or this fails
    stdout, stderr = campaign.communicate(timeout=150)
    assert campaign.returncode == 1, stderr                             # two runs failed
    assert "Traceback" not in stderr
    summary = json.loads(stdout)
    assert summary["counts"] == {"tolerated": 2, "failed": 2} and summary["retried"] == 3
    assert summary["workers"] == 2 and summary["cluster"] == "a local cluster of 2 worker process(es)"

    rows = rows_of(out)
    assert len(rows) == 4
    killed = rows[run_dir.name.rpartition(".")[0]]
    assert (killed["status"], killed["attempts"], killed["verdict"]) == ("done", 2, "tolerated")
    done = {k: r for k, r in rows.items() if r["status"] == "done"}
    failed = {k: r for k, r in rows.items() if r["status"] != "done"}
    assert {r["attempts"] for k, r in done.items() if k != killed["run_id"]} == {1}
    assert not run_dir.exists() and killed["run_dir"] != str(run_dir)     # the killed attempt's files are gone
    assert_table_equals_files(out)
    for row in failed.values():
        assert (row["status"], row["attempts"], row["summary"]) == ("failed", 2, None)
        assert "broken.csv" in row["error"] and row["data"] == str(broken)
    ports = set()
    for run_id, row in done.items():
        own = json.loads((Path(row["run_dir"]) / "summary.json").read_text())    # what `bench run` printed
        assert json.loads(row["summary"]) == own
        assert row["rows_sent"] == own["steps_sent"] == ROWS and row["exit_code"] == 0 and row["clean"] == 0
        assert row["rmse_winding_C"] == own["rmse_C"]["winding"] and row["rmse_pm_C"] == own["rmse_C"]["magnet"]
        assert row["max_can_minus_float32_C"] == max(own["max_abs_can_minus_float32_C"].values()) <= 0.005
        assert row["est_c28x_cycles"] == own["est_cycles"] and row["model_kind"] == own["metrics"]["model"]["kind"]
        assert row["throughput_rows_per_s"] == own["throughput_steps_per_s"]
        injected, detected = own["faults"]["injected"], own["faults"]["detected"]
        assert faults_of(out, run_id) == {k: (injected[k], detected[k]) for k in injected}
        assert row["faults_injected"] == sum(injected.values()) > 0 and row["faults_undetected"] == 0
        log = Path(row["log_path"])
        assert log == Path(row["run_dir"]) / "bench.blf" and log.parent.parent == out.resolve() / "runs"
        assert row["log_sha256"] == hashlib.sha256(log.read_bytes()).hexdigest()
        assert row["worker"].startswith("tcp://127.0.0.1:") and row["wall_s"] > 0
        ports.add(row["bus_port"])
    assert len(ports) == 2 and None not in ports                  # each run on a udp port of its own
    assert {r["model_kind"] for r in done.values()} == {"hammerstein", "pv-lptn"}
    md = (out / "report" / "report.md").read_text()
    assert md.count("| tolerated |") >= 1 and "failed" in md
    assert bench_runs_of(out) == []


@pytest.mark.cluster
def test_an_interrupted_campaign_resumes_with_only_the_missing_runs(tmp_path, small_dataset):
    spec = tmp_path / "spec.toml"
    spec.write_text(f"""
[fixed]
rows = {ROWS}
report = false
data = "{small_dataset}"
[axes]
model = ["hammerstein", "lti-lptn", "pv-lptn"]
""")
    out = tmp_path / "out"
    campaign = start_campaign(spec, out, "--workers", "1")
    deadline = time.monotonic() + 60
    first: dict = {}
    while not first and time.monotonic() < deadline and campaign.poll() is None:
        time.sleep(0.1)
        if (out / "campaign.sqlite").exists():
            try:
                first = rows_of(out)
            except sqlite3.OperationalError:     # the table is being created
                pass
    assert first, "no run ended"
    campaign.send_signal(signal.SIGTERM)
    _, stderr = campaign.communicate(timeout=60)
    assert campaign.returncode == 128 + signal.SIGTERM
    lines = [line for line in stderr.replace("\r", "\n").splitlines() if line.strip() and "run/s" not in line]
    assert lines[-1].startswith("bench: terminated (SIGTERM);") and "Traceback" not in stderr
    deadline = time.monotonic() + 15
    while bench_runs_of(out) and time.monotonic() < deadline:    # the run in progress was stopped too
        time.sleep(0.2)
    assert bench_runs_of(out) == []
    recorded = rows_of(out)
    assert 1 <= len(recorded) < 3 and all(r["status"] == "done" and r["summary"] for r in recorded.values())

    resumed = start_campaign(spec, out, "--workers", "1", "--resume", "--json")
    stdout, stderr = resumed.communicate(timeout=120)
    assert resumed.returncode == 0, stderr
    summary = json.loads(stdout)
    assert (summary["skipped"], summary["ran"]) == (len(recorded), 3 - len(recorded))
    assert summary["counts"] == {"clean": 3}
    final = rows_of(out)
    assert len(final) == 3 and {r["status"] for r in final.values()} == {"done"}
    for run_id, row in recorded.items():                 # the runs done before were not run again
        assert final[run_id]["started_at"] == row["started_at"] and final[run_id]["log_sha256"] == row["log_sha256"]
    assert set(summary["run_ids"]) == set(final)


def _task(tmp_path: Path, dataset: Path, timeout_s: float, *extra: str) -> dict:
    def argv(run_dir: Path) -> list[str]:
        return ["--data", str(dataset), "--rows", "2000", "--no-report", "--log", str(run_dir / "bench.blf"),
                "--json", "--quiet", "-i", "udp_multicast", *extra]

    return {"run_id": "r", "argv": argv, "runs_dir": str(tmp_path / "runs"), "timeout_s": timeout_s, "token": "t"}


@pytest.mark.slow        # 10 s of a real-time run
def test_a_run_that_takes_too_long_is_stopped_and_recorded_as_a_timeout(tmp_path, small_dataset):
    started = time.monotonic()
    # 600 rows at 5 Hz take 120 s; the 10 s limit leaves a loaded machine time to import the CLI and install its
    # SIGTERM handler first (with 4 s it once stopped the child before that, at load average 15)
    result = execute_run(_task(tmp_path, small_dataset, 10.0, "--mode", "realtime"))
    assert result["status"] == "timeout" and result["summary"] is None
    assert result["error"] == "the run took longer than 10 s and was stopped"
    assert time.monotonic() - started < 40
    run_dir = Path(result["run_dir"])
    assert run_dir.parent == tmp_path / "runs" and run_dir.name.startswith("r.")
    assert "terminated (SIGTERM)" in (run_dir / "stderr.txt").read_text()   # it stopped its own way
    assert not (run_dir / "bench.blf").exists()


def test_a_run_that_refuses_its_arguments_is_failed_with_its_sentence(tmp_path, small_dataset):
    result = execute_run(_task(tmp_path, small_dataset, 60.0, "--engine", "fpga"))
    assert (result["status"], result["exit_code"], result["verdict"]) == ("failed", 2, None)
    assert "invalid choice: 'fpga'" in result["error"] and result["worker"].endswith(f":{os.getpid()}")


@pytest.mark.cluster
def test_the_embedded_cluster_says_nothing_when_port_8787_is_taken():
    """The scheduler of a LocalCluster starts an HTTP server even without a dashboard, on 8787 by default: with
    another cluster (or any program) holding that port, dask warned "Port 8787 is already in use" on stderr."""
    import socket
    import warnings

    from bench.campaign.execute import dask_client

    with socket.socket() as holder:
        try:
            holder.bind(("127.0.0.1", 8787))
        except OSError:
            pytest.skip("port 8787 is taken by something else already")   # then the test would prove nothing new
        holder.listen()
        with warnings.catch_warnings(record=True) as caught:   # a command line shows each of them on stderr
            warnings.simplefilter("always")
            with dask_client(1, None) as (client, label):
                assert client.submit(sum, [1, 2]).result(timeout=120) == 3 and "local cluster" in label
    assert [str(w.message) for w in caught if "8787" in str(w.message)] == []
