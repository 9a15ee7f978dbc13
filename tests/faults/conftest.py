"""Fixtures of the fault-injection tests: a small synthetic dataset and run-unique udp_multicast buses."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dbc.transport import BusConfig, resolve

ROOT = Path(__file__).resolve().parents[2]


def synthetic_columns(rows: int, seed: int = 11) -> dict[str, np.ndarray]:
    """A drive-like dataset at 5 Hz: torque and speed random walks, slow coolant/ambient drift."""
    rng = np.random.default_rng(seed)
    t = np.arange(rows) * 0.2
    torque = np.round(np.clip(np.cumsum(rng.normal(0, 25, rows)) + 150, -600, 640), 1)
    speed = np.round(np.clip(np.abs(np.cumsum(rng.normal(0, 120, rows))) + 500, 0, 9000), 0)
    coolant = np.round(40 + 2 * np.sin(t / 40.0), 1)
    ambient = np.round(25 + 0.5 * np.sin(t / 70.0), 1)
    winding = np.round(40 + 30 * (1 - np.exp(-t / 300.0)), 1)
    surface = np.round(40 + 10 * (1 - np.exp(-t / 900.0)), 1)
    return {"time_s": t, "torque_Nm": torque, "speed_rpm": speed, "coolant_C": coolant, "ambient_C": ambient,
            "winding_C": winding, "rotor_surface_C": surface, "pm_C": np.round(surface + 5.0, 1)}


@pytest.fixture(scope="session")
def fault_dataset(tmp_path_factory) -> Path:
    from bench.drive.dataset import write_dataset

    path = tmp_path_factory.mktemp("faultdata") / "drive.csv"
    write_dataset(path, synthetic_columns(700), {"coolant_setpoint_C": 40.0, "note": "synthetic fault-test data"})
    return path


@pytest.fixture
def udp_bus() -> BusConfig:
    return resolve(BusConfig("udp_multicast"), session_unique=True)


def run_cli(*argv: str, timeout: float = 180) -> subprocess.CompletedProcess:
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONUNBUFFERED="1")
    return subprocess.run([sys.executable, *argv], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=timeout)


def bench_run(dataset_path: Path, log: Path, bus: BusConfig, faults=None, *, rows: int, **options):
    """`rows` rows of the dataset through a real target process (the packaged model), then the log decoded and
    analysed: (host result, metrics, decoded log). `options` go to the runner (mode, speed, reply_timeout_s)."""
    from bench.analysis.canmetrics import compute
    from bench.analysis.logdecode import decode_log
    from bench.drive.dataset import load_dataset
    from bench.model.default import default_artifact_path
    from bench.model.runs import drive_matrix, initial_temperatures
    from bench.runner import run_with_target
    from target_sim.artifact import load_artifact

    dataset = load_dataset(dataset_path)
    artifact = load_artifact(default_artifact_path())
    outcome = run_with_target(default_artifact_path(), artifact, bus, drive_matrix(dataset)[:rows],
                              initial_temperatures(dataset), sample_period_s=dataset.sample_period_s, log_path=log,
                              faults=faults, **options)
    record = decode_log(log)
    metrics, _ = compute(record, artifact, dataset)
    return outcome.result, metrics, record
