"""The bench end to end on SocketCAN vcan0: target and host as separate processes on the kernel's CAN bus.

Deselected by default (marker `socketcan`); run with `python3 -m pytest -m socketcan tests/socketcan` where vcan0
exists, or anywhere with tests/vm/run-socketcan-tests (a throwaway VM whose kernel has SocketCAN). Kept short:
Python runs 10-20x slower in that software-emulated VM.
"""

from __future__ import annotations

import json
import subprocess
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from bench.analysis.logdecode import decode_log
from bench.model.default import default_artifact_path
from target_sim.artifact import load_artifact
from target_sim.model import run_offline

from helpers import run_cli as _run_cli
from helpers import start_target

pytestmark = pytest.mark.socketcan

# 10 minutes a command in the emulated VM; a python-can interface configured in the environment must not count
run_cli = partial(_run_cli, timeout=600, can_settings=False)

ROWS = 300
TOLERANCE_C = 0.005 + 1e-9
# lockstep waits this long for each reply: generous, the emulated VM has rare multi-10-ms stalls
REPLY_TIMEOUT = "1.0"


def can_minus_float32(log: Path) -> tuple[int, float]:
    """Rows the log holds and the largest |CAN temperature - offline float32 reference| over them."""
    record = decode_log(log)
    rows, expected = run_offline(load_artifact(default_artifact_path()), record.drive, record.initial)
    return record.rows, float(np.max(np.abs(record.temps[rows] - expected)))


def test_bench_run_on_vcan0_answers_every_step_and_matches_float32(vcan0, small_dataset, tmp_path):
    log = tmp_path / "x.log"
    proc = run_cli("-m", "bench", "run", "--data", str(small_dataset), "--rows", str(ROWS), "-i", "socketcan",
                   "-c", vcan0, "--reply-timeout", REPLY_TIMEOUT, "--json", "--no-report", "--log", str(log))
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert s["bus"] == {"interface": "socketcan", "channel": vcan0}, s["bus"]
    assert (s["steps_sent"], s["replies"], s["missing"]) == (ROWS, ROWS, 0)
    assert s["clean"] and s["problems"] == [], s["problems"]
    assert s["host"]["sequence_gaps"] == 0
    assert set(s["max_abs_can_minus_float32_C"]) == {"yoke", "winding", "tooth", "magnet"}
    assert max(s["max_abs_can_minus_float32_C"].values()) <= TOLERANCE_C
    assert s["log"] == str(log)
    # the candump log decodes on its own, every row answered, and agrees with an offline float32 run
    rows, err = can_minus_float32(log)
    assert rows == ROWS and err <= TOLERANCE_C
    assert decode_log(log).answered.all()


def test_target_sim_and_host_as_separate_processes_on_vcan0(vcan0, small_dataset, tmp_path):
    stats, log = tmp_path / "target.json", tmp_path / "host.log"
    bus = ["-i", "socketcan", "-c", vcan0]
    with start_target("--model", default_artifact_path(), "--stats", stats, *bus, stderr=subprocess.PIPE,
                      text=True) as target:
        host = run_cli("-m", "bench", "host", "--data", str(small_dataset), "--rows", str(ROWS), "--log", str(log),
                       "--reply-timeout", REPLY_TIMEOUT, "--connect-timeout", "120", "--json", *bus)
    target_err = target.stderr    # stopped with SIGTERM as the block ended
    assert host.returncode == 0, host.stderr
    result = json.loads(host.stdout)
    assert (result["rows_sent"], result["replies"], result["missing"], result["sequence_gaps"]) == (ROWS, ROWS, 0, 0)
    assert result["clean"] and result["target_state"] == "STOPPED"
    assert target.returncode == 0, target_err
    counters = json.loads(stats.read_text())
    assert counters["rows_used"] == ROWS and counters["model_steps"] == ROWS * 2 // 5  # 0.2 s rows, 0.5 s steps
    assert counters["errors"] == dict.fromkeys(counters["errors"], 0)
    rows, err = can_minus_float32(log)
    assert rows == ROWS and err <= TOLERANCE_C


def test_auto_interface_picks_socketcan_vcan0(vcan0, small_dataset, tmp_path):
    proc = run_cli("-m", "bench", "run", "--data", str(small_dataset), "--rows", "100", "-i", "auto",
                   "--reply-timeout", REPLY_TIMEOUT, "--no-report", "--log", str(tmp_path / "auto.log"), "--json")
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert s["bus"] == {"interface": "socketcan", "channel": vcan0}, s["bus"]
    assert (s["steps_sent"], s["replies"], s["missing"]) == (100, 100, 0)
    assert s["clean"] and s["problems"] == [], s["problems"]


def test_faults_on_vcan0_are_detected_and_a_killed_target_continues_exactly(vcan0, small_dataset, tmp_path):
    """Bus faults on the host's frames, reply faults from the target and a SIGKILL, on the kernel's CAN bus."""
    log = tmp_path / "faults.log"
    proc = run_cli("-m", "bench", "run", "--data", str(small_dataset), "--rows", str(ROWS), "-i", "socketcan",
                   "-c", vcan0, "--reply-timeout", REPLY_TIMEOUT, "--no-report", "--log", str(log), "--json",
                   "--faults", "drop=0.02,corrupt=0.01,reply_corrupt=0.01,kill=1", "--fault-seed", "3",
                   "--tolerate-faults")
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    faults = s["faults"]
    assert faults["injected"]["kill"] == 1 and faults["injected_total"] >= 5, faults["injected"]
    assert faults["detected"] == faults["injected"] and faults["undetected"] == 0, faults["undetected_faults"]
    assert [r["checkpoint_row"] is not None for r in faults["recoveries"]] == [True]
    assert (s["steps_sent"], s["replies"], s["missing"]) == (ROWS, ROWS, 0)
    # restored from its checkpoint, the restarted target continued exactly: the whole log is the offline float32
    # run from row 0, as if nothing had happened
    rows, err = can_minus_float32(log)
    assert rows == ROWS and err <= TOLERANCE_C
