"""Fixtures of the fault-injection tests: a small synthetic dataset (`udp_bus`: tests/conftest.py), and
`bench_run`, a run through a real target process analysed as `bench run` does."""

from __future__ import annotations

from pathlib import Path

import pytest

from dbc.transport import BusConfig

from helpers import synthetic_columns, write_synthetic_dataset


@pytest.fixture(scope="session")
def fault_dataset(tmp_path_factory) -> Path:
    """700 rows of torque and speed random walks with some load (150 Nm, 500 rpm on average)."""
    columns = synthetic_columns(700, seed=11, torque_sd=25.0, torque_offset=150.0, torque_max=640.0, speed_sd=120.0,
                                speed_offset=500.0, coolant_period=40.0, ambient_period=70.0)
    return write_synthetic_dataset(tmp_path_factory.mktemp("faultdata") / "drive.csv", columns,
                                   "synthetic fault-test data")


def bench_run(dataset_path: Path, log: Path, bus: BusConfig, faults=None, *, rows: int, engine: str = "python",
              **options):
    """`rows` rows of the dataset through a real target process (the packaged model; `engine` "firmware": its
    packaged ELF in the emulated core), then the log decoded and analysed: (host result, metrics, decoded log).
    `options` go to the runner (mode, speed, reply_timeout_s)."""
    from bench.analysis.canmetrics import compute
    from bench.analysis.logdecode import decode_log
    from bench.drive.dataset import load_dataset
    from bench.firmware.images import packaged_elf
    from bench.model.default import default_artifact_path
    from bench.model.runs import drive_matrix, initial_temperatures
    from bench.run.execute import run_with_target
    from target_sim.artifact import load_artifact

    dataset = load_dataset(dataset_path)
    artifact = load_artifact(default_artifact_path())
    firmware = packaged_elf(artifact) if engine == "firmware" else None
    outcome = run_with_target(default_artifact_path(), artifact, bus, drive_matrix(dataset)[:rows],
                              initial_temperatures(dataset), sample_period_s=dataset.sample_period_s, log_path=log,
                              faults=faults, firmware=firmware, **options)
    record = decode_log(log)
    results, _ = compute(record, artifact, dataset)
    metrics = results.to_json()
    return outcome.result, metrics, record
