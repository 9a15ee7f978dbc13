"""A robustness study on a Dask cluster started the way a user starts one: `dask scheduler` and two `dask worker`
processes on localhost, `bench robustness --cluster tcp://…`; one worker is killed (SIGKILL) mid-study: its case
runs again elsewhere, no case is lost, and the table equals a serial run's."""

from __future__ import annotations

import json
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from helpers import ROOT, DaskCluster, subprocess_env

SPEC = """
[study]
seeds = 2
kinds = ["noise", "bias", "initial", "parameter"]
[perturbations.noise]
subjects = ["torque", "coolant"]
[perturbations.bias]
subjects = ["torque", "coolant"]
[perturbations.initial]
subjects = ["all", "magnet", "winding"]
[perturbations.parameter]
subjects = ["C_w", "C_m", "R_wm"]
[filters]
enabled = false
"""


def count(out: Path) -> int:
    try:
        with sqlite3.connect(out / "robustness.sqlite") as db:
            return db.execute("SELECT count(*) FROM cases").fetchone()[0]
    except sqlite3.OperationalError:
        return 0


@pytest.mark.cluster
def test_a_study_on_a_user_started_cluster_survives_a_killed_worker(tmp_path, small_dataset):
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC)
    env = subprocess_env()
    with DaskCluster(tmp_path, workers=2) as cluster:     # the scheduler and both workers up
        workers = cluster.workers
        address = cluster.address
        out = tmp_path / "cluster"
        study = subprocess.Popen([sys.executable, "-m", "bench", "robustness", "--data", str(small_dataset),
                                  "--spec", str(spec), "--out", str(out), "--cluster", address, "--json"],
                                 cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 180
            while count(out) < 2 and time.monotonic() < deadline and study.poll() is None:
                time.sleep(0.05)
            assert study.poll() is None, "the study ended before a worker could be killed"
            workers[0].send_signal(signal.SIGKILL)       # mid-study: it is running a case (one in flight per worker)
            stdout, stderr = study.communicate(timeout=300)   # waits for the survivor to finish every case
        finally:
            if study.poll() is None:                     # a failed wait leaves no study running
                study.kill()
                study.communicate()
        assert study.returncode == 0, stderr
        summary = json.loads(stdout)
        assert summary["not_done"] == 0 and summary["cases"] == count(out) == summary["ran"]
        with sqlite3.connect(out / "robustness.sqlite") as db:
            statuses = {s for (s,) in db.execute("SELECT status FROM cases")}
            workers_seen = {w for (w,) in db.execute("SELECT worker FROM cases")}
        assert statuses == {"done"} and len(workers_seen) == 2
        serial = subprocess.run([sys.executable, "-m", "bench", "robustness", "--data", str(small_dataset), "--spec",
                                 str(spec), "--out", str(tmp_path / "serial"), "--serial", "--json"], cwd=ROOT,
                                env=env, capture_output=True, text=True, timeout=300)
        assert serial.returncode == 0, serial.stderr

        def studies(where: Path) -> list:
            return json.loads((where / "report" / "robustness.json").read_text())["studies"]

        assert studies(out) == studies(tmp_path / "serial")
